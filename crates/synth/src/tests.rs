//! Scene-level tests: determinism, exact rendering, shifts, noise statistics, quantisation,
//! flags, stacks, flow, configuration and CSV.

use crate::*;
use bostrack_core::{DotFlags, Gaussian2D, GridIndex, Image};

fn small(seed: u64) -> SceneConfig {
    SceneConfig {
        width: 96,
        height: 80,
        seed,
        ..SceneConfig::default()
    }
}

fn dot(x0: f64, y0: f64, amplitude: f64, sx: f64, sy: f64, rho: f64, background: f64) -> TruthDot {
    TruthDot {
        index: GridIndex::new(0, 0),
        params: Gaussian2D {
            x0,
            y0,
            amplitude,
            sigma_x: sx,
            sigma_y: sy,
            rho,
            background,
        },
        flags: DotFlags::NONE,
        defect: None,
        crlb_x: f64::NAN,
        crlb_y: f64::NAN,
    }
}

fn same_truth(a: &[TruthDot], b: &[TruthDot]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(s, t)| {
            s.index == t.index
                && s.params == t.params
                && s.flags == t.flags
                && s.defect == t.defect
                && s.crlb_x.to_bits() == t.crlb_x.to_bits()
                && s.crlb_y.to_bits() == t.crlb_y.to_bits()
        })
}

/// Same seed → bit-identical truth and images, with 1 thread or many; another seed → different
/// noise and layout.
#[test]
fn deterministic_for_a_seed_and_any_thread_count() {
    let mut cfg = small(11);
    cfg.defects.missing = 0.05;
    cfg.defects.defective = 0.1;
    cfg.dots.amplitude_jitter = 0.1;
    cfg.lattice.angle_deg = 17.0;
    cfg.dots.rho = 0.3;
    let a = Scene::reference(&cfg).unwrap();
    let b = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| Scene::reference(&cfg).unwrap());
    let c = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap()
        .install(|| Scene::reference(&cfg).unwrap());
    for other in [&b, &c] {
        assert!(same_truth(&a.truth, &other.truth));
        assert_eq!(a.image.data(), other.image.data());
        assert_eq!(a.mean.data(), other.mean.data());
    }
    let d = Scene::reference(&small(12)).unwrap();
    assert_ne!(a.image.data(), d.image.data());
    let flow = FlowConfig {
        displacement: DisplacementField::Uniform { dx: 0.1, dy: 0.2 },
        ..Default::default()
    };
    let g1 = Scene::gradient(&cfg, &flow).unwrap();
    let g2 = Scene::gradient(&cfg, &flow).unwrap();
    assert_eq!(g1.image.data(), g2.image.data());
    assert_ne!(g1.image.data(), a.image.data());
}

/// The integrated intensity of a drawn dot equals its volume 2π I0 σx σy sqrt(1-ρ²) to < 1e-6
/// relative (erf differences at ρ = 0, quadrature otherwise; the ±6σ window leaves out < 4e-9).
#[test]
fn rendered_dot_volume_is_exact() {
    let mut cfg = SceneConfig {
        width: 64,
        height: 64,
        bits: 64,
        ..SceneConfig::default()
    };
    cfg.background.level = 37.0;
    for (sx, sy, rho) in [
        (1.6, 1.6, 0.0),
        (0.7, 1.3, 0.0),
        (2.5, 1.2, 0.5),
        (1.1, 2.9, -0.8),
        (0.5, 0.5, 0.3),
    ] {
        let t = dot(31.3, 30.8, 1000.0, sx, sy, rho, 37.0);
        let mean = render_mean(&cfg, &[t]).unwrap();
        let sum: f64 = mean.data().iter().map(|v| v - 37.0).sum();
        let rel = sum / t.params.volume() - 1.0;
        assert!(
            rel.abs() < 1e-6,
            "sigma ({sx}, {sy}) rho {rho}: relative error {rel:e}"
        );
    }
}

