//! `refit_dots`: one pass from prior fits, with and without the neighbour tails rendered once.

use bostrack_core::{DotFlags, FitStatus, Gaussian2D, GridIndex, Image, NoiseModel, Seed, Window};
use bostrack_fit::{FitConfig, FitError, NeighbourTails, fit_dots, refit_dots, refit_dots_report};
use bostrack_model::{Sampling, add_dot};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;

/// A 6 x 6 lattice of dots 8 px apart (σ 1.6 px, so every window holds its neighbours' tails),
/// read noise 10 counts; returns the image, the seeds and the true centres.
fn lattice(shift: [f64; 2], seed: u64) -> (Image, Vec<Seed>, Vec<[f64; 2]>) {
    flowing(6, |_, _| shift, seed)
}

#[test]
fn refit_with_tails_equals_refit_without_and_both_find_the_dots() {
    let cfg = FitConfig::default();
    let noise = NoiseModel::read(10.0);
    let (reference, seeds, _) = lattice([0.0, 0.0], 1);
    let prior = fit_dots(&reference, None, &seeds, &cfg, &noise).unwrap();
    // a second image of the same scene, moved by 0.01 px (below TAILS_MAX_SHIFT)
    let (img, seeds2, truth) = lattice([0.01, -0.01], 2);
    let tails = NeighbourTails::new(&prior, &seeds, &cfg, img.width(), img.height());
    let plain = refit_dots(&img, None, &seeds2, &cfg, &noise, &prior, None).unwrap();
    let cached = refit_dots(&img, None, &seeds2, &cfg, &noise, &prior, Some(&tails)).unwrap();
    let full = fit_dots(&img, None, &seeds2, &cfg, &noise).unwrap();
    let mut worst: f64 = 0.0;
    for k in 0..seeds2.len() {
        let (a, b, c) = (&plain[k], &cached[k], &full[k]);
        assert_eq!(a.status, FitStatus::Converged, "{a:?}");
        assert_eq!(b.status, FitStatus::Converged, "{b:?}");
        // the same subtraction, summed in another order
        assert!((a.params.x0 - b.params.x0).abs() < 1e-9, "{a:?} {b:?}");
        assert!((a.params.y0 - b.params.y0).abs() < 1e-9, "{a:?} {b:?}");
        // one pass from another image's fits agrees with fit_dots' two passes inside the bound:
        // the neighbours are modelled by the prior's fits, with that image's noise (measured:
        // at most 0.36 of the bound here, dots 7.4-8.6 px apart at peak SNR 100). In a stack
        // that model is the same for every image, so it does not add to the scatter.
        worst = worst
            .max((a.params.x0 - c.params.x0).abs() / c.crlb_x)
            .max((a.params.y0 - c.params.y0).abs() / c.crlb_y);
        // and finds the dot (5 bounds: a generous statistical limit for 36 dots)
        assert!(
            (a.params.x0 - truth[k][0]).abs() < 5.0 * a.crlb_x,
            "{a:?} {:?}",
            truth[k]
        );
        assert!(
            (a.params.y0 - truth[k][1]).abs() < 5.0 * a.crlb_y,
            "{a:?} {:?}",
            truth[k]
        );
    }
    println!("refit vs fit_dots: worst difference {worst:.3} of the bound");
    assert!(worst < 0.5, "{worst}");
}

#[test]
fn refit_rejects_a_prior_of_another_length() {
    let (img, seeds, _) = lattice([0.0, 0.0], 3);
    let cfg = FitConfig::default();
    let noise = NoiseModel::read(10.0);
    let prior = fit_dots(&img, None, &seeds, &cfg, &noise).unwrap();
    let err = refit_dots(&img, None, &seeds, &cfg, &noise, &prior[1..], None).unwrap_err();
    assert!(matches!(err, FitError::InvalidConfig(_)), "{err}");
}

