//! Stack statistics on synthetic point sets with known per-dot scatter.

use bostrack_core::{DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex};
use bostrack_uncertainty::{
    CommonMode, StackConfig, StackError, StackStatus, reference_stack, stack_scatter,
};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

/// c4(K) = E[s]/σ for normal samples = sqrt(2/(K-1)) r(K), r(K) = Γ(K/2)/Γ((K-1)/2), with
/// r(2) = 1/sqrt(π) and r(K+1) = ((K-1)/2) / r(K).
fn c4(k: usize) -> f64 {
    let mut r = 1.0 / std::f64::consts::PI.sqrt();
    for kk in 2..k {
        r = (kk as f64 - 1.0) / 2.0 / r;
    }
    (2.0 / (k as f64 - 1.0)).sqrt() * r
}

#[test]
fn c4_known_values() {
    // c4(2) = sqrt(2/π) = 0.7979, c4(10) = 0.9727 (tables of control-chart constants)
    assert!((c4(2) - 0.797_885).abs() < 1e-6);
    assert!((c4(10) - 0.972_659).abs() < 1e-6);
}

/// A synthetic stack: `n` dots on a lattice, dot i with its own true scatter
/// (σx_i, σy_i) ∈ [0.01, 0.06] px, image k moved by a common shift ~ N(0, shift_std) px.
/// `keep(k, i)` = false removes a sample. Returns the samples, the true sigmas and shifts.
struct Synthetic {
    samples: Vec<Vec<Option<[f64; 2]>>>,
    sigma: Vec<[f64; 2]>,
    shifts: Vec<[f64; 2]>,
}

fn synthetic(
    n: usize,
    k: usize,
    shift_std: f64,
    seed: u64,
    keep: impl Fn(usize, usize, &mut StdRng) -> bool,
) -> Synthetic {
    let mut rng = StdRng::seed_from_u64(seed);
    let unit = Normal::new(0.0, 1.0).unwrap();
    let sigma: Vec<[f64; 2]> = (0..n)
        .map(|_| [rng.random_range(0.01..0.06), rng.random_range(0.01..0.06)])
        .collect();
    let truth: Vec<[f64; 2]> = (0..n)
        .map(|i| [8.0 * (i % 100) as f64 + 3.0, 8.0 * (i / 100) as f64 + 3.0])
        .collect();
    let shifts: Vec<[f64; 2]> = (0..k)
        .map(|_| {
            [
                shift_std * unit.sample(&mut rng),
                shift_std * unit.sample(&mut rng),
            ]
        })
        .collect();
    let samples = (0..k)
        .map(|kk| {
            (0..n)
                .map(|i| {
                    let p = [
                        truth[i][0] + shifts[kk][0] + sigma[i][0] * unit.sample(&mut rng),
                        truth[i][1] + shifts[kk][1] + sigma[i][1] * unit.sample(&mut rng),
                    ];
                    keep(kk, i, &mut rng).then_some(p)
                })
                .collect()
        })
        .collect();
    Synthetic {
        samples,
        sigma,
        shifts,
    }
}

