//! What a study draws and how it measures: [`StudyConfig`] and its presets.

use crate::PaperError;
use crate::error::invalid;
use bostrack_theory::{Camera, Optics, Setup};
use serde::{Deserialize, Serialize};

/// How the noise-free image of a draw's dot is made.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Rendering {
    /// `bostrack_theory::ray_trace` (the paper's method): `rays` rays, stratified and jittered
    /// over the aperture, deflected at the slab's mid-plane, each deposited as a
    /// pixel-integrated spot of the reference dot's sigma. The truth is the mean landing point.
    RayTraced { rays: usize },
    /// The effective Gaussian that the model predicts, pixel-integrated
    /// (`bostrack_model::render`): the control, where the fitted model is exactly right.
    EffectiveModel,
}

/// What the noise standard deviation is a fraction of.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum NoiseReference {
    /// The peak `I0` of the predicted effective Gaussian (Eq. 29), the continuous dot's peak
    /// above background: independent of the sub-pixel position, and the `I0` of Eq. 35 in the
    /// form `std = sqrt(2/π) (σn/I0) sqrt(σx/σy)`. The default.
    #[default]
    ModelPeak,
    /// The brightest pixel of the noise-free rendered image above background (lower than `I0`
    /// for small dots, by the pixel integration, and dependent on the sub-pixel position).
    BrightestPixel,
    /// The peak of the *reference* (unblurred) dot, `base.camera.peak_counts`: the camera's
    /// noise does not change when the flow blurs the dot, so the blur lowers the peak's
    /// signal-to-noise ratio (the situation of the amplification ratio).
    ReferencePeak,
}

/// Where the density field is, drawn per draw.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum GeometryRange {
    /// Volumetric PTV: a particle at depth ζ (mm) inside the field, uniform in the range (the
    /// paper's Table 1: −2 to +2 mm). Predicted with the paper's volumetric form (Eq. 6 as
    /// printed: `M K ζ² / n0`, lever ζ); ray-traced as the equivalent thin slab (`Z_D = Δz =
    /// |ζ|`, which gives the same `ζ²`, lever and path).
    Volumetric { depth_mm: [f64; 2] },
    /// BOS: a slab of thickness `delta_z_m` centred `Z_D` in front of the target, `Z_D`
    /// uniform in `z_d_m` (m).
    Bos { z_d_m: [f64; 2], delta_z_m: f64 },
}

/// A Monte Carlo study in the manner of the paper's Sec. 3: `draws` random setups (Table 1's
/// ranges), each rendered once without noise, then `realisations` times with white Gaussian
/// noise and fitted by the least-squares Gaussian fit (`bostrack_fit`, 7 free parameters,
/// pixel-integrated model).
///
/// Per draw, uniformly and independently: the three transverse second derivatives `ρxx, ρxy,
/// ρyy` in `hessian_kg_m5` (kg/m⁵; the other three are zero), the geometry ([`GeometryRange`]),
/// the f-number from `f_numbers` (equally likely), the viewing direction (pitch about x and yaw
/// about y, each in `view_deg`, roll 0), and the sub-pixel position of the undeflected dot in
/// `[-0.5, 0.5)²` px. Everything else comes from `base`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudyConfig {
    /// A name for tables and files (e.g. `volumetric`).
    pub name: String,
    /// Optics, camera (peak of the reference dot and background; its read noise is replaced by
    /// `noise_fraction`) and constants shared by every draw.
    pub base: Setup,
    pub geometry: GeometryRange,
    /// Range of each of `ρxx, ρxy, ρyy` (kg/m⁵) \[0, 5000: Table 1\].
    pub hessian_kg_m5: [f64; 2],
    /// f-numbers drawn with equal probability \[8, 11, 16: Table 1\].
    pub f_numbers: Vec<f64>,
    /// Range of the pitch and of the yaw (degrees) \[−10, 10: Table 1\].
    pub view_deg: [f64; 2],
    /// Noise standard deviation as a fraction of `noise_reference` \[0.05: Sec. 3\].
    pub noise_fraction: f64,
    pub noise_reference: NoiseReference,
    pub rendering: Rendering,
    /// Fit window (and window of the exact bound): centred on the pixel nearest the true
    /// centroid, half-width `ceil(window_sigmas · σ_max)` px of the predicted dot, clamped to
    /// 3..=50 \[4\].
    pub window_sigmas: f64,
    /// Number of random setups \[1000: Sec. 3\].
    pub draws: usize,
    /// Noise realisations per draw \[1000: Sec. 3\].
    pub realisations: usize,
    /// Seed: the results depend on it and on nothing else (not on the number of threads).
    pub seed: u64,
    /// A fit whose position error exceeds this (px) counts as a failure, like a fit that did
    /// not converge \[1\].
    pub max_error_px: f64,
    /// Use the fits that the fit engine marks `Singular` but whose parameters are finite \[true\].
    /// They are least-squares minima (the paper's estimator returns them) where a sigma
    /// collapsed on an undersampled dot so that the bound *at the estimate* exceeds 1 px; at
    /// σ = 0.48 px and 5 % noise they are ~20 % of the fits, and leaving them out would bias
    /// the scatter low.
    pub include_singular: bool,
}

