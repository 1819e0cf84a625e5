//! The paper's Monte Carlo (Sec. 3, Table 1, Fig. 5) at full size, and the amplification-ratio
//! study; writes CSV, PNG and a Markdown summary.
//!
//! `cargo run --release -p bostrack-paper --example paper_mc -- --out docs/paper`
//!
//! Options: `--draws N` (1000), `--realisations N` (1000), `--seed N` (1), `--threads N`
//! (2; the rayon pool of every study), `--ar-realisations N` (2000; the reference dot gets
//! 10x), `--studies LIST` (comma-separated from `volumetric`, `volumetric-effective`,
//! `volumetric-brightest`, `bos`, `bos-effective`, `bos-fixed-noise`, `ar`; default all).

use bostrack_paper::*;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

struct Args {
    out: PathBuf,
    draws: usize,
    realisations: usize,
    seed: u64,
    threads: usize,
    ar_realisations: usize,
    studies: Vec<String>,
}

const ALL: [&str; 7] = [
    "volumetric",
    "volumetric-effective",
    "volumetric-brightest",
    "bos",
    "bos-effective",
    "bos-fixed-noise",
    "ar",
];

fn parse() -> Result<Args, String> {
    let mut a = Args {
        out: PathBuf::from("docs/paper"),
        draws: 1000,
        realisations: 1000,
        seed: 1,
        threads: 2,
        ar_realisations: 2000,
        studies: ALL.iter().map(|s| s.to_string()).collect(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut val = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        let num = |v: String| v.parse::<usize>().map_err(|e| format!("{flag}: {e}"));
        match flag.as_str() {
            "--out" => a.out = PathBuf::from(val()?),
            "--draws" => a.draws = num(val()?)?,
            "--realisations" => a.realisations = num(val()?)?,
            "--seed" => a.seed = num(val()?)? as u64,
            "--threads" => a.threads = num(val()?)?,
            "--ar-realisations" => a.ar_realisations = num(val()?)?,
            "--studies" => {
                a.studies = val()?.split(',').map(|s| s.trim().to_string()).collect();
                if let Some(bad) = a.studies.iter().find(|s| !ALL.contains(&s.as_str())) {
                    return Err(format!("unknown study `{bad}` (known: {})", ALL.join(", ")));
                }
            }
            other => return Err(format!("unknown option `{other}`")),
        }
    }
    Ok(a)
}

/// CPU time of this process (user + system, s) from /proc/self/stat (clock ticks of 1/100 s,
/// Linux's USER_HZ); NaN where unavailable.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // fields after the command name (which is in parentheses and may contain spaces)
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok());
    match (tick(11), tick(12)) {
        (Some(u), Some(s)) => (u + s) / 100.0,
        _ => f64::NAN,
    }
}

fn create(dir: &Path, name: &str) -> Result<BufWriter<File>, Box<dyn std::error::Error>> {
    let p = dir.join(name);
    Ok(BufWriter::new(
        File::create(&p).map_err(|e| format!("{}: {e}", p.display()))?,
    ))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse()?;
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads)
        .build()?;
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let mut summary = String::new();
    summary.push_str(&format!(
        "Command: `cargo run --release -p bostrack-paper --example paper_mc -- --out {} --draws {} --realisations {} --seed {} --threads {} --ar-realisations {} --studies {}`\n\n",
        args.out.display(),
        args.draws,
        args.realisations,
        args.seed,
        args.threads,
        args.ar_realisations,
        args.studies.join(",")
    ));
    summary.push_str(&format!(
        "Threads: {} (rayon). Load average at the start (/proc/loadavg): {}\n",
        args.threads,
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    ));
    let mut results = Vec::new();
    let mut times = Vec::new();
    for name in &args.studies {
        let Some(mut cfg) = StudyConfig::named(name, args.draws, args.realisations) else {
            continue; // "ar", below
        };
        cfg.seed = args.seed;
        let cpu0 = cpu_seconds();
        let r = pool.install(|| run_study(&cfg))?;
        let cpu = cpu_seconds() - cpu0;
        eprintln!(
            "{name}: {} draws x {} realisations in {:.1} s on {} threads ({cpu:.1} s CPU)",
            cfg.draws, cfg.realisations, r.wall_s, r.threads
        );
        times.push(format!(
            "- {name}: {} fits in {:.1} s wall, {cpu:.1} s CPU ({} threads)",
            r.groups[0].fits + r.groups[0].failures,
            r.wall_s,
            r.threads
        ));
        write_draws_csv(&r.rows, create(&args.out, &format!("fig5-{name}.csv"))?)?;
        let png = fig5_figure(&r)?.to_png()?;
        std::fs::write(args.out.join(format!("fig5-{name}.png")), png)?;
        results.push(r);
    }
    if !results.is_empty() {
        summary.push_str("\n## Monte Carlo against Eq. 35 and the exact bound\n\n");
        let mut table = Vec::new();
        write_study_markdown(&results.iter().collect::<Vec<_>>(), &mut table)?;
        summary.push_str(&String::from_utf8(table)?);
        summary.push_str(&format!(
            "\nExpected relative scatter of one Monte Carlo std: {:.4} (1/sqrt(2(n-1)), n = {}).\n",
            results[0].expected_rel_error, args.realisations
        ));
    }
    if args.studies.iter().any(|s| s == "ar") {
        let cfg = ArStudyConfig {
            realisations: args.ar_realisations,
            reference_realisations: 10 * args.ar_realisations,
            seed: args.seed,
            ..ArStudyConfig::default()
        };
        let cpu0 = cpu_seconds();
        let r = pool.install(|| run_ar_study(&cfg))?;
        let cpu = cpu_seconds() - cpu0;
        eprintln!(
            "ar: {} cases in {:.1} s ({cpu:.1} s CPU)",
            r.rows.len(),
            r.wall_s
        );
        times.push(format!(
            "- ar: {} gradient dots x {} + reference x {} fits in {:.1} s wall, {cpu:.1} s CPU ({} threads)",
            r.rows.len(),
            cfg.realisations,
            cfg.reference_realisations,
            r.wall_s,
            r.threads
        ));
        write_ar_csv(&r, create(&args.out, "ar.csv")?)?;
        std::fs::write(args.out.join("ar.png"), ar_figure(&r)?.to_png()?)?;
        summary.push_str(&format!(
            "\n## Amplification ratio ({} cases, reference std x {:.5} y {:.5} px, bound {:.5} px; expected rel. error of one measured AR {:.4})\n\n",
            r.rows.len(),
            r.reference.std_x,
            r.reference.std_y,
            r.reference.bound_x,
            r.expected_rel_error
        ));
        let mut table = Vec::new();
        write_ar_markdown(&r, &mut table)?;
        summary.push_str(&String::from_utf8(table)?);
    }
    summary.push_str(&format!(
        "\n## Wall times\n\nLoad average at the end: {}\n\n",
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    ));
    summary.push_str(&times.join("\n"));
    summary.push('\n');
    let mut f = create(&args.out, "summary.md")?;
    f.write_all(summary.as_bytes())?;
    f.flush()?;
    print!("{summary}");
    Ok(())
}
