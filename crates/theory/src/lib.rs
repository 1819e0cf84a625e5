//! The paper as code: Rajendran, Bane & Vlachos, "Uncertainty amplification due to
//! density/refractive-index gradients in volumetric PTV and BOS experiments" (Exp. Fluids 61:139,
//! 2020), Sections 2 and 3, with the corrections of `docs/paper/NOTES.md`
//! (docs/theory.md walks through them equation by equation).
//!
//! - [`optics`](magnification) functions: magnification (Eq. 5), shift sensitivity and
//!   apparent displacement (Eq. 6, 18), viewing direction (Eq. 9-10), cone angle (Eq. 24).
//! - The effective dot (Eq. 11-29): [`blur_covariance`] (Eq. 25-26 *and* the cross term, so ρ
//!   is predicted), [`EffectiveDot`], [`peak_from_exposure`] (Eq. 29).
//! - The bound: [`eq35`], [`eq35_rho`] (NOTES.md §2), and the exact discrete bound of the
//!   predicted pixel-integrated dot ([`exact_bound`], through `bostrack_model::crlb`).
//! - [`Setup`] (a TOML-friendly experiment description) → [`predict`] → [`Prediction`] (shift,
//!   shape, bounds, amplification ratio, [`TheoryFlags`]); [`sweep_f_number`] and [`sweep_z_d`]
//!   for experiment design.
//! - [`ray_trace`]: a dot rendered from rays through the density field, the check of the model.
//!
//! No filesystem access: callers read setup files and pass the text to [`Setup::from_toml`].
//!
//! ```
//! use bostrack_theory::{Setup, predict};
//! let setup = Setup::from_toml(r#"
//!     [optics]
//!     f_number = 11.0
//!     focal_length_mm = 105.0
//!     target_distance_m = 1.5
//!     diffraction_diameter_px = 6.0
//!     [geometry]
//!     kind = "bos"
//!     z_d_m = 0.5
//!     delta_z_m = 0.05
//!     [flow]
//!     gradient_kg_m4 = [30.0, 0.0, 0.0]
//!     hessian_kg_m5 = { xx = 20000.0 }
//! "#).unwrap();
//! let p = predict(&setup).unwrap();
//! // the dot moves against the gradient by S ∂ρ/∂x, S = M K Z_D Δz / (n0 d_r) px per kg/m⁴
//! assert!((p.shift_x + 30.0 * p.sensitivity_px).abs() < 1e-12 && p.shift_y == 0.0);
//! // curvature along x blurs the dot along x only: the bound grows along x
//! assert!(p.sigma_x > p.reference.sigma_x && p.sigma_y == p.reference.sigma_y);
//! assert!(p.ar_x > 1.0 && p.crlb_x > p.crlb_ref_x);
//! assert!(p.flags.is_empty());
//! // without flow, nothing happens
//! let r = predict(&setup.reference()).unwrap();
//! assert_eq!((r.shift_x, r.ar_x, r.ar_y), (0.0, 1.0, 1.0));
//! ```

mod bounds;
mod effective;
mod error;
mod flags;
mod optics;
mod predict;
mod raytrace;
mod setup;
mod sweep;

pub use bounds::{
    MAX_HALF_WIDTH, MIN_HALF_WIDTH, WINDOW_SIGMAS, bound_window, eq35, eq35_rho, exact_bound,
};
pub use effective::{
    EffectiveDot, blur_covariance, covariance_to_shape, effective_covariance, peak_from_exposure,
};
pub use error::TheoryError;
pub use flags::TheoryFlags;
pub use optics::{
    Aperture, ConeAngle, ConeAngleModel, GLADSTONE_DALE_AIR, Hessian, N0_AIR,
    apparent_displacement, bos_sensitivity, camera_gradient, camera_hessian, cone_angle_eq24,
    cone_angle_geometric, diffraction_diameter, magnification, rotation_matrix,
    volumetric_sensitivity,
};
pub use predict::{Prediction, predict, prediction_json};
pub use raytrace::{DotMoments, Propagation, RayTrace, RayTraceConfig, ray_trace};
pub use setup::{Camera, Constants, Flow, Geometry, Optics, Setup, View};
pub use sweep::{ExposureScaling, SweepRow, ZdHold, sweep_f_number, sweep_z_d};
