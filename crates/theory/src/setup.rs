//! The experiment description ([`Setup`], serde, unknown keys rejected) and its validated,
//! resolved form ([`Design`], crate-internal).

use crate::TheoryError;
use crate::error::{finite, invalid, non_negative, positive};
use crate::optics::{
    Aperture, ConeAngleModel, GLADSTONE_DALE_AIR, Hessian, N0_AIR, diffraction_diameter,
    magnification, rotation_matrix,
};
use bostrack_core::NoiseModel;
use serde::{Deserialize, Serialize};

/// An experiment to predict: optics, where the density field sits, its derivatives, the viewing
/// direction, the camera's brightness and noise, and the physical constants. Every field has a
/// default (in brackets in each field's doc); the defaults describe a 105 mm lens at f/11 looking
/// at a target 1.5 m away through a 50 mm slab 0.5 m in front of it, with no flow.
///
/// ```toml
/// [optics]
/// f_number = 11.0
/// focal_length_mm = 105.0
/// target_distance_m = 1.5
/// pixel_pitch_um = 6.5
/// wavelength_nm = 532.0
/// [geometry]
/// kind = "bos"
/// z_d_m = 0.5
/// delta_z_m = 0.05
/// [flow]
/// gradient_kg_m4 = [30.0, 10.0, 0.0]
/// hessian_kg_m5 = { xx = 8000.0, xy = 3000.0, yy = 2000.0 }
/// [camera]
/// peak_counts = 1000.0
/// read_noise_counts = 10.0
/// ```
///
/// (`testdata/crlb-setup.toml` is a commented example.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Setup {
    pub optics: Optics,
    pub geometry: Geometry,
    pub flow: Flow,
    pub view: View,
    pub camera: Camera,
    pub constants: Constants,
}

/// Lens, sensor and diffraction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Optics {
    /// Lens f-number f# \[11\].
    pub f_number: f64,
    /// Focal length (mm) \[105\]; with `target_distance_m` gives M by Eq. 5.
    pub focal_length_mm: f64,
    /// Distance from the lens to the dot target (the focal plane), m \[1.5\].
    pub target_distance_m: f64,
    /// Magnification |M| \[none\]. When given, `focal_length_mm` and `target_distance_m` are not
    /// used (and the check `Z_D < target distance` is skipped).
    pub magnification: Option<f64>,
    /// Pixel pitch d_r (µm) \[6.5\].
    pub pixel_pitch_um: f64,
    /// Wavelength λ (nm) \[532\], giving the diffraction diameter `2.44 f# (M+1) λ` (NOTES.md §4).
    pub wavelength_nm: f64,
    /// Diffraction diameter 4η in px at this f-number and magnification \[none\]. When given it
    /// replaces the wavelength formula; sweeps scale it ∝ f# (M+1).
    pub diffraction_diameter_px: Option<f64>,
    /// Diameter of the printed dots on the target (mm) \[0: point dots\]. Its image (M d / d_r px)
    /// is treated as a Gaussian of 4σ = that diameter (exact in the second moments for a uniform
    /// disc) and added in quadrature to the diffraction spot: the reference dot has
    /// `σ_ref² = η_diff² + (M d / (4 d_r))²`. The flow's lens effect on the finite dot is not
    /// modelled (flag `lensing`).
    pub dot_diameter_mm: f64,
    /// Ray-angle distribution over the aperture \["square": the paper's Eq. 22\].
    pub aperture: Aperture,
    /// Cone angle of the blur \["paper": Eq. 24 with the gradient term, clamped at zero\].
    pub cone_angle: ConeAngleModel,
}

impl Default for Optics {
    fn default() -> Self {
        Optics {
            f_number: 11.0,
            focal_length_mm: 105.0,
            target_distance_m: 1.5,
            magnification: None,
            pixel_pitch_um: 6.5,
            wavelength_nm: 532.0,
            diffraction_diameter_px: None,
            dot_diameter_mm: 0.0,
            aperture: Aperture::Square,
            cone_angle: ConeAngleModel::Paper,
        }
    }
}

