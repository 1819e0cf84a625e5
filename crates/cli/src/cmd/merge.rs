//! `bostrack merge`: build the campaign files of an output folder from its per-frame outputs.

use super::run::{CliProgress, print_failures};
use crate::Outcome;
use crate::jobs::JobsArg;
use bostrack_pipeline::merge_campaign;
use clap::Args;
use std::path::PathBuf;

const MERGE_LONG_ABOUT: &str = "\
Rebuild the campaign files of a run folder from its per-frame outputs: campaign.csv,
campaign.json, failures.json and the campaign figures, drawing any per-frame figure that is
missing. Use it after the shards of a campaign (`bostrack run --shard K/N`) have all finished;
it can be run again at any time (e.g. after a requeued shard finished).

The frames are those named by the run records in DIR (run.toml, shards/shard-K-of-N.toml),
numbered from 1 in natural order. A frame without complete outputs is listed in failures.json,
with the reason its shard recorded or \"not processed\"; the exit code is then 2. Records of
different configurations are an error (exit 1). When DIR has no run.toml, one is written from
the shard records. The result equals that of one unsharded run (apart from wall times).";

/// Build the campaign files from per-frame outputs.
#[derive(Debug, Args)]
#[command(
    about = "Rebuild campaign.csv/json, failures.json and the figures from per-frame outputs (after sharded runs)",
    long_about = MERGE_LONG_ABOUT
)]
pub(crate) struct MergeArgs {
    /// Output folder of the run (holds run.toml or shards/).
    #[arg(value_name = "DIR")]
    dir: PathBuf,
    /// Print no progress; only failures and errors.
    #[arg(short = 'q', long)]
    quiet: bool,
    #[command(flatten)]
    jobs: JobsArg,
}

pub(crate) fn run(args: MergeArgs) -> anyhow::Result<Outcome> {
    let pool = args.jobs.pool(0)?;
    let progress = CliProgress::new(args.quiet, "frames");
    let report =
        pool.install(|| merge_campaign(&args.dir, &progress).map_err(anyhow::Error::from))?;
    print_failures(&report.failures);
    if !args.quiet {
        eprintln!(
            "merged {} run records: {} frames, {} complete, {} failed or missing, {} with figures \
             drawn now; campaign files in {}",
            report.records,
            report.frames,
            report.complete,
            report.failures.len(),
            report.figures_drawn,
            report.out_dir.display()
        );
    }
    Ok(if report.failures.is_empty() {
        Outcome::Done
    } else {
        Outcome::SomeFailed
    })
}
