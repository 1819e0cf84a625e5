//! The normalised median test on synthetic displacement fields with injected outliers.

use bostrack_match::{MedianTest, ValidationConfig, Verdict, validate};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

#[derive(Clone, Copy, Debug)]
enum Points {
    /// Square lattice of spacing 8 px, jittered ±1 px.
    Lattice,
    /// Uniformly random points at the same density.
    Random,
}

#[derive(Clone, Copy, Debug)]
enum Field {
    /// Lamb-Oseen-like vortex: |d| peaks at 3 px at r = 120 px.
    Vortex,
    /// Linear field with gradients of 0.005 px/px.
    Linear,
}

fn field(f: Field, p: [f64; 2]) -> [f64; 2] {
    match f {
        Field::Vortex => {
            let (x, y) = (p[0] - 400.0, p[1] - 400.0);
            let r2 = x * x + y * y;
            let rc2 = 120.0f64 * 120.0 / 1.2564;
            // v_theta ∝ (1 - exp(-r²/rc²)) / r, normalised to a 3 px maximum
            let vt = if r2 < 1e-12 {
                0.0
            } else {
                (1.0 - (-r2 / rc2).exp()) / r2.sqrt()
            };
            let s = 3.0 / (0.638_2 / rc2.sqrt());
            [
                -s * vt * y / r2.sqrt().max(1e-12),
                s * vt * x / r2.sqrt().max(1e-12),
            ]
        }
        Field::Linear => [
            0.4 + 0.005 * p[0] - 0.002 * p[1],
            -0.2 + 0.003 * p[0] + 0.005 * p[1],
        ],
    }
}

struct Outcome {
    /// outliers with |error| >= 0.5 px, and how many were flagged
    big: usize,
    big_caught: usize,
    /// smaller outliers (0.1-0.5 px), flagged
    small: usize,
    small_caught: usize,
    /// clean vectors, falsely flagged
    clean: usize,
    false_pos: usize,
}

/// 10,000 vectors with displacement noise `noise` (px, per component), 2 % outliers: a random
/// direction and a size uniform in 0.1-0.5 px (a quarter of them) or 0.5-5 px.
fn run(points: Points, f: Field, noise: f64, cfg: &ValidationConfig, seed: u64) -> Outcome {
    let mut rng = StdRng::seed_from_u64(seed);
    let n_side = 100;
    let pos: Vec<[f64; 2]> = (0..n_side * n_side)
        .map(|k| match points {
            Points::Lattice => [
                8.0 * (k % n_side) as f64 + rng.random_range(-1.0..1.0),
                8.0 * (k / n_side) as f64 + rng.random_range(-1.0..1.0),
            ],
            Points::Random => [rng.random_range(0.0..800.0), rng.random_range(0.0..800.0)],
        })
        .collect();
    let nz = Normal::new(0.0, noise).unwrap();
    let mut size = vec![0.0; pos.len()];
    let d: Vec<[f64; 2]> = pos
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            let mut v = field(f, p);
            v[0] += nz.sample(&mut rng);
            v[1] += nz.sample(&mut rng);
            if rng.random_range(0.0..1.0) < 0.02 {
                let a = rng.random_range(0.0..std::f64::consts::TAU);
                let s = if rng.random_range(0.0..1.0) < 0.25 {
                    rng.random_range(0.1..0.5)
                } else {
                    rng.random_range(0.5..5.0)
                };
                v[0] += s * a.cos();
                v[1] += s * a.sin();
                size[i] = s;
            }
            v
        })
        .collect();
    let v = validate(&pos, &d, cfg).unwrap();
    let mut o = Outcome {
        big: 0,
        big_caught: 0,
        small: 0,
        small_caught: 0,
        clean: 0,
        false_pos: 0,
    };
    for (i, c) in v.checks.iter().enumerate() {
        let flagged = c.is_outlier();
        if size[i] >= 0.5 {
            o.big += 1;
            o.big_caught += flagged as usize;
        } else if size[i] > 0.0 {
            o.small += 1;
            o.small_caught += flagged as usize;
        } else {
            o.clean += 1;
            o.false_pos += flagged as usize;
        }
    }
    o
}

