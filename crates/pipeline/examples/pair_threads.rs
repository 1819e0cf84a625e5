//! How each stage of the real pair scales with threads (issue 17): the reference side
//! (`ReferenceContext::prepare`, no stack) and one gradient frame (`process_frame`) plus its
//! `dots.csv` (`write_frame`, no figures), run on rayon pools of 1 and 2 threads (or the
//! counts given), interleaved, `--runs` times (default 7); per stage the best wall time of each
//! thread count, the speed-up and the parallel fraction `p` of Amdahl's law from the largest
//! count `n` (`T_n / T_1 = 1 - p + p / n`). Results are checked identical across thread counts.
//!
//! `cargo run --release -p bostrack-pipeline --example pair_threads -- [--runs N] [--threads 1,2,4]`
//!
//! Wall times on a loaded machine are noisy: compare only numbers of the same run, and read the
//! best of several interleaved runs.

use bostrack_pipeline::{
    Plan, Quantities, ReferenceContext, load_config, process_frame, write_frame,
};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

fn arg(name: &str) -> Option<String> {
    std::env::args().skip_while(|a| a != name).nth(1)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let config = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/bos-sample.toml");
    if bostrack_io::bos_sample_dir().is_none() {
        eprintln!("no ../shared/data/bos-sample: nothing to measure");
        return Ok(());
    }
    let runs: usize = arg("--runs").map(|s| s.parse()).transpose()?.unwrap_or(7);
    let threads: Vec<usize> = arg("--threads")
        .unwrap_or_else(|| "1,2".into())
        .split(',')
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let mut cfg = load_config(&config)?;
    cfg.input.stack_dir = "".into();
    cfg.output.quantities = Quantities::Amplification;
    cfg.output.figures.clear();
    let plan = Plan::from_config(cfg, &config)?;
    let out = std::env::temp_dir().join(format!("bostrack-pair-threads-{}", std::process::id()));

    // best[(threads, stage)] = seconds
    let mut best: BTreeMap<(usize, String), f64> = BTreeMap::new();
    let mut order: Vec<String> = Vec::new();
    let mut csv_of: BTreeMap<usize, Vec<u8>> = BTreeMap::new();
    for run in 0..runs {
        let mut ts = threads.clone();
        if run % 2 == 1 {
            ts.reverse();
        }
        for &n in &ts {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build()?;
            let stages = pool
                .install(|| -> Result<_, Box<dyn std::error::Error + Send + Sync>> {
                    let t0 = Instant::now();
                    let ctx = ReferenceContext::prepare(&plan)?;
                    let t_ref = t0.elapsed().as_secs_f64();
                    let t1 = Instant::now();
                    let r = process_frame(&ctx, &plan, &plan.gradients[0])?;
                    let t_frame = t1.elapsed().as_secs_f64();
                    let t2 = Instant::now();
                    write_frame(&out.join(n.to_string()), &r)?;
                    let t_write = t2.elapsed().as_secs_f64();
                    let csv =
                        std::fs::read(out.join(n.to_string()).join(&r.stem).join("dots.csv"))?;
                    let mut s: Vec<(String, f64)> = Vec::new();
                    for (k, v) in &ctx.timings().stages {
                        s.push((format!("reference {k}"), *v));
                    }
                    s.push(("reference total".into(), t_ref));
                    for (k, v) in &r.summary.times.stages {
                        s.push((format!("frame {k}"), *v));
                    }
                    s.push(("frame total".into(), t_frame));
                    s.push(("frame write dots.csv".into(), t_write));
                    s.push(("pair total".into(), t_ref + t_frame + t_write));
                    Ok((s, csv))
                })
                .map_err(|e| e.to_string())?;
            let (s, csv) = stages;
            if let Some(prev) = csv_of.get(&n).or_else(|| csv_of.values().next()) {
                assert!(prev == &csv, "dots.csv differs between thread counts");
            }
            csv_of.insert(n, csv);
            for (k, v) in s {
                if !order.contains(&k) {
                    order.push(k.clone());
                }
                let e = best.entry((n, k)).or_insert(f64::INFINITY);
                *e = e.min(v);
            }
        }
    }
    let _ = std::fs::remove_dir_all(&out);
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "real pair (testdata/bos-sample.toml, no stack, no figures), best of {runs} interleaved runs; load {}",
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    let n_max = *threads.iter().max().unwrap_or(&1);
    let mut head = "| stage |".to_string();
    for n in &threads {
        head.push_str(&format!(
            " {n} thread{} (ms) |",
            if *n == 1 { "" } else { "s" }
        ));
    }
    head.push_str(&format!(" speed-up at {n_max} | parallel fraction |"));
    println!("{head}");
    println!("|---|{}---|---|", "---|".repeat(threads.len()));
    for k in &order {
        let mut line = format!("| {k} |");
        for n in &threads {
            line.push_str(&format!(" {:.1} |", 1e3 * best[&(*n, k.clone())]));
        }
        let (t1, tn) = (best[&(1, k.clone())], best[&(n_max, k.clone())]);
        let s = t1 / tn;
        // T_n/T_1 = 1 - p + p/n  =>  p = (1 - T_n/T_1) / (1 - 1/n)
        let p = (1.0 - tn / t1) / (1.0 - 1.0 / n_max as f64);
        line.push_str(&format!(" {s:.2} | {p:.2} |"));
        println!("{line}");
    }
    Ok(())
}