/// (mean of u/σ, mean of u²/σ², std of u/σ) over both axes of the dots with `images == k`.
fn ensemble(
    s: &bostrack_uncertainty::Scatter,
    sigma: &[[f64; 2]],
    k: usize,
) -> (f64, f64, f64, usize) {
    let mut q = Vec::new();
    for (d, t) in s.dots.iter().zip(sigma) {
        if d.images == k {
            let u = d.u.unwrap();
            q.push(u[0] / t[0]);
            q.push(u[1] / t[1]);
        }
    }
    let n = q.len() as f64;
    let m = q.iter().sum::<f64>() / n;
    let m2 = q.iter().map(|v| v * v).sum::<f64>() / n;
    let sd = (q.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    (m, m2, sd, q.len())
}

#[test]
fn recovers_per_dot_scatter_under_common_mode_motion() {
    let (n, k) = (5000, 10);
    let syn = synthetic(n, k, 0.5, 1, |_, _, _| true);
    let s = stack_scatter(&syn.samples, &StackConfig::default()).unwrap();
    let (m, m2, sd, cnt) = ensemble(&s, &syn.sigma, k);
    // statistical error of the ensemble means over `cnt` independent ratios
    let se_m2 = (2.0 / (k as f64 - 1.0)).sqrt() / (cnt as f64).sqrt();
    let rse = 1.0 / (2.0 * (k as f64 - 1.0)).sqrt();
    println!(
        "K={k}, {cnt} ratios: mean u/σ {m:.4} (c4 {:.4}), mean u²/σ² {m2:.4} (± {se_m2:.4}), std u/σ {sd:.4} (1/sqrt(2(K-1)) = {rse:.4}, exact sqrt(1-c4²) = {:.4})",
        c4(k),
        (1.0 - c4(k).powi(2)).sqrt()
    );
    assert!((m2 - 1.0).abs() < 4.0 * se_m2, "mean u²/σ² = {m2}");
    assert!((m / c4(k) - 1.0).abs() < 0.01, "mean u/σ = {m}");
    assert!((sd / rse - 1.0).abs() < 0.05, "std u/σ = {sd}");
    assert!(
        s.dots
            .iter()
            .all(|d| d.relative_standard_error == Some(rse))
    );
    // the shifts are found up to the gauge (zero mean over the images)
    let mean_true = [
        syn.shifts.iter().map(|s| s[0]).sum::<f64>() / k as f64,
        syn.shifts.iter().map(|s| s[1]).sum::<f64>() / k as f64,
    ];
    for (got, t) in s.shifts.iter().zip(&syn.shifts) {
        assert!(
            (got[0] - (t[0] - mean_true[0])).abs() < 2e-3,
            "{got:?} vs {t:?}"
        );
        assert!((got[1] - (t[1] - mean_true[1])).abs() < 2e-3);
    }
    // the mean position is the true position + mean shift, within σ/sqrt(K)
    let d = &s.dots[1234];
    let mean = d.mean.unwrap();
    let truth = [
        8.0 * 34.0 + 3.0 + mean_true[0],
        8.0 * 12.0 + 3.0 + mean_true[1],
    ];
    assert!((mean[0] - truth[0]).abs() < 5.0 * syn.sigma[1234][0] / (k as f64).sqrt());
    assert!((mean[1] - truth[1]).abs() < 5.0 * syn.sigma[1234][1] / (k as f64).sqrt());
}

#[test]
fn common_mode_removal_on_and_off() {
    let (n, k) = (2000, 10);
    // with motion and removal off, the motion (0.5 px) swamps the 0.01-0.06 px scatter
    let syn = synthetic(n, k, 0.5, 2, |_, _, _| true);
    let keep = StackConfig {
        common_mode: CommonMode::Keep,
        ..StackConfig::default()
    };
    let s = stack_scatter(&syn.samples, &keep).unwrap();
    let (m, _, _, _) = ensemble(&s, &syn.sigma, k);
    println!("motion kept: mean u/σ {m:.2}");
    assert!(m > 5.0);
    assert!(s.shifts.iter().all(|v| *v == [0.0, 0.0]));
    // without motion, removal costs nothing measurable and keeping gives the same answer
    let syn = synthetic(n, k, 0.0, 3, |_, _, _| true);
    let on = stack_scatter(&syn.samples, &StackConfig::default()).unwrap();
    let off = stack_scatter(&syn.samples, &keep).unwrap();
    let (m_on, m2_on, _, cnt) = ensemble(&on, &syn.sigma, k);
    let (m_off, _, _, _) = ensemble(&off, &syn.sigma, k);
    println!("no motion: mean u/σ removal on {m_on:.4}, off {m_off:.4}");
    let se_m2 = (2.0 / (k as f64 - 1.0)).sqrt() / (cnt as f64).sqrt();
    assert!((m2_on - 1.0).abs() < 4.0 * se_m2);
    assert!((m_on / m_off - 1.0).abs() < 0.005);
}

#[test]
fn missing_samples_vary_k_per_dot() {
    let (n, k) = (6000, 10);
    // each sample missing with probability 0.25; dots 0..50 seen in images 0 and 1 only
    let syn = synthetic(n, k, 0.3, 4, |kk, i, rng| {
        if i < 50 {
            kk < 2
        } else {
            rng.random_range(0.0..1.0) > 0.25
        }
    });
    let s = stack_scatter(&syn.samples, &StackConfig::default()).unwrap();
    for d in &s.dots[..50] {
        assert_eq!(d.images, 2);
        assert_eq!(d.status, StackStatus::TooFewImages);
        assert!(d.u.is_none() && d.relative_standard_error.is_none() && d.mean.is_some());
    }
    for kk in 5..=9 {
        let (m, m2, sd, cnt) = ensemble(&s, &syn.sigma, kk);
        let rse = 1.0 / (2.0 * (kk as f64 - 1.0)).sqrt();
        let exact = (1.0 - c4(kk).powi(2)).sqrt();
        let se_m2 = (2.0 / (kk as f64 - 1.0)).sqrt() / (cnt as f64).sqrt();
        println!(
            "K={kk}: {cnt} ratios, mean u/σ {m:.4} (c4 {:.4}), mean u²/σ² {m2:.4} ± {se_m2:.4}, std u/σ {sd:.4} (1/sqrt(2(K-1)) {rse:.4}, exact {exact:.4})",
            c4(kk)
        );
        assert!((m2 - 1.0).abs() < 4.0 * se_m2, "K={kk}: mean u²/σ² = {m2}");
        // the spread follows the exact small-sample value; the reported 1/sqrt(2(K-1)) is its
        // large-K form (within 5 % of it from K = 5)
        let se_sd = exact / (2.0 * cnt as f64).sqrt();
        assert!(
            (sd - exact).abs() < 5.0 * se_sd + 0.01,
            "K={kk}: std u/σ = {sd}"
        );
        assert!((rse / exact - 1.0).abs() < 0.05);
    }
}

fn dot(i: i32, j: i32, x: f64, y: f64, status: FitStatus) -> DotFit {
    DotFit {
        index: GridIndex::new(i, j),
        params: Gaussian2D::circular(x, y, 1000.0, 1.5, 100.0),
        crlb_x: 0.01,
        crlb_y: 0.01,
        rms: 1.0,
        iterations: 4,
        status,
        flags: DotFlags::NONE,
    }
}

#[test]
fn reference_stack_matches_by_grid_index() {
    let reference = vec![
        dot(0, 0, 10.0, 10.0, FitStatus::Converged),
        dot(1, 0, 18.0, 10.0, FitStatus::Converged),
        dot(2, 0, 26.0, 10.0, FitStatus::Converged),
    ];
    // four images, listed in a different order each time; dot (2,0) fails in two images, an
    // unknown index and a repeated index appear
    let jitter = [[0.01, -0.02], [-0.01, 0.0], [0.02, 0.01], [-0.02, 0.01]];
    let stack: Vec<Vec<DotFit>> = (0..4)
        .map(|k| {
            let [jx, jy] = jitter[k];
            let mut img = vec![
                dot(
                    2,
                    0,
                    26.0 - jx,
                    10.0 + jy,
                    if k < 2 {
                        FitStatus::Singular
                    } else {
                        FitStatus::Converged
                    },
                ),
                dot(0, 0, 10.0 + jx, 10.0 + jy, FitStatus::Converged),
                dot(1, 0, 18.0 + jy, 10.0 - jx, FitStatus::IterationLimit),
                dot(9, 9, 99.0, 99.0, FitStatus::Converged),
            ];
            if k == 3 {
                img.push(dot(0, 0, 500.0, 500.0, FitStatus::Converged)); // repeated: ignored
            }
            img
        })
        .collect();
    let cfg = StackConfig {
        common_mode: CommonMode::Keep,
        ..StackConfig::default()
    };
    let r = reference_stack(&reference, &stack, &cfg).unwrap();
    assert_eq!(r.unknown, vec![1, 1, 1, 2]);
    let by = r.by_index();
    let d0 = by[&GridIndex::new(0, 0)];
    assert_eq!(d0.images, 4);
    // sample std of the x jitter by hand
    let xs = [0.01, -0.01, 0.02, -0.02];
    let mx = xs.iter().sum::<f64>() / 4.0;
    let sx = (xs.iter().map(|v| (v - mx).powi(2)).sum::<f64>() / 3.0).sqrt();
    assert!((d0.u.unwrap()[0] - sx).abs() < 1e-12);
    assert!((d0.mean.unwrap()[0] - (10.0 + mx)).abs() < 1e-12);
    assert_eq!(by[&GridIndex::new(1, 0)].images, 4);
    let d2 = by[&GridIndex::new(2, 0)];
    assert_eq!((d2.images, d2.status), (2, StackStatus::TooFewImages));
    // empty stack: every dot K = 0
    let none: Vec<Vec<DotFit>> = Vec::new();
    let r = reference_stack(&reference, &none, &StackConfig::default()).unwrap();
    assert!(
        r.dots
            .iter()
            .all(|d| d.scatter.images == 0 && d.scatter.mean.is_none())
    );
}

#[test]
fn bad_arguments_are_errors() {
    let s = vec![vec![Some([0.0, 0.0])], vec![]];
    assert!(matches!(
        stack_scatter(&s, &StackConfig::default()),
        Err(StackError::Shape {
            image: 1,
            len: 0,
            expected: 1
        })
    ));
    let cfg = StackConfig {
        min_images: 1,
        ..StackConfig::default()
    };
    assert!(matches!(
        stack_scatter(&[], &cfg),
        Err(StackError::Config(_))
    ));
    let cfg = StackConfig {
        common_mode: CommonMode::Remove { passes: 0 },
        ..StackConfig::default()
    };
    assert!(stack_scatter(&[], &cfg).is_err());
    // non-finite samples count as absent
    let s = vec![
        vec![Some([f64::NAN, 0.0])],
        vec![Some([1.0, 0.0])],
        vec![Some([1.1, 0.0])],
    ];
    let r = stack_scatter(&s, &StackConfig::default()).unwrap();
    assert_eq!(r.dots[0].images, 2);
}