/// ≥ 99 % of outliers of 0.5 px and more flagged, ≤ 0.5 % of clean vectors flagged, on
/// lattices and random point sets, vortex and linear fields, displacement noise 0.02-0.05 px
/// (fits at the CRLB give 0.01-0.03 px per position; the displacement adds two).
#[test]
fn catches_outliers_and_leaves_clean_vectors() {
    let cfg = ValidationConfig::default();
    let (mut big, mut caught, mut clean, mut fp) = (0, 0, 0, 0);
    let mut seed = 100;
    for points in [Points::Lattice, Points::Random] {
        for f in [Field::Vortex, Field::Linear] {
            for noise in [0.02, 0.05] {
                seed += 1;
                let o = run(points, f, noise, &cfg, seed);
                println!(
                    "{points:?} {f:?} noise {noise}: outliers >= 0.5 px caught {}/{} ({:.2} %), 0.1-0.5 px caught {}/{}, false positives {}/{} ({:.3} %)",
                    o.big_caught,
                    o.big,
                    100.0 * o.big_caught as f64 / o.big as f64,
                    o.small_caught,
                    o.small,
                    o.false_pos,
                    o.clean,
                    100.0 * o.false_pos as f64 / o.clean as f64
                );
                assert!(o.big_caught as f64 >= 0.99 * o.big as f64);
                assert!(o.false_pos as f64 <= 0.005 * o.clean as f64);
                big += o.big;
                caught += o.big_caught;
                clean += o.clean;
                fp += o.false_pos;
            }
        }
    }
    println!(
        "all: {caught}/{big} caught ({:.2} %), {fp}/{clean} false positives ({:.3} %)",
        100.0 * caught as f64 / big as f64,
        100.0 * fp as f64 / clean as f64
    );
}

/// ε sets the noise floor: at a noise far above it, the test flags many clean vectors, which
/// is why ε is configurable (and should sit near the displacement noise).
#[test]
fn epsilon_below_the_noise_raises_false_positives() {
    let small_eps = ValidationConfig {
        median_test: Some(MedianTest {
            epsilon: 0.0,
            ..MedianTest::default()
        }),
        ..ValidationConfig::default()
    };
    let o = run(Points::Lattice, Field::Linear, 0.05, &small_eps, 7);
    let d = run(
        Points::Lattice,
        Field::Linear,
        0.05,
        &ValidationConfig::default(),
        7,
    );
    println!(
        "epsilon 0: {} false positives; epsilon 0.1: {}",
        o.false_pos, d.false_pos
    );
    assert!(o.false_pos > 5 * d.false_pos.max(1));
}

#[test]
fn threshold_replacement_and_untested_vectors() {
    // 10 x 10 lattice, uniform field (1, 0); vector 44 wild, vector 45 just large, 46 NaN
    let pos: Vec<[f64; 2]> = (0..100)
        .map(|k| [8.0 * (k % 10) as f64, 8.0 * (k / 10) as f64])
        .collect();
    let mut d = vec![[1.0, 0.0]; 100];
    d[44] = [9.0, 3.0];
    d[45] = [1.0, 1.5];
    d[46] = [f64::NAN, 0.0];
    let cfg = ValidationConfig {
        max_displacement: Some(5.0),
        replace: true,
        ..ValidationConfig::default()
    };
    let v = validate(&pos, &d, &cfg).unwrap();
    assert_eq!(v.checks[44].verdict, Verdict::TooLarge);
    assert_eq!(v.checks[45].verdict, Verdict::MedianTest);
    assert_eq!(v.checks[46].verdict, Verdict::NotTested);
    assert_eq!(v.outliers(), 2);
    let r = v.replaced.unwrap();
    assert_eq!((r[44], r[45]), ([1.0, 0.0], [1.0, 0.0]));
    assert!(r[46][0].is_nan()); // untested vectors are not touched
    assert_eq!(r[0], [1.0, 0.0]);
    // the residual is the normalised one: |1.5 - 0| / (0 + 0.1) = 15 in y
    let res = v.checks[45].residual.unwrap();
    assert!((res[1] - 15.0).abs() < 1e-12 && res[0].abs() < 1e-12);
    // no replacement unless asked
    let v = validate(&pos, &d, &ValidationConfig::default()).unwrap();
    assert!(v.replaced.is_none());
    assert_eq!(v.checks[44].verdict, Verdict::MedianTest);
    // too few neighbours: not tested; bad arguments: errors
    let v = validate(&pos[..3], &d[..3], &ValidationConfig::default()).unwrap();
    assert!(v.checks.iter().all(|c| c.verdict == Verdict::NotTested));
    assert!(validate(&pos[..3], &d[..2], &ValidationConfig::default()).is_err());
    let bad = ValidationConfig {
        median_test: Some(MedianTest {
            neighbours: 2,
            ..MedianTest::default()
        }),
        ..ValidationConfig::default()
    };
    assert!(validate(&pos, &d, &bad).is_err());
}

