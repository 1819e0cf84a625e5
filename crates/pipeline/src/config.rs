//! `pipeline.toml` as written: the first of the two configuration levels.
//!
//! Every struct here rejects unknown keys (`deny_unknown_fields` is not inherited, so it is on
//! each one) and fills missing keys from its `Default`, which is the single place a default is
//! written. The annotated template ([`crate::template`]) is generated from these defaults.

use bostrack_core::DotFlags;
use bostrack_displacement::DisplacementConfig;
pub use bostrack_io::Saturation;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// A whole campaign configuration, one section per stage.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PipelineConfig {
    pub input: InputConfig,
    pub detect: DetectSection,
    pub fit: FitSection,
    /// `[match]` in the file (`match` is a Rust keyword).
    #[serde(rename = "match")]
    pub matching: MatchConfig,
    pub uncertainty: UncertaintyConfig,
    pub output: OutputConfig,
    pub run: RunConfig,
    /// `[optics]`, `[geometry]`, `[constants]`: the optical setup with the keys and meaning of
    /// `bostrack crlb`'s setup file (`bostrack_theory`; `[flow]`, `[view]`, `[camera]` of that
    /// file are accepted and not used). With `[optics]` a run also writes the density gradient
    /// per dot and the density field (`[density]`, crate::density); without, nothing of it runs.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub optics: Option<bostrack_theory::Optics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub geometry: Option<bostrack_theory::Geometry>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub constants: Option<bostrack_theory::Constants>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flow: Option<bostrack_theory::Flow>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view: Option<bostrack_theory::View>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera: Option<bostrack_theory::Camera>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub density: Option<crate::density::DensitySection>,
}

impl PipelineConfig {
    /// The default configuration with the campaign folder `input.dir` set to `dir`.
    pub fn with_input_dir(dir: impl Into<PathBuf>) -> Self {
        let mut cfg = PipelineConfig::default();
        cfg.input.dir = dir.into();
        cfg
    }
}

/// `[detect]`: the detection stage's own configuration.
pub type DetectSection = bostrack_detect::DetectConfig;

/// `[fit]`: the fit stage's own configuration.
pub type FitSection = bostrack_fit::FitConfig;

/// Where the reference (no-flow) image comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReferenceFrom {
    /// The file named by `input.reference`.
    File,
    /// The pixel-wise mean of the no-flow stack.
    StackMean,
}

/// `[input]`: the images of one campaign. Paths are relative to `dir`, which is itself relative
/// to the configuration file's folder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InputConfig {
    /// Campaign folder.
    pub dir: PathBuf,
    /// Whether the reference image is a file or the mean of the no-flow stack.
    pub reference_from: ReferenceFrom,
    /// Reference image file (used when `reference_from = "file"`).
    pub reference: PathBuf,
    /// The no-flow stack as one multi-page TIFF file (many cameras write one); empty to read
    /// the stack from `stack_dir`. When set, `stack_dir` and `stack_glob` are not used.
    pub stack: PathBuf,
    /// Folder of the no-flow stack; empty for none.
    pub stack_dir: PathBuf,
    /// File-name pattern of the stack images.
    pub stack_glob: String,
    /// Folder of the gradient (flow-on) images.
    pub gradient_dir: PathBuf,
    /// File-name pattern of the gradient images.
    pub gradient_glob: String,
    /// Region-of-interest mask; empty for the whole image.
    pub mask: PathBuf,
    /// Clip level of the camera data: `"auto"` (found in every image read, see
    /// `bostrack_io::find_clip_level`) or a level in counts. Samples at or above it are left
    /// out of the fits and flag their dot `saturated`.
    pub saturation: Saturation,
}

impl Default for InputConfig {
    fn default() -> Self {
        InputConfig {
            dir: PathBuf::from("."),
            reference_from: ReferenceFrom::File,
            reference: PathBuf::from("reference.tif"),
            stack: PathBuf::new(),
            stack_dir: PathBuf::from("stack"),
            stack_glob: "*.tif".into(),
            gradient_dir: PathBuf::from("gradient"),
            gradient_glob: "*.tif".into(),
            mask: PathBuf::new(),
            saturation: Saturation::Auto,
        }
    }
}

