//! The per-frame pair pipeline: the reference side once per campaign ([`ReferenceContext`]),
//! then each gradient frame ([`process_frame`]) and its outputs ([`write_frame`]).
//!
//! CONTRACT with helper "batch" (/work/contract-run.md): the types and signatures of
//! `ReferenceContext::{prepare, timings, summary, image_size, mask}`, `FrameResult`,
//! `FrameSummary`, `StageTimes`, `process_frame`, `write_frame` and `frame_is_complete` are
//! shared; they may grow fields but do not change shape without a note here.
//! Notes: `PipelineError::SizeMismatch` has a `what` field ("image size", "bit depth", ...).
//! Note from batch: `FrameMedians::abs_u_d` (median |u_d| over the valid dots, computed next to
//! `abs_d` in pair/frame.rs) was added by batch; the campaign figure plots `medians.abs_d` and
//! `medians.abs_u_d` from summary.json.
//!
//! # The chain
//! Reference side ([`ReferenceContext::prepare`]):
//! 1. **decode** the reference image (or the pixel mean of the no-flow stack) and the mask;
//! 2. **noise** model (variance against mean, docs/CONVENTIONS.md): from the no-flow stack when
//!    one is configured (`bostrack_fit::noise_from_stack`), else from the reference image
//!    (`bostrack_fit::estimate_noise`). It weights every fit and sets every per-dot bound;
//! 3. **detect** the lattice and one seed per site (`bostrack_detect::detect`);
//! 4. **fit** every seed (`bostrack_fit::fit_dots`; rayon over dots);
//! 5. only with `[output] quantities = "uncertainty"`: the **stack** — every no-flow image is
//!    tracked from the reference seeds (`bostrack_detect::track`, grid indices kept), fitted,
//!    matched to the reference fits (`bostrack_match::match_dots`: by grid index, kd-tree as
//!    fall-back and cross-check; pairs flagged `GRID_MISMATCH` are left out) and the per-dot
//!    scatter is taken after removing each image's common-mode shift
//!    (`bostrack_uncertainty::reference_stack`): `u_ref` per dot (sample std, divisor K - 1),
//!    with relative standard error `1/sqrt(2(K - 1))` (24 % at K = 10).
//!
//! Per frame ([`process_frame`]):
//! 1. **decode**; the image must have the reference's size;
//! 2. **detect**: track the reference seeds into the frame (grid indices kept);
//! 3. **fit** every tracked seed with the campaign's noise model;
//! 4. **match** the fits to the reference fits (grid index, kd-tree fall-back and cross-check,
//!    search radius `[match] search_radius` × spacing, iterative local-median predictor seeded
//!    with the median tracked displacement) and **validate** the displacements (optional
//!    threshold `[match] max_displacement`, then the normalised median test of Westerweel &
//!    Scarano 2005 over the 8 nearest vectors; outliers are flagged `OUTLIER`, never replaced);
//! 5. **pair**: per reference dot `d = x_grad - x_ref`, the amplification ratio (by default
//!    the ratio of the two fits' bounds; the closed form of NOTES.md §2 with `ar_variant =
//!    "notes"`, the published variant only with `"published"`), `u_grad = AR · u_ref`,
//!    `u_d = sqrt(u_refpos² + u_grad²)`, and `valid` unless a flag of [`Plan::invalid_if`]
//!    is set (`bostrack_displacement::pair_dot`).
//!
//! [`Plan::invalid_if`]: crate::Plan::invalid_if
//!
//! **AR shapes** (for the `notes` and `published` variants; `bounds` takes no shapes). With the
//! default least-squares fit of the pixel-integrated model the fitted sigmas are those of the dot
//! *before* the pixel box; the light the pixels record is that dot blurred by the box, so AR is
//! evaluated on `bostrack_displacement::pixel_blurred` shapes
//! ([`ArShapes::PixelBlurred`](bostrack_displacement::ArShapes)): the plain formula on
//! pixel-integrated fits is off by 3 % at σ = 1.5 px and 7.5 % at σ = 1 px. Point-sampled fits
//! and the moment estimators already describe the recorded light: AR on the fitted shapes.
//!
//! **Determinism.** Every parallel loop collects in input order, so `dots.csv` is
//! byte-identical whatever the number of threads; only the wall times in `summary.json` differ.

mod frame;
mod output;
mod reference;
mod stats;

pub use frame::{process_frame, process_image};
pub use output::{frame_is_complete, write_frame};
pub use reference::ReferenceContext;

use serde::Serialize;
use std::path::PathBuf;

/// Stage wall times in seconds, in the order the stages ran. Serialised as a JSON object
/// `{"decode": 0.012, ...}` in that order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// `(stage name, seconds)`.
    pub stages: Vec<(String, f64)>,
}

impl StageTimes {
    /// Seconds of a stage (summed if it ran more than once), `None` if it did not run.
    pub fn get(&self, stage: &str) -> Option<f64> {
        let mut found = None;
        for (n, s) in &self.stages {
            if n == stage {
                *found.get_or_insert(0.0) += s;
            }
        }
        found
    }