/// The median test with neighbour lists made once for the positions gives what it gives
/// without them, vector for vector: on an exact lattice (every distance tied four ways), a
/// jittered one and random points, with vectors that are not finite, above the threshold or
/// outliers, which the lists' neighbourhoods must skip as the spatial index does; at every
/// position, at a subset of them (a frame whose pairs miss some reference dots), and in an
/// order the lists cannot serve (searched as without them).
#[test]
fn neighbour_lists_give_the_same_validation() {
    use bostrack_match::{NeighbourLists, Validation, validate_at};
    // equal checks, and replaced vectors equal to the bit (the vectors that are not finite
    // stay NaN in both)
    let same = |a: &Validation, b: &Validation| {
        let bits = |v: &Validation| {
            v.replaced
                .as_ref()
                .map(|r| r.iter().map(|d| d.map(f64::to_bits)).collect::<Vec<_>>())
        };
        a.checks == b.checks && bits(a) == bits(b)
    };
    let mut rng = StdRng::seed_from_u64(17);
    let normal = Normal::new(0.0, 0.05).expect("a normal distribution");
    let lattice = |jitter: f64, rng: &mut StdRng| -> Vec<[f64; 2]> {
        let mut v = Vec::new();
        for j in 0..30 {
            for i in 0..30 {
                v.push([
                    8.0 * i as f64 + jitter * rng.random_range(-1.0..1.0),
                    8.0 * j as f64 + jitter * rng.random_range(-1.0..1.0),
                ]);
            }
        }
        v
    };
    let random: Vec<[f64; 2]> = (0..900)
        .map(|_| [rng.random_range(0.0..240.0), rng.random_range(0.0..240.0)])
        .collect();
    let exact = lattice(0.0, &mut rng);
    let jittered = lattice(1.0, &mut rng);
    let mut compared = 0;
    for (name, all) in [("exact", exact), ("jittered", jittered), ("random", random)] {
        for k in [3, 8, 12] {
            let lists = NeighbourLists::new(&all, k);
            for round in 0..3 {
                // every position; about 85 % of them, in order; all of them backwards
                let some: Vec<usize> = (0..all.len())
                    .filter(|_| rng.random_range(0.0..1.0) < 0.85)
                    .collect();
                let backwards: Vec<usize> = (0..all.len()).rev().collect();
                for at in [(0..all.len()).collect::<Vec<usize>>(), some, backwards] {
                    let pos: Vec<[f64; 2]> = at.iter().map(|&i| all[i]).collect();
                    let disp: Vec<[f64; 2]> = pos
                        .iter()
                        .map(|p| {
                            let d = field(Field::Vortex, *p);
                            let u: f64 = rng.random_range(0.0..1.0);
                            if u < 0.05 {
                                [f64::NAN, f64::NAN]
                            } else if u < 0.15 {
                                [d[0] + 5.0, d[1] - 4.0] // an outlier, above the threshold too
                            } else {
                                [
                                    d[0] + normal.sample(&mut rng),
                                    d[1] + normal.sample(&mut rng),
                                ]
                            }
                        })
                        .collect();
                    let cfg = ValidationConfig {
                        max_displacement: (round > 0).then_some(5.0),
                        median_test: Some(MedianTest {
                            neighbours: k,
                            ..MedianTest::default()
                        }),
                        replace: round == 2,
                    };
                    let plain = validate(&pos, &disp, &cfg).expect("valid input");
                    let listed = validate_at(&lists, &at, &disp, &cfg).expect("valid input");
                    assert!(same(&plain, &listed), "{name}, k {k}, round {round}");
                    assert!(plain.outliers() > 0, "{name}");
                    compared += 1;
                }
            }
        }
    }
    assert_eq!(compared, 81);
    // a vector at a position the lists do not have
    let lists = NeighbourLists::new(&[[0.0, 0.0], [1.0, 0.0]], 8);
    let cfg = ValidationConfig::default();
    assert!(validate_at(&lists, &[0, 2], &[[0.0, 0.0]; 2], &cfg).is_err());
}
