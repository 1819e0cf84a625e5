//! Batch processing of a campaign: every gradient frame of a [`Plan`], in parallel, with
//! resumable, atomic per-frame outputs, a campaign summary and figures; shards for clusters and
//! their merge.
//!
//! Output folder `DIR` ([`run_batch`]):
//!
//! ```text
//! DIR/run.toml              run record: version, inputs, fully resolved configuration
//! DIR/<stem>/dots.csv       per dot of frame <stem> (columns: bostrack_displacement::COLUMNS)
//! DIR/<stem>/summary.json   per-frame summary; written last: its presence marks the frame done
//! DIR/<stem>/*.png|svg      per-frame figures, then figures.json (what was drawn or skipped)
//! DIR/campaign.csv, .json   one row per frame: status, counts, medians, then timings (*_s)
//! DIR/failures.json         the frames that failed, each with its file and the reason
//! DIR/campaign.png|svg, DIR/detections.png|svg   campaign figures
//! DIR/shards/shard-K-of-N.toml, .json   the record and outcome of shard K of N
//! ```
//!
//! **Frames are numbered from 1** in natural order of their file names (`frame2` before
//! `frame10`). A run with `--shard K/N` ([`Shard`]) processes frames `n` with
//! `(n - 1) mod N = K - 1` and writes only those frames and its own records under
//! `DIR/shards/`; [`merge_campaign`] builds the campaign files from whatever frames are
//! complete. An unsharded run ends with the same merge, so the campaign files of N merged
//! shards equal those of one run (apart from the timing columns).
//!
//! **Resumable and idempotent.** A frame whose `summary.json` exists (and whose requested
//! figures are recorded in `figures.json`) is skipped; `force` recomputes it. Every file is
//! written under a temporary name and renamed, and a killed run's temporaries are removed when
//! the frame is next computed, so an interrupted run leaves no half-written frame. A folder
//! written with another configuration (detection, fit, matching, uncertainty, quantities,
//! reference, stack or mask) is refused unless `force`; added gradient frames are simply
//! computed.
//!
//! **Changed inputs** ([`inputs`]). The run record holds the fingerprint (size, modification
//! time, XXH3-128 content hash) of every reference-side file and of the run's frames, and each
//! frame's `DIR/<stem>/inputs.json` (written after its outputs) that of its gradient image and
//! a digest of the reference side. A complete frame whose image changed, or whose record is
//! missing or names another reference side, is computed again (with a note); a changed
//! reference image, mask or no-flow image is refused ([`BatchError::InputsChanged`], naming
//! the files) unless `force`.
//!
//! **Failures are data.** A frame that cannot be processed (unreadable file, no dots) is
//! recorded with its reason in `failures.json`; the other frames finish. Only configuration
//! and reference-side problems stop a run ([`BatchError`]).
//!
//! **Deterministic.** Frames are independent and every output is written per frame, so the
//! outputs do not depend on the number of threads (the caller's rayon pool).
//!
//! **Flat memory.** Frames are streamed: a worker holds one frame at a time and drops it once
//! written; the campaign files are built from the per-frame files.

pub(crate) mod campaign;
pub(crate) mod dots;
pub(crate) mod fsx;
pub(crate) mod inputs;
pub(crate) mod record;
mod shard;

pub use shard::{Shard, ShardError};

