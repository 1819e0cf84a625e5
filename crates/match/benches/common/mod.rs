//! The synthetic 12k-dot field shared by `benches/matching.rs` and `examples/match_timing.rs`:
//! a 110 x 110 lattice of spacing 8 px (jittered by up to ±0.5 px), moved by a smooth field of
//! up to about 2 px plus 0.03 px noise per coordinate (like the real sample: ~12.2k dots on a
//! 1024 x 1024 image).

use bostrack_core::{DotFit, GridIndex};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::hint::black_box;
use std::time::Instant;

pub const SIDE: usize = 110;
pub const SPACING: f64 = 8.0;

pub struct Field {
    /// Reference and gradient positions (px), site k = (k % SIDE, k / SIDE).
    pub reference: Vec<[f64; 2]>,
    pub gradient: Vec<[f64; 2]>,
    /// The same as fitted-dot records with their grid indices.
    pub reference_dots: Vec<DotFit>,
    pub gradient_dots: Vec<DotFit>,
    /// `gradient - reference`.
    pub displacement: Vec<[f64; 2]>,
}

#[path = "../../tests/common/mod.rs"]
mod record;

fn dots(p: &[[f64; 2]]) -> Vec<DotFit> {
    p.iter()
        .enumerate()
        .map(|(k, p)| record::dot(GridIndex::new((k % SIDE) as i32, (k / SIDE) as i32), *p))
        .collect()
}

pub fn field() -> Field {
    let mut rng = StdRng::seed_from_u64(5);
    let n = Normal::new(0.0, 0.03).unwrap();
    let reference: Vec<[f64; 2]> = (0..SIDE * SIDE)
        .map(|k| {
            [
                SPACING * (k % SIDE) as f64 + rng.random_range(-0.5..0.5),
                SPACING * (k / SIDE) as f64 + rng.random_range(-0.5..0.5),
            ]
        })
        .collect();
    let gradient: Vec<[f64; 2]> = reference
        .iter()
        .map(|p| {
            let (x, y) = (p[0] / 880.0, p[1] / 880.0);
            [
                p[0] + 2.0 * (std::f64::consts::PI * y).sin() + n.sample(&mut rng),
                p[1] + 1.5 * (std::f64::consts::PI * x).cos() + n.sample(&mut rng),
            ]
        })
        .collect();
    let displacement = reference
        .iter()
        .zip(&gradient)
        .map(|(a, b)| [b[0] - a[0], b[1] - a[1]])
        .collect();
    Field {
        reference_dots: dots(&reference),
        gradient_dots: dots(&gradient),
        reference,
        gradient,
        displacement,
    }
}

/// The baseline measured in the same run: kiddo's immutable kd-tree over the gradient
/// positions, built and asked for the nearest point to every reference position (a plain
/// nearest-neighbour pairing of the two sets).
pub fn baseline_kd(reference: &[[f64; 2]], gradient: &[[f64; 2]]) -> usize {
    let tree = ImmutableKdTree::<f64, 2>::new_from_slice(gradient).unwrap();
    let mut s = 0usize;
    for q in reference {
        s = s.wrapping_add(
            tree.query(q)
                .nearest_one::<SquaredEuclidean<f64>>()
                .execute()
                .item as usize,
        );
    }
    s
}

/// kiddo's tree build alone.
#[allow(dead_code)] // used by the bench, not the example
pub fn baseline_build(gradient: &[[f64; 2]]) -> usize {
    let tree = black_box(ImmutableKdTree::<f64, 2>::new_from_slice(gradient).unwrap());
    black_box(&tree);
    gradient.len()
}

/// Minimum wall time (ms) over `runs` calls: a figure robust to load on a shared machine.
pub fn min_ms(runs: usize, mut f: impl FnMut()) -> f64 {
    (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min)
}