/// `[match]`: pairing each reference dot with its partner in a gradient image, and validating
/// the displacements with the normalised median test (Westerweel & Scarano, Exp. Fluids 39:1096,
/// 2005): a displacement is an outlier when `|d - median(d_nb)| / (median(|d_nb - median(d_nb)|)
/// + epsilon) > threshold` over its 8 grid neighbours.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MatchConfig {
    /// Largest distance to a partner, as a fraction of the dot spacing (0, 1].
    pub search_radius: f64,
    /// Median-test epsilon (px): the displacement noise floor.
    pub median_epsilon: f64,
    /// Median-test threshold (dimensionless).
    pub median_threshold: f64,
    /// Displacements longer than this (px) are outliers; `None`: no threshold.
    pub max_displacement: Option<f64>,
    /// A frame in which fewer than this fraction of the fitted reference dots are matched is
    /// an error (a wrong or empty image), not a result.
    pub min_matched_fraction: f64,
    /// Names of flags that by default make a displacement invalid but are to leave it valid
    /// here (only those of [`MatchConfig::KEEPABLE`]; the flags stay in the `flags` column).
    pub keep_flagged: Vec<String>,
}

impl MatchConfig {
    /// The flags `keep_flagged` may name: the fit-quality flags whose dots are invalid by
    /// default (`bostrack_displacement::DisplacementConfig::DEFAULT_INVALID_IF`) but still carry
    /// a displacement that a user may judge usable.
    pub const KEEPABLE: [DotFlags; 2] = [DotFlags::UNCONVERGED, DotFlags::RESIDUAL];

    /// The flags that make a displacement invalid: the default set without those named by
    /// `keep_flagged`. `Err` with the first name that is not one of [`MatchConfig::KEEPABLE`].
    pub fn invalid_if(&self) -> Result<DotFlags, String> {
        let mut flags = DisplacementConfig::DEFAULT_INVALID_IF;
        for name in &self.keep_flagged {
            let flag = Self::KEEPABLE
                .into_iter()
                .find(|f| f.to_string() == *name)
                .ok_or_else(|| name.clone())?;
            flags.remove(flag);
        }
        Ok(flags)
    }
}

impl Default for MatchConfig {
    fn default() -> Self {
        MatchConfig {
            search_radius: 0.4,
            median_epsilon: 0.1,
            median_threshold: 2.0,
            max_displacement: None,
            min_matched_fraction: 0.1,
            keep_flagged: Vec::new(),
        }
    }
}

/// Which position of a reference dot the displacement is measured from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReferencePosition {
    /// The fit in the single reference image (uncertainty u_ref). The default, as in
    /// `bostrack-displacement`.
    Image,
    /// The mean of the fits over the K no-flow stack images (uncertainty u_ref / sqrt(K)).
    StackMean,
}

/// Which amplification-ratio formula to use: the model crate's own (serde names `notes`,
/// `bounds`, `published`; docs/paper/NOTES.md §2). The pipeline's default is `bounds`
/// ([`UncertaintyConfig::default`]).
pub use bostrack_model::ArVariant;

/// `[uncertainty]`: per-dot displacement uncertainty.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct UncertaintyConfig {
    /// Remove each no-flow image's common-mode shift before the per-dot scatter is computed.
    pub common_mode: bool,
    /// Reference position: single image or stack mean.
    pub reference_position: ReferencePosition,
    /// Amplification-ratio variant; default `bounds` (the ratio of the two fits' Cramér-Rao
    /// bounds, which needs `[fit] bound = true`), as in `bostrack-displacement`.
    pub ar_variant: ArVariant,
}

impl Default for UncertaintyConfig {
    fn default() -> Self {
        UncertaintyConfig {
            common_mode: true,
            reference_position: ReferencePosition::Image,
            ar_variant: DisplacementConfig::default().ar_variant,
        }
    }
}

/// A figure the run can draw.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Figure {
    /// Campaign figure: the reference dots at their positions, coloured by the magnitude of
    /// their Cramér-Rao bound; dots without a usable reference fit marked (`DIR/detections.*`).
    Detections,
    /// Per frame: displacement arrows over the dots coloured by |d| (`displacement.*`).
    Displacement,
    /// Per frame: map of the displacement uncertainty |u_d| (`uncertainty.*`).
    Uncertainty,
    /// Per frame: map of the amplification ratio max(AR_x, AR_y) (`amplification.*`).
    Amplification,
    /// Per frame: histograms of the position uncertainty magnitudes u_ref and u_grad (the
    /// paper's Fig. 6c,f; `uncertainty-histogram.*`) and of max(AR_x, AR_y) (`ar-histogram.*`).
    Histograms,
    /// Campaign figure: median |d| and median |u_d| against the frame number
    /// (`DIR/campaign.*`).
    Campaign,
    /// Per frame, only with `[optics]`: maps of the density ρ (`density.*`) and of its 1σ
    /// uncertainty u_ρ (`density-uncertainty.*`), kg/m³.
    Density,
}

