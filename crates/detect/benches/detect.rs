//! Detection and tracking speed on the real 1024x1024 sample (single thread: the crate uses no
//! threads), reported by criterion per image and, below, as µs per dot and ms per megapixel.
//! Without the sample data, a synthetic 1024x1024 target of the same kind is used.
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

    let td = best_of(15, || {
        black_box(detect(&inp.reference, mask, &cfg).unwrap());
    });
    let tt = best_of(15, || {
        black_box(track(&inp.gradient, mask, &det, &cfg).unwrap());
    });
    eprintln!(
        "{}: {} dots, {:.2} Mpx; best of 15: detect {:.1} ms = {:.2} µs/dot = {:.1} ms/Mpx; track {:.1} ms = {:.2} µs/dot = {:.1} ms/Mpx",
        inp.name,
        dots,
        mp,
        td * 1e3,
        td * 1e6 / dots,
        td * 1e3 / mp,
        tt * 1e3,
        tt * 1e6 / dots,
        tt * 1e3 / mp
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
