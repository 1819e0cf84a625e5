//! Noise estimation on synthetic images with known read + shot noise.

use bostrack_core::{Image, Mask, NoiseModel};
use bostrack_fit::{FitError, estimate_noise, estimate_noise_detailed, noise_from_stack};
use bostrack_synth::{Scene, SceneConfig, stack};

fn scene(seed: u64) -> SceneConfig {
    let mut cfg = SceneConfig {
        width: 320,
        height: 320,
        seed,
        ..Default::default()
    };
    cfg.noise.read_noise = 15.0;
    cfg.noise.gain = 0.8;
    cfg.noise.offset = 0.0;
    cfg
}

/// Truth: read + shot, plus the 12-bit rounding (variance 1/12).
fn truth(cfg: &SceneConfig) -> NoiseModel {
    NoiseModel {
        read_variance: cfg.noise.read_noise.powi(2) + 1.0 / 12.0,
        gain: cfg.noise.gain,
        offset: cfg.noise.offset,
    }
}

/// Relative error of the predicted standard deviation at a few intensities, and of the gain.
fn check(est: &NoiseModel, truth: &NoiseModel, levels: &[f64], tol: f64, what: &str) {
    for &m in levels {
        let rel = est.sigma(m) / truth.sigma(m) - 1.0;
        assert!(
            rel.abs() < tol,
            "{what}: sigma at {m}: {} vs {} ({est:?})",
            est.sigma(m),
            truth.sigma(m)
        );
    }
    assert!(
        (est.gain / truth.gain - 1.0).abs() < 0.1,
        "{what}: gain {} vs {}",
        est.gain,
        truth.gain
    );
}

#[test]
fn estimate_noise_recovers_synthetic_noise() {
    let cfg = scene(5);
    let img = Scene::reference(&cfg).unwrap().image;
    let (_, hi, _) = img.stats().unwrap();
    let fit = estimate_noise_detailed(&img, None).unwrap();
    let lo = fit.bins[0].mean;
    let levels = [lo, 0.5 * (lo + hi), 0.9 * hi];
    check(&fit.model, &truth(&cfg), &levels, 0.1, "single image");
    // the bins cover the intensity range and most are used
    assert!(fit.bins.iter().filter(|b| b.used).count() >= 24);
}

#[test]
fn noise_from_stack_recovers_synthetic_noise() {
    let cfg = scene(9);
    let frames = stack(&cfg, 6).unwrap();
    let est = noise_from_stack(&frames, None).unwrap();
    let (lo, hi, _) = frames[0].stats().unwrap();
    check(
        &est,
        &truth(&cfg),
        &[lo.max(100.0), 0.5 * (lo + hi), 0.9 * hi],
        0.1,
        "stack",
    );
}

#[test]
fn constant_read_noise_gives_zero_gain() {
    let mut cfg = scene(2);
    cfg.noise.gain = 0.0;
    cfg.bits = 64;
    let img = Scene::reference(&cfg).unwrap().image;
    let est = estimate_noise(&img, None).unwrap();
    assert!(est.gain < 0.02, "{est:?}");
    assert!((est.sigma(500.0) / 15.0 - 1.0).abs() < 0.1, "{est:?}");
}

#[test]
fn masked_pixels_are_not_used_and_bad_inputs_are_errors() {
    let cfg = scene(3);
    let mut img = Scene::reference(&cfg).unwrap().image;
    // garbage in the left half, masked out
    for y in 0..img.height() {
        for x in 0..160 {
            img.data_mut()[y * 320 + x] = if (x + y) % 2 == 0 { 0.0 } else { 3000.0 };
        }
    }
    let mask = Mask::from_fn(320, 320, |x, _| x >= 160);
    let est = estimate_noise(&img, Some(&mask)).unwrap();
    check(&est, &truth(&cfg), &[300.0, 1000.0], 0.12, "masked");
    let small = Mask::all(10, 10);
    assert!(matches!(
        estimate_noise(&img, Some(&small)),
        Err(FitError::MaskSize { .. })
    ));
    assert!(matches!(
        noise_from_stack(&[img.clone()], None),
        Err(FitError::StackTooShort(1))
    ));
    let other = Image::from_fn(5, 5, |_, _| 0.0);
    assert!(matches!(
        noise_from_stack(&[img.clone(), other], None),
        Err(FitError::StackSize { index: 1, .. })
    ));
    let tiny = Image::from_fn(4, 40, |_, _| 0.0);
    assert!(estimate_noise(&tiny, None).is_err());
}

/// The noise estimates are the same, to the last bit, on 1 and on 2 threads (the stack's means
/// hold many ties, whose order in the sort decides the bins).
#[test]
fn noise_estimates_do_not_depend_on_threads() {
    let cfg = SceneConfig {
        width: 700,
        height: 700,
        ..scene(21)
    };
    let imgs = stack(&cfg, 4).unwrap();
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            (
                estimate_noise(&imgs[0], None).unwrap(),
                noise_from_stack(&imgs, None).unwrap(),
            )
        })
    };
    assert_eq!(on(1), on(2));
}