/// An integer shift of the lattice origin moves every dot by exactly that amount (same grid
/// index, same jitter and defects) and the noise-free image by whole pixels (to rounding, 1e-9
/// relative: `px - x0` is computed from shifted operands).
#[test]
fn integer_origin_shift_moves_dots_and_image() {
    let mut cfg = small(5);
    cfg.bits = 64;
    cfg.dots.amplitude_jitter = 0.2;
    cfg.dots.sigma_jitter = 0.1;
    cfg.dots.rho = -0.3;
    cfg.defects.missing = 0.1;
    cfg.defects.defective = 0.2;
    cfg.lattice.angle_deg = 23.0;
    cfg.lattice.origin = Some([40.3, 41.7]);
    let a = Scene::reference(&cfg).unwrap();
    let (sx, sy) = (3i64, -2i64);
    cfg.lattice.origin = Some([40.3 + sx as f64, 41.7 + sy as f64]);
    let b = Scene::reference(&cfg).unwrap();
    let mut matched = 0;
    for t in &a.truth {
        if let Some(u) = b.truth.iter().find(|u| u.index == t.index) {
            assert!((u.params.x0 - t.params.x0 - sx as f64).abs() < 1e-12);
            assert!((u.params.y0 - t.params.y0 - sy as f64).abs() < 1e-12);
            assert_eq!(
                (
                    u.params.amplitude,
                    u.params.sigma_x,
                    u.params.sigma_y,
                    u.params.rho,
                    u.defect
                ),
                (
                    t.params.amplitude,
                    t.params.sigma_x,
                    t.params.sigma_y,
                    t.params.rho,
                    t.defect
                )
            );
            for f in [DotFlags::MISSING, DotFlags::DEFECT] {
                assert_eq!(u.flags.contains(f), t.flags.contains(f));
            }
            matched += 1;
        }
    }
    assert!(matched > 90, "{matched}");
    let (w, h) = (cfg.width as i64, cfg.height as i64);
    let mut worst: f64 = 0.0;
    for y in 0..h {
        for x in 0..w {
            let (x2, y2) = (x + sx, y + sy);
            if x2 < 0 || y2 < 0 || x2 >= w || y2 >= h {
                continue;
            }
            let (p, q) = (
                a.mean.get(x as usize, y as usize),
                b.mean.get(x2 as usize, y2 as usize),
            );
            worst = worst.max((p - q).abs() / p.abs().max(1.0));
        }
    }
    assert!(worst < 1e-9, "worst relative difference {worst:e}");
}

/// Flat field: read noise std and Poisson variance `gain·mean` from 65k pixels. The sample
/// variance of N Gaussian-like values has relative std sqrt(2/N) ≈ 0.55 %: tolerance 3 %.
#[test]
fn noise_statistics() {
    let flat = |read: f64, gain: f64, offset: f64, level: f64| {
        let mut cfg = SceneConfig {
            width: 256,
            height: 256,
            bits: 64,
            ..SceneConfig::default()
        };
        cfg.dots.amplitude = 0.0;
        cfg.background.level = level;
        cfg.noise = NoiseConfig {
            read_noise: read,
            gain,
            offset,
        };
        let img = Scene::reference(&cfg).unwrap().image;
        let n = img.data().len() as f64;
        let m = img.data().iter().sum::<f64>() / n;
        let v = img.data().iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
        (m, v, img)
    };
    // read noise only
    let (m, v, _) = flat(7.0, 0.0, 0.0, 500.0);
    assert!(
        (m - 500.0).abs() < 0.2 && (v.sqrt() / 7.0 - 1.0).abs() < 0.03,
        "{m} {v}"
    );
    // shot noise only: variance = gain · mean, values on the gain grid
    let (m, v, img) = flat(0.0, 2.5, 0.0, 1000.0);
    assert!(
        (m - 1000.0).abs() < 1.0 && (v / (2.5 * 1000.0) - 1.0).abs() < 0.03,
        "{m} {v}"
    );
    assert!(
        img.data()
            .iter()
            .all(|x| (x / 2.5 - (x / 2.5).round()).abs() < 1e-9)
    );
    // both, with an offset that carries no shot noise: var = read² + gain (mean - offset)
    let (m, v, _) = flat(5.0, 0.8, 200.0, 1200.0);
    let expected = 25.0 + 0.8 * 1000.0;
    assert!(
        (m - 1200.0).abs() < 0.5 && (v / expected - 1.0).abs() < 0.03,
        "{m} {v} vs {expected}"
    );
    // low counts (Knuth branch of the Poisson sampler): mean 3 photo-electrons
    let (m, v, _) = flat(0.0, 1.0, 0.0, 3.0);
    assert!(
        (m - 3.0).abs() < 0.03 && (v / 3.0 - 1.0).abs() < 0.03,
        "{m} {v}"
    );
}