impl Figure {
    /// Every figure, in the order of the documentation.
    pub const ALL: [Figure; 7] = [
        Figure::Detections,
        Figure::Displacement,
        Figure::Uncertainty,
        Figure::Amplification,
        Figure::Histograms,
        Figure::Campaign,
        Figure::Density,
    ];

    /// The name used in `pipeline.toml`.
    pub fn name(self) -> &'static str {
        match self {
            Figure::Detections => "detections",
            Figure::Displacement => "displacement",
            Figure::Uncertainty => "uncertainty",
            Figure::Amplification => "amplification",
            Figure::Histograms => "histograms",
            Figure::Campaign => "campaign",
            Figure::Density => "density",
        }
    }
}

/// A file format of the figures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FigureFormat {
    /// 8-bit RGB PNG.
    Png,
    /// SVG (text as `<text>` elements).
    Svg,
}

impl FigureFormat {
    /// The file extension (and the name used in `pipeline.toml`).
    pub fn extension(self) -> &'static str {
        match self {
            FigureFormat::Png => "png",
            FigureFormat::Svg => "svg",
        }
    }
}

/// A file format of the per-frame lattice arrays (`crate::LatticeFields`: every `dots.csv`
/// quantity as a 2-D array, rows i, columns j).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ArrayFormat {
    /// numpy `.npz` (`<frame>/fields.npz`).
    Npz,
    /// MATLAB Level 5 MAT-file (`<frame>/fields.mat`).
    Mat,
}

impl ArrayFormat {
    /// The file name in a frame's folder.
    pub fn file_name(self) -> &'static str {
        match self {
            ArrayFormat::Npz => "fields.npz",
            ArrayFormat::Mat => "fields.mat",
        }
    }
}

/// What the pair pipeline computes per dot; each level includes the ones before it, and
/// nothing beyond the level asked for is computed (no stack fits below `uncertainty`, no
/// amplification ratio below `amplification`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Quantities {
    /// Displacement (and the per-dot bound of both fits).
    Displacement,
    /// Displacement and amplification ratio.
    Amplification,
    /// Displacement, amplification ratio, and the stack's u_ref, u_grad = AR u_ref, u_d.
    Uncertainty,
}

impl Quantities {
    /// The name used in `pipeline.toml`.
    pub fn name(self) -> &'static str {
        match self {
            Quantities::Displacement => "displacement",
            Quantities::Amplification => "amplification",
            Quantities::Uncertainty => "uncertainty",
        }
    }
}

/// `[output]`: what a run writes, and where. Every frame always gets its `dots.csv` and
/// `summary.json` (they also mark the frame as complete for reruns and `bostrack merge`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Output folder (relative to the configuration file's folder).
    pub dir: PathBuf,
    /// What is computed per dot (each level includes the ones before it).
    pub quantities: Quantities,
    /// Figures to draw.
    pub figures: Vec<Figure>,
    /// File formats of every figure.
    pub figure_formats: Vec<FigureFormat>,
    /// Lattice arrays per frame (`<frame>/fields.npz`, `<frame>/fields.mat`; default none).
    pub arrays: Vec<ArrayFormat>,
    /// Recompute every frame and accept an output folder of another configuration (as
    /// `bostrack run --force`).
    pub overwrite: bool,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            dir: PathBuf::from("out"),
            quantities: Quantities::Uncertainty,
            figures: Figure::ALL.to_vec(),
            figure_formats: vec![FigureFormat::Png],
            arrays: Vec::new(),
            overwrite: false,
        }
    }
}

/// `[run]`: how the work is run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Worker threads; 0 = every CPU available to the process (see [`crate::available_jobs`]).
    pub jobs: usize,
    /// Most frames processed at once (each holds its image and fit state, ~56 MB for a 1-MP
    /// frame); their stages share the `jobs` threads. 0 = automatic
    /// ([`crate::frames_in_flight`]).
    pub frames_in_flight: usize,
}