use crate::error::{ConfigError, PipelineError};
use crate::figures::{FigureSetup, FigureSpec, draw_frame_figures, write_frame_arrays};
use crate::pair::{ReferenceContext, frame_is_complete, process_frame, write_frame};
use crate::plan::{Plan, ReferenceImage};
use inputs::{Fingerprint, FrameInputs, Freshness, freshness};
use rayon::prelude::*;
use record::{RUN_RECORD, RunRecord, SHARDS_DIR};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// What stops a batch command: configuration, reference-side or output-folder problems. A
/// single frame's problem is never one of these (it is a [`FrameFailure`]).
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    /// The configuration or the files it names.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The reference side of the campaign could not be prepared.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// An image or mask needed for the figures could not be read.
    #[error(transparent)]
    Io(#[from] bostrack_io::IoError),
    /// A file or folder could not be written.
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A file could not be read.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The output folder is not a folder and cannot be created (a file, a link loop).
    #[error("{}: cannot be the output folder: {problem}", path.display())]
    OutputDir { path: PathBuf, problem: String },
    /// A file of an output folder is not what bostrack writes.
    #[error("{}: {message}", path.display())]
    Corrupt { path: PathBuf, message: String },
    /// The frames of the campaign cannot be given one output folder each.
    #[error("{}: {message}", path.display())]
    Frames { path: PathBuf, message: String },
    /// The output folder holds results of another configuration.
    #[error(
        "{}: the output folder holds results of another configuration ({what} differs); use \
         --force (or output.overwrite = true) to recompute every frame, or another output folder",
        path.display()
    )]
    Mismatch { path: PathBuf, what: String },
    /// Files on the reference side (reference image, mask, no-flow images) changed since the
    /// results in the output folder were computed: every frame depends on them.
    #[error(
        "{}: the results in this folder were computed from other versions of {}: {}; every \
         frame depends on them: use --force (or output.overwrite = true) to recompute every \
         frame, or another output folder",
        path.display(),
        if files.len() == 1 { "a reference-side file" } else { "reference-side files" },
        files.join("; ")
    )]
    InputsChanged { path: PathBuf, files: Vec<String> },
    /// The records of an output folder disagree (shards run with different configurations).
    #[error(
        "{} and {} disagree ({what} differs): rerun the shards with one configuration (--force)",
        first.display(),
        second.display()
    )]
    RecordsDisagree {
        first: PathBuf,
        second: PathBuf,
        what: String,
    },
    /// The run was stopped ([`Progress::cancelled`]) before every frame was computed; the
    /// frames done are complete, and a rerun computes the rest.
    #[error(
        "{}: interrupted after {done} of {to_do} frames; the frames done are complete, and a \
         rerun computes the rest",
        path.display()
    )]
    Interrupted {
        path: PathBuf,
        done: usize,
        to_do: usize,
    },
    /// A folder without any run record.
    #[error(
        "{}: no run record ({RUN_RECORD} or {SHARDS_DIR}/shard-K-of-N.toml): not a bostrack run folder",
        dir.display()
    )]
    NoRecord { dir: PathBuf },
}

/// How a batch run is asked to behave.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BatchOptions {
    /// Output folder; `None`: the plan's `output.dir`.
    pub out_dir: Option<PathBuf>,
    /// Recompute every frame, even complete ones, and accept a folder written with another
    /// configuration (also set by `output.overwrite`).
    pub force: bool,
    /// Process only this shard's frames.
    pub shard: Option<Shard>,
}

/// What happened to one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FrameStatus {
    /// Processed and written.
    Computed,
    /// Its outputs were complete but some requested figures were missing: drawn.
    FiguresDrawn,
    /// Complete already: nothing done.
    Skipped,
    /// Could not be processed (see [`FrameFailure`]).
    Failed,
}

/// One frame's outcome, as reported to [`Progress::frame_done`].
#[derive(Clone, Copy, Debug)]
pub struct FrameEvent<'a> {
    /// Frame number, from 1.
    pub frame: usize,
    pub stem: &'a str,
    pub status: FrameStatus,
    /// The reason of a failure.
    pub error: Option<&'a str>,
    /// Wall time spent on it (s).
    pub seconds: f64,
}

/// Receives the progress of a batch run (called from worker threads).
pub trait Progress: Sync {
    /// Before the first frame: frames to work on and frames skipped as complete.
    fn start(&self, _to_do: usize, _skipped: usize) {}
    /// After each frame that was worked on.
    fn frame_done(&self, _event: &FrameEvent<'_>) {}
    /// A warning that does not stop anything (e.g. a figure with nothing to plot).
    fn note(&self, _message: &str) {}
    /// A step of the run outside the frame loop begins (e.g. preparing the reference).
    fn phase(&self, _what: &str) {}
    /// After the last frame.
    fn finish(&self) {}
    /// Whether the run is to stop (asked before each frame; e.g. Ctrl-C in the Python
    /// package): frames not started then are left, and the run ends with
    /// [`BatchError::Interrupted`] once the frames in progress are written.
    fn cancelled(&self) -> bool {
        false
    }
}

/// A [`Progress`] that reports nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Progress for Silent {}

/// A frame that could not be processed.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameFailure {
    /// Frame number, from 1.
    pub frame: usize,
    pub stem: String,
    /// The gradient image.
    pub file: PathBuf,
    /// Why (names the file and the problem).
    pub reason: String,
}