/// Quantisation rounds to integers and clips at 0 and 2^bits - 1; metadata says so.
#[test]
fn quantisation_and_saturation() {
    for bits in [8u16, 12, 16] {
        let sat = ((1u64 << bits) - 1) as f64;
        let mut cfg = SceneConfig {
            width: 64,
            height: 64,
            bits,
            ..SceneConfig::default()
        };
        cfg.noise = NoiseConfig {
            read_noise: 0.0,
            gain: 0.0,
            offset: 0.0,
        };
        cfg.background.level = 3.0;
        cfg.dots.amplitude = 1.6 * sat;
        let s = Scene::reference(&cfg).unwrap();
        assert_eq!(s.image.meta, bostrack_core::ImageMeta::synthetic(bits));
        assert_eq!(s.image.meta.saturation, Some(sat));
        let expect_sat = s.mean.data().iter().filter(|&&m| m >= sat - 0.5).count();
        let got_sat = s
            .image
            .data()
            .iter()
            .filter(|&&v| s.image.is_saturated(v))
            .count();
        assert_eq!(got_sat, expect_sat);
        assert!(expect_sat > 50, "bits {bits}: {expect_sat}");
        for (v, m) in s.image.data().iter().zip(s.mean.data()) {
            assert_eq!(*v, m.round().min(sat));
        }
        // every dot has saturated pixels in its window: flagged
        assert!(
            s.truth
                .iter()
                .filter(|t| t.centre_inside(64, 64))
                .all(|t| t.flags.contains(DotFlags::SATURATED))
        );
        // with noise, still integers in range
        cfg.noise = NoiseConfig {
            read_noise: 20.0,
            gain: 1.0,
            offset: 0.0,
        };
        let s = Scene::reference(&cfg).unwrap();
        assert!(
            s.image
                .data()
                .iter()
                .all(|&v| v == v.round() && (0.0..=sat).contains(&v))
        );
        assert!(s.image.data().contains(&sat));
    }
    // float output is not quantised
    let s = Scene::reference(&SceneConfig {
        width: 32,
        height: 32,
        bits: 32,
        ..SceneConfig::default()
    })
    .unwrap();
    assert_eq!(s.image.meta.saturation, None);
    assert!(s.image.data().iter().any(|v| v.fract() != 0.0));
}

/// Stack images: the same noise-free image, independent noise of the scene's variance.
#[test]
fn stack_images_differ_only_by_noise() {
    let mut cfg = small(3);
    cfg.bits = 64;
    cfg.noise = NoiseConfig {
        read_noise: 10.0,
        gain: 0.0,
        offset: 0.0,
    };
    let k = 6;
    let imgs = stack(&cfg, k).unwrap();
    assert_eq!(imgs.len(), k);
    let mean = Scene::reference(&cfg).unwrap().mean;
    let n = mean.data().len() as f64;
    for a in 0..k {
        let r: Vec<f64> = imgs[a]
            .data()
            .iter()
            .zip(mean.data())
            .map(|(x, m)| x - m)
            .collect();
        let v = r.iter().map(|x| x * x).sum::<f64>() / n;
        assert!(
            (v.sqrt() / 10.0 - 1.0).abs() < 0.04,
            "image {a}: residual std {}",
            v.sqrt()
        );
        for b in a + 1..k {
            assert_ne!(imgs[a].data(), imgs[b].data());
            // independent noise: correlation of residuals ~ N(0, 1/sqrt(n)) = 0.011
            let rb: Vec<f64> = imgs[b]
                .data()
                .iter()
                .zip(mean.data())
                .map(|(x, m)| x - m)
                .collect();
            let c = r.iter().zip(&rb).map(|(x, y)| x * y).sum::<f64>() / n / v;
            assert!(c.abs() < 0.05, "images {a}, {b}: correlation {c}");
        }
    }
    // the stack is not the reference image either
    assert_ne!(imgs[0].data(), Scene::reference(&cfg).unwrap().image.data());
}

