//! Matching and validation of ~12k dots (a 110 x 110 lattice, spacing 8 px, a smooth field of
//! up to ~2 px plus 0.03 px noise).
//!
//! `cargo bench -p bostrack-match --bench matching`
use bostrack_core::{DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex};
use bostrack_match::{
    MatchConfig, NearestConfig, ValidationConfig, match_dots, match_points, validate,
};
use criterion::{Criterion, criterion_group, criterion_main};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::hint::black_box;

const SIDE: usize = 110;

fn data() -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let mut rng = StdRng::seed_from_u64(5);
    let n = Normal::new(0.0, 0.03).unwrap();
    let r: Vec<[f64; 2]> = (0..SIDE * SIDE)
        .map(|k| {
            [
                8.0 * (k % SIDE) as f64 + rng.random_range(-0.5..0.5),
                8.0 * (k / SIDE) as f64 + rng.random_range(-0.5..0.5),
            ]
        })
        .collect();
    let g = r
        .iter()
        .map(|p| {
            let (x, y) = (p[0] / 880.0, p[1] / 880.0);
            [
                p[0] + 2.0 * (std::f64::consts::PI * y).sin() + n.sample(&mut rng),
                p[1] + 1.5 * (std::f64::consts::PI * x).cos() + n.sample(&mut rng),
            ]
        })
        .collect();
    (r, g)
}

fn dots(p: &[[f64; 2]]) -> Vec<DotFit> {
    p.iter()
        .enumerate()
        .map(|(k, p)| DotFit {
            index: GridIndex::new((k % SIDE) as i32, (k / SIDE) as i32),
            params: Gaussian2D::circular(p[0], p[1], 1000.0, 1.5, 100.0),
            crlb_x: 0.01,
            crlb_y: 0.01,
            rms: 1.0,
            iterations: 4,
            status: FitStatus::Converged,
            flags: DotFlags::NONE,
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let (r, g) = data();
    let plain = NearestConfig {
        iterations: 0,
        ..NearestConfig::for_spacing(8.0)
    };
    let default = NearestConfig::for_spacing(8.0);
    let m = match_points(&r, &g, &default).unwrap();
    assert_eq!(m.pairs.len(), r.len());
    println!(
        "{} points per side; default config ran {} passes",
        r.len(),
        m.passes
    );
    c.bench_function("mutual_nn_12k_plain", |b| {
        b.iter(|| match_points(black_box(&r), black_box(&g), &plain).unwrap())
    });
    c.bench_function("mutual_nn_12k_with_predictor", |b| {
        b.iter(|| match_points(black_box(&r), black_box(&g), &default).unwrap())
    });
    let (rd, gd) = (dots(&r), dots(&g));
    let cfg = MatchConfig::for_spacing(8.0);
    c.bench_function("match_dots_12k_grid_index", |b| {
        b.iter(|| match_dots(black_box(&rd), black_box(&gd), &cfg).unwrap())
    });
    let d: Vec<[f64; 2]> = r
        .iter()
        .zip(&g)
        .map(|(a, b)| [b[0] - a[0], b[1] - a[1]])
        .collect();
    let vcfg = ValidationConfig::default();
    c.bench_function("median_test_12k", |b| {
        b.iter(|| validate(black_box(&r), black_box(&d), &vcfg).unwrap())
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
