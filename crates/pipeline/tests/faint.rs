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
use bostrack_detect::{DetectConfig, detect};
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
    let img = &scene.image;
    let noise = estimate_noise(img, None).unwrap();
    let det = detect(img, None, &DetectConfig::default()).unwrap();
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
    println!("peak {amplitude}, {missing} empty: {s:?}");
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
