//! How many worker threads a run gets.

/// The number of CPUs this process may actually use: `SLURM_CPUS_PER_TASK` when it is set to a
/// positive integer (a Slurm allocation), otherwise [`std::thread::available_parallelism`], which
/// honours cgroup CPU quotas and the affinity mask; 1 if neither is known.
pub fn available_jobs() -> usize {
    slurm_cpus(std::env::var("SLURM_CPUS_PER_TASK").ok().as_deref())
        .or_else(|| std::thread::available_parallelism().ok().map(|n| n.get()))
        .unwrap_or(1)
}

/// Most worker threads a run (`[run] jobs`, `--jobs`) may ask for: each thread is a stack of
/// memory, and no machine this runs on has more cores.
pub const MAX_JOBS: usize = 1024;

/// `requested` threads, or [`available_jobs`] when `requested` is 0 ("all available").
pub fn resolve_jobs(requested: usize) -> usize {
    if requested == 0 {
        available_jobs()
    } else {
        requested
    }
}

/// The frames a run processes at once on `jobs` threads: `requested`, or with 0 (automatic)
/// a third of the threads, rounded up, and at least 2. Each frame's stages run in parallel on
/// the whole pool, so fewer frames than threads still keep the cores busy, while the memory
/// of the frames in flight (image, fit canvas and records: ~56 MB per 1-MP frame) stays
/// bounded: 16 jobs on 1-MP frames hold 6 frames, 0.42-0.46 GB in all (issue 17); 16
/// frames would be 1 GB.
pub fn frames_in_flight(requested: usize, jobs: usize) -> usize {
    let n = if requested == 0 {
        jobs.div_ceil(3).max(2)
    } else {
        requested
    };
    n.clamp(1, jobs.max(1))
}

fn slurm_cpus(value: Option<&str>) -> Option<usize> {
    value?.trim().parse::<usize>().ok().filter(|&n| n > 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slurm_value_is_parsed_strictly() {
        assert_eq!(slurm_cpus(Some("4")), Some(4));
        assert_eq!(slurm_cpus(Some(" 12\n")), Some(12));
        assert_eq!(slurm_cpus(Some("0")), None);
        assert_eq!(slurm_cpus(Some("4(x2)")), None);
        assert_eq!(slurm_cpus(None), None);
    }

    #[test]
    fn frames_in_flight_is_a_third_of_the_threads_unless_set() {
        assert_eq!(frames_in_flight(0, 16), 6);
        assert_eq!(frames_in_flight(0, 4), 2);
        assert_eq!(frames_in_flight(0, 2), 2);
        assert_eq!(frames_in_flight(0, 1), 1);
        assert_eq!(frames_in_flight(5, 16), 5);
        // never more frames than threads, never none
        assert_eq!(frames_in_flight(32, 16), 16);
        assert_eq!(frames_in_flight(0, 0), 1);
    }

    #[test]
    fn zero_means_available() {
        assert_eq!(resolve_jobs(3), 3);
        assert!(resolve_jobs(0) >= 1);
        assert_eq!(resolve_jobs(0), available_jobs());
    }
}