/// What a batch run did.
#[derive(Clone, Debug, PartialEq)]
pub struct BatchReport {
    /// The output folder.
    pub out_dir: PathBuf,
    /// Frames of the campaign (all shards).
    pub campaign_frames: usize,
    /// Frames of this run (this shard's share).
    pub frames: usize,
    pub computed: usize,
    /// Of the computed frames, those whose complete outputs no longer described their inputs
    /// (the gradient file changed, or the outputs carry no input record): recomputed.
    pub stale: usize,
    pub figures_drawn: usize,
    pub skipped: usize,
    /// Frames of this run that failed, in frame order.
    pub failures: Vec<FrameFailure>,
    /// Wall time of the run (s).
    pub seconds: f64,
    /// Whether the campaign files were written (not by a shard).
    pub campaign_written: bool,
}

/// What a merge found.
#[derive(Clone, Debug, PartialEq)]
pub struct MergeReport {
    pub out_dir: PathBuf,
    /// Frames of the campaign (union of the records' frames).
    pub frames: usize,
    /// Frames with complete outputs.
    pub complete: usize,
    /// Frames without complete outputs, with the recorded reason (or "not processed").
    pub failures: Vec<FrameFailure>,
    /// Run records found.
    pub records: usize,
    /// Frames whose missing figures were drawn.
    pub figures_drawn: usize,
}

/// A gradient frame of the campaign.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct FrameRef {
    /// From 1, natural order.
    pub number: usize,
    pub stem: String,
    pub path: PathBuf,
}

impl FrameRef {
    /// The title naming the frame in its figures.
    pub fn title(&self, total: usize) -> String {
        let name = self
            .path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.stem.clone());
        format!("{name} (frame {} of {total})", self.number)
    }
}

/// Numbers the frames from 1 and gives each its output folder name (the file stem), refusing
/// names that two frames share or that would collide with the run's own files. Paths are made
/// absolute, as in the run records.
pub(crate) fn frame_refs(paths: &[PathBuf], source: &Path) -> Result<Vec<FrameRef>, BatchError> {
    let mut seen: HashMap<String, &Path> = HashMap::new();
    let mut out = Vec::with_capacity(paths.len());
    for (k, p) in paths.iter().enumerate() {
        let stem = p
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let bad = |message: String| BatchError::Frames {
            path: source.to_path_buf(),
            message,
        };
        if stem.is_empty() || stem.starts_with('.') || stem == SHARDS_DIR {
            return Err(bad(format!(
                "{}: a frame's output folder is named after its file stem, and `{stem}` cannot be \
                 one (empty, hidden or reserved); rename the file or narrow input.gradient_glob",
                p.display()
            )));
        }
        if let Some(other) = seen.insert(stem.clone(), p) {
            return Err(bad(format!(
                "{} and {} share the stem `{stem}` (each frame's outputs go to DIR/<stem>/); \
                 narrow input.gradient_glob",
                other.display(),
                p.display()
            )));
        }
        out.push(FrameRef {
            number: k + 1,
            stem,
            path: record::canonical(p),
        });
    }
    Ok(out)
}

/// What to do with one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Action {
    /// Not complete (or forced): compute.
    Compute,
    /// Complete, but its outputs no longer describe its inputs: compute again.
    Recompute,
    Figures,
    Skip,
}

impl Action {
    fn computes(self) -> bool {
        matches!(self, Action::Compute | Action::Recompute)
    }
}