/// Largest |a − b| over the dots' positions, in units of b's bound.
fn worst_in_bounds(a: &[bostrack_core::DotFit], b: &[bostrack_core::DotFit]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| {
            ((a.params.x0 - b.params.x0) / b.crlb_x)
                .abs()
                .max(((a.params.y0 - b.params.y0) / b.crlb_y).abs())
        })
        .fold(0.0, f64::max)
}

/// The no-flow stack's way (`NeighbourTails::coupled`): one pass with the neighbours at the
/// reference's fits, then the rest of the neighbour iteration on the linear map, lands on the
/// joint solution that the pixel iteration reaches when run deep.
#[test]
fn coupled_refit_reaches_the_joint_solution_without_refitting() {
    let cfg = FitConfig::default();
    let deep = FitConfig {
        neighbour_tolerance: 0.0005,
        neighbour_passes: 100,
        ..cfg.clone()
    };
    let noise = NoiseModel::read(10.0);
    let (reference, seeds, _) = lattice([0.0, 0.0], 1);
    let prior = fit_dots(&reference, None, &seeds, &deep, &noise).unwrap();
    let (img, _, _) = lattice([0.0, 0.0], 2);
    let coupled = NeighbourTails::coupled(&prior, &seeds, &cfg, &reference, None, &noise);
    let tails = NeighbourTails::new(&prior, &seeds, &cfg, img.width(), img.height());
    let (lin, report) =
        refit_dots_report(&img, None, &seeds, &cfg, &noise, &prior, Some(&coupled)).unwrap();
    let (joint, deep_report) =
        refit_dots_report(&img, None, &seeds, &deep, &noise, &prior, Some(&tails)).unwrap();
    let one = FitConfig {
        neighbour_passes: 1,
        ..cfg.clone()
    };
    let first = refit_dots(&img, None, &seeds, &one, &noise, &prior, Some(&tails)).unwrap();
    println!("linear {report:?}; pixel iteration {deep_report:?}");
    assert_eq!(report.passes, 1, "{report:?}");
    assert!(report.linear_sweeps > 0 && report.converged, "{report:?}");
    assert!(deep_report.converged, "{deep_report:?}");
    assert!(lin.iter().all(|f| f.status == FitStatus::Converged));
    let (w_lin, w_first) = (
        worst_in_bounds(&lin, &joint),
        worst_in_bounds(&first, &joint),
    );
    // measured: 0.049 (linear) against 0.31 (the first pass alone); the first pass's
    // Gauss-Newton steps from the prior leave up to ~0.04 (a second step per dot brought it to
    // 0.017, for 8 % more of the real stack's time; the stack's scatter, all its positions are
    // for, did not change: `converge --stack-only`); within the neighbour tolerance
    println!("worst against the joint solution: linear {w_lin:.3}, first pass {w_first:.3} bounds");
    assert!(w_lin < cfg.neighbour_tolerance, "{w_lin}");
    assert!(w_first > 0.2, "{w_first}");
}

/// A dot the reference's fits did not model but this image's first pass found: the map does
/// not hold, so the pixel iteration runs (and still converges).
#[test]
fn coupled_refit_falls_back_to_the_pixel_iteration_for_a_new_dot() {
    let cfg = FitConfig::default();
    let noise = NoiseModel::read(10.0);
    let (reference, seeds, _) = lattice([0.0, 0.0], 1);
    let mut prior = fit_dots(&reference, None, &seeds, &cfg, &noise).unwrap();
    prior[14].status = FitStatus::NotFitted;
    let (img, _, _) = lattice([0.0, 0.0], 2);
    let coupled = NeighbourTails::coupled(&prior, &seeds, &cfg, &reference, None, &noise);
    let (fits, report) =
        refit_dots_report(&img, None, &seeds, &cfg, &noise, &prior, Some(&coupled)).unwrap();
    assert_eq!(report.linear_sweeps, 0, "{report:?}");
    assert!(report.passes > 1 && report.converged, "{report:?}");
    assert_eq!(fits[14].status, FitStatus::Converged, "{:?}", fits[14]);
}

