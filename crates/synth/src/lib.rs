//! Synthetic dot-target images with exact ground truth.
//!
//! A scene is a lattice of elliptical Gaussian dots ([`SceneConfig`]: square or hexagonal, any
//! rotation, missing and defective dots, per-dot jitter) drawn pixel-integrated through
//! [`bostrack_model::add_dot`] on a background with vignetting and dark regions, with read and
//! shot noise and 8/12/16-bit quantisation (or float). [`Scene::reference`] gives the image
//! and its truth ([`TruthDot`]: grid index per docs/CONVENTIONS.md, exact parameters, flags and
//! the exact per-dot Cramér-Rao bound); [`Scene::gradient`] moves and blurs the same dots by a
//! [`FlowConfig`] (uniform, affine, vortex or Gaussian-bump displacement; blur from the
//! displacement's Jacobian as in Rajendran et al. 2020), so a reference/gradient pair has a
//! known answer; [`Scene::frame`] is gradient frame `n` of a campaign (the same dots, its own
//! noise, as `bostrack synth` writes it); [`stack`] gives K no-flow images that differ only by
//! noise.
//!
//! Everything is deterministic for a given seed (derived seeds per site and per image row, so
//! the result does not depend on the number of threads). The crate touches no files: the truth
//! goes out through [`write_truth_csv`] to any `impl Write`.
//!
//! ```
//! use bostrack_synth::{FlowConfig, DisplacementField, Scene, SceneConfig, write_truth_csv};
//! let mut cfg = SceneConfig::default();
//! cfg.width = 64;
//! cfg.height = 64;
//! cfg.seed = 7;
//! let reference = Scene::reference(&cfg).unwrap();
//! assert_eq!(reference.image.width(), 64);
//! assert_eq!(reference.image.meta.saturation, Some(4095.0)); // 12-bit by default
//! // 8 px pitch: about 8 x 8 dots centred on the image, plus partial ones at the edges.
//! let inside = reference.truth.iter().filter(|t| t.centre_inside(64, 64)).count();
//! assert_eq!(inside, 64);
//! let t = &reference.truth[0];
//! assert!(t.crlb_x > 0.0 || t.flags.contains(bostrack_core::DotFlags::BORDER));
//!
//! let flow = FlowConfig { displacement: DisplacementField::Uniform { dx: 0.25, dy: -0.5 }, ..Default::default() };
//! let gradient = Scene::gradient(&cfg, &flow).unwrap();
//! let dx = gradient.truth[10].params.x0 - reference.truth[10].params.x0;
//! assert!((dx - 0.25).abs() < 1e-12);
//!
//! let mut csv = Vec::new();
//! write_truth_csv(&mut csv, &reference.truth).unwrap();
//! assert!(String::from_utf8(csv).unwrap().starts_with("i,j,x,y,sigma_x,sigma_y,rho,amplitude,background,flags"));
//! ```

mod config;
mod error;
mod field;
mod render;
mod rng;
mod scene;
mod truth;

pub use bostrack_model::Sampling;
pub use config::{
    BackgroundConfig, DarkRegion, DefectConfig, DefectKind, DisplacementField, DotConfig,
    FlowConfig, LatticeConfig, LatticeKind, MaskConfig, NoiseConfig, RenderConfig, SceneConfig,
    TruthConfig,
};
pub use error::SynthError;
pub use field::{FieldValue, apply_flow};
pub use render::{add_noise, render, render_mean, scene_mask};
pub use scene::{Scene, lattice_for, layout, stack};
pub use truth::{TRUTH_CSV_COLUMNS, TruthDot, compute_bounds, read_truth_csv, write_truth_csv};

#[cfg(test)]
mod crlb_tests;
#[cfg(test)]
mod tests;