impl StudyConfig {
    /// The paper's volumetric PTV study (Table 1) with the optical values it leaves open,
    /// chosen for a typical volumetric PTV camera: |M| = 0.2 (e.g. a 50 mm lens 0.3 m from the
    /// volume), 6.5 µm pixels (sCMOS), 532 nm light (Nd:YAG), diffraction-limited particle
    /// images (a 1 µm tracer images to 0.2 µm, nothing beside the diffraction spot of
    /// `2.44 f# (1+M) λ` = 1.9, 2.6 and 3.8 px at f/8, 11, 16, i.e. σ = 0.48, 0.66, 0.96 px),
    /// square pupil (Eq. 22), reference peak 1000 counts on a background of 100.
    pub fn volumetric(draws: usize, realisations: usize) -> StudyConfig {
        StudyConfig {
            name: "volumetric".into(),
            base: Setup {
                optics: Optics {
                    magnification: Some(0.2),
                    pixel_pitch_um: 6.5,
                    wavelength_nm: 532.0,
                    dot_diameter_mm: 0.0,
                    ..Optics::default()
                },
                camera: Camera {
                    peak_counts: 1000.0,
                    background_counts: 100.0,
                    ..Camera::default()
                },
                ..Setup::default()
            },
            geometry: GeometryRange::Volumetric {
                depth_mm: [-2.0, 2.0],
            },
            hessian_kg_m5: [0.0, 5000.0],
            f_numbers: vec![8.0, 11.0, 16.0],
            view_deg: [-10.0, 10.0],
            noise_fraction: 0.05,
            noise_reference: NoiseReference::ModelPeak,
            rendering: Rendering::RayTraced { rays: 2500 },
            window_sigmas: 4.0,
            draws,
            realisations,
            seed: 1,
            max_error_px: 1.0,
            include_singular: true,
        }
    }

    /// The same study in a BOS configuration where the blur matters: the example setup of
    /// docs/theory.md (105 mm lens at 1.5 m from the target, |M| = 0.0753, 6.5 µm pixels,
    /// 532 nm, printed dots of 0.4 mm: reference σ 1.24, 1.30, 1.44 px at f/8, 11, 16), a slab
    /// 0.1 m thick with `Z_D` uniform in 0.4-0.6 m, Table 1's second derivatives, f-numbers and
    /// viewing angles.
    pub fn bos(draws: usize, realisations: usize) -> StudyConfig {
        StudyConfig {
            name: "bos".into(),
            base: Setup {
                optics: Optics {
                    focal_length_mm: 105.0,
                    target_distance_m: 1.5,
                    pixel_pitch_um: 6.5,
                    wavelength_nm: 532.0,
                    dot_diameter_mm: 0.4,
                    ..Optics::default()
                },
                camera: Camera {
                    peak_counts: 1000.0,
                    background_counts: 100.0,
                    ..Camera::default()
                },
                ..Setup::default()
            },
            geometry: GeometryRange::Bos {
                z_d_m: [0.4, 0.6],
                delta_z_m: 0.1,
            },
            ..StudyConfig::volumetric(draws, realisations)
        }
    }