/// What each dot's own least-squares fit does with its neighbours held at `fits`: one pass of
/// full fits (no Gauss-Newton steps, no linear map), in units of the bound of `fits`. At the
/// joint solution no dot moves by more than the tolerances allow.
fn stationarity(img: &Image, seeds: &[Seed], fits: &[bostrack_core::DotFit]) -> f64 {
    let one = FitConfig {
        neighbour_passes: 1,
        ..FitConfig::default()
    };
    let noise = NoiseModel::read(10.0);
    let again = refit_dots(img, None, seeds, &one, &noise, fits, None).unwrap();
    worst_in_bounds(&again, fits)
}

/// The neighbour iteration's Gauss-Newton steps (in place of refits) land where the dots' own
/// fits stay: on a fresh image (`fit_dots`), on a frame refitted from another image's fits, and
/// on a stack image through the coupling map (whose first pass is made of steps too).
#[test]
fn linear_steps_land_on_the_fits_own_solution() {
    let cfg = FitConfig::default();
    let noise = NoiseModel::read(10.0);
    let (reference, seeds, _) = lattice([0.0, 0.0], 1);
    let (prior, r0) =
        bostrack_fit::fit_dots_report(&reference, None, &seeds, &cfg, &noise).unwrap();
    let (img, seeds2, _) = lattice([0.3, -0.2], 4);
    let (frame, r1) = refit_dots_report(&img, None, &seeds2, &cfg, &noise, &prior, None).unwrap();
    let (still, _, _) = lattice([0.0, 0.0], 5);
    let coupled = NeighbourTails::coupled(&prior, &seeds, &cfg, &reference, None, &noise);
    let (stack, r2) =
        refit_dots_report(&still, None, &seeds, &cfg, &noise, &prior, Some(&coupled)).unwrap();
    println!("fit_dots {r0:?}\nframe {r1:?}\nstack {r2:?}");
    assert!(r1.linear_steps > 0 && r1.converged, "{r1:?}");
    assert!(r2.linear_steps > 0 && r2.linear_sweeps > 0, "{r2:?}");
    let (s0, s1, s2) = (
        stationarity(&reference, &seeds, &prior),
        stationarity(&img, &seeds2, &frame),
        stationarity(&still, &seeds, &stack),
    );
    println!("largest move of a full refit: fit_dots {s0:.3}, frame {s1:.3}, stack {s2:.3} bounds");
    assert!(s0 < 0.2 && s1 < 0.2 && s2 < 0.2, "{s0} {s1} {s2}");
}

/// A frame refitted with the reference fits' memory: its first pass takes Gauss-Newton steps
/// from the priors (here, the same dots up to noise) and lands where the dots' own fits stay;
/// the memory of a reference weighted with a 4 × smaller noise variance, scaled back by
/// `for_variance_ratio(4)`, gives the same frame fits.
#[test]
fn a_remembered_reference_lets_a_frame_step_from_its_priors() {
    let cfg = FitConfig::default();
    let noise = NoiseModel::read(10.0);
    let (reference, seeds, _) = lattice([0.0, 0.0], 1);
    let (prior, _, memory) =
        bostrack_fit::fit_dots_remembered(&reference, None, &seeds, &cfg, &noise).unwrap();
    assert_eq!(memory.len(), seeds.len());
    let (img, _, _) = lattice([0.0, 0.0], 6);
    let (plain, r0) = refit_dots_report(&img, None, &seeds, &cfg, &noise, &prior, None).unwrap();
    let (stepped, r1) = bostrack_fit::refit_dots_remembered(
        &img,
        None,
        &seeds,
        &cfg,
        &noise,
        &prior,
        None,
        Some(&memory),
    )
    .unwrap();
    println!("without memory {r0:?}\nwith memory {r1:?}");
    // (the steps of the first pass count among the refits' steps)
    assert!(
        r1.linear_steps >= r0.linear_steps + seeds.len() / 2,
        "{r0:?} {r1:?}"
    );
    let s = stationarity(&img, &seeds, &stepped);
    let d = worst_in_bounds(&stepped, &plain);
    println!("largest move of a full refit {s:.3}, from the fits without memory {d:.3} bounds");
    assert!(s < 0.2 && d < 0.2, "{s} {d}");
    // read noise only: the weights are uniform, so the fits do not depend on the variance's
    // scale (but for where they stop within their tolerances: ~1e-4 of the bound), and the
    // scaled memory is the memory (without the scaling every step would be 4 × too short)
    let quarter = NoiseModel::read(5.0);
    let (prior4, _, memory4) =
        bostrack_fit::fit_dots_remembered(&reference, None, &seeds, &cfg, &quarter).unwrap();
    let (again, _) = bostrack_fit::refit_dots_remembered(
        &img,
        None,
        &seeds,
        &cfg,
        &noise,
        &prior4,
        None,
        Some(&memory4.for_variance_ratio(4.0)),
    )
    .unwrap();
    let w = worst_in_bounds(&again, &stepped);
    println!("scaled memory against the memory: {w:e} bounds");
    assert!(w < 1e-3, "{w}");
}