/// Where the density field is, relative to the dot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Geometry {
    /// BOS: a slab of thickness `delta_z_m` (path length along the line of sight) centred
    /// `z_d_m` in front of the dot target \[z_d_m = 0.5, delta_z_m = 0.05\]. Eq. 6's `ζ²` is
    /// `Z_D Δz`, the lever of the blur (Eq. 16, 23) is `Z_D`, the path of Eq. 24 is `Δz`.
    Bos { z_d_m: f64, delta_z_m: f64 },
    /// A particle at depth ζ = `depth_m` inside the field (volumetric PTV, the paper's Eq. 6 as
    /// printed): `ζ²`, lever `ζ`, path `ζ`. Give the magnification at the particle's depth.
    Volumetric { depth_m: f64 },
}

impl Default for Geometry {
    fn default() -> Self {
        Geometry::Bos {
            z_d_m: 0.5,
            delta_z_m: 0.05,
        }
    }
}

/// Path-averaged density derivatives at the cone's bisector, in the flow frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Flow {
    /// First derivatives `[∂ρ/∂x, ∂ρ/∂y, ∂ρ/∂z]`, kg/m⁴ \[0, 0, 0\].
    pub gradient_kg_m4: [f64; 3],
    /// Second derivatives, kg/m⁵ \[all 0\].
    pub hessian_kg_m5: Hessian,
}

/// Viewing direction (paper Eq. 9-10): the camera frame is the flow frame rotated by pitch
/// (about x), yaw (about y) and roll (about z), `R = R_pitch R_yaw R_roll`
/// ([`crate::rotation_matrix`]). All zero = head-on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct View {
    /// Pitch (degrees) \[0\].
    pub pitch_deg: f64,
    /// Yaw (degrees) \[0\].
    pub yaw_deg: f64,
    /// Roll (degrees) \[0\].
    pub roll_deg: f64,
}

/// Brightness, noise and the window of the exact bound.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Camera {
    /// Peak of the *reference* dot above background (counts) \[1000\]; sets the exposure
    /// `α0 = 2π peak σ_ref²` (Eq. 27).
    pub peak_counts: f64,
    /// Exposure α0, the dot's integrated counts above background (counts·px²) \[none\]. When
    /// given it replaces `peak_counts`.
    pub exposure_counts: Option<f64>,
    /// Background level (counts) \[100\].
    pub background_counts: f64,
    /// Read noise σn (counts) \[10\]: the paper's white noise.
    pub read_noise_counts: f64,
    /// Shot-noise gain (counts per photo-electron) \[0: read noise only\]; used by the exact
    /// bound only (variance = σn² + gain · signal, docs/CONVENTIONS.md).
    pub gain: f64,
    /// Half-width of the exact bound's window (px) \[none: ceil(4 σ_max), at least 3, at most 50\].
    pub window_half_px: Option<usize>,
    /// Position of the undeflected dot image (px) \[0, 0\]: its sub-pixel part matters to the
    /// exact bound.
    pub position_px: [f64; 2],
}

impl Default for Camera {
    fn default() -> Self {
        Camera {
            peak_counts: 1000.0,
            exposure_counts: None,
            background_counts: 100.0,
            read_noise_counts: 10.0,
            gain: 0.0,
            window_half_px: None,
            position_px: [0.0, 0.0],
        }
    }
}

/// Physical constants.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Constants {
    /// Gladstone-Dale constant K (m³/kg) \[0.225e-3, air\].
    pub gladstone_dale_m3_kg: f64,
    /// Ambient refractive index n0 \[1.000278, air\].
    pub n0: f64,
}

impl Default for Constants {
    fn default() -> Self {
        Constants {
            gladstone_dale_m3_kg: GLADSTONE_DALE_AIR,
            n0: N0_AIR,
        }
    }
}