    /// Sum over every stage.
    pub fn total(&self) -> f64 {
        self.stages.iter().map(|(_, s)| s).sum()
    }

    pub(crate) fn push(&mut self, stage: &str, seconds: f64) {
        self.stages.push((stage.to_string(), seconds));
    }
}

impl Serialize for StageTimes {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = s.serialize_map(Some(self.stages.len()))?;
        for (n, t) in &self.stages {
            m.serialize_entry(n, t)?;
        }
        m.end()
    }
}

/// Dot counts of one frame.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct FrameCounts {
    /// Reference sites (rows of `dots.csv`), MISSING ones included.
    pub reference_sites: usize,
    /// Reference dots with a usable fit.
    pub reference_fitted: usize,
    /// Gradient dots with a usable fit ("found").
    pub found: usize,
    /// Pairs with a usable fit on both sides.
    pub matched: usize,
    /// Pairs found by grid index / by the kd-tree fall-back.
    pub matched_by_index: usize,
    pub matched_by_nearest: usize,
    /// Pairs whose grid index and kd-tree match disagree (`GRID_MISMATCH`).
    pub grid_mismatches: usize,
    /// Reference records without a partner, and gradient records without one.
    pub unmatched_reference: usize,
    pub unmatched_gradient: usize,
    /// Displacements rejected by the validation (`OUTLIER`).
    pub outliers: usize,
    /// Rows with `valid = true`.
    pub valid: usize,
}

/// Medians over the valid dots (`None` where no valid dot has the quantity). Per-axis values
/// are `[x, y]`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FrameMedians {
    /// Median |d| (px).
    pub abs_d: Option<f64>,
    /// Median |u_d| = √(u_dx² + u_dy²) (px; plotted by the campaign figure).
    pub abs_u_d: Option<f64>,
    pub d: [Option<f64>; 2],
    pub ar: [Option<f64>; 2],
    /// 99th percentile of AR.
    pub ar_p99: [Option<f64>; 2],
    pub u_ref: [Option<f64>; 2],
    pub u_grad: [Option<f64>; 2],
    pub u_d: [Option<f64>; 2],
    /// Per-dot Cramér-Rao bound of the reference and the gradient fits (px).
    pub crlb_ref: [Option<f64>; 2],
    pub crlb_grad: [Option<f64>; 2],
}

/// The noise model every fit was weighted with: `variance = read_variance + gain · max(mean -
/// offset, 0)` counts².
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NoiseSummary {
    pub read_variance: f64,
    pub gain: f64,
    pub offset: f64,
    /// `"stack"` (`noise_from_stack`) or `"reference image"` (`estimate_noise`).
    pub source: String,
}

/// The no-flow stack statistics behind the `u_ref` columns.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StackSummary {
    /// K: images in the stack.
    pub images: usize,
    /// Relative standard error of a per-dot u_ref from K images, `1/sqrt(2(K - 1))`.
    pub relative_standard_error: f64,
    /// Reference dots with a u_ref.
    pub dots_with_u_ref: usize,
    /// Median u_ref over those dots (px).
    pub median_u_ref: [Option<f64>; 2],
    /// Whether each image's common-mode shift was removed, and the RMS of those shifts (px).
    pub common_mode_removed: bool,
    pub shift_rms: [f64; 2],
}

/// Per-frame summary (`summary.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FrameSummary {
    /// bostrack version.
    pub version: String,
    /// The gradient image.
    pub frame: PathBuf,
    /// `[output] quantities` ("displacement", "amplification", "uncertainty").
    pub quantities: String,
    /// Shapes the amplification ratio was evaluated on: "pixel-blurred" or "fitted".
    pub ar_shapes: String,
    /// Amplification-ratio variant: "bounds", "notes" or "published".
    pub ar_variant: String,
    pub counts: FrameCounts,
    pub medians: FrameMedians,
    pub noise: Option<NoiseSummary>,
    pub stack: Option<StackSummary>,
    /// Why the stack columns (u_ref, u_grad, u_d) are empty, when they are.
    pub stack_note: Option<String>,
    /// The frame's clip level and how it was found (`[input] saturation`); `None` for an image
    /// handed over in memory ([`process_image`]), whose `meta.saturation` is used as it is.
    pub saturation: Option<bostrack_io::ClipLevel>,
    /// The density field (only with `[optics]`; absent from `summary.json` otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub density: Option<crate::density::DensitySummary>,
    /// Frame stage wall times (s): decode, detect, fit, match, pair (and density).
    pub times: StageTimes,
}

/// One processed gradient frame.
#[derive(Clone, Debug)]
pub struct FrameResult {
    /// File stem of the frame.
    pub stem: String,
    /// One per reference dot, reference order.
    pub dots: Vec<bostrack_displacement::PairDot>,
    /// With `[optics]`: per dot (same order) the position and density gradient in SI units.
    pub physical: Option<Vec<crate::density::PhysicalDot>>,
    /// With `[optics]`: the density field on the lattice.
    pub density: Option<crate::density::FrameDensity>,
    pub summary: FrameSummary,
}
