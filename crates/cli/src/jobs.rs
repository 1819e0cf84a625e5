//! `--jobs N` for every command that computes, and the rayon pool it builds.

use anyhow::Context as _;
use clap::Args;
use std::num::NonZeroUsize;

/// The worker-thread option shared by every computing command.
#[derive(Clone, Copy, Debug, Args)]
pub(crate) struct JobsArg {
    /// Worker threads [default: the CPUs available to this process: SLURM_CPUS_PER_TASK when
    /// set, else the cgroup quota / affinity mask].
    #[arg(short = 'j', long = "jobs", value_name = "N", value_parser = positive_up_to::<{ bostrack_pipeline::MAX_JOBS }>)]
    pub jobs: Option<NonZeroUsize>,
}

/// A count from 0 to `MAX`: every option that scales the work is bounded.
pub(crate) fn up_to<const MAX: usize>(s: &str) -> Result<usize, String> {
    let n: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a whole number"))?;
    if n > MAX {
        return Err(format!("{n} is more than the limit of {MAX}"));
    }
    Ok(n)
}

/// A count from 1 to `MAX`.
pub(crate) fn positive_up_to<const MAX: usize>(s: &str) -> Result<NonZeroUsize, String> {
    NonZeroUsize::new(up_to::<MAX>(s)?).ok_or_else(|| "must be at least 1".to_string())
}

impl JobsArg {
    /// The number of threads: the option, else `fallback` when positive (a configuration's
    /// `run.jobs`), else the available CPUs.
    pub fn threads(&self, fallback: usize) -> usize {
        self.jobs
            .map(NonZeroUsize::get)
            .unwrap_or_else(|| bostrack_pipeline::resolve_jobs(fallback))
    }

    /// A rayon pool with [`JobsArg::threads`] threads.
    pub fn pool(&self, fallback: usize) -> anyhow::Result<rayon::ThreadPool> {
        let n = self.threads(fallback);
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .thread_name(|i| format!("bostrack-{i}"))
            .build()
            .with_context(|| format!("cannot start {n} worker threads"))
    }
}
