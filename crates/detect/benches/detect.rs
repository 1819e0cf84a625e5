//! Detection and tracking speed on the real 1024x1024 sample, reported by criterion per image
//! and, below, as µs per dot and ms per megapixel, single thread and on two threads. Without
//! the sample data, a synthetic 1024x1024 target of the same kind is used.
//!
//! The crate runs its per-row and per-dot loops on the current rayon pool (results do not
//! depend on the number of threads). "Single thread" runs inside a one-thread pool that holds
//! the calling thread, so nothing is handed to other threads. Wall times on a shared machine
//! vary with its load; the summary therefore also times a reference operation in the same run
//! (a plain 3x3 box mean over the image, f64) and gives each time as a multiple of it.
//!
//! `cargo bench -p bostrack-detect --bench detect`

use bostrack_core::{Image, Mask};
use bostrack_detect::{DetectConfig, detect, track};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Instant;

struct Input {
    name: &'static str,
    reference: Image,
    gradient: Image,
    mask: Option<Mask>,
}

fn input() -> Input {
    if let Some(dir) = bostrack_io::bos_sample_dir() {
        return Input {
            name: "bos-sample",
            reference: bostrack_io::read_image(&dir.join("pair/reference.tif")).unwrap(),
            gradient: bostrack_io::read_image(&dir.join("pair/gradient.tif")).unwrap(),
            mask: Some(bostrack_io::read_mask(&dir.join("mask.tif")).unwrap()),
        };
    }
    let cfg = bostrack_synth::SceneConfig {
        width: 1024,
        height: 1024,
        truth: bostrack_synth::TruthConfig {
            crlb: false,
            ..Default::default()
        },
        defects: bostrack_synth::DefectConfig {
            missing: 0.01,
            ..Default::default()
        },
        ..Default::default()
    };
    let flow = bostrack_synth::FlowConfig {
        displacement: bostrack_synth::DisplacementField::Uniform { dx: 0.3, dy: -0.2 },
        ..Default::default()
    };
    Input {
        name: "synthetic",
        reference: bostrack_synth::Scene::reference(&cfg).unwrap().image,
        gradient: bostrack_synth::Scene::gradient(&cfg, &flow).unwrap().image,
        mask: None,
    }
}

/// Smallest wall time of `n` runs, in seconds (robust to other load on the machine).
fn best_of(n: usize, mut f: impl FnMut()) -> f64 {
    (0..n)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The reference operation: mean over the 3x3 neighbourhood of every interior pixel.
fn box3(img: &Image) -> Vec<f64> {
    let (w, h) = (img.width(), img.height());
    let d = img.data();
    let mut out = vec![0.0; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let mut s = 0.0;
            for yy in y - 1..=y + 1 {
                s += d[yy * w + x - 1] + d[yy * w + x] + d[yy * w + x + 1];
            }
            out[y * w + x] = s / 9.0;
        }
    }
    out
}

/// A rayon pool of `n` threads that includes the calling one.
fn pool(n: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .use_current_thread()
        .build()
        .unwrap()
}

fn bench(c: &mut Criterion) {
    let inp = input();
    let cfg = DetectConfig::default();
    let mask = inp.mask.as_ref();
    let det = detect(&inp.reference, mask, &cfg).unwrap();
    let mp = (inp.reference.width() * inp.reference.height()) as f64 / 1e6;
    let dots = det.stats.found as f64;

    let mut g = c.benchmark_group(format!("detect/{}", inp.name));
    g.sample_size(20);
    g.bench_function("detect", |b| {
        b.iter(|| detect(black_box(&inp.reference), mask, &cfg).unwrap())
    });
    g.bench_function("track", |b| {
        b.iter(|| track(black_box(&inp.gradient), mask, &det, &cfg).unwrap())
    });
    g.finish();

    let tb = best_of(15, || {
        black_box(box3(&inp.reference));
    });
    eprintln!(
        "{}: {} dots, {:.2} Mpx; reference operation (3x3 box mean, f64): {:.2} ms",
        inp.name,
        dots,
        mp,
        tb * 1e3
    );
    // A pool per setting, each built on a fresh thread that it includes (with one thread, all
    // the work stays on that thread).
    for threads in [1, 2] {
        let (td, tt) = std::thread::scope(|s| {
            s.spawn(|| {
                let p = pool(threads);
                p.install(|| {
                    let td = best_of(15, || {
                        black_box(detect(&inp.reference, mask, &cfg).unwrap());
                    });
                    let tt = best_of(15, || {
                        black_box(track(&inp.gradient, mask, &det, &cfg).unwrap());
                    });
                    (td, tt)
                })
            })
            .join()
            .unwrap()
        });
        eprintln!(
            "  {threads} thread(s), best of 15: detect {:.1} ms = {:.2} µs/dot = {:.1} ms/Mpx = {:.1}x the reference operation; track {:.1} ms = {:.2} µs/dot = {:.1} ms/Mpx = {:.1}x",
            td * 1e3,
            td * 1e6 / dots,
            td * 1e3 / mp,
            td / tb,
            tt * 1e3,
            tt * 1e6 / dots,
            tt * 1e3 / mp,
            tt / tb
        );
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
