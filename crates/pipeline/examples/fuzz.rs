//! The fuzzing round of issue #14 (see `tests/common/fuzz.rs` for what it mutates and runs):
//! mutated image and configuration files through the readers, the clip level, the detector,
//! the fits and the plan, in-process; panics are saved for reproduction and make it exit 1.
//!
//! ```sh
//! cargo run --release -p bostrack-pipeline --example fuzz -- [--iterations 100000] [--seed 1] [--out DIR] [--no-sample]
//! ```
//!
//! `--out`: where the cases are written and panicking ones kept (default: a temporary folder,
//! removed unless something panicked); `--no-sample`: without the real sample's files in the
//! seed corpus. The CI test `tests/fuzz.rs` runs a reduced round.

#[path = "../tests/common/fuzz.rs"]
mod fuzz;

use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (mut iterations, mut seed, mut out, mut sample) = (100_000u64, 1u64, None, true);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--iterations" => iterations = value()?.parse()?,
            "--seed" => seed = value()?.parse()?,
            "--out" => out = Some(PathBuf::from(value()?)),
            "--no-sample" => sample = false,
            other => {
                return Err(format!(
                    "unknown argument `{other}` (--iterations N --seed N --out DIR --no-sample)"
                )
                .into());
            }
        }
    }
    let sample_dir = if sample {
        bostrack_io::bos_sample_dir()
    } else {
        None
    };
    let corpus = fuzz::corpus(sample_dir.as_deref());
    let tmp = tempfile::tempdir()?;
    let dir = out.unwrap_or_else(|| tmp.path().to_path_buf());
    std::fs::create_dir_all(&dir)?;
    let t = Instant::now();
    let round = fuzz::run(&corpus, iterations, seed, &dir);
    println!(
        "{} executions in {:.1} s ({} seeds{}): {} image cases ({} decoded, {} through detection and fits), {} configuration cases; {} panics; slowest execution {:.3} s ({}); peak memory {:.0} MiB",
        round.executions,
        t.elapsed().as_secs_f64(),
        corpus.len(),
        if sample_dir.is_some() {
            ", the real sample's included"
        } else {
            ""
        },
        round.image_cases,
        round.decoded,
        round.fitted,
        round.config_cases,
        round.panics.len(),
        round.slowest.0,
        round.slowest.1,
        fuzz::peak_rss_mib().unwrap_or(f64::NAN),
    );
    for (p, what) in &round.panics {
        println!("PANIC {}: {what}", p.display());
    }
    if !round.panics.is_empty() {
        let _ = tmp.keep();
        std::process::exit(1);
    }
    Ok(())
}