/// Runs a campaign (or one shard of it) into its output folder, in the current rayon pool
/// (install the pool with the wanted number of threads around the call).
///
/// Returns the report; frames that failed are in [`BatchReport::failures`] (the command's exit
/// code 2). Errors only for the configuration, the reference side, an output folder written
/// with another configuration (unless `force`) or an output folder that cannot be written.
pub fn run_batch(
    plan: &Plan,
    options: &BatchOptions,
    progress: &dyn Progress,
) -> Result<BatchReport, BatchError> {
    let t0 = Instant::now();
    let out = options
        .out_dir
        .clone()
        .unwrap_or_else(|| plan.output.dir.clone());
    let frames = frame_refs(&plan.gradients, &plan.config_file)?;
    let mine: Vec<&FrameRef> = frames
        .iter()
        .filter(|f| options.shard.is_none_or(|s| s.contains(f.number)))
        .collect();
    if let Some(problem) = crate::files::output_dir_problem(&out) {
        return Err(BatchError::OutputDir { path: out, problem });
    }
    fsx::create_dir(&out)?;
    let force = options.force || plan.output.overwrite;
    let jobs = rayon::current_num_threads();
    let mut record = RunRecord::new(plan, &out, options.shard, jobs)?;
    let mut olds: Vec<(PathBuf, Option<RunRecord>)> = Vec::new();
    for path in record::record_files(&out) {
        match RunRecord::read(&path) {
            Ok(old) => olds.push((path, Some(old))),
            Err(e) if !force => return Err(e),
            Err(_) => olds.push((path, None)),
        }
    }
    let known: Vec<&RunRecord> = olds.iter().filter_map(|(_, r)| r.as_ref()).collect();
    record.fingerprint_reference_side(&known)?;
    for (path, old) in &olds {
        let problem = match old {
            None => Some(BatchError::Mismatch {
                path: path.clone(),
                what: "the record itself".into(),
            }),
            Some(old) => match record.differs_from(old) {
                Some(what) => Some(BatchError::Mismatch {
                    path: path.clone(),
                    what,
                }),
                None => {
                    let files = record.changed_inputs(old);
                    (!files.is_empty()).then(|| BatchError::InputsChanged {
                        path: path.clone(),
                        files,
                    })
                }
            },
        };
        match problem {
            None => {}
            Some(e) if !force => return Err(e),
            // Forced: a record of another configuration no longer describes the folder. An
            // unsharded run recomputes every frame, so it drops the shard records; a shard
            // drops run.toml (merge writes it again once every shard agrees).
            Some(_) => {
                let is_run = path.file_name() == Some(RUN_RECORD.as_ref());
                if is_run == options.shard.is_some() {
                    let _ = std::fs::remove_file(path);
                    let _ = std::fs::remove_file(path.with_extension("json"));
                }
            }
        }
    }

    let spec = FigureSpec {
        figures: plan.output.figures.clone(),
        formats: plan.output.figure_formats.clone(),
        arrays: plan.output.arrays.clone(),
    };
    // Each frame's inputs now against those its outputs were computed from (a file is read
    // only when its size or time differ from the recorded ones).
    let reference_side = record.reference_side_key();
    let checked: Vec<(Option<Fingerprint>, Action, Option<String>)> = mine
        .par_iter()
        .map(|f| {
            let dir = out.join(&f.stem);
            let complete = !force && frame_is_complete(&out, &f.stem);
            let stored = complete.then(|| FrameInputs::read(&dir)).flatten();
            let now = Fingerprint::of(&f.path, stored.as_ref().map(|s| &s.frame)).ok();
            if !complete {
                return (now, Action::Compute, None);
            }
            let fresh = freshness(stored.as_ref(), now.as_ref(), &reference_side, &f.path);
            let action = match &fresh {
                Freshness::Stale(_) => Action::Recompute,
                Freshness::Touched | Freshness::Current => {
                    if let (Freshness::Touched, Some(now)) = (&fresh, &now) {
                        // Same content: record the new size and time (a failure only means
                        // the file is read again next time).
                        let _ = FrameInputs {
                            frame: now.clone(),
                            reference_side: reference_side.clone(),
                        }
                        .write(&dir);
                    }
                    if spec.frame_complete(&dir) {
                        Action::Skip
                    } else {
                        Action::Figures
                    }
                }
            };
            let why = match fresh {
                Freshness::Stale(why) => Some(format!("frame {}: {why}: recomputed", f.number)),
                _ => None,
            };
            (now, action, why)
        })
        .collect();
    let mut fingerprints = Vec::with_capacity(checked.len());
    let mut actions = Vec::with_capacity(checked.len());
    for (fingerprint, action, why) in checked {
        if let Some(why) = why {
            progress.note(&why);
        }
        fingerprints.push(fingerprint);
        actions.push(action);
    }
    record.inputs.frames = fingerprints.iter().flatten().cloned().collect();
    let n_compute = actions.iter().filter(|a| a.computes()).count();
    let n_skip = actions.iter().filter(|a| **a == Action::Skip).count();

    let ctx = if n_compute > 0 {
        progress.phase(&format!(
            "preparing the reference side: detection and fits in {} and the no-flow stack ({} file(s))",
            match &plan.reference {
                ReferenceImage::File(p) => p
                    .file_name()
                    .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
                ReferenceImage::StackMean => "stack mean".into(),
            },
            plan.stack.len()
        ));
        Some(ReferenceContext::prepare(plan)?)
    } else {
        None
    };
    let record_path = match options.shard {
        None => out.join(RUN_RECORD),
        Some(s) => out.join(SHARDS_DIR).join(format!("{}.toml", s.label())),
    };
    let previous = olds
        .iter()
        .find(|(p, _)| *p == record_path)
        .and_then(|(_, r)| r.as_ref());
    if let Some(ctx) = &ctx {
        let (width, height) = ctx.image_size();
        record.image = Some(record::ImageSize { width, height });
        record.reference = json_to_toml_table(&ctx.summary());
    } else if let Some(old) = previous {
        // Nothing computed: the reference-side facts of the record are still those.
        record.image = old.image;
        record.reference = old.reference.clone();
    }
    let inputs_moved = previous.is_none_or(|old| {
        old.inputs.reference_side != record.inputs.reference_side
            || old.inputs.frames != record.inputs.frames
    });
    if ctx.is_some() || inputs_moved || !record_path.is_file() {
        if let Some(parent) = record_path.parent() {
            fsx::create_dir(parent)?;
        }
        record.write(&record_path)?;
    }

    let needs_figures = spec.has_frame_figures() && actions.iter().any(|a| *a != Action::Skip);
    let setup = if needs_figures || (options.shard.is_none() && spec.has_campaign_figures()) {
        Some(figure_setup(
            spec.clone(),
            ctx.as_ref(),
            record.image,
            reference_file(plan),
            reference_file(plan).or(plan.stack.first().map(PathBuf::as_path)),
            plan.mask.as_deref(),
        )?)
    } else {
        None
    };

    progress.start(mine.len() - n_skip, n_skip);
    let total = frames.len();
    // At most `lanes` frames at once, each using the whole pool for its stages: the memory
    // of a run is bounded by the frames in flight, not by the threads (issue 17).
    let lanes = crate::jobs::frames_in_flight(plan.config.run.frames_in_flight, jobs);
    let outcomes: Vec<(FrameStatus, Option<String>)> = in_lanes(mine.len(), lanes, |k| {
        let (f, action, fingerprint) = (mine[k], &actions[k], &fingerprints[k]);
        {
            if *action == Action::Skip || progress.cancelled() {
                return (FrameStatus::Skipped, None);
            }
            let t = Instant::now();
            let result = match action {
                Action::Compute | Action::Recompute => compute_frame(
                    ctx.as_ref().expect("prepared when a frame is computed"),
                    plan,
                    &out,
                    f,
                    &f.title(total),
                    setup.as_ref(),
                    &spec,
                    progress,
                    fingerprint.as_ref().map(|frame| FrameInputs {
                        frame: frame.clone(),
                        reference_side: reference_side.clone(),
                    }),
                )
                .map(|()| FrameStatus::Computed),
                _ => draw_figures(&out, f, &f.title(total), setup.as_ref(), &spec, progress)
                    .map(|()| FrameStatus::FiguresDrawn),
            };
            let (status, error) = match result {
                Ok(s) => (s, None),
                Err(reason) => (FrameStatus::Failed, Some(reason)),
            };
            progress.frame_done(&FrameEvent {
                frame: f.number,
                stem: &f.stem,
                status,
                error: error.as_deref(),
                seconds: t.elapsed().as_secs_f64(),
            });
            (status, error)
        }
    });
    progress.finish();
    drop(ctx);
    if progress.cancelled() {
        let worked = |o: &&(FrameStatus, Option<String>)| o.0 != FrameStatus::Skipped;
        return Err(BatchError::Interrupted {
            path: out,
            done: outcomes.iter().filter(worked).count(),
            to_do: mine.len() - n_skip,
        });
    }

    let count = |s: FrameStatus| outcomes.iter().filter(|o| o.0 == s).count();
    let failures: Vec<FrameFailure> = mine
        .iter()
        .zip(&outcomes)
        .filter_map(|(f, (_, e))| {
            e.as_ref().map(|reason| FrameFailure {
                frame: f.number,
                stem: f.stem.clone(),
                file: f.path.clone(),
                reason: reason.clone(),
            })
        })
        .collect();
    let mut report = BatchReport {
        out_dir: out.clone(),
        campaign_frames: total,
        frames: mine.len(),
        computed: count(FrameStatus::Computed),
        stale: actions
            .iter()
            .zip(&outcomes)
            .filter(|(a, o)| **a == Action::Recompute && o.0 == FrameStatus::Computed)
            .count(),
        figures_drawn: count(FrameStatus::FiguresDrawn),
        skipped: count(FrameStatus::Skipped),
        failures,
        seconds: 0.0,
        campaign_written: false,
    };
    match options.shard {
        Some(s) => {
            let outcome = ShardOutcome {
                shard: s.to_string(),
                frames: mine.iter().map(|f| f.number).collect(),
                failures: report.failures.clone(),
            };
            let path = out.join(SHARDS_DIR).join(format!("{}.json", s.label()));
            write_json(&path, &outcome)?;
        }
        None => {
            let reasons: HashMap<String, String> = report
                .failures
                .iter()
                .map(|f| (f.stem.clone(), f.reason.clone()))
                .collect();
            let title = campaign_title(&plan.config_file);
            campaign::build(
                &out,
                &frames,
                &reasons,
                &spec,
                setup.as_ref(),
                &title,
                progress,
            )?;
            report.campaign_written = true;
        }
    }
    report.seconds = t0.elapsed().as_secs_f64();
    Ok(report)
}

