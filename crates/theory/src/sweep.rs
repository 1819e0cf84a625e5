//! Experiment-design sweeps (paper Sec. 2.3): the bound against the f-number, and against the
//! target-field distance Z_D at fixed shift sensitivity M·Z_D or at fixed magnification.

use crate::TheoryError;
use crate::error::{invalid, positive};
use crate::flags::TheoryFlags;
use crate::predict::{Prediction, predict_design};
use crate::setup::{Brightness, Design, PathGeometry, Setup};
use serde::{Deserialize, Serialize};

/// How the dot's exposure follows the optics in a sweep.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ExposureScaling {
    /// The exposure stays that of the setup (the illumination is adjusted to compensate).
    #[default]
    Fixed,
    /// Fixed illumination and a fixed dot image size: the exposure follows the image-plane
    /// irradiance of a lens, `∝ 1 / (f#² (1 + M)²)`.
    Aperture,
}

/// What a Z_D sweep holds fixed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ZdHold {
    /// The shift sensitivity `M·Z_D`: `M = M0 Z_D0 / Z_D` (another focal length at the same
    /// target distance). The shift is unchanged; the blur's lever and cone change.
    #[default]
    Sensitivity,
    /// The magnification: the sensitivity, the shift and the blur (∝ Z_D²) all grow with Z_D;
    /// the ratio of shift to displacement uncertainty has an optimum.
    Magnification,
}

/// One row of a sweep: the swept optics and the main predictions (flat, for CSV).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepRow {
    pub f_number: f64,
    pub magnification: f64,
    /// Z_D (m); empty for a volumetric setup.
    pub z_d_m: Option<f64>,
    /// M·Z_D (m); empty for a volumetric setup.
    pub m_z_d_m: Option<f64>,
    /// px per kg/m⁴.
    pub sensitivity_px: f64,
    pub cone_angle_rad: f64,
    pub exposure: f64,
    pub reference_diameter_px: f64,
    pub shift_x: f64,
    pub shift_y: f64,
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
    pub crlb_x: f64,
    pub crlb_y: f64,
    pub crlb_ref_x: f64,
    pub crlb_ref_y: f64,
    pub eq35_x: f64,
    pub eq35_y: f64,
    pub eq35_ref: f64,
    pub ar_x: f64,
    pub ar_y: f64,
    pub ar_exact_x: f64,
    pub ar_exact_y: f64,
    /// Displacement uncertainty of one reference/gradient pair from the exact bounds,
    /// `u_d = sqrt(crlb_ref² + crlb²)` (NOTES.md §4) (px).
    pub u_d_x: f64,
    pub u_d_y: f64,
    /// Shift over its uncertainty, `|shift| / u_d`, per axis: the measurement's
    /// signal-to-noise ratio.
    pub snr_x: f64,
    pub snr_y: f64,
    pub flags: TheoryFlags,
}

impl SweepRow {
    fn new(d: &Design, p: &Prediction) -> Self {
        let z_d = match d.geometry {
            PathGeometry::Bos { z_d, .. } => Some(z_d),
            PathGeometry::Volumetric { .. } => None,
        };
        SweepRow {
            f_number: d.f_number,
            magnification: d.m,
            z_d_m: z_d,
            m_z_d_m: z_d.map(|z| z * d.m),
            sensitivity_px: p.sensitivity_px,
            cone_angle_rad: p.cone_angle_rad,
            exposure: p.exposure,
            reference_diameter_px: p.reference_diameter_px,
            shift_x: p.shift_x,
            shift_y: p.shift_y,
            sigma_x: p.sigma_x,
            sigma_y: p.sigma_y,
            rho: p.rho,
            crlb_x: p.crlb_x,
            crlb_y: p.crlb_y,
            crlb_ref_x: p.crlb_ref_x,
            crlb_ref_y: p.crlb_ref_y,
            eq35_x: p.eq35_x,
            eq35_y: p.eq35_y,
            eq35_ref: p.eq35_ref,
            ar_x: p.ar_x,
            ar_y: p.ar_y,
            ar_exact_x: p.ar_exact_x,
            ar_exact_y: p.ar_exact_y,
            u_d_x: p.crlb_ref_x.hypot(p.crlb_x),
            u_d_y: p.crlb_ref_y.hypot(p.crlb_y),
            snr_x: p.shift_x.abs() / p.crlb_ref_x.hypot(p.crlb_x),
            snr_y: p.shift_y.abs() / p.crlb_ref_y.hypot(p.crlb_y),
            flags: p.flags,
        }
    }
}