/// Campaign frames: the dots and noise-free image of the gradient scene, independent noise per
/// frame, and a frame seed kept bit for bit (committed campaigns such as testdata/demo were
/// written with it).
#[test]
fn frames_differ_only_by_noise() {
    let mut cfg = small(5);
    cfg.bits = 64;
    let flow = FlowConfig {
        displacement: DisplacementField::Uniform { dx: 0.3, dy: -0.2 },
        blur: 0.0,
        conserve_intensity: true,
    };
    let g = Scene::gradient(&cfg, &flow).unwrap();
    let frames: Vec<Scene> = (1..=3)
        .map(|n| Scene::frame(&cfg, &flow, n).unwrap())
        .collect();
    for (a, f) in frames.iter().enumerate() {
        assert!(same_truth(&f.truth, &g.truth));
        assert_eq!(f.mean.data(), g.mean.data());
        assert_ne!(f.image.data(), g.image.data());
        for b in &frames[a + 1..] {
            assert_ne!(f.image.data(), b.image.data());
        }
    }
    // the same frame twice is the same image
    assert_eq!(
        Scene::frame(&cfg, &flow, 2).unwrap().image.data(),
        frames[1].image.data()
    );
    assert_eq!(crate::rng::frame_seed(0, 1), 0x7d4b_c0a5_5e62_c91a);
    assert_ne!(crate::rng::frame_seed(0, 1), crate::rng::frame_seed(1, 1));
}

/// Gradient scene: every dot at ref + d(ref) with the blurred shape of the flow model.
#[test]
fn gradient_scene_has_known_answer() {
    let mut cfg = small(9);
    cfg.defects.missing = 0.05;
    let flow = FlowConfig {
        displacement: DisplacementField::GaussianBump {
            centre: [48.0, 40.0],
            amplitude: 60.0,
            width: 12.0,
        },
        blur: 10.0,
        conserve_intensity: true,
    };
    let r = Scene::reference(&cfg).unwrap();
    let g = Scene::gradient(&cfg, &flow).unwrap();
    assert_eq!(r.truth.len(), g.truth.len());
    let mut grew = 0;
    for (a, b) in r.truth.iter().zip(&g.truth) {
        assert_eq!(a.index, b.index);
        assert_eq!(
            a.flags.contains(DotFlags::MISSING),
            b.flags.contains(DotFlags::MISSING)
        );
        let d = flow.displacement.eval([a.params.x0, a.params.y0]).d;
        assert_eq!(
            (b.params.x0, b.params.y0),
            (a.params.x0 + d[0], a.params.y0 + d[1])
        );
        assert_eq!(b.params, apply_flow(&a.params, &flow));
        assert!((b.params.volume() / a.params.volume() - 1.0).abs() < 1e-12);
        if b.params.sigma_x > a.params.sigma_x * 1.05 {
            grew += 1;
            // blurred dots have a larger bound (AR > 1)
            if b.crlb_x.is_finite() && a.crlb_x.is_finite() {
                assert!(b.crlb_x > a.crlb_x);
            }
        }
    }
    assert!(grew >= 4, "{grew}");
    // the rendered gradient image is the render of its truth
    let again = render_mean(&cfg, &g.truth).unwrap();
    assert_eq!(again.data(), g.mean.data());
}

