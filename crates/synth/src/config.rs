//! Scene and flow configuration: plain serde structs (TOML-friendly, unknown keys rejected on
//! every struct), each default documented next to its field.

use crate::SynthError;
use bostrack_model::Sampling;
use serde::{Deserialize, Serialize};

/// Everything that defines a synthetic no-flow scene (the reference image and its stack).
///
/// Every field has a default (shown in brackets), chosen to look roughly like the real sample
/// (12-bit camera, 8 px pitch, dot diameter 4σ ≈ 6.4 px, read + shot noise), on a smaller
/// 256×256 frame so tests stay fast:
///
/// ```toml
/// width = 256
/// height = 256
/// bits = 12          # 8, 12, 16: quantised integers; 32, 64: float, no quantisation
/// seed = 0
/// [lattice]
/// kind = "square"    # or "hexagonal"
/// spacing = 8.0
/// angle_deg = 0.0
/// # origin = [128.0, 128.0]   (default: the pixel centre at (width/2, height/2), rounded down)
/// [dots]
/// sigma_x = 1.6
/// sigma_y = 1.6
/// rho = 0.0
/// amplitude = 1500.0
/// [noise]
/// read_noise = 12.0
/// gain = 0.6
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneConfig {
    /// Image width in pixels (default: 256).
    pub width: usize,
    /// Image height in pixels (default: 256).
    pub height: usize,
    /// The dot lattice.
    pub lattice: LatticeConfig,
    /// Nominal dot shape and per-dot jitter.
    pub dots: DotConfig,
    /// Missing and defective dots.
    pub defects: DefectConfig,
    /// Background level, vignetting and dark regions.
    pub background: BackgroundConfig,
    /// Region of interest written next to the image (default: none).
    pub mask: Option<MaskConfig>,
    /// Read and shot noise.
    pub noise: NoiseConfig,
    /// Bits per sample (default: 12): 8, 12 or 16 quantise (round to the nearest integer, clip to
    /// `[0, 2^bits - 1]`); 32 or 64 give float samples without quantisation or clipping.
    pub bits: u16,
    /// Master seed (default: 0). Layout randomness (missing dots, defects, jitter) and the noise of each
    /// image are drawn from seeds derived from it, so the same seed gives identical scenes.
    pub seed: u64,
    /// How dots are drawn.
    pub render: RenderConfig,
    /// How the per-dot truth (Cramér-Rao bound) is computed.
    pub truth: TruthConfig,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig {
            width: 256,
            height: 256,
            lattice: LatticeConfig::default(),
            dots: DotConfig::default(),
            defects: DefectConfig::default(),
            background: BackgroundConfig::default(),
            mask: None,
            noise: NoiseConfig::default(),
            bits: 12,
            seed: 0,
            render: RenderConfig::default(),
            truth: TruthConfig::default(),
        }
    }
}

/// Lattice geometry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LatticeConfig {
    /// `square` (default) or `hexagonal`.
    pub kind: LatticeKind,
    /// Distance between nearest neighbours, px (default: 8.0).
    pub spacing: f64,
    /// Rotation of the lattice, degrees (default: 0.0); positive turns +x towards +y (clockwise on
    /// screen, since y points down). Any angle is accepted; the grid index follows
    /// docs/CONVENTIONS.md whatever the angle (see [`crate::lattice_for`]).
    pub angle_deg: f64,
    /// Position of site (0, 0), px [the pixel centre `(floor(width/2), floor(height/2))`, so
    /// that by default dot centres fall on pixel centres, never on the border of the pixel area].
    pub origin: Option<[f64; 2]>,
}

impl Default for LatticeConfig {
    fn default() -> Self {
        LatticeConfig {
            kind: LatticeKind::Square,
            spacing: 8.0,
            angle_deg: 0.0,
            origin: None,
        }
    }
}

/// Square or hexagonal lattice.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LatticeKind {
    Square,
    Hexagonal,
}

/// Nominal dot: an elliptical Gaussian (docs/CONVENTIONS.md).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DotConfig {
    /// σx, px (default: 1.6).
    pub sigma_x: f64,
    /// σy, px (default: 1.6).
    pub sigma_y: f64,
    /// Correlation coefficient ρ ∈ (-1, 1) (default: 0.0).
    pub rho: f64,
    /// Peak height above the background, counts (default: 1500.0), before illumination and jitter.
    pub amplitude: f64,
    /// Relative standard deviation of a per-dot amplitude factor `1 + amplitude_jitter·N(0,1)`,
    /// clamped to at least 0.05 (default: 0.0).
    pub amplitude_jitter: f64,
    /// Relative standard deviation of a per-dot size factor `1 + sigma_jitter·N(0,1)` applied to
    /// both sigmas, clamped to at least 0.2 (default: 0.0).
    pub sigma_jitter: f64,
}