    /// The studies of docs/theory.md, by name: `volumetric` (the paper's study, ray-traced),
    /// `volumetric-effective` (its effective-model control), `volumetric-brightest` (noise 5 %
    /// of the brightest pixel), `bos`, `bos-effective`, `bos-fixed-noise` (noise 5 % of the
    /// reference dot's peak). `None` for another name.
    pub fn named(name: &str, draws: usize, realisations: usize) -> Option<StudyConfig> {
        let mut cfg = match name {
            "volumetric" | "volumetric-effective" | "volumetric-brightest" => {
                StudyConfig::volumetric(draws, realisations)
            }
            "bos" | "bos-effective" | "bos-fixed-noise" => StudyConfig::bos(draws, realisations),
            _ => return None,
        };
        cfg.name = name.to_string();
        if name.ends_with("-effective") {
            cfg.rendering = Rendering::EffectiveModel;
        }
        if name.ends_with("-brightest") {
            cfg.noise_reference = NoiseReference::BrightestPixel;
        }
        if name.ends_with("-fixed-noise") {
            cfg.noise_reference = NoiseReference::ReferencePeak;
        }
        Some(cfg)
    }

    /// Names accepted by [`StudyConfig::named`].
    pub const NAMES: [&'static str; 6] = [
        "volumetric",
        "volumetric-effective",
        "volumetric-brightest",
        "bos",
        "bos-effective",
        "bos-fixed-noise",
    ];

    /// Checks every number; the error names the field.
    pub fn validate(&self) -> Result<(), PaperError> {
        let range = |field: &str, r: [f64; 2]| {
            if r.iter().all(|v| v.is_finite()) && r[0] <= r[1] {
                Ok(())
            } else {
                Err(invalid(
                    field,
                    format!("must be a finite range [lo, hi] with lo <= hi, got {r:?}"),
                ))
            }
        };
        range("hessian_kg_m5", self.hessian_kg_m5)?;
        range("view_deg", self.view_deg)?;
        match self.geometry {
            GeometryRange::Volumetric { depth_mm } => range("geometry.depth_mm", depth_mm)?,
            GeometryRange::Bos { z_d_m, delta_z_m } => {
                range("geometry.z_d_m", z_d_m)?;
                if z_d_m[0] <= 0.0 {
                    return Err(invalid("geometry.z_d_m", "must be > 0"));
                }
                if !(delta_z_m.is_finite() && delta_z_m > 0.0) {
                    return Err(invalid(
                        "geometry.delta_z_m",
                        format!("must be finite and > 0, got {delta_z_m}"),
                    ));
                }
            }
        }
        if self.f_numbers.is_empty() || self.f_numbers.iter().any(|f| !(f.is_finite() && *f > 0.0))
        {
            return Err(invalid(
                "f_numbers",
                format!(
                    "must be a non-empty list of positive numbers, got {:?}",
                    self.f_numbers
                ),
            ));
        }
        if !(self.noise_fraction.is_finite() && self.noise_fraction > 0.0) {
            return Err(invalid(
                "noise_fraction",
                format!("must be finite and > 0, got {}", self.noise_fraction),
            ));
        }
        if !(self.window_sigmas.is_finite() && (1.0..=20.0).contains(&self.window_sigmas)) {
            return Err(invalid(
                "window_sigmas",
                format!("must be in 1..=20, got {}", self.window_sigmas),
            ));
        }
        if let Rendering::RayTraced { rays } = self.rendering
            && !(1..=1_000_000).contains(&rays)
        {
            return Err(invalid(
                "rendering.rays",
                format!("must be in 1..=1000000, got {rays}"),
            ));
        }
        if self.draws == 0 {
            return Err(invalid("draws", "must be at least 1"));
        }
        if self.realisations < 3 {
            return Err(invalid(
                "realisations",
                format!(
                    "must be at least 3 (a standard deviation), got {}",
                    self.realisations
                ),
            ));
        }
        if !(self.max_error_px.is_finite() && self.max_error_px > 0.0) {
            return Err(invalid(
                "max_error_px",
                format!("must be finite and > 0, got {}", self.max_error_px),
            ));
        }
        self.base
            .validate()
            .map_err(|source| PaperError::Setup { draw: 0, source })
    }
}
