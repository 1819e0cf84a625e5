//! The optimised matching and validation (kd-tree searches, index neighbourhoods, sorting
//! networks, backward queries only where needed) against straightforward implementations of
//! the documented algorithms: brute-force nearest neighbours (ties to the lower index),
//! medians by sorting, hash-map index lookups. The results must be identical, bit for bit.

mod common;

use bostrack_core::{DotFit, DotFlags, FitStatus, GridIndex};
use bostrack_match::{
    MatchConfig, MatchMode, MatchedBy, Matches, MedianTest, NearestConfig, Pair, ValidationConfig,
    Verdict, match_dots, match_points, validate,
};
use common::dot;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::collections::HashMap;

// ---------------------------------------------------------------- straightforward versions

fn finite(p: &[f64; 2]) -> bool {
    p[0].is_finite() && p[1].is_finite()
}

fn d2(a: &[f64; 2], b: &[f64; 2]) -> f64 {
    let (dx, dy) = (a[0] - b[0], a[1] - b[1]);
    dx * dx + dy * dy
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The `k` nearest of the candidates to `p` (brute force, ties to the lower index).
fn nearest_k(pts: &[[f64; 2]], cand: impl Fn(usize) -> bool, p: &[f64; 2], k: usize) -> Vec<usize> {
    let mut all: Vec<(f64, usize)> = (0..pts.len())
        .filter(|&m| cand(m) && finite(&pts[m]))
        .map(|m| (d2(&pts[m], p), m))
        .collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    all.truncate(k);
    all.into_iter().map(|x| x.1).collect()
}

type Check = (Verdict, Option<[f64; 2]>, Option<[f64; 2]>);

/// `validate` as documented.
fn validate_ref(pos: &[[f64; 2]], d: &[[f64; 2]], cfg: &ValidationConfig) -> Vec<Check> {
    let n = pos.len();
    let ok = |i: usize| finite(&pos[i]) && finite(&d[i]);
    let mut out: Vec<Check> = (0..n)
        .map(|i| {
            let v = if !ok(i) {
                Verdict::NotTested
            } else {
                match cfg.max_displacement {
                    Some(t) if d[i][0].hypot(d[i][1]) > t => Verdict::TooLarge,
                    Some(_) => Verdict::Valid,
                    None if cfg.median_test.is_none() => Verdict::Valid,
                    None => Verdict::NotTested,
                }
            };
            (v, None, None)
        })
        .collect();
    let k = cfg
        .median_test
        .map_or(MedianTest::default().neighbours, |m| m.neighbours);
    let eligible: Vec<bool> = (0..n)
        .map(|i| ok(i) && out[i].0 != Verdict::TooLarge)
        .collect();
    for i in 0..n {
        if !ok(i) {
            continue;
        }
        let nb = nearest_k(pos, |m| m != i && eligible[m], &pos[i], k);
        if nb.len() < 3 {
            continue;
        }
        let mut bx: Vec<f64> = nb.iter().map(|&q| d[q][0]).collect();
        let mut by: Vec<f64> = nb.iter().map(|&q| d[q][1]).collect();
        let (mx, my) = (median(&mut bx), median(&mut by));
        out[i].2 = Some([mx, my]);
        let Some(m) = cfg.median_test else { continue };
        if out[i].0 == Verdict::TooLarge {
            continue;
        }
        let mut ax: Vec<f64> = nb.iter().map(|&q| (d[q][0] - mx).abs()).collect();
        let mut ay: Vec<f64> = nb.iter().map(|&q| (d[q][1] - my).abs()).collect();
        let rx = (d[i][0] - mx).abs() / (median(&mut ax) + m.epsilon);
        let ry = (d[i][1] - my).abs() / (median(&mut ay) + m.epsilon);
        out[i].1 = Some([rx, ry]);
        out[i].0 = if rx > m.threshold || ry > m.threshold {
            Verdict::MedianTest
        } else {
            Verdict::Valid
        };
    }
    out
}

/// One mutual-nearest-neighbour pass among the allowed points (brute force).
fn mutual_ref(
    r: &[[f64; 2]],
    g: &[[f64; 2]],
    ur: &[bool],
    ug: &[bool],
    pred: &[[f64; 2]],
    radius: f64,
) -> Vec<Option<usize>> {
    let p: Vec<[f64; 2]> = (0..r.len())
        .map(|i| [r[i][0] + pred[i][0], r[i][1] + pred[i][1]])
        .collect();
    (0..r.len())
        .map(|i| {
            if !ur[i] || !finite(&p[i]) {
                return None;
            }
            let j = *nearest_k(g, |j| ug[j], &p[i], 1).first()?;
            let back = *nearest_k(&p, |m| ur[m], &g[j], 1).first()?;
            (d2(&g[j], &p[i]) <= radius * radius && back == i).then_some(j)
        })
        .collect()
}

/// The iterated matcher of `match_points` as documented, over the allowed points.
fn iterate_ref(
    r: &[[f64; 2]],
    g: &[[f64; 2]],
    ur: &[bool],
    ug: &[bool],
    cfg: &NearestConfig,
) -> (Vec<Option<usize>>, usize) {
    let init = cfg.initial_displacement.unwrap_or([0.0, 0.0]);
    let mut partner = mutual_ref(r, g, ur, ug, &vec![init; r.len()], cfg.radius);
    let mut passes = 1;
    for _ in 0..cfg.iterations {
        if partner.iter().all(Option::is_none) {
            break;
        }
        let pred: Vec<[f64; 2]> = (0..r.len())
            .map(|i| {
                if !ur[i] {
                    return init;
                }
                let nb = nearest_k(r, |m| partner[m].is_some(), &r[i], cfg.predictor_neighbours);
                if nb.is_empty() {
                    return init;
                }
                let mut bx: Vec<f64> = nb
                    .iter()
                    .map(|&m| g[partner[m].unwrap()][0] - r[m][0])
                    .collect();
                let mut by: Vec<f64> = nb
                    .iter()
                    .map(|&m| g[partner[m].unwrap()][1] - r[m][1])
                    .collect();
                [median(&mut bx), median(&mut by)]
            })
            .collect();
        let next = mutual_ref(r, g, ur, ug, &pred, cfg.radius);
        passes += 1;
        if next == partner {
            break;
        }
        partner = next;
    }
    (partner, passes)
}

fn usable(d: &DotFit) -> bool {
    d.status.is_ok() && d.params.x0.is_finite() && d.params.y0.is_finite()
}

fn pos(d: &DotFit) -> [f64; 2] {
    [d.params.x0, d.params.y0]
}

fn finish(pairs: Vec<Pair>, n_ref: usize, n_grad: usize, passes: usize) -> Matches {
    let mut pairs = pairs;
    pairs.sort_by_key(|p| p.reference);
    let rt: Vec<usize> = pairs.iter().map(|p| p.reference).collect();
    let gt: Vec<usize> = pairs.iter().map(|p| p.gradient).collect();
    Matches {
        unmatched_reference: (0..n_ref).filter(|i| !rt.contains(i)).collect(),
        unmatched_gradient: (0..n_grad).filter(|j| !gt.contains(j)).collect(),
        pairs,
        passes,
    }
}

/// `match_dots` as documented ([`MatchMode`]).
fn match_dots_ref(reference: &[DotFit], gradient: &[DotFit], cfg: &MatchConfig) -> Matches {
    let (nr, ng) = (reference.len(), gradient.len());
    let r: Vec<[f64; 2]> = reference.iter().map(pos).collect();
    let g: Vec<[f64; 2]> = gradient.iter().map(pos).collect();
    let ur: Vec<bool> = reference.iter().map(usable).collect();
    let ug: Vec<bool> = gradient.iter().map(usable).collect();
    let nc = &cfg.nearest;
    let init = nc.initial_displacement.unwrap_or([0.0, 0.0]);
    if let MatchMode::Nearest { compare_indices } = cfg.mode {
        let (partner, passes) = iterate_ref(&r, &g, &ur, &ug, nc);
        let pairs = (0..nr)
            .filter_map(|i| {
                let j = partner[i]?;
                let mismatch = compare_indices && reference[i].index != gradient[j].index;
                Some(Pair {
                    reference: i,
                    gradient: j,
                    by: MatchedBy::Nearest,
                    flags: if mismatch {
                        DotFlags::GRID_MISMATCH
                    } else {
                        DotFlags::NONE
                    },
                })
            })
            .collect();
        return finish(pairs, nr, ng, passes);
    }
    let mut first: HashMap<GridIndex, usize> = HashMap::new();
    for (i, d) in reference.iter().enumerate() {
        first.entry(d.index).or_insert(i);
    }
    let mut partner: Vec<Option<usize>> = vec![None; nr];
    let mut taken = vec![false; ng];
    for (j, d) in gradient.iter().enumerate() {
        if let Some(&i) = first.get(&d.index)
            && partner[i].is_none()
        {
            partner[i] = Some(j);
            taken[j] = true;
        }
    }
    let paired: Vec<Option<usize>> = (0..nr)
        .map(|i| partner[i].filter(|&j| ur[i] && ug[j]))
        .collect();
    let need = nc.predictor_neighbours.div_ceil(2).max(1);
    let predict = |i: usize, excluded: &[bool]| -> [f64; 2] {
        let (a, b) = (reference[i].index.i, reference[i].index.j);
        let (mut bx, mut by) = (Vec::new(), Vec::new());
        for w in 1..=3i32 {
            for da in -w..=w {
                for db in -w..=w {
                    if da.abs().max(db.abs()) != w {
                        continue;
                    }
                    let Some(&m) = first.get(&GridIndex::new(a + da, b + db)) else {
                        continue;
                    };
                    if m != i
                        && !excluded[m]
                        && let Some(j) = paired[m]
                    {
                        bx.push(g[j][0] - r[m][0]);
                        by.push(g[j][1] - r[m][1]);
                    }
                }
            }
            if bx.len() >= need {
                break;
            }
        }
        if bx.is_empty() {
            init
        } else {
            [median(&mut bx), median(&mut by)]
        }
    };
    let mut flagged = vec![false; nr];
    let mut passes = 0;
    if paired.iter().any(Option::is_some) {
        loop {
            let pred: Vec<[f64; 2]> = (0..nr)
                .map(|i| if ur[i] { predict(i, &flagged) } else { init })
                .collect();
            let kd = mutual_ref(&r, &g, &ur, &ug, &pred, nc.radius);
            let mut inv = vec![None; ng];
            for (i, k) in kd.iter().enumerate() {
                if let Some(k) = k {
                    inv[*k] = Some(i);
                }
            }
            let next: Vec<bool> = (0..nr)
                .map(|i| {
                    paired[i].is_some_and(|j| {
                        kd[i].is_some_and(|k| k != j) || inv[j].is_some_and(|m| m != i)
                    })
                })
                .collect();
            passes += 1;
            let settled = next == flagged;
            flagged = next;
            if settled || passes > nc.iterations {
                break;
            }
        }
    }
    let mut pairs: Vec<Pair> = (0..nr)
        .filter_map(|i| {
            let j = partner[i]?;
            Some(Pair {
                reference: i,
                gradient: j,
                by: MatchedBy::GridIndex,
                flags: if flagged[i] {
                    DotFlags::GRID_MISMATCH
                } else {
                    DotFlags::NONE
                },
            })
        })
        .collect();
    let lr: Vec<bool> = (0..nr).map(|i| ur[i] && partner[i].is_none()).collect();
    let lg: Vec<bool> = (0..ng).map(|j| ug[j] && !taken[j]).collect();
    if lr.contains(&true) && lg.contains(&true) {
        let trusted = (0..nr).any(|i| paired[i].is_some() && !flagged[i]);
        let fb = if trusted {
            let pred: Vec<[f64; 2]> = (0..nr)
                .map(|i| if lr[i] { predict(i, &flagged) } else { init })
                .collect();
            mutual_ref(&r, &g, &lr, &lg, &pred, nc.radius)
        } else {
            iterate_ref(&r, &g, &lr, &lg, nc).0
        };
        for (i, k) in fb.iter().enumerate() {
            let Some(j) = *k else { continue };
            let gi = gradient[j].index;
            let mismatch = gi != reference[i].index && first.contains_key(&gi);
            pairs.push(Pair {
                reference: i,
                gradient: j,
                by: MatchedBy::Nearest,
                flags: if mismatch {
                    DotFlags::GRID_MISMATCH
                } else {
                    DotFlags::NONE
                },
            });
        }
    }
    finish(pairs, nr, ng, passes)
}

// ---------------------------------------------------------------- test data

fn lattice(side: usize, s: f64, jitter: f64, rng: &mut StdRng) -> Vec<[f64; 2]> {
    (0..side * side)
        .map(|k| {
            let mut j = || {
                if jitter > 0.0 {
                    rng.random_range(-jitter..jitter)
                } else {
                    0.0
                }
            };
            [s * (k % side) as f64 + j(), s * (k / side) as f64 + j()]
        })
        .collect()
}

/// Displacement fields (spacing `s`): a Gaussian bump of 0.6 s, a uniform 0.7 s shift, a
/// small rotation, a uniform 0.3 s shift.
fn field(kind: usize, p: [f64; 2], s: f64) -> [f64; 2] {
    match kind % 4 {
        0 => {
            let e = (-((p[0] - 120.0).powi(2) + (p[1] - 110.0).powi(2)) / (2.0 * 900.0)).exp();
            [0.6 * s * e * 0.8, -0.6 * s * e * 0.6]
        }
        1 => [0.7 * s, 0.1],
        2 => [0.004 * (p[1] - 100.0), -0.004 * (p[0] - 100.0)],
        _ => [0.3 * s, -0.2 * s],
    }
}

/// Reference and gradient records with the usual troubles: failed fits on both sides, dropped
/// and spurious gradient dots, unknown and duplicated indices, a swapped pair and a 3 x 3
/// patch indexed one column over.
fn scene(seed: u64) -> (Vec<DotFit>, Vec<DotFit>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let (side, s) = (26usize, 8.0);
    let r = lattice(side, s, [0.0, 0.5, 1.0][seed as usize % 3], &mut rng);
    let nz = Normal::new(0.0, 0.03).unwrap();
    let reference: Vec<DotFit> = r
        .iter()
        .enumerate()
        .map(|(k, &p)| dot(GridIndex::new((k % side) as i32, (k / side) as i32), p))
        .collect();
    let mut gradient: Vec<DotFit> = Vec::new();
    for (k, &p) in r.iter().enumerate() {
        if rng.random_range(0.0..1.0) < 0.03 {
            continue; // not found
        }
        let d = field(seed as usize, p, s);
        let q = [
            p[0] + d[0] + nz.sample(&mut rng),
            p[1] + d[1] + nz.sample(&mut rng),
        ];
        gradient.push(dot(reference[k].index, q));
    }
    // failed fits
    let mut reference = reference;
    for _ in 0..8 {
        let k = rng.random_range(0..reference.len());
        reference[k].status = FitStatus::Singular;
        let k = rng.random_range(0..gradient.len());
        gradient[k].status = FitStatus::LeftWindow;
        gradient[k].params.x0 = f64::NAN;
    }
    // unknown indices and spurious dots
    for t in 0..6 {
        let k = rng.random_range(0..gradient.len());
        gradient[k].index = GridIndex::new(500 + t, -7);
        let q = [rng.random_range(0.0..200.0), rng.random_range(0.0..200.0)];
        gradient.push(dot(GridIndex::new(-40 - t, 900), q));
    }
    // a duplicated reference index
    reference[40].index = reference[41].index;
    // a swapped pair and a patch one column over
    let at = |g: &[DotFit], i: i32, j: i32| g.iter().position(|d| d.index == GridIndex::new(i, j));
    if let (Some(a), Some(b)) = (at(&gradient, 5, 5), at(&gradient, 6, 5)) {
        gradient.swap(a, b);
        let t = gradient[a].index;
        gradient[a].index = gradient[b].index;
        gradient[b].index = t;
    }
    for d in gradient.iter_mut() {
        if (14..17).contains(&d.index.i) && (12..15).contains(&d.index.j) {
            d.index.i += 1;
        }
    }
    (reference, gradient)
}

// ---------------------------------------------------------------- tests

#[test]
fn match_dots_agrees_with_the_straightforward_version() {
    let configs = |s: f64| {
        let d = MatchConfig::for_spacing(s);
        vec![
            d,
            MatchConfig {
                nearest: NearestConfig {
                    iterations: 0,
                    predictor_neighbours: 3,
                    ..d.nearest
                },
                ..d
            },
            MatchConfig {
                nearest: NearestConfig {
                    radius: 0.3 * s,
                    predictor_neighbours: 20,
                    initial_displacement: Some([1.0, -0.5]),
                    ..d.nearest
                },
                ..d
            },
            MatchConfig {
                mode: MatchMode::Nearest {
                    compare_indices: true,
                },
                ..d
            },
        ]
    };
    let mut flagged = 0;
    for seed in 0..8 {
        let (reference, gradient) = scene(seed);
        for cfg in configs(8.0) {
            let got = match_dots(&reference, &gradient, &cfg).unwrap();
            let want = match_dots_ref(&reference, &gradient, &cfg);
            assert_eq!(got, want, "seed {seed}, {cfg:?}");
            flagged += got.grid_mismatches();
        }
        // reference records with no index information at all (hash-map lookup path)
        let mut sparse = reference.clone();
        for (k, d) in sparse.iter_mut().enumerate() {
            d.index = GridIndex::new(d.index.i * 1000, d.index.j * 1000 + (k % 2) as i32);
        }
        let cfg = MatchConfig::for_spacing(8.0);
        assert_eq!(
            match_dots(&sparse, &gradient, &cfg).unwrap(),
            match_dots_ref(&sparse, &gradient, &cfg),
            "seed {seed}, sparse indices"
        );
    }
    // the scenes do contain index errors for the check to find
    assert!(flagged > 50, "{flagged}");
}

#[test]
fn match_points_agrees_with_the_straightforward_version() {
    for seed in 0..6 {
        let mut rng = StdRng::seed_from_u64(100 + seed);
        let s = 8.0;
        let r = lattice(24, s, [0.0, 0.5, 2.0][seed as usize % 3], &mut rng);
        let mut g: Vec<[f64; 2]> = r
            .iter()
            .map(|&p| {
                let d = field(seed as usize + 2, p, s);
                [
                    p[0] + d[0],
                    p[1] + d[1] + 0.01 * rng.random_range(-1.0..1.0),
                ]
            })
            .collect();
        g.truncate(g.len() - 11);
        g.push([f64::NAN, 3.0]);
        g.push([50.0, 51.0]);
        let mut r = r;
        r[7] = [f64::INFINITY, 0.0];
        for cfg in [
            NearestConfig::for_spacing(s),
            NearestConfig {
                iterations: 0,
                ..NearestConfig::for_spacing(s)
            },
            NearestConfig {
                predictor_neighbours: 1,
                initial_displacement: Some([0.5 * s, 0.0]),
                ..NearestConfig::for_spacing(s)
            },
        ] {
            let m = match_points(&r, &g, &cfg).unwrap();
            let (partner, passes) =
                iterate_ref(&r, &g, &vec![true; r.len()], &vec![true; g.len()], &cfg);
            let want: Vec<(usize, usize)> = partner
                .iter()
                .enumerate()
                .filter_map(|(i, p)| p.map(|j| (i, j)))
                .collect();
            assert_eq!((m.pairs, m.passes), (want, passes), "seed {seed} {cfg:?}");
        }
    }
}

#[test]
fn validate_agrees_with_the_straightforward_version() {
    let same = |a: f64, b: f64| a == b || (a.is_nan() && b.is_nan());
    let same2 = |a: Option<[f64; 2]>, b: Option<[f64; 2]>| match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => same(a[0], b[0]) && same(a[1], b[1]),
        _ => false,
    };
    for seed in 0..8 {
        let mut rng = StdRng::seed_from_u64(200 + seed);
        let n_side = 30;
        let pos: Vec<[f64; 2]> = match seed % 3 {
            0 => lattice(n_side, 8.0, 1.0, &mut rng),
            // exact lattice: ties in distance everywhere
            1 => lattice(n_side, 8.0, 0.0, &mut rng),
            _ => (0..n_side * n_side)
                .map(|_| [rng.random_range(0.0..240.0), rng.random_range(0.0..240.0)])
                .collect(),
        };
        let nz = Normal::new(0.0, 0.05).unwrap();
        let mut d: Vec<[f64; 2]> = pos
            .iter()
            .map(|p| {
                let mut v = [
                    0.003 * p[1] + nz.sample(&mut rng),
                    -0.2 + nz.sample(&mut rng),
                ];
                if rng.random_range(0.0..1.0) < 0.03 {
                    v[0] += rng.random_range(-4.0..4.0);
                }
                v
            })
            .collect();
        d[3] = [f64::NAN, 0.0];
        let mut pos = pos;
        pos[9] = [1.0, f64::INFINITY];
        for cfg in [
            ValidationConfig::default(),
            ValidationConfig {
                max_displacement: Some(2.0),
                replace: true,
                ..ValidationConfig::default()
            },
            ValidationConfig {
                median_test: Some(MedianTest {
                    neighbours: 5,
                    threshold: 1.5,
                    epsilon: 0.0,
                }),
                ..ValidationConfig::default()
            },
            ValidationConfig {
                median_test: Some(MedianTest {
                    neighbours: 30,
                    ..MedianTest::default()
                }),
                ..ValidationConfig::default()
            },
            ValidationConfig {
                median_test: None,
                max_displacement: Some(1.0),
                replace: true,
            },
        ] {
            let v = validate(&pos, &d, &cfg).unwrap();
            let want = validate_ref(&pos, &d, &cfg);
            for (i, (c, w)) in v.checks.iter().zip(&want).enumerate() {
                assert!(
                    c.verdict == w.0 && same2(c.residual, w.1) && same2(c.neighbour_median, w.2),
                    "seed {seed} vector {i}: {c:?} vs {w:?} ({cfg:?})"
                );
            }
            if let Some(rep) = v.replaced {
                for (i, x) in rep.iter().enumerate() {
                    let want = match want[i] {
                        (Verdict::TooLarge | Verdict::MedianTest, _, Some(m)) => m,
                        _ => d[i],
                    };
                    assert!(
                        same(x[0], want[0]) && same(x[1], want[1]),
                        "seed {seed} {i}"
                    );
                }
            }
        }
    }
}