impl Setup {
    /// Parse a setup from TOML text and validate it.
    pub fn from_toml(text: &str) -> Result<Setup, TheoryError> {
        let s: Setup = toml::from_str(text).map_err(|e| TheoryError::Toml(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }

    /// Check every value (ranges, consistency); the error names the offending field.
    pub fn validate(&self) -> Result<(), TheoryError> {
        Design::from_setup(self).map(|_| ())
    }

    /// The same setup without density derivatives: the reference (no-flow) dot.
    pub fn reference(&self) -> Setup {
        Setup {
            flow: Flow::default(),
            ..self.clone()
        }
    }
}

/// How the diffraction sigma follows the optics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Diffraction {
    /// From the wavelength (m).
    Wavelength(f64),
    /// A diameter in px given at f-number `f_number` and magnification `m`; scaled ∝ f# (M+1).
    Fixed { d_px: f64, f_number: f64, m: f64 },
}

/// How bright the dot is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Brightness {
    /// Peak of the reference dot (counts).
    Peak(f64),
    /// Exposure (counts·px²).
    Exposure(f64),
}

/// The path geometry as the formulas need it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum PathGeometry {
    Bos { z_d: f64, delta_z: f64 },
    Volumetric { depth: f64 },
}

impl PathGeometry {
    /// Lever ℓ of Eq. 16 (m).
    pub(crate) fn lever(&self) -> f64 {
        match *self {
            PathGeometry::Bos { z_d, .. } => z_d,
            PathGeometry::Volumetric { depth } => depth,
        }
    }
    /// Path length through the field, the ζ of Eq. 24 (m).
    pub(crate) fn path(&self) -> f64 {
        match *self {
            PathGeometry::Bos { delta_z, .. } => delta_z,
            PathGeometry::Volumetric { depth } => depth,
        }
    }
}

/// A validated setup with every number resolved (SI units, px).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Design {
    pub m: f64,
    pub f_number: f64,
    pub pitch_m: f64,
    pub target_distance_m: Option<f64>,
    pub diffraction: Diffraction,
    /// Diameter of the printed dot's image (px); held fixed by the sweeps (a target printed for
    /// the magnification at hand).
    pub dot_diameter_px: f64,
    pub aperture: Aperture,
    pub cone_model: ConeAngleModel,
    pub geometry: PathGeometry,
    pub gradient: [f64; 3],
    pub hessian: Hessian,
    pub rotation: [[f64; 3]; 3],
    pub brightness: Brightness,
    pub background: f64,
    pub read_noise: f64,
    pub gain: f64,
    pub window_half: Option<usize>,
    pub position: [f64; 2],
    pub k: f64,
    pub n0: f64,
}

