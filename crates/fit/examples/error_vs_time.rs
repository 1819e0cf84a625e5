//! Error against run time of every estimator and model on synthetic scenes.
//!
//! `cargo run --release -p bostrack-fit --example error_vs_time -- --out docs/benchmarks/error-vs-time.csv [--realisations 1000] [--seed 1] [--scenes clean_s1.6,touching]`

use bostrack_fit::study::{StudyConfig, error_vs_time, study_scenes, write_study_csv};
use std::io::Write;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut cfg = StudyConfig::default();
    let mut out: Option<String> = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut val = || args.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--out" => out = Some(val()?),
            "--realisations" => cfg.realisations = val()?.parse()?,
            "--seed" => cfg.seed = val()?.parse()?,
            "--scenes" => cfg.scenes = val()?.split(',').map(str::to_string).collect(),
            "--list" => {
                for s in study_scenes() {
                    println!("{:20} {}", s.name, s.description);
                }
                return Ok(());
            }
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    let t0 = std::time::Instant::now();
    let rows = error_vs_time(&cfg)?;
    eprintln!("{} rows in {:.1} s", rows.len(), t0.elapsed().as_secs_f64());
    match out {
        Some(path) => {
            let mut f = std::io::BufWriter::new(std::fs::File::create(&path)?);
            write_study_csv(&mut f, &rows)?;
            f.flush()?;
            eprintln!("wrote {path}");
        }
        None => write_study_csv(std::io::stdout().lock(), &rows)?,
    }
    Ok(())
}