/// Grid index per docs/CONVENTIONS.md at any rotation: a is the basis vector closest to +x, so
/// i grows with x and j with y on screen.
#[test]
fn grid_index_follows_conventions_at_any_angle() {
    for kind in [LatticeKind::Square, LatticeKind::Hexagonal] {
        for angle in [
            -170.0, -95.0, -50.0, -44.0, 0.0, 12.5, 37.0, 44.9, 61.0, 100.0, 225.0, 719.0,
        ] {
            let mut cfg = small(1);
            cfg.lattice.kind = kind;
            cfg.lattice.angle_deg = angle;
            let lat = lattice_for(&cfg);
            let ang_a = lat.a[1].atan2(lat.a[0]).to_degrees();
            let lim = if kind == LatticeKind::Square {
                45.0
            } else {
                30.0
            };
            assert!(
                ang_a > -lim - 1e-9 && ang_a <= lim + 1e-9,
                "{kind:?} {angle}: a at {ang_a}"
            );
            let ang_b = lat.b[1].atan2(lat.b[0]).to_degrees();
            assert!(ang_b > 0.0 && ang_b < 180.0, "b points towards +y");
            // the same point set as the unreduced rotation: every site's neighbours at `spacing`
            let s = Scene::reference(&cfg).unwrap();
            for t in s.truth.iter().take(20) {
                let p = lat.position(t.index);
                assert!((p[0] - t.params.x0).abs() < 1e-12 && (p[1] - t.params.y0).abs() < 1e-12);
            }
            let th = f64::to_radians(angle);
            let raw = if kind == LatticeKind::Square {
                bostrack_core::Lattice::square(lat.origin, 8.0, th)
            } else {
                bostrack_core::Lattice::hexagonal(lat.origin, 8.0, th)
            };
            for t in s.truth.iter().step_by(7) {
                let f = raw.fractional([t.params.x0, t.params.y0]).unwrap();
                assert!((f[0] - f[0].round()).abs() < 1e-9 && (f[1] - f[1].round()).abs() < 1e-9);
            }
        }
    }
    // hexagonal density: sites per area = 2 / (sqrt(3) spacing²)
    let mut cfg = SceneConfig {
        width: 200,
        height: 200,
        ..SceneConfig::default()
    };
    cfg.lattice.kind = LatticeKind::Hexagonal;
    let n = Scene::reference(&cfg)
        .unwrap()
        .truth
        .iter()
        .filter(|t| t.centre_inside(200, 200))
        .count() as f64;
    let expected = 200.0 * 200.0 * 2.0 / (3f64.sqrt() * 64.0);
    assert!((n / expected - 1.0).abs() < 0.03, "{n} vs {expected}");
}

/// Missing and defective fractions are drawn as configured; missing dots are not drawn.
#[test]
fn missing_and_defective_dots() {
    let mut cfg = SceneConfig {
        width: 256,
        height: 256,
        bits: 64,
        ..SceneConfig::default()
    };
    cfg.noise = NoiseConfig {
        read_noise: 0.0,
        gain: 0.0,
        offset: 0.0,
    };
    cfg.defects.missing = 0.1;
    cfg.defects.defective = 0.2;
    let s = Scene::reference(&cfg).unwrap();
    let n = s.truth.len() as f64;
    let missing = s
        .truth
        .iter()
        .filter(|t| t.flags.contains(DotFlags::MISSING))
        .count() as f64;
    let defect = s
        .truth
        .iter()
        .filter(|t| t.flags.contains(DotFlags::DEFECT))
        .count() as f64;
    // binomial: 4 standard deviations
    assert!(
        (missing - 0.1 * n).abs() < 4.0 * (n * 0.09).sqrt(),
        "{missing} of {n}"
    );
    let rest = n - missing;
    assert!(
        (defect - 0.2 * rest).abs() < 4.0 * (rest * 0.16).sqrt(),
        "{defect} of {rest}"
    );
    for kind in [
        DefectKind::Small,
        DefectKind::Large,
        DefectKind::Faint,
        DefectKind::Misshapen,
    ] {
        assert!(s.truth.iter().any(|t| t.defect == Some(kind)), "{kind:?}");
    }
    for t in &s.truth {
        let (x, y) = (t.params.x0.round(), t.params.y0.round());
        if !t.centre_inside(256, 256) || x < 0.0 || y < 0.0 || x > 255.0 || y > 255.0 {
            continue;
        }
        let v = s.mean.get(x as usize, y as usize);
        if t.flags.contains(DotFlags::MISSING) {
            // only the neighbours' tails: at 8 px pitch and sigma 1.6 far below the peak
            assert!(
                v < 150.0 + 0.05 * 1500.0,
                "missing dot {:?} drawn: {v}",
                t.index
            );
            assert!(t.crlb_x.is_nan());
        } else if t.defect != Some(DefectKind::Faint) {
            assert!(v > 150.0 + 0.3 * 1500.0, "dot {:?} not drawn: {v}", t.index);
        }
        match t.defect {
            Some(DefectKind::Faint) => assert!(t.flags.contains(DotFlags::FAINT)),
            Some(DefectKind::Misshapen) => assert_eq!(t.params.rho, 0.6),
            Some(DefectKind::Small) => assert_eq!(t.params.sigma_x, 0.8),
            _ => {}
        }
    }
}

