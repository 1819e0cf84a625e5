//! From a setup to the predicted dot and its bounds.

use crate::TheoryError;
use crate::bounds::{bound_window, eq35, eq35_rho, exact_bound};
use crate::effective::{EffectiveDot, blur_covariance};
use crate::flags::TheoryFlags;
use crate::optics::{
    ConeAngleModel, apparent_displacement, bos_sensitivity, camera_gradient, camera_hessian,
    cone_angle_eq24, cone_angle_geometric, volumetric_sensitivity,
};
use crate::setup::{Design, PathGeometry, Setup};
use bostrack_core::{Gaussian2D, Window};
use bostrack_model::{ArVariant, amplification_ratio};
use serde::{Deserialize, Serialize};

/// Geometric (full) cone angle beyond which the small-angle assumption is flagged (rad, 2°).
const WIDE_CONE_RAD: f64 = 0.035;
/// Relative change of the cone angle by Eq. 24's gradient term beyond which it is flagged.
const CONE_CORRECTION: f64 = 0.25;
/// Displacement gradient (px/px) beyond which the lens effect on a finite dot is flagged.
const LENSING: f64 = 0.1;
/// Smallest sigma for which the closed form holds (px, NOTES.md §3).
const UNDERSAMPLED_SIGMA: f64 = 0.8;

/// The prediction as one JSON object (`bostrack crlb --json`, Python's `bostrack.crlb`): every
/// field of [`Prediction`] (NaN as null), `setup` (the file) and the displacement uncertainty of
/// one pair `u_d_x`, `u_d_y` = √(crlb_ref² + crlb²) (px).
pub fn prediction_json(
    p: &Prediction,
    setup: &std::path::Path,
) -> Result<serde_json::Value, serde_json::Error> {
    let mut v = serde_json::to_value(p)?;
    if let Some(obj) = v.as_object_mut() {
        obj.insert("setup".into(), setup.display().to_string().into());
        obj.insert("u_d_x".into(), p.crlb_ref_x.hypot(p.crlb_x).into());
        obj.insert("u_d_y".into(), p.crlb_ref_y.hypot(p.crlb_y).into());
    }
    Ok(v)
}