/// `f(0), ..., f(n - 1)` on the current rayon pool with at most `lanes` calls in progress at
/// once (each lane takes the next index when its call returns; the calls' own parallel loops
/// use every thread of the pool); the results in index order.
///
/// A plain parallel iterator over the frames would start as many frames as there are threads,
/// and more: a thread waiting inside one frame's parallel loop may steal and start another
/// frame. Lanes bound the frames in flight whatever the pool does.
fn in_lanes<T: Send>(n: usize, lanes: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<T>>> = (0..n).map(|_| Mutex::new(None)).collect();
    rayon::scope(|s| {
        for _ in 0..lanes.clamp(1, n.max(1)) {
            s.spawn(|_| {
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    if k >= n {
                        break;
                    }
                    let r = f(k);
                    *slots[k].lock().unwrap_or_else(|e| e.into_inner()) = Some(r);
                }
            });
        }
    });
    slots
        .into_iter()
        .map(|m| {
            m.into_inner()
                .unwrap_or_else(|e| e.into_inner())
                .expect("every index is taken by a lane")
        })
        .collect()
}

/// The outcome of one shard: `DIR/shards/shard-K-of-N.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct ShardOutcome {
    pub shard: String,
    /// Frame numbers of the shard.
    pub frames: Vec<usize>,
    pub failures: Vec<FrameFailure>,
}

