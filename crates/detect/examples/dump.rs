//! Writes every seed of the real sample's detection and trackings as CSV (full precision), for
//! before/after comparisons of optimisations; or runs detect and track once each (for a
//! profiler such as `valgrind --tool=callgrind`).
//!
//! `cargo run --release -p bostrack-detect --example dump -- OUT_DIR` writes
//! `OUT_DIR/{reference,gradient,im_0001..im_0010}.csv` and `OUT_DIR/stats.txt`;
//! `... --example dump -- --profile [none|detect]` runs detect and track on the gradient once
//! and prints the counts (`detect`: detect only; `none`: reading the images only);
//! `... --example dump -- --time N` prints the best of N wall times of each. `DUMP_THREADS=n`
//! runs on a rayon pool of n threads that includes the calling one.

use bostrack_detect::{DetectConfig, Detection, detect, track};
use std::io::Write;
use std::path::Path;

fn write_csv(path: &Path, d: &Detection) -> std::io::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(
        f,
        "i,j,pred_x,pred_y,x,y,win_x,win_y,win_w,win_h,flags,contrast"
    )?;
    for (s, c) in d.seeds.iter().zip(&d.contrast) {
        writeln!(
            f,
            "{},{},{:?},{:?},{:?},{:?},{},{},{},{},{},{:?}",
            s.index.i,
            s.index.j,
            s.predicted[0],
            s.predicted[1],
            s.centre[0],
            s.centre[1],
            s.window.x,
            s.window.y,
            s.window.width,
            s.window.height,
            s.flags,
            c
        )?;
    }
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Some(dir) = bostrack_io::bos_sample_dir() else {
        eprintln!("no sample data");
        return Ok(());
    };
    let arg = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "/tmp/detect-dump".into());
    // DUMP_THREADS=n: run on a pool of n threads that includes this one (n = 1: everything on
    // this thread, as a profiler of this thread wants it).
    let _pool = match std::env::var("DUMP_THREADS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .use_current_thread()
                .build()?;
            Some(pool)
        }
        None => None,
    };
    let reference = bostrack_io::read_image(&dir.join("pair/reference.tif"))?;
    let mask = bostrack_io::read_mask(&dir.join("mask.tif"))?;
    let cfg = DetectConfig::default();
    if arg == "--time" {
        // Best of N wall times (the machine may be shared).
        let n: usize = std::env::args()
            .nth(2)
            .and_then(|a| a.parse().ok())
            .unwrap_or(20);
        let gradient = bostrack_io::read_image(&dir.join("pair/gradient.tif"))?;
        let det = detect(&reference, Some(&mask), &cfg)?;
        let best = |f: &mut dyn FnMut()| {
            (0..n)
                .map(|_| {
                    let t = std::time::Instant::now();
                    f();
                    t.elapsed().as_secs_f64() * 1e3
                })
                .fold(f64::INFINITY, f64::min)
        };
        let td = best(&mut || {
            std::hint::black_box(detect(&reference, Some(&mask), &cfg).unwrap());
        });
        let tt = best(&mut || {
            std::hint::black_box(track(&gradient, Some(&mask), &det, &cfg).unwrap());
        });
        println!("best of {n}: detect {td:.2} ms, track {tt:.2} ms");
        return Ok(());
    }
    if arg == "--profile" {
        let what = std::env::args().nth(2).unwrap_or_default();
        let gradient = bostrack_io::read_image(&dir.join("pair/gradient.tif"))?;
        if what == "none" {
            // Reading only: the baseline to subtract from the other two.
            return Ok(());
        }
        let det = detect(&reference, Some(&mask), &cfg)?;
        println!("detect: {:?}", det.stats);
        if what != "detect" {
            let tr = track(&gradient, Some(&mask), &det, &cfg)?;
            println!("track: {:?}", tr.stats);
        }
        return Ok(());
    }
    let out = Path::new(&arg);
    std::fs::create_dir_all(out)?;
    let det = detect(&reference, Some(&mask), &cfg)?;
    let mut stats = std::fs::File::create(out.join("stats.txt"))?;
    writeln!(
        stats,
        "reference: spacing {:?} diameter {:?} lattice {:?}\n{:?}",
        det.spacing, det.diameter, det.lattice, det.stats
    )?;
    write_csv(&out.join("reference.csv"), &det)?;
    let nomask = detect(&reference, None, &cfg)?;
    writeln!(stats, "reference without mask: {:?}", nomask.stats)?;
    write_csv(&out.join("reference-nomask.csv"), &nomask)?;
    for (name, path) in [("gradient".to_string(), dir.join("pair/gradient.tif"))]
        .into_iter()
        .chain((1..=10).map(|k| {
            (
                format!("im_{k:04}"),
                dir.join(format!("ref-stack/im_{k:04}.tif")),
            )
        }))
    {
        let img = bostrack_io::read_image(&path)?;
        let tr = track(&img, Some(&mask), &det, &cfg)?;
        writeln!(stats, "{name}: {:?}", tr.stats)?;
        write_csv(&out.join(format!("{name}.csv")), &tr)?;
    }
    println!("written to {}", out.display());
    Ok(())
}
