//! Matching on synthetic point sets and dot records with known correspondence.

mod common;

use bostrack_core::{DotFit, DotFlags, FitStatus, GridIndex};
use bostrack_match::{MatchConfig, MatchMode, MatchedBy, NearestConfig, match_dots, match_points};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

/// `nx` x `ny` square lattice of spacing `s`, jittered by ±jitter px.
fn lattice(nx: usize, ny: usize, s: f64, jitter: f64, rng: &mut StdRng) -> Vec<[f64; 2]> {
    (0..nx * ny)
        .map(|k| {
            [
                s * (k % nx) as f64 + rng.random_range(-jitter..=jitter),
                s * (k / nx) as f64 + rng.random_range(-jitter..=jitter),
            ]
        })
        .collect()
}

/// Solid-body rotation about `c` with |d| = `dmax` at distance `rmax`.
fn rotation(p: [f64; 2], c: [f64; 2], rmax: f64, dmax: f64) -> [f64; 2] {
    let w = dmax / rmax;
    [-w * (p[1] - c[1]), w * (p[0] - c[0])]
}

fn moved(
    r: &[[f64; 2]],
    f: impl Fn([f64; 2]) -> [f64; 2],
    noise: f64,
    rng: &mut StdRng,
) -> Vec<[f64; 2]> {
    let n = Normal::new(0.0, noise).unwrap();
    r.iter()
        .map(|&p| {
            let d = f(p);
            [p[0] + d[0] + n.sample(rng), p[1] + d[1] + n.sample(rng)]
        })
        .collect()
}

/// A displacement field larger than the search radius in part of the domain: plain mutual
/// nearest neighbours leave those dots unmatched, the local-median predictor recovers them
/// all, without a single wrong pair.
#[test]
fn predictor_follows_a_field_larger_than_the_radius() {
    let mut rng = StdRng::seed_from_u64(11);
    let spacing = 10.0;
    let r = lattice(60, 60, spacing, 0.5, &mut rng);
    let c = [295.0, 295.0];
    // |d| = 4.8 px at 300 px from the centre and 6.7 px in the corners: beyond the radius
    // (4 px = 0.4 spacing) and, in the corners, beyond half the spacing
    let g = moved(&r, |p| rotation(p, c, 300.0, 4.8), 0.03, &mut rng);
    let plain = NearestConfig {
        iterations: 0,
        ..NearestConfig::for_spacing(spacing)
    };
    let m0 = match_points(&r, &g, &plain).unwrap();
    let m = match_points(&r, &g, &NearestConfig::for_spacing(spacing)).unwrap();
    println!(
        "plain: {} pairs, {} unmatched; with predictor: {} pairs in {} passes",
        m0.pairs.len(),
        m0.unmatched_reference.len(),
        m.pairs.len(),
        m.passes
    );
    assert!(m0.pairs.iter().all(|&(i, j)| i == j));
    assert!(m0.unmatched_reference.len() > 100);
    assert_eq!(m.pairs.len(), r.len());
    assert!(m.pairs.iter().all(|&(i, j)| i == j));
    assert!(m.unmatched_gradient.is_empty());
}

/// A uniform shift of 1.3 spacings: ambiguous to any nearest-neighbour rule (every dot gets a
/// neighbour's partner), resolved by the initial displacement.
#[test]
fn large_uniform_shift_needs_the_initial_displacement() {
    let mut rng = StdRng::seed_from_u64(12);
    let r = lattice(30, 30, 8.0, 0.0, &mut rng);
    let shift = [1.3 * 8.0, 0.2];
    let g = moved(&r, |_| shift, 0.02, &mut rng);
    let m = match_points(&r, &g, &NearestConfig::for_spacing(8.0)).unwrap();
    assert!(m.pairs.iter().all(|&(i, j)| i != j)); // all wrong (by one column)
    let with_prior = NearestConfig {
        initial_displacement: Some([10.0, 0.0]),
        ..NearestConfig::for_spacing(8.0)
    };
    let m = match_points(&r, &g, &with_prior).unwrap();
    assert!(m.pairs.iter().all(|&(i, j)| i == j));
    assert_eq!(m.pairs.len(), r.len());
}