fn campaign_title(config_file: &Path) -> String {
    let name = config_file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "campaign".into());
    format!("Campaign {name}")
}

/// Computes, writes and draws one frame; the error is the failure reason. `inputs` (what the
/// frame is computed from, fingerprinted before it was read) is recorded once the outputs are
/// written (without it, the next run computes the frame again).
fn compute_frame(
    ctx: &ReferenceContext,
    plan: &Plan,
    out: &Path,
    f: &FrameRef,
    title: &str,
    setup: Option<&FigureSetup>,
    spec: &FigureSpec,
    progress: &dyn Progress,
    inputs: Option<FrameInputs>,
) -> Result<(), String> {
    fsx::remove_stale_temporaries(out, &f.stem);
    let dir = out.join(&f.stem);
    let _ = std::fs::remove_file(dir.join(crate::figures::FIGURES_RECORD));
    let _ = std::fs::remove_file(dir.join(inputs::FRAME_INPUTS));
    let result = process_frame(ctx, plan, &f.path).map_err(|e| e.to_string())?;
    write_frame(out, &result).map_err(|e| e.to_string())?;
    drop(result);
    if let Some(inputs) = inputs {
        inputs.write(&dir).map_err(|e| e.to_string())?;
    }
    draw_figures(out, f, title, setup, spec, progress)
}

fn draw_figures(
    out: &Path,
    f: &FrameRef,
    title: &str,
    setup: Option<&FigureSetup>,
    spec: &FigureSpec,
    progress: &dyn Progress,
) -> Result<(), String> {
    let dir = out.join(&f.stem);
    fsx::remove_stale_files(&dir);
    write_frame_arrays(&dir, spec).map_err(|e| format!("arrays: {e}"))?;
    let Some(setup) = setup else { return Ok(()) };
    let notes = draw_frame_figures(&dir, title, setup).map_err(|e| format!("figures: {e}"))?;
    for n in notes {
        progress.note(&n);
    }
    Ok(())
}

/// The reference image file (`None`: the stack mean).
fn reference_file(plan: &Plan) -> Option<&Path> {
    match &plan.reference {
        ReferenceImage::File(p) => Some(p),
        ReferenceImage::StackMean => None,
    }
}

