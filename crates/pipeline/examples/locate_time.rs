//! In-process time of `bostrack locate` on one image: reading (with the clip level), noise
//! estimate, detection and fits, as the command does them, without the process start or the
//! CSV. The baseline of the Python package's overhead benchmark (python/benches/locate_overhead.py).
//!
//! `cargo run --release -p bostrack-pipeline --example locate_time -- IMAGE [RUNS] [JOBS]`
//! prints one line: `runs N jobs J best_s B median_s M rows R`.

use bostrack_io::Saturation;
use bostrack_pipeline::{LocateOptions, locate};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let path = std::path::PathBuf::from(
        args.get(1)
            .ok_or("usage: locate_time IMAGE [RUNS] [JOBS]")?,
    );
    let runs: usize = args.get(2).map_or(Ok(5), |s| s.parse())?;
    let jobs: usize = args.get(3).map_or(Ok(0), |s| s.parse())?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(bostrack_pipeline::resolve_jobs(jobs))
        .build()?;
    let mut times = Vec::new();
    let mut rows = 0;
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        let (img, _) = bostrack_io::read_image_clipped(&path, Saturation::Auto)?;
        let found = pool.install(|| locate(&img, None, &LocateOptions::default(), &path))?;
        times.push(t.elapsed().as_secs_f64());
        rows = found.rows().len();
    }
    times.sort_by(f64::total_cmp);
    println!(
        "runs {} jobs {} best_s {:.4} median_s {:.4} rows {rows}",
        times.len(),
        pool.current_num_threads(),
        times[0],
        times[times.len() / 2]
    );
    Ok(())
}