/// Flags of the truth: BORDER, MASKED, FAINT in a dark band, and the illumination model.
#[test]
fn flags_background_and_mask() {
    let mut cfg = SceneConfig {
        width: 128,
        height: 96,
        ..SceneConfig::default()
    };
    cfg.background.vignetting = 0.4;
    cfg.background.dark = vec![DarkRegion {
        x: None,
        y: Some([70.0, f64::INFINITY]),
        factor: 0.1,
        edge: 0.0,
    }];
    cfg.mask = Some(MaskConfig::Illumination { min: 0.5 });
    let s = Scene::reference(&cfg).unwrap();
    let mask = s.mask.as_ref().unwrap();
    // dark band rows ≥ 70 are masked out; rows above are kept (vignetting ≥ 0.6)
    assert!((0..128).all(|x| mask.keeps(x, 69) && !mask.keeps(x, 70)));
    // background: level · (1 - v r²/r_corner²) · dark factor
    let (cx, cy) = (63.5, 47.5);
    let rc2 = 64.0f64 * 64.0 + 48.0 * 48.0;
    for (x, y) in [(0usize, 0usize), (64, 48), (100, 80), (10, 69)] {
        let r2 = (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2);
        let dark = if y >= 70 { 0.1 } else { 1.0 };
        let expected = 150.0 * (1.0 - 0.4 * r2 / rc2) * dark;
        let t = dot(x as f64, y as f64, 0.0, 1.0, 1.0, 0.0, 0.0);
        let only_bg = render_mean(
            &cfg,
            &[TruthDot {
                flags: DotFlags::MISSING,
                ..t
            }],
        )
        .unwrap();
        assert!((only_bg.get(x, y) - expected).abs() < 1e-9, "({x}, {y})");
    }
    for t in &s.truth {
        let p = &t.params;
        let win = bostrack_core::Window::centred(p.x0, p.y0, cfg.crlb_half_width());
        let inside = win.clip(128, 96) == Some(win);
        assert_eq!(t.flags.contains(DotFlags::BORDER), !inside, "{:?}", t.index);
        let masked = win
            .clip(128, 96)
            .is_some_and(|c| c.y + c.height as i64 > 70);
        assert_eq!(t.flags.contains(DotFlags::MASKED), masked, "{:?}", t.index);
        if p.y0 > 72.0 && t.centre_inside(128, 96) {
            assert!(t.flags.contains(DotFlags::FAINT));
            assert!(
                p.amplitude < 0.1 * 1500.0 + 1e-9
                    && (p.background - 150.0 * 0.1).abs() < 15.0 * 0.4 + 1e-9
            );
        }
        if inside && !masked {
            assert!(t.crlb_x.is_finite() && t.crlb_x > 0.0 && t.crlb_y > 0.0);
        }
    }
}

/// The truth bound is the model's exact bound for that dot, window and noise model.
#[test]
fn truth_bound_is_the_model_bound() {
    let mut cfg = small(4);
    cfg.dots.rho = 0.4;
    cfg.dots.sigma_x = 1.9;
    let s = Scene::reference(&cfg).unwrap();
    let noise = cfg.noise_model();
    assert_eq!(noise.read_variance, 144.0 + 1.0 / 12.0);
    let mut checked = 0;
    for t in s.truth.iter().filter(|t| t.flags.is_empty()) {
        let w = bostrack_core::Window::centred(t.params.x0, t.params.y0, 4);
        let b = bostrack_model::crlb(
            &t.params,
            w,
            &noise,
            Sampling::Integrated,
            bostrack_model::ModelKind::Elliptical,
        )
        .unwrap();
        assert_eq!((t.crlb_x, t.crlb_y), (b.std[0], b.std[1]));
        checked += 1;
    }
    assert!(checked > 40);
    // bound off
    cfg.truth.crlb = false;
    assert!(
        Scene::reference(&cfg)
            .unwrap()
            .truth
            .iter()
            .all(|t| t.crlb_x.is_nan())
    );
}