/// The figure setup: size and mask from the reference context, else from the record, else
/// from the files. `reference` is the reference image (`None`: the stack mean) and `probe`
/// the file to read the size from.
fn figure_setup(
    spec: FigureSpec,
    ctx: Option<&ReferenceContext>,
    size: Option<record::ImageSize>,
    reference: Option<&Path>,
    probe: Option<&Path>,
    mask: Option<&Path>,
) -> Result<FigureSetup, BatchError> {
    let reference_name = match reference {
        Some(p) => p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| p.display().to_string()),
        None => "the mean of the no-flow stack".to_string(),
    };
    if let Some(ctx) = ctx {
        let (width, height) = ctx.image_size();
        return Ok(FigureSetup {
            spec,
            width,
            height,
            mask: ctx.mask().cloned(),
            reference_name,
        });
    }
    let (width, height) = match (size, probe) {
        (Some(s), _) => (s.width, s.height),
        (None, Some(p)) => {
            let info = bostrack_io::probe(p)?;
            (info.width, info.height)
        }
        (None, None) => (0, 0),
    };
    let mask = match mask {
        Some(p) => Some(bostrack_io::read_mask_for(p, width, height)?),
        None => None,
    };
    Ok(FigureSetup {
        spec,
        width,
        height,
        mask,
        reference_name,
    })
}