impl Default for DotConfig {
    fn default() -> Self {
        DotConfig {
            sigma_x: 1.6,
            sigma_y: 1.6,
            rho: 0.0,
            amplitude: 1500.0,
            amplitude_jitter: 0.0,
            sigma_jitter: 0.0,
        }
    }
}

/// Kinds of target defects. Each defective dot is still an exact elliptical Gaussian, so the
/// truth stays exact.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DefectKind {
    /// Both sigmas times `small` (peak height kept).
    Small,
    /// Both sigmas times `large` (peak height kept).
    Large,
    /// Amplitude times `faint`.
    Faint,
    /// σx times `elongation`, σy divided by it, ρ set to `misshapen_rho`.
    Misshapen,
}

impl DefectKind {
    /// Snake-case name used in CSV files.
    pub fn as_str(self) -> &'static str {
        match self {
            DefectKind::Small => "small",
            DefectKind::Large => "large",
            DefectKind::Faint => "faint",
            DefectKind::Misshapen => "misshapen",
        }
    }
    /// Inverse of [`DefectKind::as_str`].
    pub fn parse(s: &str) -> Option<Self> {
        [
            DefectKind::Small,
            DefectKind::Large,
            DefectKind::Faint,
            DefectKind::Misshapen,
        ]
        .into_iter()
        .find(|k| k.as_str() == s)
    }
}

/// Missing and defective dots. Which sites are affected is drawn per site from a seed derived
/// from the scene seed and the grid index, so it does not depend on the image size or origin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DefectConfig {
    /// Fraction of sites left empty (default: 0.0) (kept in the truth with the MISSING flag).
    pub missing: f64,
    /// Fraction of the remaining sites that get a defect (default: 0.0) (DEFECT flag).
    pub defective: f64,
    /// Defect kinds to draw from, uniformly (default: all four).
    pub kinds: Vec<DefectKind>,
    /// Size factor of `small` defects (default: 0.5).
    pub small: f64,
    /// Size factor of `large` defects (default: 1.8).
    pub large: f64,
    /// Amplitude factor of `faint` defects (default: 0.25).
    pub faint: f64,
    /// Elongation of `misshapen` defects (default: 2.0).
    pub elongation: f64,
    /// ρ of `misshapen` defects (default: 0.6).
    pub misshapen_rho: f64,
}

impl Default for DefectConfig {
    fn default() -> Self {
        DefectConfig {
            missing: 0.0,
            defective: 0.0,
            kinds: vec![
                DefectKind::Small,
                DefectKind::Large,
                DefectKind::Faint,
                DefectKind::Misshapen,
            ],
            small: 0.5,
            large: 1.8,
            faint: 0.25,
            elongation: 2.0,
            misshapen_rho: 0.6,
        }
    }
}

/// Background and illumination.
///
/// The illumination factor is `L(x, y) = V(x, y) · Π_regions D(x, y)` with vignetting
/// `V = max(0, 1 - vignetting · (r / r_corner)²)` (r from `vignetting_centre`, `r_corner` the distance
/// from that centre to the farthest corner of the pixel area) and, per dark region,
/// `D = 1 - (1 - factor) · s_x(x) · s_y(y)`, where `s(t) = ½(tanh((t - lo)/edge) - tanh((t - hi)/edge))`
/// is a smooth box (a sharp one when `edge = 0`; 1 for an absent interval).
///
/// The background sample of pixel `(x, y)` is `level · L(x, y)` (evaluated at the pixel
/// centre: the field is smooth). When `illuminate_dots` is set, each dot's amplitude is
/// multiplied by `L` at its centre, so every dot stays an exact Gaussian; its truth background
/// is the background at its centre.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BackgroundConfig {
    /// Background level at full illumination, counts (default: 150.0).
    pub level: f64,
    /// Relative illumination loss at the image corners, in [0, 1) (default: 0.0 = none).
    pub vignetting: f64,
    /// Centre of the vignetting, px [the image centre, `((width-1)/2, (height-1)/2)`].
    pub vignetting_centre: Option<[f64; 2]>,
    /// Dark regions (e.g. the real sample's dark bottom band) (default: none).
    pub dark: Vec<DarkRegion>,
    /// Whether the illumination also scales the dots' amplitudes (default: true).
    pub illuminate_dots: bool,
}