#[test]
fn truth_csv_round_trip() {
    let mut cfg = small(2);
    cfg.defects.missing = 0.1;
    cfg.defects.defective = 0.3;
    let s = Scene::reference(&cfg).unwrap();
    let mut buf = Vec::new();
    write_truth_csv(&mut buf, &s.truth).unwrap();
    let text = String::from_utf8(buf.clone()).unwrap();
    assert_eq!(text.lines().next().unwrap(), TRUTH_CSV_COLUMNS.join(","));
    assert_eq!(text.lines().count(), s.truth.len() + 1);
    assert!(text.contains("missing") && text.contains("border"));
    // an unknown bound (a missing dot's) is an empty field, never NaN
    assert!(!text.contains("NaN") && text.lines().any(|l| l.ends_with(",,")));
    assert!(s.truth.iter().any(|t| t.crlb_x.is_nan()));
    let back = read_truth_csv(buf.as_slice()).unwrap();
    assert!(same_truth(&s.truth, &back));
    // empty truth still has the header
    let mut buf = Vec::new();
    write_truth_csv(&mut buf, &[]).unwrap();
    assert_eq!(
        String::from_utf8(buf).unwrap().trim_end(),
        TRUTH_CSV_COLUMNS.join(",")
    );
    assert!(read_truth_csv("i,j\n1,2\n".as_bytes()).is_err());
}

#[test]
fn config_from_toml() {
    let text = r#"
        width = 128
        height = 100
        bits = 16
        seed = 42
        [lattice]
        kind = "hexagonal"
        spacing = 10.0
        angle_deg = 5.0
        [dots]
        sigma_x = 2.0
        rho = 0.1
        [background]
        vignetting = 0.2
        [[background.dark]]
        y = [90.0, inf]
        factor = 0.2
        [mask]
        kind = "rect"
        x = [5.0, 120.0]
        y = [5.0, 85.0]
        [noise]
        gain = 0.0
        [render]
        sampling = "point"
    "#;
    let cfg = SceneConfig::from_toml(text).unwrap();
    assert_eq!(
        (cfg.width, cfg.height, cfg.bits, cfg.seed),
        (128, 100, 16, 42)
    );
    assert_eq!(cfg.lattice.kind, LatticeKind::Hexagonal);
    assert_eq!((cfg.dots.sigma_x, cfg.dots.sigma_y), (2.0, 1.6));
    assert_eq!(cfg.background.dark[0].y, Some([90.0, f64::INFINITY]));
    assert_eq!(cfg.background.dark[0].edge, 2.0);
    assert_eq!(
        cfg.mask,
        Some(MaskConfig::Rect {
            x: [5.0, 120.0],
            y: [5.0, 85.0]
        })
    );
    assert_eq!(cfg.render.sampling, Sampling::Point);
    assert!(Scene::reference(&cfg).is_ok());
    assert_eq!(SceneConfig::from_toml("").unwrap(), SceneConfig::default());
    // unknown keys are errors at every level, including tagged enums
    for bad in [
        "widht = 3",
        "[lattice]\nspacin = 3.0",
        "[dots]\nsigma = 1.0",
        "[[background.dark]]\nfactr = 0.1",
        "[mask]\nkind = \"circle\"\ncentre = [1.0, 1.0]\nradius = 3.0\nextra = 1",
        "[noise]\nread = 1.0",
        "[render]\nwindow = 5.0",
        "[truth]\nhalf = 3",
        "[defects]\nkinds = [\"tiny\"]",
    ] {
        assert!(
            matches!(SceneConfig::from_toml(bad), Err(SynthError::Toml(_))),
            "{bad}"
        );
    }
    // values out of range name the field
    for (bad, field) in [
        ("bits = 10", "bits"),
        ("[lattice]\nspacing = -1.0", "lattice.spacing"),
        ("[dots]\nrho = 1.0", "dots.rho"),
        ("[defects]\nmissing = 1.5", "defects.missing"),
        ("[lattice]\nspacing = 0.01", "lattice.spacing"),
        ("width = 0", "width/height"),
        ("[render]\nwindow_sigmas = 1.0", "render.window_sigmas"),
    ] {
        match SceneConfig::from_toml(bad) {
            Err(SynthError::InvalidConfig { field: f, .. }) => assert_eq!(f, field, "{bad}"),
            other => panic!("{bad}: {other:?}"),
        }
    }
    let flow = FlowConfig::from_toml(
        "blur = 2.0\n[displacement]\nkind = \"vortex\"\ncentre = [10.0, 20.0]\nstrength = 5.0\ncore = 4.0\n",
    )
    .unwrap();
    assert_eq!(
        flow.displacement,
        DisplacementField::Vortex {
            centre: [10.0, 20.0],
            strength: 5.0,
            core: 4.0
        }
    );
    assert!(flow.conserve_intensity);
    assert!(
        FlowConfig::from_toml("[displacement]\nkind = \"uniform\"\ndx = 1.0\ndy = 0.0\ndz = 1.0")
            .is_err()
    );
    assert!(
        FlowConfig::from_toml(
            "[displacement]\nkind = \"vortex\"\ncentre = [0.0, 0.0]\nstrength = 1.0\ncore = 0.0"
        )
        .is_err()
    );
    assert_eq!(FlowConfig::from_toml("").unwrap(), FlowConfig::default());
}