/// Rebuilds the campaign files of an output folder (`campaign.csv`, `campaign.json`,
/// `failures.json`, campaign figures) from its per-frame outputs and run records, drawing any
/// missing per-frame figures; writes `run.toml` from the shard records when it is absent.
///
/// The frames are the union of the records' frames (natural order); a frame without complete
/// outputs is a failure, with the reason a shard recorded or "not processed". Runs in the
/// current rayon pool.
pub fn merge_campaign(out_dir: &Path, progress: &dyn Progress) -> Result<MergeReport, BatchError> {
    let records = record::read_records(out_dir)?;
    let Some((first_path, first)) = records.first() else {
        return Err(BatchError::NoRecord {
            dir: out_dir.to_path_buf(),
        });
    };
    for (path, r) in &records[1..] {
        let changed = || first.changed_inputs(r).into_iter().next();
        if let Some(what) = first.differs_from(r).or_else(changed) {
            return Err(BatchError::RecordsDisagree {
                first: first_path.clone(),
                second: path.clone(),
                what,
            });
        }
    }
    let paths = record::union_of_frames(records.iter().map(|(_, r)| r));
    let frames = frame_refs(&paths, first_path)?;
    let (figures, formats) = first.figures();
    let spec = FigureSpec {
        figures,
        formats,
        arrays: first.arrays(),
    };

    // Per-frame figures that are missing.
    let missing: Vec<&FrameRef> = frames
        .iter()
        .filter(|f| {
            frame_is_complete(out_dir, &f.stem) && !spec.frame_complete(&out_dir.join(&f.stem))
        })
        .collect();
    let setup = if !missing.is_empty() || spec.has_campaign_figures() {
        let size = records.iter().find_map(|(_, r)| r.image);
        let reference = first.inputs.reference.as_deref();
        Some(figure_setup(
            spec.clone(),
            None,
            size,
            reference,
            reference.or(first.inputs.stack.first().map(PathBuf::as_path)),
            first.inputs.mask.as_deref(),
        )?)
    } else {
        None
    };
    let total = frames.len();
    progress.start(missing.len(), total - missing.len());
    let drawn: Vec<Result<(), String>> = missing
        .par_iter()
        .map(|f| {
            let t = Instant::now();
            let r = draw_figures(out_dir, f, &f.title(total), setup.as_ref(), &spec, progress);
            progress.frame_done(&FrameEvent {
                frame: f.number,
                stem: &f.stem,
                status: if r.is_ok() {
                    FrameStatus::FiguresDrawn
                } else {
                    FrameStatus::Failed
                },
                error: r.as_ref().err().map(String::as_str),
                seconds: t.elapsed().as_secs_f64(),
            });
            r
        })
        .collect();
    progress.finish();

    // Reasons recorded by earlier runs and shards, the latest shard outcome last.
    let mut reasons: HashMap<String, String> = HashMap::new();
    if let Ok(bytes) = std::fs::read(out_dir.join(campaign::FAILURES))
        && let Ok(f) = serde_json::from_slice::<campaign::FailuresFile>(&bytes)
    {
        for x in f.failures {
            reasons.insert(x.stem, x.reason);
        }
    }
    if let Ok(files) = crate::files::list_matching(&out_dir.join(SHARDS_DIR), "shard-*-of-*.json") {
        for p in files {
            if let Ok(bytes) = std::fs::read(&p)
                && let Ok(o) = serde_json::from_slice::<ShardOutcome>(&bytes)
            {
                for x in o.failures {
                    reasons.insert(x.stem, x.reason);
                }
            }
        }
    }
    for (f, r) in missing.iter().zip(&drawn) {
        if let Err(e) = r {
            reasons.insert(f.stem.clone(), e.clone());
        }
    }
    let title = campaign_title(&first.inputs.config_file);
    let built = campaign::build(
        out_dir,
        &frames,
        &reasons,
        &spec,
        setup.as_ref(),
        &title,
        progress,
    )?;

    let run_path = out_dir.join(RUN_RECORD);
    if !run_path.is_file() {
        let mut merged = first.clone();
        merged.kind = "merge".into();
        merged.shard = None;
        merged.jobs = 0;
        merged.merged_from = records
            .iter()
            .filter_map(|(p, _)| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect();
        merged.inputs.gradients = paths.clone();
        merged.inputs.frames = paths
            .iter()
            .filter_map(|p| {
                records
                    .iter()
                    .find_map(|(_, r)| r.inputs.frames.iter().find(|f| &f.path == p))
                    .cloned()
            })
            .collect();
        merged.write(&run_path)?;
    }
    Ok(MergeReport {
        out_dir: out_dir.to_path_buf(),
        frames: total,
        complete: total - built.failures.len(),
        failures: built.failures,
        records: records.len(),
        figures_drawn: drawn.iter().filter(|r| r.is_ok()).count(),
    })
}

fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), BatchError> {
    if let Some(parent) = path.parent() {
        fsx::create_dir(parent)?;
    }
    let mut bytes = serde_json::to_vec_pretty(value).map_err(|e| BatchError::Corrupt {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    bytes.push(b'\n');
    fsx::write_atomic(path, &bytes)
}

/// A JSON object as a TOML table (nulls, which TOML cannot hold, are left out).
fn json_to_toml_table(v: &serde_json::Value) -> Option<toml::Table> {
    match json_to_toml(v)? {
        toml::Value::Table(t) => Some(t),
        _ => None,
    }
}

fn json_to_toml(v: &serde_json::Value) -> Option<toml::Value> {
    use serde_json::Value as J;
    Some(match v {
        J::Null => return None,
        J::Bool(b) => toml::Value::Boolean(*b),
        J::Number(n) => match n.as_i64() {
            Some(i) => toml::Value::Integer(i),
            None => toml::Value::Float(n.as_f64()?),
        },
        J::String(s) => toml::Value::String(s.clone()),
        J::Array(a) => toml::Value::Array(a.iter().filter_map(json_to_toml).collect()),
        J::Object(o) => toml::Value::Table(
            o.iter()
                .filter_map(|(k, v)| json_to_toml(v).map(|v| (k.clone(), v)))
                .collect(),
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lanes_bound_the_calls_in_flight_and_keep_the_order() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(4)
            .build()
            .unwrap();
        let (now, most) = (AtomicUsize::new(0), AtomicUsize::new(0));
        let out = pool.install(|| {
            in_lanes(40, 2, |k| {
                let n = now.fetch_add(1, Ordering::SeqCst) + 1;
                most.fetch_max(n, Ordering::SeqCst);
                // an inner parallel loop: a waiting thread must not start another call
                let s: usize = (0..2000usize).into_par_iter().map(|x| x % 7).sum();
                now.fetch_sub(1, Ordering::SeqCst);
                (k, s)
            })
        });
        assert_eq!(out.len(), 40);
        assert!(out.iter().enumerate().all(|(i, &(k, s))| i == k && s > 0));
        assert!(most.load(Ordering::SeqCst) <= 2);
        assert!(in_lanes(0, 3, |k| k).is_empty());
    }

    #[test]
    fn frames_are_numbered_and_stems_checked() {
        let src = Path::new("p.toml");
        let f = frame_refs(&[PathBuf::from("g/a1.tif"), PathBuf::from("g/a2.tif")], src).unwrap();
        assert_eq!((f[0].number, f[1].number), (1, 2));
        assert_eq!(f[1].stem, "a2");
        assert_eq!(f[1].title(9), "a2.tif (frame 2 of 9)");
        let e = frame_refs(&[PathBuf::from("g/a.tif"), PathBuf::from("h/a.png")], src).unwrap_err();
        assert!(e.to_string().contains("share the stem `a`"), "{e}");
        let e = frame_refs(&[PathBuf::from("g/shards.tif")], src).unwrap_err();
        assert!(e.to_string().contains("reserved"), "{e}");
    }

    #[test]
    fn json_becomes_toml_without_nulls() {
        let v = serde_json::json!({"a": 1, "b": null, "c": [1.5, null], "d": {"e": "x"}});
        let t = json_to_toml_table(&v).unwrap();
        assert_eq!(
            toml::to_string(&t).unwrap(),
            "a = 1\nc = [1.5]\n\n[d]\ne = \"x\"\n"
        );
        assert!(json_to_toml_table(&serde_json::json!([1])).is_none());
    }
}