/// Missing partners and spurious extra dots: no wrong pair, the missing ones unmatched.
#[test]
fn missing_and_spurious_dots() {
    let mut rng = StdRng::seed_from_u64(13);
    let r = lattice(80, 80, 8.0, 1.0, &mut rng);
    let g_all = moved(&r, |p| [0.5 + 0.002 * p[1], -0.3], 0.05, &mut rng);
    let mut g = Vec::new();
    let mut truth = Vec::new(); // gradient index -> reference index (None: spurious)
    let mut dropped = 0;
    for (i, p) in g_all.iter().enumerate() {
        if rng.random_range(0.0..1.0) < 0.05 {
            dropped += 1;
        } else {
            g.push(*p);
            truth.push(Some(i));
        }
    }
    for _ in 0..128 {
        g.push([rng.random_range(0.0..632.0), rng.random_range(0.0..632.0)]);
        truth.push(None);
    }
    let m = match_points(&r, &g, &NearestConfig::for_spacing(8.0)).unwrap();
    let wrong = m
        .pairs
        .iter()
        .filter(|&&(i, j)| truth[j] != Some(i))
        .count();
    let real_matched = m.pairs.iter().filter(|&&(_, j)| truth[j].is_some()).count();
    println!(
        "{} pairs ({} wrong, {} real), {} reference dots without partner ({dropped} dropped)",
        m.pairs.len(),
        wrong,
        real_matched,
        m.unmatched_reference.len()
    );
    // a spurious dot can only take a reference dot whose partner was dropped
    for &(i, j) in &m.pairs {
        if truth[j] != Some(i) {
            assert!(truth[j].is_none() && !truth.contains(&Some(i)));
        }
    }
    assert_eq!(real_matched, r.len() - dropped);
    assert_eq!(m.pairs.len() + m.unmatched_reference.len(), r.len());
    assert_eq!(m.pairs.len() + m.unmatched_gradient.len(), g.len());
}

fn dot(i: i32, j: i32, p: [f64; 2]) -> DotFit {
    common::dot(GridIndex::new(i, j), p)
}

/// Grid-index mode: index pairs first (failed fits included), kd-tree for the rest, and
/// swapped indices caught as GRID_MISMATCH.
#[test]
fn grid_index_mode_with_fallback_and_mismatch() {
    let (nx, ny, s) = (40, 40, 8.0);
    let mut rng = StdRng::seed_from_u64(14);
    let pos = lattice(nx, ny, s, 0.3, &mut rng);
    let shift = |p: [f64; 2]| [p[0] + 0.8, p[1] - 0.4];
    let reference: Vec<DotFit> = pos
        .iter()
        .enumerate()
        .map(|(k, &p)| dot((k % nx) as i32, (k / nx) as i32, p))
        .collect();
    let mut gradient: Vec<DotFit> = reference
        .iter()
        .map(|d| dot(d.index.i, d.index.j, shift([d.params.x0, d.params.y0])))
        .collect();
    gradient.reverse(); // order must not matter
    let at = |g: &[DotFit], i: i32, j: i32| {
        g.iter()
            .position(|d| d.index == GridIndex::new(i, j))
            .unwrap()
    };
    // (a) swap the indices of two neighbours
    let (a, b) = (at(&gradient, 10, 10), at(&gradient, 11, 10));
    gradient[a].index = GridIndex::new(11, 10);
    gradient[b].index = GridIndex::new(10, 10);
    // (b) a dot whose index detection did not keep: fall-back, no mismatch
    let c = at(&gradient, 20, 5);
    gradient[c].index = GridIndex::new(900, 900);
    // (c) a failed gradient fit: still paired by index, and not used by the kd-tree
    let f = at(&gradient, 3, 30);
    gradient[f].status = FitStatus::Singular;
    gradient[f].params.x0 = f64::NAN;
    let m = match_dots(&reference, &gradient, &MatchConfig::for_spacing(s)).unwrap();
    assert_eq!(m.pairs.len(), reference.len());
    assert!(m.unmatched_reference.is_empty() && m.unmatched_gradient.is_empty());
    for p in &m.pairs {
        let (ri, gi) = (reference[p.reference].index, gradient[p.gradient].index);
        let want_mismatch = ri == GridIndex::new(10, 10) || ri == GridIndex::new(11, 10);
        assert_eq!(
            p.flags.contains(DotFlags::GRID_MISMATCH),
            want_mismatch,
            "{ri:?}"
        );
        if ri == GridIndex::new(20, 5) {
            assert_eq!((p.by, gi), (MatchedBy::Nearest, GridIndex::new(900, 900)));
            assert_eq!(p.gradient, c);
        } else {
            assert_eq!((p.by, gi), (MatchedBy::GridIndex, ri));
        }
    }
    assert_eq!(m.grid_mismatches(), 2);

    // a whole gradient image indexed with an offset of one column: locally the same as a
    // correct pairing with a displacement one spacing smaller, so the check raises no flag
    // (the documented limit); what shows is the displacement, off by one lattice vector
    let offset: Vec<DotFit> = reference
        .iter()
        .map(|d| dot(d.index.i + 1, d.index.j, shift([d.params.x0, d.params.y0])))
        .collect();
    let m = match_dots(&reference, &offset, &MatchConfig::for_spacing(s)).unwrap();
    assert_eq!(m.pairs.len(), (nx - 1) * ny);
    assert_eq!(m.grid_mismatches(), 0);
    for p in &m.pairs {
        // the gradient dot of reference site (i, j) is the moved site (i - 1, j)
        let (r, g) = (&reference[p.reference], &offset[p.gradient]);
        let left = reference
            .iter()
            .find(|d| d.index == GridIndex::new(r.index.i - 1, r.index.j))
            .unwrap();
        let want = shift([left.params.x0, left.params.y0]);
        assert_eq!((g.params.x0, g.params.y0), (want[0], want[1]));
        assert!((g.params.x0 - r.params.x0 - (0.8 - s)).abs() < 0.7);
    }
    assert_eq!(
        (m.unmatched_reference.len(), m.unmatched_gradient.len()),
        (ny, ny)
    );

    // nearest mode: kd-tree only, indices compared; the failed fit is unmatched on both sides
    let cfg = MatchConfig {
        mode: MatchMode::Nearest {
            compare_indices: true,
        },
        ..MatchConfig::for_spacing(s)
    };
    let m = match_dots(&reference, &gradient, &cfg).unwrap();
    assert_eq!(m.pairs.len(), reference.len() - 1);
    assert_eq!(m.unmatched_gradient, vec![f]);
    assert_eq!(m.unmatched_reference.len(), 1);
    assert_eq!(
        reference[m.unmatched_reference[0]].index,
        GridIndex::new(3, 30)
    );
    // geometry-correct pairs; the swapped pair and the re-indexed dot disagree with the index
    assert_eq!(m.grid_mismatches(), 3);
    for p in &m.pairs {
        let g = &gradient[p.gradient];
        let r = &reference[p.reference];
        let e = shift([r.params.x0, r.params.y0]);
        assert!((g.params.x0 - e[0]).abs() < 1e-9 && (g.params.y0 - e[1]).abs() < 1e-9);
    }
}

