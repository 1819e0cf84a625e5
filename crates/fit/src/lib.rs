//! Fit every dot: the elliptical least-squares Gaussian engine and cheaper estimators.
//!
//! [`fit_dots`] fits every seed's window of an image (rayon over dots, output in seed order)
//! and returns one [`DotFit`](bostrack_core::DotFit) per seed: the 7 parameters of
//! docs/CONVENTIONS.md, the exact per-dot Cramér-Rao bound of the position (`crlb_x`,
//! `crlb_y`, from the fitted parameters, the noise model and the pixels actually used), the
//! residual rms, a [`FitStatus`](bostrack_core::FitStatus) and [`DotFlags`](bostrack_core::DotFlags).
//! [`fit_window`] / [`Fitter`] fit one window. [`estimate_noise`] and [`noise_from_stack`] give
//! the read + shot noise model from one image or a no-flow stack. [`study`] measures error
//! against run time of every estimator.
//!
//! Design (details and measured numbers in `crates/fit/README.md`):
//! - **Models**: elliptical (7 parameters), axis-aligned (ρ = 0) and circular, each
//!   point-sampled or pixel-integrated ([`FitConfig`]).
//! - **Parameterisation** `[x0, y0, A, ln σx, ln σy, atanh ρ, B]`: σ > 0 and |ρ| < 1 hold by
//!   construction; box bounds σ ∈ [0.1 px, window side], |ρ| ≤ 0.999 and no narrower than
//!   0.1 px along the ellipse's minor axis, A > 0 (a fit ending on one is flagged
//!   `AT_BOUND`); a step that takes the centre out of the window is rejected.
//! - **Fast solver**: Levenberg-Marquardt with Marquardt scaling, the normal equations built in
//!   one fused pass per trial point (the trial's cost, and its normal matrix for the next step).
//!   Every derivative is a combination of `E·{1, X, Y, X², XY, Y²}`, so for the point-sampled
//!   model the normal matrix is assembled from moments `Σ E^k X^m Y^n` accumulated as row sums
//!   (14 multiply-adds per pixel), and `E` over the window costs 8 values of `exp` (multiplicative
//!   recurrences along rows and from row to row). Fixed-size arrays, no allocation per dot.
//! - **Weights**: `1 / variance(model)` of the [`NoiseModel`](bostrack_core::NoiseModel), so the
//!   final normal matrix is the Fisher matrix and its inverse gives the bound for free.
//! - **Neighbours**: with [`Neighbours::Subtract`] every dot is refitted after its neighbours'
//!   fitted dots were subtracted from its window (block Jacobi, `neighbour_passes` times).
//!
//! ```
//! use bostrack_core::{DotFlags, FitStatus, Gaussian2D, GridIndex, Image, NoiseModel, Seed, Window};
//! use bostrack_fit::{FitConfig, fit_dots};
//! use bostrack_model::{Sampling, add_dot};
//!
//! // two dots 8 px apart on a 24 x 16 image
//! let truth = [(7.3, 7.6), (15.2, 7.9)];
//! let mut data = vec![100.0; 24 * 16];
//! for &(x0, y0) in &truth {
//!     let g = Gaussian2D { x0, y0, amplitude: 1000.0, sigma_x: 1.6, sigma_y: 1.4, rho: 0.2, background: 0.0 };
//!     add_dot(&g, Window::new(0, 0, 24, 16), Sampling::Integrated, &mut data);
//! }
//! let img = Image::from_fn(24, 16, |x, y| data[y * 24 + x]);
//! let seeds: Vec<Seed> = truth
//!     .iter()
//!     .enumerate()
//!     .map(|(k, &(x, y))| {
//!         let c = [x.round(), y.round()];
//!         Seed { index: GridIndex::new(k as i32, 0), predicted: c, centre: c, window: Window::centred(c[0], c[1], 4), flags: DotFlags::NONE }
//!     })
//!     .collect();
//! let fits = fit_dots(&img, None, &seeds, &FitConfig::default(), &NoiseModel::read(10.0)).unwrap();
//! for (f, &(x0, y0)) in fits.iter().zip(&truth) {
//!     assert_eq!(f.status, FitStatus::Converged);
//!     assert!((f.params.x0 - x0).abs() < 1e-4 && (f.params.y0 - y0).abs() < 1e-4);
//!     assert!(f.crlb_x > 0.0 && f.crlb_x < 0.02);
//! }
//! ```

mod config;
mod coupling;
mod dots;
mod error;
mod eval;
mod fit;
mod joint;
mod lmcrate;
mod noise;
mod simd;
mod solver;
mod start;
pub mod study;

pub use config::{
    AUTO_SIGMA, Estimator, FitConfig, FitSampling, MAX_ITERATIONS, MAX_NEIGHBOUR_PASSES,
    Neighbours, Solver,
};
pub use dots::{
    FitMemory, NeighbourTails, PassReport, TAILS_MAX_SHIFT, fit_dots, fit_dots_remembered,
    fit_dots_report, refit_dots, refit_dots_remembered, refit_dots_report,
};
pub use error::FitError;
pub use fit::{Fitter, WindowSamples, fit_window};
pub use noise::{
    NoiseBin, NoiseFit, estimate_noise, estimate_noise_detailed, noise_from_stack,
    noise_from_stack_detailed,
};