/// A resolved configuration written as TOML reads back identical (the CLI stores it next to its
/// outputs to be fed back).
#[test]
fn config_toml_round_trip() {
    let mut cfg = SceneConfig::default();
    cfg.lattice.origin = Some([10.25, -3.5]);
    cfg.lattice.kind = LatticeKind::Hexagonal;
    cfg.background.dark = vec![DarkRegion {
        x: None,
        y: Some([90.0, f64::INFINITY]),
        factor: 0.2,
        edge: 1.0,
    }];
    cfg.mask = Some(MaskConfig::Circle {
        centre: [50.0, 60.0],
        radius: 40.0,
    });
    cfg.defects.kinds = vec![DefectKind::Faint, DefectKind::Misshapen];
    cfg.truth.crlb_half_width = Some(5);
    cfg.render.sampling = Sampling::Point;
    let text = toml::to_string(&cfg).unwrap();
    assert_eq!(SceneConfig::from_toml(&text).unwrap(), cfg, "{text}");
    for d in [
        DisplacementField::Zero,
        DisplacementField::Uniform { dx: 0.1, dy: -0.2 },
        DisplacementField::Affine {
            centre: [1.0, 2.0],
            offset: [0.0, 0.5],
            matrix: [[0.01, 0.0], [0.0, -0.02]],
        },
        DisplacementField::Vortex {
            centre: [1.0, 2.0],
            strength: 3.0,
            core: 4.0,
        },
        DisplacementField::GaussianBump {
            centre: [1.0, 2.0],
            amplitude: 3.0,
            width: 4.0,
        },
    ] {
        let flow = FlowConfig {
            displacement: d,
            blur: 1.5,
            conserve_intensity: false,
        };
        let text = toml::to_string(&flow).unwrap();
        assert_eq!(FlowConfig::from_toml(&text).unwrap(), flow, "{text}");
    }
}

#[test]
fn invalid_dots_are_errors_not_panics() {
    let cfg = small(0);
    let bad = dot(10.0, 10.0, 100.0, 0.0, 1.0, 0.0, 0.0);
    assert!(matches!(
        render_mean(&cfg, &[bad]),
        Err(SynthError::InvalidDot { .. })
    ));
    let nan = dot(f64::NAN, 10.0, 100.0, 1.0, 1.0, 0.0, 0.0);
    assert!(render(&cfg, &[nan], 1).is_err());
    let wrong = Image::from_fn(3, 3, |_, _| 0.0);
    assert!(add_noise(&cfg, &wrong, 1).is_err());
    // dots far outside the image are fine (nothing drawn)
    let far = dot(-1e6, 1e7, 100.0, 1.0, 1.0, 0.0, 0.0);
    let very_far = dot(1e300, -1e300, 100.0, 1e200, 1.0, 0.0, 0.0);
    let wide = dot(10.0, 10.0, 100.0, 1e200, 1e200, 0.0, 0.0);
    let m = render_mean(&cfg, &[far, very_far, wide]).unwrap();
    assert!(m.data().iter().all(|v| v.is_finite()));
    // a gradient that throws every dot far away: all BORDER, no bound, no panic
    let flow = FlowConfig {
        displacement: DisplacementField::Uniform { dx: 1e300, dy: 0.0 },
        ..Default::default()
    };
    let g = Scene::gradient(&cfg, &flow).unwrap();
    assert!(
        g.truth
            .iter()
            .all(|t| t.flags.contains(DotFlags::BORDER) && t.crlb_x.is_nan())
    );
}
