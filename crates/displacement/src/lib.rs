//! Per-dot displacement, amplification ratio and displacement uncertainty of a reference /
//! gradient image pair.
//!
//! For one dot fitted in both images (docs/CONVENTIONS.md, docs/paper/NOTES.md):
//!
//! - displacement `d = x_grad - x_ref` (px), `x_ref` the reference fit or the no-flow stack mean
//!   ([`ReferencePosition`]);
//! - amplification ratio AR: by default ([`ArVariant::Bounds`]) the ratio of the two fits' exact
//!   per-dot Cramér-Rao bounds, `crlb_grad / crlb_ref` per axis (`bostrack_model::bound_ratio`),
//!   which holds under read and shot noise; or ([`ArVariant::Notes`]) the closed form of NOTES.md
//!   §2 (the paper's Eq. 37 corrected), from the continuum bound
//!   `var(x0) = (2/π) (σn/I0)² (σx/σy) / sqrt(1 - ρ²)` for the same noise in both images:
//!
//!   `AR_x = (I0_ref/I0_grad) · sqrt((σx_grad/σx_ref)(σy_ref/σy_grad)) · ((1-ρ_ref²)/(1-ρ_grad²))^(1/4)`,
//!
//!   `AR_y` with x and y exchanged (`bostrack_model::amplification_ratio`), equal to the ratio
//!   of the bounds for untruncated dots under signal-independent noise but over-stating AR for
//!   dimmer, blurred dots under shot noise; the published variant only as the named option
//!   [`ArVariant::Published`];
//! - `u_grad = AR · u_ref` per axis, with `u_ref` the single-image reference position
//!   uncertainty from a no-flow stack (`bostrack-uncertainty`);
//! - `u_d = sqrt(u_refpos² + u_grad²)`, `u_refpos = u_ref` (one reference image) or
//!   `u_ref/sqrt(K)` (reference position = mean of K stack images).
//!
//! [`pair_dot`] returns a [`PairDot`] whose absent quantities are `None` (no stack: no `u_*`;
//! not requested: see [`Quantities`]); [`to_row`] writes it as the strings of [`COLUMNS`].
//!
//! ```
//! use bostrack_core::{DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex};
//! use bostrack_displacement::{
//!     ArVariant, DisplacementConfig, PairInput, ReferenceStats, COLUMNS, pair_dot, to_row,
//! };
//! let fit = |x0: f64, amplitude: f64, sigma: f64| DotFit {
//!     index: GridIndex::new(3, 4),
//!     params: Gaussian2D::circular(x0, 20.0, amplitude, sigma, 100.0),
//!     crlb_x: 0.01,
//!     crlb_y: 0.01,
//!     rms: 5.0,
//!     iterations: 6,
//!     status: FitStatus::Converged,
//!     flags: DotFlags::NONE,
//! };
//! let r = fit(10.0, 1000.0, 1.5);
//! // half as bright: under read noise its bound is twice the reference's
//! let g = DotFit { crlb_x: 0.02, crlb_y: 0.02, ..fit(10.25, 500.0, 1.5) };
//! let stack = ReferenceStats { images: 10, mean: Some([10.0, 20.0]), u: Some([0.02, 0.02]) };
//! let input = PairInput { reference: Some(&r), gradient: Some(&g), stack: Some(stack), flags: DotFlags::NONE };
//! let p = pair_dot(&input, &DisplacementConfig::default()).unwrap();
//! assert_eq!(p.displacement, Some([0.25, 0.0]));
//! assert_eq!(p.ar, Some([2.0, 2.0])); // crlb_grad / crlb_ref
//! let notes = DisplacementConfig { ar_variant: ArVariant::Notes, ..DisplacementConfig::default() };
//! assert_eq!(pair_dot(&input, &notes).unwrap().ar, Some([2.0, 2.0])); // I0_ref / I0_grad
//! let u_d = p.u_d.unwrap()[0]; // sqrt(0.02² + (2 · 0.02)²)
//! assert!((u_d - 0.02 * 5f64.sqrt()).abs() < 1e-15);
//! let row = to_row(&p);
//! assert_eq!(row.len(), COLUMNS.len());
//! assert_eq!((row[6].as_str(), row[16].as_str(), row[28].as_str()), ("0.250000", "2.000000", "true"));
//! ```

mod csv;
mod pair;

pub use bostrack_model::ArVariant;
pub use csv::{COLUMNS, DECIMALS, to_row, write_row};
pub use pair::{
    ArShapes, DisplacementConfig, PairDot, PairInput, Quantities, ReferencePosition,
    ReferenceSource, ReferenceStats, pair_dot, pair_dot_at, pair_dots, pixel_blurred,
};