/// A `n × n` lattice of dots 8 px apart (σ 1.6 / 1.5 px, ρ 0.1), each moved by `flow` of its
/// position, read noise 10 counts: the image, seeds at the moved dots' rounded centres (as
/// tracking gives them) and the true centres.
fn flowing(
    n: usize,
    flow: impl Fn(f64, f64) -> [f64; 2],
    seed: u64,
) -> (Image, Vec<Seed>, Vec<[f64; 2]>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let side = 8 * (n + 1);
    let mut data = vec![100.0; side * side];
    let (mut truth, mut seeds) = (Vec::new(), Vec::new());
    let mut jitter = StdRng::seed_from_u64(99);
    for j in 0..n {
        for i in 0..n {
            let (x, y) = (
                8.0 + 8.0 * i as f64 + jitter.random_range(-0.3..0.3),
                8.0 + 8.0 * j as f64 + jitter.random_range(-0.3..0.3),
            );
            let [dx, dy] = flow(x, y);
            let g = Gaussian2D {
                x0: x + dx,
                y0: y + dy,
                amplitude: 1000.0,
                sigma_x: 1.6,
                sigma_y: 1.5,
                rho: 0.1,
                background: 0.0,
            };
            add_dot(
                &g,
                Window::new(0, 0, side, side),
                Sampling::Integrated,
                &mut data,
            );
            truth.push([g.x0, g.y0]);
            let c = [g.x0.round(), g.y0.round()];
            seeds.push(Seed {
                index: GridIndex::new(i as i32, j as i32),
                predicted: c,
                centre: c,
                window: Window::centred(c[0], c[1], 4),
                flags: DotFlags::NONE,
            });
        }
    }
    for v in data.iter_mut() {
        let z: f64 = rng.sample(StandardNormal);
        *v += 10.0 * z;
    }
    (
        Image::from_fn(side, side, |x, y| data[y * side + x]),
        seeds,
        truth,
    )
}