/// The exposure of `d` relative to `base` under `scaling`.
fn rescale(base: &Design, d: &mut Design, scaling: ExposureScaling) {
    let e = base.exposure();
    let f = match scaling {
        ExposureScaling::Fixed => 1.0,
        ExposureScaling::Aperture => {
            (base.f_number * (1.0 + base.m) / (d.f_number * (1.0 + d.m))).powi(2)
        }
    };
    d.brightness = Brightness::Exposure(e * f);
}

/// The bound against the f-number (Sec. 2.3: a larger f# narrows the ray cone, hence the blur,
/// but enlarges the diffraction spot and, at fixed illumination, darkens the dot). Everything
/// else is the setup's; the diffraction diameter follows `2.44 f# (M+1) λ` (or scales ∝ f# when
/// given in px); the printed dot's image does not change.
pub fn sweep_f_number(
    setup: &Setup,
    f_numbers: &[f64],
    exposure: ExposureScaling,
) -> Result<Vec<SweepRow>, TheoryError> {
    let base = Design::from_setup(setup)?;
    f_numbers
        .iter()
        .map(|&f| {
            let mut d = base.clone();
            d.f_number = positive("sweep f_number", f)?;
            rescale(&base, &mut d, exposure);
            Ok(SweepRow::new(&d, &predict_design(&d)))
        })
        .collect()
}

/// The bound against Z_D, the distance from the target to the density field (Sec. 2.3's
/// sensitivity/precision trade-off). Each row moves the slab (thickness unchanged) to `Z_D` and,
/// with [`ZdHold::Sensitivity`], sets `M = M0 Z_D0 / Z_D` so that the shift sensitivity `M·Z_D`
/// and the shift stay those of the setup, while the ray cone `M/((1+M) f#)`, the diffraction
/// spot (∝ M+1) and the lever of the blur (Z_D) change; with [`ZdHold::Magnification`], M stays
/// and the shift grows ∝ Z_D, the blur ∝ Z_D². The printed dot's image size is held (a target
/// printed for the magnification). BOS setups only; with a known target distance every slab must
/// stay between target and lens.
pub fn sweep_z_d(
    setup: &Setup,
    z_d: &[f64],
    hold: ZdHold,
    exposure: ExposureScaling,
) -> Result<Vec<SweepRow>, TheoryError> {
    let base = Design::from_setup(setup)?;
    let PathGeometry::Bos { z_d: z0, delta_z } = base.geometry else {
        return Err(TheoryError::Unsupported(
            "the Z_D sweep needs a BOS geometry (geometry.kind = \"bos\")".into(),
        ));
    };
    let sensitivity = base.m * z0;
    z_d.iter()
        .map(|&z| {
            let z = positive("sweep z_d_m", z)?;
            if delta_z > 2.0 * z {
                return Err(invalid(
                    "sweep z_d_m",
                    format!("{z} m puts the {delta_z} m slab behind the target"),
                ));
            }
            if let Some(zt) = base.target_distance_m
                && z + 0.5 * delta_z >= zt
            {
                return Err(invalid(
                    "sweep z_d_m",
                    format!("{z} m puts the slab beyond the lens ({zt} m from the target)"),
                ));
            }
            let mut d = base.clone();
            if hold == ZdHold::Sensitivity {
                d.m = sensitivity / z;
            }
            d.geometry = PathGeometry::Bos { z_d: z, delta_z };
            rescale(&base, &mut d, exposure);
            Ok(SweepRow::new(&d, &predict_design(&d)))
        })
        .collect()
}