impl Default for BackgroundConfig {
    fn default() -> Self {
        BackgroundConfig {
            level: 150.0,
            vignetting: 0.0,
            vignetting_centre: None,
            dark: Vec::new(),
            illuminate_dots: true,
        }
    }
}

/// A dark rectangle or band: the illumination is multiplied by `factor` inside.
///
/// ```toml
/// [[background.dark]]      # the real sample's dark bottom band
/// y = [860.0, inf]
/// factor = 0.1
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DarkRegion {
    /// Column interval `[lo, hi]`, px (default: none = all columns); `inf` is allowed.
    pub x: Option<[f64; 2]>,
    /// Row interval `[lo, hi]`, px (default: none = all rows); `inf` is allowed.
    pub y: Option<[f64; 2]>,
    /// Illumination factor inside, ≥ 0 (default: 0.1).
    pub factor: f64,
    /// Width of the smooth edge, px (default: 2.0); 0 = sharp.
    pub edge: f64,
}

impl Default for DarkRegion {
    fn default() -> Self {
        DarkRegion {
            x: None,
            y: None,
            factor: 0.1,
            edge: 2.0,
        }
    }
}

/// Region of interest (`true` = keep). Dots whose truth window reaches a masked-out pixel get the
/// MASKED flag and their bound leaves those pixels out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MaskConfig {
    /// Keep the pixels whose centres lie in `[x0, x1] × [y0, y1]`.
    Rect { x: [f64; 2], y: [f64; 2] },
    /// Keep the pixels whose centres lie within `radius` of `centre`.
    Circle { centre: [f64; 2], radius: f64 },
    /// Keep the pixels whose illumination factor is at least `min` (e.g. leaves out dark bands).
    Illumination { min: f64 },
}

/// Camera noise. The pixel value of mean `μ` (counts) is
/// `min(μ, offset) + gain · Poisson(max(μ - offset, 0) / gain) + read_noise · N(0, 1)`, so its
/// variance is `read_noise² + gain · max(μ - offset, 0)` (docs/CONVENTIONS.md); `gain = 0`
/// leaves out the shot noise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseConfig {
    /// Standard deviation of the additive Gaussian read noise, counts (default: 12.0).
    pub read_noise: f64,
    /// Counts per photo-electron (default: 0.6); 0 = no shot noise.
    pub gain: f64,
    /// Dark level that carries no shot noise, counts (default: 0.0).
    pub offset: f64,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        NoiseConfig {
            read_noise: 12.0,
            gain: 0.6,
            offset: 0.0,
        }
    }
}

/// How dots are drawn.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderConfig {
    /// Pixel sampling (default: `integrated`, the mean over each pixel's unit square, what a
    /// camera records; `point`: the value at the pixel centre).
    pub sampling: Sampling,
    /// Each dot is drawn only near its centre, not over the whole image (default: 6.0): over the
    /// rectangle `round(x0) ± ceil(window_sigmas·σx + 1)` (likewise in y) when ρ = 0 and the
    /// sampling is integrated (separable erf differences), and otherwise over the pixels whose
    /// unit square meets the ellipse `q/(1-ρ²) ≤ window_sigmas²`, which holds all but
    /// `exp(-window_sigmas²/2)` of the light (1.5e-8 at 6). At least 3.
    pub window_sigmas: f64,
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig {
            sampling: Sampling::Integrated,
            window_sigmas: 6.0,
        }
    }
}

/// How the per-dot truth is computed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TruthConfig {
    /// Whether to compute the per-dot Cramér-Rao bound (default: true) (NaN otherwise).
    pub crlb: bool,
    /// Half-width of the square bound window `Window::centred(x0, y0, h)`, px
    /// (default: round(spacing / 2): the dot's Voronoi cell on a square lattice).
    pub crlb_half_width: Option<usize>,
}

impl Default for TruthConfig {
    fn default() -> Self {
        TruthConfig {
            crlb: true,
            crlb_half_width: None,
        }
    }
}

