//! Wall time of the two noise estimators on the real sample, and the models they give.
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p bostrack-fit --example noise_speed [runs] [single|stack]`
//!
//! Loads `pair/reference.tif` with `mask.tif` (for [`estimate_noise`]) and the 10-image no-flow
//! stack `ref-stack/im_0001.tif`..`im_0010.tif` with the same mask (for [`noise_from_stack`]),
//! runs each estimator `runs` times (default 15) and prints the best and the median wall time
//! in ms (take the best: the machine is shared), the mean user and system CPU time and minor
//! page faults per call (whole process, all threads, from `/proc/self/stat`), and the model with
//! every digit (`{:?}` of an f64 round-trips). A second argument `single` or `stack` runs only
//! that estimator (e.g. under callgrind).

use bostrack_core::NoiseModel;
use bostrack_fit::{estimate_noise, noise_from_stack};
use std::time::Instant;

/// (user CPU ms, system CPU ms, minor page faults) of the whole process so far (all threads),
/// from `/proc/self/stat`; CPU times in clock ticks of 10 ms, so meaningful over many runs only.
/// `None` off Linux.
fn usage() -> Option<[f64; 3]> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // the fields after the parenthesised command name: minflt is field 10, utime 14, stime 15
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<f64> = rest
        .split_whitespace()
        .map(|x| x.parse().unwrap_or(f64::NAN))
        .collect();
    Some([*f.get(11)? * 10.0, *f.get(12)? * 10.0, *f.get(7)?])
}

struct Timing {
    best: f64,
    median: f64,
    /// per call: user ms, system ms, minor page faults
    usage: Option<[f64; 3]>,
}

/// Wall times of `runs` calls and the mean CPU use per call, and the last result.
fn time<T>(runs: usize, mut f: impl FnMut() -> T) -> (Timing, T) {
    let mut ms = Vec::with_capacity(runs);
    let mut last = None;
    let before = usage();
    for _ in 0..runs {
        let t = Instant::now();
        let out = std::hint::black_box(f());
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        last = Some(out);
    }
    let usage = usage()
        .zip(before)
        .map(|(b, a)| std::array::from_fn(|i| (b[i] - a[i]) / runs as f64));
    ms.sort_by(f64::total_cmp);
    let timing = Timing {
        best: ms[0],
        median: ms[ms.len() / 2],
        usage,
    };
    (timing, last.expect("at least one run"))
}

fn show(what: &str, (t, m): (Timing, NoiseModel)) {
    let usage = t.usage.map_or("n/a".into(), |[u, s, f]| {
        format!("user {u:.1} ms, sys {s:.1} ms, {f:.0} page faults")
    });
    println!(
        "{what:<16} best {:6.2} ms  median {:6.2} ms  per call: {usage}\n  \
         read_variance {:?}  gain {:?}  offset {:?}",
        t.best, t.median, m.read_variance, m.gain, m.offset
    );
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Some(dir) = bostrack_io::bos_sample_dir() else {
        eprintln!("the BOS sample is not available: nothing measured");
        return Ok(());
    };
    let runs: usize = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 15,
    }
    .max(1);
    let img = bostrack_io::read_image(&dir.join("pair/reference.tif"))?;
    let mask = bostrack_io::read_mask_for(&dir.join("mask.tif"), img.width(), img.height())?;
    let stack = (1..=10)
        .map(|i| bostrack_io::read_image(&dir.join(format!("ref-stack/im_{i:04}.tif"))))
        .collect::<Result<Vec<_>, _>>()?;
    println!(
        "{}x{} px, {} threads, best of {runs}",
        img.width(),
        img.height(),
        rayon::current_num_threads()
    );
    let which = std::env::args().nth(2).unwrap_or_default();
    if which != "stack" {
        show(
            "estimate_noise",
            time(runs, || estimate_noise(&img, Some(&mask)).expect("noise")),
        );
    }
    if which != "single" {
        show(
            "noise_from_stack",
            time(runs, || {
                noise_from_stack(&stack, Some(&mask)).expect("noise")
            }),
        );
    }
    Ok(())
}
