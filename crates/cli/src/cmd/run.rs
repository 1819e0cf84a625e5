//! `bostrack run`: process a campaign (or one shard of it) into its output folder.

use crate::Outcome;
use crate::jobs::JobsArg;
use bostrack_pipeline::{
    BatchOptions, BatchReport, FrameEvent, FrameFailure, FrameStatus, Plan, Progress, Shard,
    run_batch,
};
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle};
use std::io::IsTerminal as _;
use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

const RUN_LONG_ABOUT: &str = "\
Process every gradient frame of a campaign (pipeline.toml): detect and fit the reference dots
once (and the no-flow stack), then per frame track, fit, match and validate the dots and compute
the displacement, amplification ratio and uncertainties; frames run in parallel (--jobs).

Outputs in DIR (output.dir of the configuration, or --out):

  run.toml                 run record: version, inputs, the fully resolved configuration
  <frame>/dots.csv         one row per reference dot (i,j,x_ref,y_ref,...,dx,dy,...,u_dx,u_dy,
                           valid,flags); <frame> is the file stem of the gradient image
  <frame>/summary.json     counts, medians, noise model, stack, stage times; written last
  <frame>/*.png, *.svg     the figures of output.figures, then figures.json
  campaign.csv, .json      one row per frame: status, counts, medians, timings (*times*, last)
  failures.json            frames that failed, each with its file and the reason
  campaign.png, ...        campaign figures (\"campaign\", \"detections\")

Frames are numbered from 1 in natural order of their file names (frame2 before frame10).

Resumable: a frame whose outputs are complete is skipped, so a rerun after an interruption
only computes what is missing and a rerun of a finished campaign takes seconds; --force
recomputes everything. Files are written under temporary names and renamed, so a killed run
leaves no half-written frame. A folder holding results of another configuration is refused
(exit 1) unless --force.

Changed inputs: the run record (run.toml) and each frame's <frame>/inputs.json hold every
input file's size, modification time and content hash (XXH3-128). A rerun recomputes a frame
whose gradient image changed (named in a note); a changed reference image, mask or no-flow
image invalidates every frame, so the run is refused (exit 1, naming the files) unless --force.
A file whose size and modification time are unchanged is not read again.

A frame that fails (unreadable file, no dots) is listed in failures.json and on stderr, the
others finish, and the exit code is 2.

Cluster: --shard K/N processes frames n with (n - 1) mod N = K - 1 (K from 1) and writes only
those frames and DIR/shards/shard-K-of-N.{toml,json}; `bostrack merge DIR` then builds the
campaign files (docs/cluster.md).

Progress: a bar with frames done, frames/s and ETA when stderr is a terminal, a line every few
seconds otherwise; --quiet prints only warnings (e.g. a gradient pattern that also matches the
reference image), failures and errors.";

/// Process a campaign.
#[derive(Debug, Args)]
#[command(
    about = "Process every gradient frame of a campaign into per-frame outputs, campaign summary and figures",
    long_about = RUN_LONG_ABOUT
)]
pub(crate) struct RunArgs {
    /// Campaign configuration file.
    #[arg(value_name = "CONFIG", default_value = "pipeline.toml")]
    config: PathBuf,
    /// Output folder [default: output.dir of the configuration, relative to its folder].
    #[arg(short = 'o', long = "out", value_name = "DIR")]
    out: Option<PathBuf>,
    /// Recompute every frame, even those whose outputs are complete, and accept an output
    /// folder written with another configuration.
    #[arg(long)]
    force: bool,
    /// Process only shard K of N (1 <= K <= N): frames n with (n - 1) mod N = K - 1, frames
    /// numbered from 1 in natural order. Combine the shards with `bostrack merge DIR`.
    #[arg(long, value_name = "K/N")]
    shard: Option<Shard>,
    /// Print no progress; only warnings, failures and errors.
    #[arg(short = 'q', long)]
    quiet: bool,
    #[command(flatten)]
    jobs: JobsArg,
}

pub(crate) fn run(args: RunArgs) -> anyhow::Result<Outcome> {
    let plan = Plan::load(&args.config)?;
    for w in &plan.warnings {
        eprintln!("warning: {w}");
    }
    let pool = args.jobs.pool(plan.config.run.jobs)?;
    let options = BatchOptions {
        out_dir: args.out.clone(),
        force: args.force,
        shard: args.shard,
    };
    let progress = CliProgress::new(args.quiet, "frames");
    let report =
        pool.install(|| run_batch(&plan, &options, &progress).map_err(anyhow::Error::from))?;
    print_failures(&report.failures);
    if !args.quiet {
        eprintln!("{}", summary_line(&report, pool.current_num_threads()));
        if let Some(s) = args.shard {
            eprintln!(
                "shard {s} done; when every shard is done: bostrack merge {}",
                report.out_dir.display()
            );
        }
    }
    Ok(if report.failures.is_empty() {
        Outcome::Done
    } else {
        Outcome::SomeFailed
    })
}

fn summary_line(r: &BatchReport, threads: usize) -> String {
    let worked = r.computed + r.figures_drawn + r.failures.len();
    let rate = if r.seconds > 0.0 {
        worked as f64 / r.seconds
    } else {
        0.0
    };
    let share = if r.frames == r.campaign_frames {
        format!("{} frames", r.frames)
    } else {
        format!("{} of {} frames", r.frames, r.campaign_frames)
    };
    let rss = peak_rss_mib().map_or(String::new(), |m| format!(", peak RSS {m:.0} MiB"));
    let stale = if r.stale > 0 {
        format!(" ({} of them again, as their inputs changed)", r.stale)
    } else {
        String::new()
    };
    format!(
        "{share}: {} computed{stale}, {} only missing figures drawn, {} complete already, {} failed, in {:.1} s \
         ({rate:.2} frames/s, {threads} threads{rss}); outputs in {}",
        r.computed,
        r.figures_drawn,
        r.skipped,
        r.failures.len(),
        r.seconds,
        r.out_dir.display()
    )
}

/// Peak resident memory of this process (MiB): `VmHWM` of /proc/self/status (Linux only).
fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// One line per failure on stderr.
pub(crate) fn print_failures(failures: &[FrameFailure]) {
    for f in failures {
        eprintln!(
            "failed: frame {} ({}): {}",
            f.frame,
            f.file.display(),
            f.reason
        );
    }
}

/// Progress on stderr: an indicatif bar on a terminal, a plain line every few seconds
/// otherwise, nothing with --quiet.
pub(crate) struct CliProgress {
    quiet: bool,
    /// What is counted ("frames").
    unit: &'static str,
    bar: Option<ProgressBar>,
    state: Mutex<LineState>,
    done: AtomicUsize,
    failed: AtomicUsize,
    total: AtomicUsize,
}

struct LineState {
    start: Instant,
    last: Instant,
}

/// Seconds between two plain progress lines.
const LINE_EVERY: Duration = Duration::from_secs(5);

impl CliProgress {
    pub(crate) fn new(quiet: bool, unit: &'static str) -> CliProgress {
        let bar = (!quiet && std::io::stderr().is_terminal()).then(|| {
            let style = ProgressStyle::with_template(
                "{elapsed_precise} [{bar:32}] {pos}/{len} {unit}  {rate}  ETA {eta}  {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .with_key(
                "unit",
                move |_: &ProgressState, w: &mut dyn std::fmt::Write| {
                    let _ = w.write_str(unit);
                },
            )
            .with_key("rate", |s: &ProgressState, w: &mut dyn std::fmt::Write| {
                let _ = write!(w, "{:.2}/s", s.per_sec());
            })
            .progress_chars("=> ");
            let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr());
            bar.set_style(style);
            bar
        });
        let now = Instant::now();
        CliProgress {
            quiet,
            unit,
            bar,
            state: Mutex::new(LineState {
                start: now,
                last: now,
            }),
            done: AtomicUsize::new(0),
            failed: AtomicUsize::new(0),
            total: AtomicUsize::new(0),
        }
    }

    fn line(&self, force: bool) {
        let Ok(mut st) = self.state.lock() else {
            return;
        };
        let now = Instant::now();
        if !force && now.duration_since(st.last) < LINE_EVERY {
            return;
        }
        st.last = now;
        let (done, total) = (
            self.done.load(Ordering::Relaxed),
            self.total.load(Ordering::Relaxed),
        );
        let failed = self.failed.load(Ordering::Relaxed);
        let secs = now.duration_since(st.start).as_secs_f64();
        let rate = if secs > 0.0 { done as f64 / secs } else { 0.0 };
        let eta = if rate > 0.0 && total >= done {
            format!("{:.0} s", (total - done) as f64 / rate)
        } else {
            "?".into()
        };
        eprintln!(
            "{} {done}/{total} ({failed} failed), {rate:.2} {}/s, elapsed {secs:.0} s, ETA {eta}",
            self.unit, self.unit
        );
    }
}

impl Progress for CliProgress {
    fn start(&self, to_do: usize, skipped: usize) {
        self.total.store(to_do, Ordering::Relaxed);
        if let Ok(mut st) = self.state.lock() {
            let now = Instant::now();
            st.start = now;
            st.last = now;
        }
        if self.quiet {
            return;
        }
        if skipped > 0 {
            eprintln!(
                "{skipped} {} complete already (skipped; --force recomputes them)",
                self.unit
            );
        }
        match &self.bar {
            Some(bar) => {
                bar.set_length(to_do as u64);
                bar.reset_eta();
            }
            None if to_do > 0 => eprintln!("{} to do: {to_do}", self.unit),
            None => {}
        }
    }

    fn frame_done(&self, event: &FrameEvent<'_>) {
        self.done.fetch_add(1, Ordering::Relaxed);
        if event.status == FrameStatus::Failed {
            let n = self.failed.fetch_add(1, Ordering::Relaxed) + 1;
            if let Some(bar) = &self.bar {
                bar.set_message(format!("{n} failed"));
            }
        }
        if self.quiet {
            return;
        }
        match &self.bar {
            Some(bar) => bar.inc(1),
            None => self.line(false),
        }
    }

    fn note(&self, message: &str) {
        if self.quiet {
            return;
        }
        match &self.bar {
            Some(bar) => bar.println(format!("note: {message}")),
            None => eprintln!("note: {message}"),
        }
    }

    fn phase(&self, what: &str) {
        if !self.quiet {
            eprintln!("{what}");
        }
    }

    fn finish(&self) {
        if self.quiet {
            return;
        }
        match &self.bar {
            Some(bar) => bar.finish_and_clear(),
            None if self.total.load(Ordering::Relaxed) > 0 => self.line(true),
            None => {}
        }
    }
}