/// Everything the theory predicts for one dot of a [`Setup`]. Lengths in px unless a name says
/// otherwise; bounds are standard deviations (px).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Prediction {
    /// |M| (Eq. 5).
    pub magnification: f64,
    /// f-number.
    pub f_number: f64,
    /// Shift sensitivity S: px of shift per kg/m⁴ of path-averaged gradient (Eq. 6).
    pub sensitivity_px: f64,
    /// Geometric cone angle `M / ((1+M) f#)` (rad).
    pub cone_angle_geometric_rad: f64,
    /// Cone angle used for the blur (Eq. 24 or geometric, after clamping) (rad).
    pub cone_angle_rad: f64,
    /// Diffraction diameter 4η (px).
    pub diffraction_diameter_px: f64,
    /// Diameter 4σ_ref of the reference dot (diffraction and printed dot) (px).
    pub reference_diameter_px: f64,
    /// Camera-frame transverse density gradient `[∂ρ/∂x', ∂ρ/∂y']` (kg/m⁴) (Eq. 10).
    pub gradient_camera: [f64; 2],
    /// Camera-frame transverse second derivatives `[ρxx', ρxy', ρyy']` (kg/m⁵).
    pub hessian_camera: [f64; 3],
    /// Centroid shift (px), Eq. 18: `-S ∇⊥ρ`.
    pub shift_x: f64,
    pub shift_y: f64,
    /// Effective dot shape (Eqs. 25-26 and the cross term).
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
    /// Diameters 4σ (px).
    pub diameter_x: f64,
    pub diameter_y: f64,
    /// Blur covariance `[Σxx, Σxy, Σyy]` (px²).
    pub blur_covariance: [f64; 3],
    /// Gradient of the displacement field over the target, `∂(shift)/∂(image position)`
    /// (px/px, rows: shift x, y): `-S d_r (1 - Z_D/Z_T) H / M` (S in px per kg/m⁴, d_r the
    /// pixel pitch) for BOS with a known target distance (the chief rays of neighbouring target
    /// points cross the field `(1 - Z_D/Z_T)` times their spacing apart), `-S d_r H / M`
    /// otherwise; `K Z_D Δz H / n0` for a distant camera. The lens effect
    /// that stretches a finite dot; not part of the effective model.
    pub displacement_gradient: [[f64; 2]; 2],
    /// Exposure α0 (counts·px²), the same in both images (Eq. 28).
    pub exposure: f64,
    /// Peak of the gradient dot above background (counts), Eq. 29.
    pub peak: f64,
    /// The reference (no-flow) dot and the predicted gradient dot.
    pub reference: Gaussian2D,
    pub gradient: Gaussian2D,
    /// Exact discrete bound of the gradient dot (pixel-integrated, 7 free parameters, over
    /// `window`) (px); NaN with flag `bound_singular` if singular.
    pub crlb_x: f64,
    pub crlb_y: f64,
    /// Exact bound of the reference dot (over `reference_window`) (px).
    pub crlb_ref_x: f64,
    pub crlb_ref_y: f64,
    /// Closed form of the gradient dot: Eq. 35 generalised to ρ (NOTES.md §2) (px).
    pub eq35_x: f64,
    pub eq35_y: f64,
    /// Eq. 35 as printed (ρ ignored) (px).
    pub eq35_printed_x: f64,
    pub eq35_printed_y: f64,
    /// Closed form of the reference dot (Eq. 36) (px).
    pub eq35_ref: f64,
    /// Amplification ratio of NOTES.md §2 (`bostrack_model::amplification_ratio`, Notes
    /// variant) between the reference and the gradient dot.
    pub ar_x: f64,
    pub ar_y: f64,
    /// Ratio of the exact bounds, gradient over reference.
    pub ar_exact_x: f64,
    pub ar_exact_y: f64,
    /// Windows of the exact bounds.
    pub window: Window,
    pub reference_window: Window,
    pub flags: TheoryFlags,
}

/// Predict the dot of a setup: validate, then [`Prediction`].
pub fn predict(setup: &Setup) -> Result<Prediction, TheoryError> {
    Design::from_setup(setup).map(|d| predict_design(&d))
}