/// A named displacement field.
type FieldFn = Box<dyn Fn([f64; 2]) -> [f64; 2]>;

/// A Gaussian bump of `amp` px (1/e² radius 2·sigma) centred at `c`, pointing along `dir`.
fn bump(p: [f64; 2], c: [f64; 2], amp: f64, sigma: f64, dir: [f64; 2]) -> [f64; 2] {
    let e = (-((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2)) / (2.0 * sigma * sigma)).exp();
    [amp * e * dir[0], amp * e * dir[1]]
}

/// Reference records on an `n` x `n` lattice (spacing `s`, jittered) and their gradient
/// records moved by `f` (plus 0.03 px noise), with the correct indices.
fn indexed_pair(
    n: usize,
    s: f64,
    f: impl Fn([f64; 2]) -> [f64; 2],
    seed: u64,
) -> (Vec<DotFit>, Vec<DotFit>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let pos = lattice(n, n, s, 0.3, &mut rng);
    let g = moved(&pos, &f, 0.03, &mut rng);
    let reference = pos
        .iter()
        .enumerate()
        .map(|(k, &p)| dot((k % n) as i32, (k / n) as i32, p))
        .collect();
    let gradient = g
        .iter()
        .enumerate()
        .map(|(k, &p)| dot((k % n) as i32, (k / n) as i32, p))
        .collect();
    (reference, gradient)
}

/// The known false flag: correct index pairs in a displacement field larger than the search
/// radius (0.4 spacing) were flagged GRID_MISMATCH by the index-free cross-check (97 of 1024
/// dots on a 6 px bump at an 8 px spacing; every dot for a uniform shift beyond half the
/// spacing). With the index-pair predictor, none is.
#[test]
fn large_smooth_fields_with_correct_indices_raise_no_grid_mismatch() {
    let s = 8.0;
    let c = [156.0, 148.0];
    let fields: Vec<(&str, FieldFn)> = vec![
        (
            "bump 0.6 s, wide",
            Box::new(move |p| bump(p, c, 0.6 * s, 4.0 * s, [0.8, 0.6])),
        ),
        (
            "bump 0.6 s, narrow",
            Box::new(move |p| bump(p, c, 0.6 * s, 2.0 * s, [1.0, 0.0])),
        ),
        (
            "bump 6 px",
            Box::new(move |p| bump(p, c, 6.0, 5.0 * s, [0.0, -1.0])),
        ),
        ("uniform 0.3 s", Box::new(move |_| [0.3 * s, 0.0])),
        ("uniform 0.7 s", Box::new(move |_| [0.7 * s, 0.0])),
        ("uniform 0.7 s, y", Box::new(move |_| [0.05, -0.7 * s])),
        (
            "uniform 0.7 s, diagonal",
            Box::new(move |_| [0.5 * s, 0.5 * s]),
        ),
    ];
    for (seed, (name, f)) in fields.iter().enumerate() {
        let (reference, gradient) = indexed_pair(40, s, f, 30 + seed as u64);
        let m = match_dots(&reference, &gradient, &MatchConfig::for_spacing(s)).unwrap();
        println!(
            "{name}: {} GRID_MISMATCH, {} passes",
            m.grid_mismatches(),
            m.passes
        );
        assert_eq!(m.grid_mismatches(), 0, "{name}");
        assert_eq!(m.passes, 1, "{name}");
        assert_eq!(m.pairs.len(), reference.len(), "{name}");
        assert!(
            m.pairs
                .iter()
                .all(|p| p.by == MatchedBy::GridIndex && p.reference == p.gradient),
            "{name}"
        );
    }
}