/// The flow seen in the gradient image: a displacement field and the blur it causes.
///
/// A reference dot at `p` with covariance `Σ = [[σx², ρσxσy], [ρσxσy, σy²]]` and amplitude `I0`
/// becomes, in the gradient image, the dot at `p + d(p)` with covariance
///
/// `Σ' = Σ + blur · J Jᵀ`,  `J = ∂d/∂p` (the displacement Jacobian at `p`),
///
/// i.e. `σx'² = σx² + blur·(J_xx² + J_xy²)`, `σy'² = σy² + blur·(J_yx² + J_yy²)`,
/// `ρ' σx' σy' = ρ σx σy + blur·(J_xx J_yx + J_xy J_yy)`. This is the paper's blur model
/// (Rajendran et al. 2020, Eqs. 20-26): rays of one dot cross the gradient field over a
/// footprint of variance `blur` per axis (the paper's `ζ²Δθ0²/12`), and each ray is displaced
/// by `d` at its crossing point, so the image spreads by `J` times the footprint. For a BOS
/// field `d = ∇φ`, `J` is the Hessian of `φ`, so the blur grows with the field's second
/// derivatives; the paper keeps only the diagonal, the off-diagonal term gives ρ'.
///
/// With `conserve_intensity` the integrated intensity `2π I0 σx σy sqrt(1-ρ²)` is kept (the
/// rays' light is spread, not lost): `I0' = I0 · sqrt(det Σ / det Σ')`; otherwise `I0' = I0`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FlowConfig {
    /// The displacement field (default: zero).
    pub displacement: DisplacementField,
    /// Footprint variance `blur` of the blur model, px² (default: 0.0 = no blur).
    pub blur: f64,
    /// Keep each dot's integrated intensity under blur (default: true).
    pub conserve_intensity: bool,
}

impl Default for FlowConfig {
    fn default() -> Self {
        FlowConfig {
            displacement: DisplacementField::Zero,
            blur: 0.0,
            conserve_intensity: true,
        }
    }
}

/// Displacement fields with closed-form values and Jacobians (see [`DisplacementField::eval`]).
///
/// ```toml
/// [displacement]
/// kind = "gaussian_bump"
/// centre = [128.0, 128.0]
/// amplitude = 40.0
/// width = 12.0
/// ```
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum DisplacementField {
    /// `d = 0`.
    #[default]
    Zero,
    /// `d = (dx, dy)` everywhere.
    Uniform { dx: f64, dy: f64 },
    /// `d = offset + M (p - centre)`, `M = matrix` (rows: `[[dxx, dxy], [dyx, dyy]]`,
    /// `dxy = ∂d_x/∂y`).
    Affine {
        centre: [f64; 2],
        offset: [f64; 2],
        matrix: [[f64; 2]; 2],
    },
    /// Lamb-Oseen-like vortex: tangential displacement `u(r) = strength/r · (1 - exp(-r²/core²))`
    /// along `(-(y-yc), x-xc)/r`, i.e. `d = strength (1 - exp(-r²/core²))/r² · (-(y-yc), x-xc)`;
    /// positive strength turns +x towards +y (clockwise on screen). `strength` in px², `core` in
    /// px; the largest displacement is ≈ 0.638 strength/core at r ≈ 1.121 core.
    Vortex {
        centre: [f64; 2],
        strength: f64,
        core: f64,
    },
    /// BOS-like field: the gradient of a Gaussian bump, `d = A ∇ exp(-r²/(2 s²))
    /// = -A (p - centre)/s² · exp(-r²/(2 s²))`, `A = amplitude` (px²), `s = width` (px). Positive
    /// `A` points towards the centre; the largest |d| is `|A| e^(-1/2)/s` at `r = s`.
    GaussianBump {
        centre: [f64; 2],
        amplitude: f64,
        width: f64,
    },
}

pub(crate) fn invalid(field: &str, msg: impl std::fmt::Display) -> SynthError {
    SynthError::InvalidConfig {
        field: field.to_string(),
        problem: msg.to_string(),
    }
}

fn finite(field: &str, v: f64) -> Result<(), SynthError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(invalid(field, format!("must be finite, got {v}")))
    }
}

fn positive(field: &str, v: f64) -> Result<(), SynthError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(field, format!("must be finite and > 0, got {v}")))
    }
}

fn non_negative(field: &str, v: f64) -> Result<(), SynthError> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(invalid(field, format!("must be finite and >= 0, got {v}")))
    }
}

fn fraction(field: &str, v: f64) -> Result<(), SynthError> {
    if (0.0..=1.0).contains(&v) {
        Ok(())
    } else {
        Err(invalid(field, format!("must lie in [0, 1], got {v}")))
    }
}

