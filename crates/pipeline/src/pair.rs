//! The per-frame pair pipeline: reference context (once per campaign) and one gradient frame.
//!
//! CONTRACT with helper "batch" (see /work/contract-run.md): the types and signatures below are
//! shared; they may grow fields but do not change shape without a note here.

use crate::error::PipelineError;
use crate::plan::Plan;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Stage wall times in seconds, in the order the stages ran.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StageTimes {
    /// `(stage name, seconds)`.
    pub stages: Vec<(String, f64)>,
}

/// Everything computed once per campaign: reference image + mask, its detection and fits, the
/// noise model (from the stack when given, else from the reference image), the no-flow stack's
/// per-dot scatter (u_ref, K) when a stack is configured and the outputs need it.
#[derive(Debug)]
pub struct ReferenceContext {
    size: (usize, usize),
    mask: Option<bostrack_core::Mask>,
    times: StageTimes,
}

impl ReferenceContext {
    /// Prepares the reference side of a campaign. Runs inside the caller's rayon pool.
    pub fn prepare(plan: &Plan) -> Result<ReferenceContext, PipelineError> {
        let _ = plan;
        Err(PipelineError::Unfinished)
    }

    /// Reference-side stage wall times (s).
    pub fn timings(&self) -> &StageTimes {
        &self.times
    }

    /// Reference-side facts for run.toml / the summary (dots found, noise, stack K...).
    pub fn summary(&self) -> serde_json::Value {
        serde_json::Value::Null
    }

    /// `(width, height)` of the reference image.
    pub fn image_size(&self) -> (usize, usize) {
        self.size
    }

    /// The region-of-interest mask, if one is configured.
    pub fn mask(&self) -> Option<&bostrack_core::Mask> {
        self.mask.as_ref()
    }
}

/// Per-frame summary (summary.json).
#[derive(Clone, Debug, Default, Serialize)]
pub struct FrameSummary {
    pub version: String,
    pub frame: PathBuf,
}

/// One processed gradient frame.
#[derive(Clone, Debug)]
pub struct FrameResult {
    /// File stem of the frame.
    pub stem: String,
    /// One per reference dot, reference order.
    pub dots: Vec<bostrack_displacement::PairDot>,
    pub summary: FrameSummary,
}

/// Processes one gradient frame against the reference context.
pub fn process_frame(
    ctx: &ReferenceContext,
    plan: &Plan,
    frame: &Path,
) -> Result<FrameResult, PipelineError> {
    let _ = (ctx, plan, frame);
    Err(PipelineError::Unfinished)
}

/// Writes `DIR/<stem>/dots.csv` and `DIR/<stem>/summary.json` atomically.
pub fn write_frame(out_dir: &Path, result: &FrameResult) -> Result<(), PipelineError> {
    let _ = (out_dir, result);
    Err(PipelineError::Unfinished)
}

/// Whether `DIR/<stem>/summary.json` exists (written last, so it marks a complete frame).
pub fn frame_is_complete(out_dir: &Path, stem: &str) -> bool {
    out_dir.join(stem).join("summary.json").is_file()
}
