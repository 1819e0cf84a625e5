//! Minimum wall time over repeated runs of matching and validation of ~12k dots (a load-robust
//! figure on a shared machine), or one run of a single operation for an instruction count:
//!
//! `cargo run --release -p bostrack-match --example match_timing`
//! `valgrind --tool=callgrind target/release/examples/match_timing plain` (or `predictor`,
//! `dots`, `median`)
use bostrack_core::{DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex};
use bostrack_match::{
    MatchConfig, NearestConfig, ValidationConfig, match_dots, match_points, validate,
};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::hint::black_box;
use std::time::Instant;

const SIDE: usize = 110;

type Op<'a> = (&'static str, Box<dyn Fn() + 'a>);

fn main() {
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
    let g: Vec<[f64; 2]> = r
        .iter()
        .map(|p| {
            let (x, y) = (p[0] / 880.0, p[1] / 880.0);
            [
                p[0] + 2.0 * (std::f64::consts::PI * y).sin() + n.sample(&mut rng),
                p[1] + 1.5 * (std::f64::consts::PI * x).cos() + n.sample(&mut rng),
            ]
        })
        .collect();
    let dots = |p: &[[f64; 2]]| -> Vec<DotFit> {
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
    };
    let (rd, gd) = (dots(&r), dots(&g));
    let d: Vec<[f64; 2]> = r
        .iter()
        .zip(&g)
        .map(|(a, b)| [b[0] - a[0], b[1] - a[1]])
        .collect();
    let plain = NearestConfig {
        iterations: 0,
        ..NearestConfig::for_spacing(8.0)
    };
    let default = NearestConfig::for_spacing(8.0);
    let mcfg = MatchConfig::for_spacing(8.0);
    let vcfg = ValidationConfig::default();
    let ops: Vec<Op> = vec![
        (
            "plain",
            Box::new(|| drop(black_box(match_points(&r, &g, &plain).unwrap()))),
        ),
        (
            "predictor",
            Box::new(|| drop(black_box(match_points(&r, &g, &default).unwrap()))),
        ),
        (
            "dots",
            Box::new(|| drop(black_box(match_dots(&rd, &gd, &mcfg).unwrap()))),
        ),
        (
            "median",
            Box::new(|| drop(black_box(validate(&r, &d, &vcfg).unwrap()))),
        ),
    ];
    let only = std::env::args().nth(1);
    for (name, f) in &ops {
        match &only {
            Some(o) if o == name => f(),
            Some(_) => {}
            None => {
                let best = (0..30)
                    .map(|_| {
                        let t = Instant::now();
                        f();
                        t.elapsed().as_secs_f64()
                    })
                    .fold(f64::INFINITY, f64::min);
                println!(
                    "{name:10} {} x {} points: min {:.2} ms",
                    r.len(),
                    g.len(),
                    best * 1e3
                );
            }
        }
    }
}