fn interval(field: &str, v: &[f64; 2]) -> Result<(), SynthError> {
    if v.iter().any(|t| t.is_nan()) || v[0] > v[1] {
        return Err(invalid(
            field,
            format!("must be an interval [lo, hi] with lo <= hi, got {v:?}"),
        ));
    }
    Ok(())
}

/// Largest number of pixels accepted (2^28, a 16384×16384 frame).
const MAX_PIXELS: usize = 1 << 28;
/// Largest number of lattice sites accepted.
const MAX_SITES: f64 = 2.0e7;

impl SceneConfig {
    /// Parse a TOML document (unknown keys are errors) and validate it.
    pub fn from_toml(text: &str) -> Result<Self, SynthError> {
        let cfg: SceneConfig = toml::from_str(text).map_err(|e| SynthError::Toml(e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Check every value; the error names the offending field.
    pub fn validate(&self) -> Result<(), SynthError> {
        if self.width == 0
            || self.height == 0
            || self.width.saturating_mul(self.height) > MAX_PIXELS
        {
            return Err(invalid(
                "width/height",
                format!(
                    "image must have between 1 and {MAX_PIXELS} pixels, got {}x{}",
                    self.width, self.height
                ),
            ));
        }
        let l = &self.lattice;
        positive("lattice.spacing", l.spacing)?;
        finite("lattice.angle_deg", l.angle_deg)?;
        if let Some(o) = l.origin {
            finite("lattice.origin[0]", o[0])?;
            finite("lattice.origin[1]", o[1])?;
        }
        let cell = match l.kind {
            LatticeKind::Square => l.spacing * l.spacing,
            LatticeKind::Hexagonal => l.spacing * l.spacing * 3f64.sqrt() / 2.0,
        };
        let d = &self.dots;
        positive("dots.sigma_x", d.sigma_x)?;
        positive("dots.sigma_y", d.sigma_y)?;
        if d.rho.is_nan() || d.rho.abs() >= 1.0 {
            return Err(invalid(
                "dots.rho",
                format!("must lie in (-1, 1), got {}", d.rho),
            ));
        }
        non_negative("dots.amplitude", d.amplitude)?;
        non_negative("dots.amplitude_jitter", d.amplitude_jitter)?;
        non_negative("dots.sigma_jitter", d.sigma_jitter)?;
        let f = &self.defects;
        fraction("defects.missing", f.missing)?;
        fraction("defects.defective", f.defective)?;
        if f.defective > 0.0 && f.kinds.is_empty() {
            return Err(invalid(
                "defects.kinds",
                "must name at least one kind when defects.defective > 0",
            ));
        }
        positive("defects.small", f.small)?;
        positive("defects.large", f.large)?;
        non_negative("defects.faint", f.faint)?;
        positive("defects.elongation", f.elongation)?;
        if f.misshapen_rho.is_nan() || f.misshapen_rho.abs() >= 1.0 {
            return Err(invalid(
                "defects.misshapen_rho",
                format!("must lie in (-1, 1), got {}", f.misshapen_rho),
            ));
        }
        let b = &self.background;
        finite("background.level", b.level)?;
        if !(0.0..1.0).contains(&b.vignetting) {
            return Err(invalid(
                "background.vignetting",
                format!("must lie in [0, 1), got {}", b.vignetting),
            ));
        }
        if let Some(c) = b.vignetting_centre {
            finite("background.vignetting_centre[0]", c[0])?;
            finite("background.vignetting_centre[1]", c[1])?;
        }
        for r in &b.dark {
            if let Some(x) = &r.x {
                interval("background.dark.x", x)?;
            }
            if let Some(y) = &r.y {
                interval("background.dark.y", y)?;
            }
            non_negative("background.dark.factor", r.factor)?;
            non_negative("background.dark.edge", r.edge)?;
        }
        match &self.mask {
            None => {}
            Some(MaskConfig::Rect { x, y }) => {
                interval("mask.x", x)?;
                interval("mask.y", y)?;
            }
            Some(MaskConfig::Circle { centre, radius }) => {
                finite("mask.centre[0]", centre[0])?;
                finite("mask.centre[1]", centre[1])?;
                non_negative("mask.radius", *radius)?;
            }
            Some(MaskConfig::Illumination { min }) => finite("mask.min", *min)?,
        }
        let n = &self.noise;
        non_negative("noise.read_noise", n.read_noise)?;
        non_negative("noise.gain", n.gain)?;
        finite("noise.offset", n.offset)?;
        if !matches!(self.bits, 8 | 12 | 16 | 32 | 64) {
            return Err(invalid(
                "bits",
                format!("must be 8, 12, 16, 32 or 64, got {}", self.bits),
            ));
        }
        let w = self.render.window_sigmas;
        if !(w.is_finite() && (3.0..=50.0).contains(&w)) {
            return Err(invalid(
                "render.window_sigmas",
                format!("must lie in [3, 50], got {w}"),
            ));
        }
        // Sites over the image plus the render margin, before anything is allocated.
        let margin = 2.0 * self.render_margin();
        let sites = (self.width as f64 + margin) * (self.height as f64 + margin) / cell;
        if sites > MAX_SITES {
            return Err(invalid(
                "lattice.spacing",
                format!(
                    "{sites:.3e} lattice sites over the image: at most {MAX_SITES:.0e} are allowed"
                ),
            ));
        }
        if let Some(h) = self.truth.crlb_half_width
            && (h == 0 || h > 1000)
        {
            return Err(invalid(
                "truth.crlb_half_width",
                format!("must lie in [1, 1000], got {h}"),
            ));
        }
        Ok(())
    }

    /// Half-width of the truth (bound) window.
    pub fn crlb_half_width(&self) -> usize {
        self.truth
            .crlb_half_width
            .unwrap_or_else(|| ((self.lattice.spacing / 2.0).round() as usize).max(1))
    }

    /// The noise model of the scene, as the bound uses it: `read_noise² (+ 1/12 for the
    /// rounding of quantised images) + gain · max(μ - offset, 0)`.
    pub fn noise_model(&self) -> bostrack_core::NoiseModel {
        let q = if self.bits <= 16 { 1.0 / 12.0 } else { 0.0 };
        bostrack_core::NoiseModel {
            read_variance: self.noise.read_noise * self.noise.read_noise + q,
            gain: self.noise.gain,
            offset: self.noise.offset,
        }
    }

    /// Saturation level `2^bits - 1` of quantised images; `None` for float.
    pub fn saturation(&self) -> Option<f64> {
        (self.bits <= 16).then(|| ((1u64 << self.bits) - 1) as f64)
    }

    /// Lattice sites whose dots can reach the image lie within this distance of it (px).
    pub(crate) fn render_margin(&self) -> f64 {
        let d = &self.dots;
        let f = &self.defects;
        let mut grow: f64 = 1.0;
        if f.defective > 0.0 {
            grow = grow.max(f.large).max(f.small).max(f.elongation);
        }
        grow *= 1.0 + 4.0 * d.sigma_jitter;
        (self.render.window_sigmas * d.sigma_x.max(d.sigma_y) * grow + 2.0).ceil()
    }
}

impl FlowConfig {
    /// Parse a TOML document (unknown keys are errors) and validate it.
    pub fn from_toml(text: &str) -> Result<Self, SynthError> {
        let cfg: FlowConfig = toml::from_str(text).map_err(|e| SynthError::Toml(e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Check every value; the error names the offending field.
    pub fn validate(&self) -> Result<(), SynthError> {
        non_negative("flow.blur", self.blur)?;
        match &self.displacement {
            DisplacementField::Zero => {}
            DisplacementField::Uniform { dx, dy } => {
                finite("flow.displacement.dx", *dx)?;
                finite("flow.displacement.dy", *dy)?;
            }
            DisplacementField::Affine {
                centre,
                offset,
                matrix,
            } => {
                for v in centre.iter().chain(offset).chain(matrix.iter().flatten()) {
                    finite("flow.displacement (affine)", *v)?;
                }
            }
            DisplacementField::Vortex {
                centre,
                strength,
                core,
            } => {
                finite("flow.displacement.centre", centre[0])?;
                finite("flow.displacement.centre", centre[1])?;
                finite("flow.displacement.strength", *strength)?;
                positive("flow.displacement.core", *core)?;
            }
            DisplacementField::GaussianBump {
                centre,
                amplitude,
                width,
            } => {
                finite("flow.displacement.centre", centre[0])?;
                finite("flow.displacement.centre", centre[1])?;
                finite("flow.displacement.amplitude", *amplitude)?;
                positive("flow.displacement.width", *width)?;
            }
        }
        Ok(())
    }
}