impl Design {
    pub(crate) fn from_setup(s: &Setup) -> Result<Design, TheoryError> {
        let o = &s.optics;
        let f_number = positive("optics.f_number", o.f_number)?;
        let (m, target_distance_m) = match o.magnification {
            Some(m) => (positive("optics.magnification", m)?, None),
            None => {
                let f = positive("optics.focal_length_mm", o.focal_length_mm)? * 1e-3;
                let z = positive("optics.target_distance_m", o.target_distance_m)?;
                if z <= f {
                    return Err(invalid(
                        "optics.target_distance_m",
                        format!("must exceed the focal length ({f} m), got {z} m"),
                    ));
                }
                (magnification(f, z), Some(z))
            }
        };
        let pitch_m = positive("optics.pixel_pitch_um", o.pixel_pitch_um)? * 1e-6;
        let diffraction = match o.diffraction_diameter_px {
            Some(d) => Diffraction::Fixed {
                d_px: positive("optics.diffraction_diameter_px", d)?,
                f_number,
                m,
            },
            None => {
                Diffraction::Wavelength(positive("optics.wavelength_nm", o.wavelength_nm)? * 1e-9)
            }
        };
        let dot_diameter_px =
            non_negative("optics.dot_diameter_mm", o.dot_diameter_mm)? * 1e-3 * m / pitch_m;
        let geometry = match s.geometry {
            Geometry::Bos { z_d_m, delta_z_m } => {
                let z_d = positive("geometry.z_d_m", z_d_m)?;
                let delta_z = positive("geometry.delta_z_m", delta_z_m)?;
                if delta_z > 2.0 * z_d {
                    return Err(invalid(
                        "geometry.delta_z_m",
                        format!(
                            "the slab ({delta_z} m thick) must not reach behind the target (z_d_m = {z_d} m)"
                        ),
                    ));
                }
                if let Some(zt) = target_distance_m
                    && z_d + 0.5 * delta_z >= zt
                {
                    return Err(invalid(
                        "geometry.z_d_m",
                        format!("the slab must lie between the target and the lens ({zt} m away)"),
                    ));
                }
                PathGeometry::Bos { z_d, delta_z }
            }
            Geometry::Volumetric { depth_m } => PathGeometry::Volumetric {
                depth: finite("geometry.depth_m", depth_m)?,
            },
        };
        for (k, v) in s.flow.gradient_kg_m4.iter().enumerate() {
            finite(&format!("flow.gradient_kg_m4[{k}]"), *v)?;
        }
        let h = &s.flow.hessian_kg_m5;
        for (name, v) in [
            ("xx", h.xx),
            ("yy", h.yy),
            ("zz", h.zz),
            ("xy", h.xy),
            ("xz", h.xz),
            ("yz", h.yz),
        ] {
            finite(&format!("flow.hessian_kg_m5.{name}"), v)?;
        }
        let deg = |field: &str, v: f64| finite(field, v).map(f64::to_radians);
        let rotation = rotation_matrix(
            deg("view.pitch_deg", s.view.pitch_deg)?,
            deg("view.yaw_deg", s.view.yaw_deg)?,
            deg("view.roll_deg", s.view.roll_deg)?,
        );
        let c = &s.camera;
        let brightness = match c.exposure_counts {
            Some(e) => Brightness::Exposure(positive("camera.exposure_counts", e)?),
            None => Brightness::Peak(positive("camera.peak_counts", c.peak_counts)?),
        };
        let background = finite("camera.background_counts", c.background_counts)?;
        let read_noise = positive("camera.read_noise_counts", c.read_noise_counts)?;
        let gain = non_negative("camera.gain", c.gain)?;
        if c.window_half_px == Some(0) {
            return Err(invalid("camera.window_half_px", "must be >= 1"));
        }
        let position = [
            finite("camera.position_px[0]", c.position_px[0])?,
            finite("camera.position_px[1]", c.position_px[1])?,
        ];
        let k = positive(
            "constants.gladstone_dale_m3_kg",
            s.constants.gladstone_dale_m3_kg,
        )?;
        let n0 = positive("constants.n0", s.constants.n0)?;
        Ok(Design {
            m,
            f_number,
            pitch_m,
            target_distance_m,
            diffraction,
            dot_diameter_px,
            aperture: o.aperture,
            cone_model: o.cone_angle,
            geometry,
            gradient: s.flow.gradient_kg_m4,
            hessian: s.flow.hessian_kg_m5,
            rotation,
            brightness,
            background,
            read_noise,
            gain,
            window_half: c.window_half_px,
            position,
            k,
            n0,
        })
    }

    /// Diffraction diameter 4η in px.
    pub(crate) fn diffraction_diameter_px(&self) -> f64 {
        match self.diffraction {
            Diffraction::Wavelength(l) => {
                diffraction_diameter(self.f_number, self.m, l) / self.pitch_m
            }
            Diffraction::Fixed { d_px, f_number, m } => {
                d_px * (self.f_number / f_number) * ((1.0 + self.m) / (1.0 + m))
            }
        }
    }

    /// Sigma of the reference dot (px): diffraction and printed dot in quadrature.
    pub(crate) fn sigma_ref(&self) -> f64 {
        let eta = 0.25 * self.diffraction_diameter_px();
        let dot = 0.25 * self.dot_diameter_px;
        eta.hypot(dot)
    }

    /// Exposure α0 (counts·px²).
    pub(crate) fn exposure(&self) -> f64 {
        match self.brightness {
            Brightness::Exposure(e) => e,
            Brightness::Peak(p) => 2.0 * std::f64::consts::PI * p * self.sigma_ref().powi(2),
        }
    }

    pub(crate) fn noise(&self) -> NoiseModel {
        NoiseModel {
            read_variance: self.read_noise * self.read_noise,
            gain: self.gain,
            offset: 0.0,
        }
    }
}
