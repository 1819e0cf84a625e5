//! Faint dots (issue #14, finding 2): whether a lattice site holds a dot is decided by its fit,
//! not only by the detector's threshold. A site the detector calls empty is fitted with the
//! shape held at the image's median dot; it holds a dot where the amplitude at the predicted
//! site reaches 3.5 standard deviations (a linear fit: 2.3e-4 false alarms per empty site), or
//! that of the fit with its position free in the window reaches 4.5 (`bostrack_fit`,
//! `PRESENCE_SITE_MIN_Z`, `PRESENCE_MIN_Z`).
//!
//! Scenes from the generator (σ 1.25 px, spacing 10 px rotated by 2°, read noise 10 counts and
//! shot noise on a background of 150, so 15.8 counts of noise at the background; each dot's
//! peak varies by 10 %); peak SNR = peak / background noise. Every site the pipeline reports is
//! scored against the truth: a true dot is found (usable fit), missed (still `missing`) or
//! failed (any other unusable fit); an empty site of the target (a printed dot left out) must
//! not become a dot.

use bostrack_core::DotFlags;
use bostrack_detect::{DetectConfig, detect, track};
use bostrack_fit::{FitConfig, estimate_noise, fit_dots};
use bostrack_synth::{Scene, SceneConfig};

#[derive(Debug, Default)]
struct Score {
    found: usize,
    missed: usize,
    failed: usize,
    /// True dots the detector alone called missing.
    detector_missed: usize,
    /// Empty sites reported as dots, and all empty sites.
    spurious: usize,
    empty: usize,
}

fn score(amplitude: f64, missing: f64, size: usize, seed: u64) -> Score {
    score_in(amplitude, missing, size, seed, false)
}

/// [`score`] of the reference image, or (`tracked`) of a no-flow image of the same target with
/// its own noise, its dots tracked from the reference's detection (as a gradient frame's are:
/// its still dots found from the template measure at the reference centres, the sites the
/// reference found empty tested at their prediction) and fitted.
fn score_in(amplitude: f64, missing: f64, size: usize, seed: u64, tracked: bool) -> Score {
    let mut cfg = SceneConfig {
        width: size,
        height: size,
        seed,
        ..Default::default()
    };
    cfg.lattice.spacing = 10.0;
    cfg.lattice.angle_deg = 2.0;
    cfg.lattice.origin = Some([size as f64 / 2.0 - 0.7, size as f64 / 2.0 - 0.3]);
    cfg.dots.sigma_x = 1.25;
    cfg.dots.sigma_y = 1.25;
    cfg.dots.amplitude = amplitude;
    cfg.dots.amplitude_jitter = 0.1;
    cfg.defects.missing = missing;
    cfg.background.level = 150.0;
    cfg.noise.read_noise = 10.0;
    cfg.noise.gain = 1.0;
    let scene = Scene::reference(&cfg).unwrap();
    let other;
    let mut det = detect(&scene.image, None, &DetectConfig::default()).unwrap();
    let img = if tracked {
        other = bostrack_synth::stack(&cfg, 1).unwrap().remove(0);
        det = track(&other, None, &det, &DetectConfig::default()).unwrap();
        &other
    } else {
        &scene.image
    };
    let noise = estimate_noise(img, None).unwrap();
    let fits = fit_dots(img, None, &det.seeds, &FitConfig::default(), &noise).unwrap();
    let mut s = Score::default();
    for (seed, fit) in det.seeds.iter().zip(&fits) {
        if seed.flags.contains(DotFlags::BORDER) {
            continue;
        }
        // the truth site nearest the predicted lattice position
        let [px, py] = seed.predicted;
        let t = scene
            .truth
            .iter()
            .min_by(|a, b| {
                let d = |g: &bostrack_core::Gaussian2D| (g.x0 - px).powi(2) + (g.y0 - py).powi(2);
                d(&a.params).total_cmp(&d(&b.params))
            })
            .unwrap();
        let ok = fit.status.is_ok();
        if t.flags.contains(DotFlags::MISSING) {
            s.empty += 1;
            s.spurious += ok as usize;
        } else {
            s.detector_missed += seed.flags.contains(DotFlags::MISSING) as usize;
            if ok {
                s.found += 1;
            } else if fit.flags.contains(DotFlags::MISSING) {
                s.missed += 1;
            } else {
                s.failed += 1;
            }
        }
    }
    println!("peak {amplitude}, {missing} empty, tracked {tracked}: {s:?}");
    s
}

fn dots(s: &Score) -> usize {
    s.found + s.missed + s.failed
}

/// Peak SNR 6: at most 0.5 % of the dots missed and 0.5 % failed, no empty site made a dot.
#[test]
fn peak_snr_6_misses_and_fails_at_most_half_a_percent() {
    let s = score(95.0, 0.05, 512, 3);
    let n = dots(&s);
    assert!(s.empty > 50, "{s:?}");
    assert!(s.missed * 200 <= n, "{s:?}");
    assert!(s.failed * 200 <= n, "{s:?}");
    assert_eq!(s.spurious, 0, "{s:?}");
}

/// Peak SNR 3.5: the detector alone misses 6 % of the dots (152 of 2,401); after the fits at
/// most 0.5 % are missed (11) and 0.5 % failed, and no empty site becomes a dot.
#[test]
fn peak_snr_3_5_dots_the_detector_misses_are_found_by_their_fit() {
    let s = score(55.0, 0.05, 512, 5);
    let n = dots(&s);
    assert!(s.detector_missed * 100 >= 3 * n, "{s:?}");
    assert!(s.missed * 200 <= n, "{s:?}");
    assert!(s.failed * 200 <= n, "{s:?}");
    assert_eq!(s.spurious, 0, "{s:?}");
}

/// The false-alarm rate of the presence test, on a target with 30 % of its dots left out at
/// peak SNR 6: at most 2 of ~700 empty sites become dots (measured: 1 of 716 here, 1 of 2,963
/// on a 1-MP image; expected from the site test alone 2.3e-4 per empty site).
#[test]
fn empty_sites_seldom_become_dots() {
    let s = score(95.0, 0.3, 512, 77);
    assert!(s.empty > 600, "{s:?}");
    assert!(s.spurious <= 2, "{s:?}");
    assert_eq!(s.missed + s.failed, 0, "{s:?}");
}

/// The same rates in a tracked image (a no-flow image of the peak-SNR-3.5 target and of the
/// target with 30 % of its dots left out): tracking's still dots are tested at their
/// reference centre and its empty sites among them at their prediction, without a search
/// (whose maximum over the noise had passed more faint dots: the detector now misses 276 of
/// the 2,401 dots here, against 137 with the search), and the fits decide. Measured: 19 missed
/// and none failed (16 and 2 with the search), no empty site made a dot.
#[test]
fn tracked_images_find_the_faint_dots_and_leave_the_empty_sites() {
    let s = score_in(55.0, 0.05, 512, 5, true);
    let n = dots(&s);
    assert!((s.missed + s.failed) * 100 <= n, "{s:?}");
    assert_eq!(s.spurious, 0, "{s:?}");
    let s = score_in(95.0, 0.3, 512, 77, true);
    assert!(s.empty > 600, "{s:?}");
    assert!(s.spurious <= 2, "{s:?}");
    assert_eq!(s.missed + s.failed, 0, "{s:?}");
}
