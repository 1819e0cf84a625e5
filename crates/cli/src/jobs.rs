//! `--jobs N` for every command that computes, and the rayon pool it builds.

use anyhow::Context as _;
use clap::Args;
use std::num::NonZeroUsize;

/// The worker-thread option shared by every computing command.
#[derive(Clone, Copy, Debug, Args)]
pub(crate) struct JobsArg {
    /// Worker threads [default: the CPUs available to this process: SLURM_CPUS_PER_TASK when
    /// set, else the cgroup quota / affinity mask].
    #[arg(short = 'j', long = "jobs", value_name = "N")]
    pub jobs: Option<NonZeroUsize>,
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