pub(crate) fn predict_design(d: &Design) -> Prediction {
    let mut flags = TheoryFlags::NONE;
    let sensitivity_m = match d.geometry {
        PathGeometry::Bos { z_d, delta_z } => bos_sensitivity(d.m, d.k, d.n0, z_d, delta_z),
        PathGeometry::Volumetric { depth } => volumetric_sensitivity(d.m, d.k, d.n0, depth),
    };
    let s_px = sensitivity_m / d.pitch_m;
    let g3 = camera_gradient(&d.rotation, d.gradient);
    let h3 = camera_hessian(&d.rotation, &d.hessian);
    let g = [g3[0], g3[1]];
    let h = [h3.xx, h3.xy, h3.yy];

    // Eq. 24
    let geometric = cone_angle_geometric(d.f_number, d.m);
    let cone = match d.cone_model {
        ConeAngleModel::Paper => {
            let c = cone_angle_eq24(d.f_number, d.m, d.k, d.n0, d.geometry.path(), g);
            if c.clamped {
                flags.insert(TheoryFlags::CONE_CLAMPED);
            }
            if (c.value - geometric).abs() > CONE_CORRECTION * geometric {
                flags.insert(TheoryFlags::CONE_CORRECTED);
            }
            c.value
        }
        ConeAngleModel::Geometric => geometric,
    };
    if geometric > WIDE_CONE_RAD {
        flags.insert(TheoryFlags::WIDE_CONE);
    }

    // Eqs. 18, 25-26 (+ cross term), 29
    let shift = apparent_displacement(s_px, g);
    let blur = blur_covariance(s_px, d.geometry.lever(), cone, d.aperture, h);
    let sigma_ref = d.sigma_ref();
    let exposure = d.exposure();
    let dot = EffectiveDot::new(shift, sigma_ref, blur, exposure);
    let refdot = EffectiveDot::new([0.0; 2], sigma_ref, [0.0; 3], exposure);
    if blur[0] > sigma_ref * sigma_ref || blur[2] > sigma_ref * sigma_ref {
        flags.insert(TheoryFlags::NON_GAUSSIAN);
    }
    if dot.sigma_x.min(dot.sigma_y) < UNDERSAMPLED_SIGMA {
        flags.insert(TheoryFlags::UNDERSAMPLED);
    }

    // lens effect of the field on a finite dot
    let spread = match (d.geometry, d.target_distance_m) {
        (PathGeometry::Bos { z_d, .. }, Some(zt)) => 1.0 - z_d / zt,
        _ => 1.0,
    };
    let lg = -s_px * spread * d.pitch_m / d.m;
    let displacement_gradient = [[lg * h[0], lg * h[1]], [lg * h[1], lg * h[2]]];
    if displacement_gradient
        .iter()
        .flatten()
        .any(|v| v.abs() > LENSING)
    {
        flags.insert(TheoryFlags::LENSING);
    }

    // bounds
    let reference = refdot.gaussian(d.position, d.background);
    let gradient = dot.gaussian(d.position, d.background);
    let noise = d.noise();
    let (window, capped) = bound_window(&gradient, d.window_half);
    let (reference_window, capped_ref) = bound_window(&reference, d.window_half);
    if capped || capped_ref {
        flags.insert(TheoryFlags::WINDOW_CAPPED);
    }
    let exact = exact_bound(&gradient, window, &noise);
    let exact_ref = exact_bound(&reference, reference_window, &noise);
    if exact.is_none() || exact_ref.is_none() {
        flags.insert(TheoryFlags::BOUND_SINGULAR);
    }
    let exact = exact.unwrap_or([f64::NAN; 2]);
    let exact_ref = exact_ref.unwrap_or([f64::NAN; 2]);
    let closed = eq35_rho(d.read_noise, exposure, dot.sigma_x, dot.sigma_y, dot.rho);
    let printed = eq35(d.read_noise, exposure, dot.sigma_x, dot.sigma_y);
    let closed_ref = eq35(d.read_noise, exposure, sigma_ref, sigma_ref)[0];
    let ar = amplification_ratio(&reference, &gradient, ArVariant::Notes);

    Prediction {
        magnification: d.m,
        f_number: d.f_number,
        sensitivity_px: s_px,
        cone_angle_geometric_rad: geometric,
        cone_angle_rad: cone,
        diffraction_diameter_px: d.diffraction_diameter_px(),
        reference_diameter_px: 4.0 * sigma_ref,
        gradient_camera: g,
        hessian_camera: h,
        shift_x: shift[0],
        shift_y: shift[1],
        sigma_x: dot.sigma_x,
        sigma_y: dot.sigma_y,
        rho: dot.rho,
        diameter_x: 4.0 * dot.sigma_x,
        diameter_y: 4.0 * dot.sigma_y,
        blur_covariance: blur,
        displacement_gradient,
        exposure,
        peak: dot.peak,
        reference,
        gradient,
        crlb_x: exact[0],
        crlb_y: exact[1],
        crlb_ref_x: exact_ref[0],
        crlb_ref_y: exact_ref[1],
        eq35_x: closed[0],
        eq35_y: closed[1],
        eq35_printed_x: printed[0],
        eq35_printed_y: printed[1],
        eq35_ref: closed_ref,
        ar_x: ar[0],
        ar_y: ar[1],
        ar_exact_x: exact[0] / exact_ref[0],
        ar_exact_y: exact[1] / exact_ref[1],
        window,
        reference_window,
        flags,
    }
}