/// Wrong index pairs are still flagged where the displacement is large: a swapped pair, a
/// single dot carrying its neighbour's index, and a 3 x 3 patch indexed one column over, on
/// the bump of 0.6 spacing and on the uniform shift of 0.7 spacing. Exactly the wrong pairs
/// are flagged.
#[test]
fn wrong_index_pairs_in_large_fields_are_flagged() {
    let (n, s) = (40usize, 8.0);
    let c = [156.0, 148.0];
    let fields: Vec<(&str, FieldFn)> = vec![
        (
            "bump 0.6 s",
            Box::new(move |p| bump(p, c, 0.6 * s, 3.0 * s, [0.8, 0.6])),
        ),
        ("uniform 0.7 s", Box::new(move |_| [0.7 * s, 0.1])),
        ("uniform 0.2 s", Box::new(move |_| [0.2 * s, 0.1])),
    ];
    let site = |i: usize, j: usize| j * n + i;
    for (seed, (name, f)) in fields.iter().enumerate() {
        for case in ["swap", "stolen index", "3x3 patch"] {
            let (reference, mut gradient) = indexed_pair(n, s, f, 50 + seed as u64);
            // the bump peaks near site (19, 18)
            match case {
                "swap" => {
                    let (a, b) = (site(19, 18), site(20, 18));
                    let t = gradient[a].index;
                    gradient[a].index = gradient[b].index;
                    gradient[b].index = t;
                }
                "stolen index" => {
                    // the dot of (19, 18) is labelled (19, 19), listed before the real one
                    gradient[site(19, 18)].index = gradient[site(19, 19)].index;
                }
                _ => {
                    for j in 17..20 {
                        for i in 18..21 {
                            gradient[site(i, j)].index.i += 1;
                        }
                    }
                }
            }
            let m = match_dots(&reference, &gradient, &MatchConfig::for_spacing(s)).unwrap();
            let wrong: Vec<usize> = m
                .pairs
                .iter()
                .filter(|p| {
                    let (r, g) = (&reference[p.reference], &gradient[p.gradient]);
                    // a wrong pair: the gradient dot is not the reference dot's own
                    let e = f([r.params.x0, r.params.y0]);
                    (g.params.x0 - r.params.x0 - e[0]).hypot(g.params.y0 - r.params.y0 - e[1]) > 1.0
                })
                .map(|p| p.reference)
                .collect();
            let flagged: Vec<usize> = m
                .pairs
                .iter()
                .filter(|p| p.flags.contains(DotFlags::GRID_MISMATCH))
                .map(|p| p.reference)
                .collect();
            println!(
                "{name}, {case}: {} wrong pairs, {} flagged, {} passes",
                wrong.len(),
                flagged.len(),
                m.passes
            );
            let want = match case {
                "swap" => 2,
                "stolen index" => 1,
                _ => 9,
            };
            assert_eq!(wrong.len(), want, "{name} {case}");
            assert_eq!(flagged, wrong, "{name} {case}");
        }
    }
}

/// The per-dot loops run on rayon: the pairs, their flags and the passes are the same on 1 and
/// 3 threads (wrong index pairs included, so that the check's every branch runs; 1,600 dots,
/// above the loops' task size).
#[test]
fn matching_does_not_depend_on_the_thread_count() {
    let (n, s) = (40usize, 8.0);
    let c = [156.0, 148.0];
    let f = move |p: [f64; 2]| bump(p, c, 0.6 * s, 3.0 * s, [0.8, 0.6]);
    let (reference, mut gradient) = indexed_pair(n, s, f, 77);
    let t = gradient[19 * n + 18].index;
    gradient[19 * n + 18].index = gradient[19 * n + 19].index;
    gradient[19 * n + 19].index = t;
    // a dot without partner index, found by the nearest-neighbour fall-back
    gradient[5].index.i += 1000;
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| match_dots(&reference, &gradient, &MatchConfig::for_spacing(s)).unwrap())
    };
    let (a, b) = (on(1), on(3));
    assert!(
        a.pairs
            .iter()
            .any(|p| p.flags.contains(DotFlags::GRID_MISMATCH))
    );
    assert_eq!(a, b);
}