/// A gradient frame with the reference's linear coupling map (`FitMemory::linearised`): the
/// dots outside a local flow (a bump of up to 0.6 px in one corner of a 16 × 16 lattice, the
/// rest moved by a common 0.02 px) are solved on the map, the flow and a ring around it by the
/// passes. Every dot ends where a full refit with its neighbours at the result leaves it (the
/// joint solution, inside the flow and out), within a fifth of a bound of the pixel iteration
/// alone, with fewer refits; a map of other seeds is not used, nor any map with `frame_map`
/// off.
#[test]
fn a_frame_solves_its_still_part_on_the_reference_map() {
    let cfg = FitConfig {
        frame_map: true,
        ..FitConfig::default()
    };
    let noise = NoiseModel::read(10.0);
    let n = 16;
    let (reference, seeds, _) = flowing(n, |_, _| [0.0, 0.0], 1);
    let (prior_fits, _, memory) =
        bostrack_fit::fit_dots_remembered(&reference, None, &seeds, &cfg, &noise).unwrap();
    let with_map = memory
        .clone()
        .linearised(&prior_fits, &seeds, &cfg, &reference, None, &noise);
    assert!(with_map.has_map() && !memory.has_map());
    let bump = |x: f64, y: f64| {
        let r2 = ((x - 30.0).powi(2) + (y - 30.0).powi(2)) / (2.0 * 12.0 * 12.0);
        let a = 0.6 * (-r2).exp();
        [0.02 + a, 0.02 - 0.5 * a]
    };
    let (img, seeds2, truth) = flowing(n, bump, 7);
    // the prior: the reference fits moved by a tracked displacement (off by up to 0.06 px)
    let mut tracking = StdRng::seed_from_u64(3);
    let prior: Vec<_> = prior_fits
        .iter()
        .zip(&truth)
        .map(|(f, t)| {
            let mut p = *f;
            let [dx, dy] = bump(t[0] - 0.02, t[1] - 0.02);
            p.params.x0 += dx + tracking.random_range(-0.06..0.06);
            p.params.y0 += dy + tracking.random_range(-0.06..0.06);
            p
        })
        .collect();
    let fit = |m: &bostrack_fit::FitMemory| {
        bostrack_fit::refit_dots_remembered(
            &img,
            None,
            &seeds2,
            &cfg,
            &noise,
            &prior,
            None,
            Some(m),
        )
        .unwrap()
    };
    let (mapped, rm) = fit(&with_map);
    let (plain, rp) = fit(&memory);
    // (with `frame_map` off the memory's map is left aside)
    let (off, ro) = bostrack_fit::refit_dots_remembered(
        &img,
        None,
        &seeds2,
        &FitConfig {
            frame_map: false,
            ..FitConfig::default()
        },
        &noise,
        &prior,
        None,
        Some(&with_map),
    )
    .unwrap();
    assert_eq!(ro, rp);
    assert!(worst_in_bounds(&off, &plain) == 0.0);
    println!("with the map {rm:?}\npixel iteration {rp:?}");
    assert!(rm.linear_sweeps > 0 && rm.converged, "{rm:?}");
    assert_eq!(rp.linear_sweeps, 0);
    let after_first = |r: &bostrack_fit::PassReport| r.refits.iter().skip(1).sum::<usize>();
    assert!(
        2 * after_first(&rm) < after_first(&rp),
        "refits after the first pass: map {} pixel {}",
        after_first(&rm),
        after_first(&rp)
    );
    let s = stationarity(&img, &seeds2, &mapped);
    let d = worst_in_bounds(&mapped, &plain);
    println!("largest move of a full refit {s:.3}, from the pixel iteration {d:.3} bounds");
    assert!(s < 0.2 && d < 0.2, "{s} {d}");
    // both against the truth: the same errors (the map changes where the iteration stops, not
    // what it estimates)
    let rms = |f: &[bostrack_core::DotFit]| {
        let e: f64 = f
            .iter()
            .zip(&truth)
            .map(|(f, t)| (f.params.x0 - t[0]).powi(2) + (f.params.y0 - t[1]).powi(2))
            .sum();
        (e / f.len() as f64).sqrt()
    };
    let (em, ep) = (rms(&mapped), rms(&plain));
    println!("rms error: map {em:.5} px, pixel {ep:.5} px");
    assert!((em / ep - 1.0).abs() < 0.02, "{em} {ep}");
    // a map made for other seeds (a smaller lattice) is left aside: the pixel iteration
    let (small, small_seeds, _) = flowing(4, |_, _| [0.0, 0.0], 1);
    let (sf, _, sm) =
        bostrack_fit::fit_dots_remembered(&small, None, &small_seeds, &cfg, &noise).unwrap();
    let other = sm.linearised(&sf, &small_seeds, &cfg, &small, None, &noise);
    let (again, ro) = fit(&other);
    assert_eq!(ro.linear_sweeps, 0, "{ro:?}");
    assert!(stationarity(&img, &seeds2, &again) < 0.2);
}
