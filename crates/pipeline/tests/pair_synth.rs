//! Statistical acceptance of the pair pipeline on synthetic scenes with exact ground truth
//! (`bostrack-synth`): the displacement uncertainty u_d predicts the actual displacement error,
//! and the amplification ratio predicts the ratio of the position scatters.
//!
//! Both use read noise only (`gain = 0`): the amplification ratio of NOTES.md §2 is derived for
//! the same signal-independent noise in both images, and that is what is tested here. Under
//! shot noise the formula over-states the scatter ratio of blurred (dimmer) dots; the ignored
//! test `ar_under_shot_noise` measures by how much (run it with `--ignored --nocapture`).
//!
//! Release build only (a 768 x 768 scene with a 10-image stack, and 96 pipeline runs for the
//! scatter): CI runs the tests with `--release`.
//! `cargo test --release -p bostrack-pipeline --test pair_synth -- --nocapture` prints the
//! measurements.

use bostrack_core::DotFlags;
use bostrack_displacement::ArVariant;
use bostrack_pipeline::{PipelineConfig, Plan, Quantities, ReferenceContext, process_image};
use bostrack_synth::{DisplacementField, FlowConfig, Scene, SceneConfig, add_noise, stack};
use std::collections::HashMap;
use std::path::Path;

/// A plan with the stage settings of `cfg`; its file lists point at empty placeholder files
/// (the tests hand the images over in memory).
struct Campaign {
    _dir: tempfile::TempDir,
    plan: Plan,
}

fn campaign(mut cfg: PipelineConfig) -> Campaign {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("reference.tif"), b"").unwrap();
    std::fs::create_dir(dir.path().join("gradient")).unwrap();
    std::fs::write(dir.path().join("gradient/g.tif"), b"").unwrap();
    cfg.input.dir = ".".into();
    cfg.input.reference = "reference.tif".into();
    cfg.input.stack_dir = "".into();
    cfg.input.gradient_dir = "gradient".into();
    let plan = Plan::from_config(cfg, &dir.path().join("pipeline.toml")).unwrap();
    Campaign { _dir: dir, plan }
}

/// `P(|T| <= t)` for Student's t with an odd number `nu` of degrees of freedom (Abramowitz &
/// Stegun 26.7.3): `(2/π) [θ + sin θ (cos θ + (2/3) cos³ θ + ... + (2·4···(ν-3))/(1·3···(ν-2))
/// cos^(ν-2) θ)]`, `θ = atan(t/√ν)`.
fn t_coverage(t: f64, nu: usize) -> f64 {
    assert!(nu % 2 == 1);
    let th = (t / (nu as f64).sqrt()).atan();
    let (s, c) = th.sin_cos();
    let mut sum = 0.0;
    let mut term = c;
    let mut k = 1;
    while 2 * k < nu {
        sum += term;
        term *= c * c * (2 * k) as f64 / (2 * k + 1) as f64;
        k += 1;
    }
    2.0 / std::f64::consts::PI * (th + s * sum)
}

#[test]
fn student_t_coverage_matches_known_values() {
    // Cauchy: P(|T| <= 1) = 1/2; large nu tends to the normal 0.6827
    assert!((t_coverage(1.0, 1) - 0.5).abs() < 1e-12);
    assert!((t_coverage(1.0, 3) - 0.6090).abs() < 1e-4); // tables: t_3 CDF(1) = 0.8045
    assert!((t_coverage(1.0, 1001) - 0.6825).abs() < 1e-3);
}

/// Per-axis error statistics of a set of dots.
#[derive(Debug, Default)]
struct Errors {
    n: usize,
    sum_e2: [f64; 2],
    sum_u2: [f64; 2],
    covered: [usize; 2],
}

impl Errors {
    fn add(&mut self, e: [f64; 2], u: [f64; 2]) {
        self.n += 1;
        for a in 0..2 {
            self.sum_e2[a] += e[a] * e[a];
            self.sum_u2[a] += u[a] * u[a];
            self.covered[a] += usize::from(e[a].abs() <= u[a]);
        }
    }
    fn rms_error(&self) -> [f64; 2] {
        self.sum_e2.map(|v| (v / self.n as f64).sqrt())
    }
    fn rms_predicted(&self) -> [f64; 2] {
        self.sum_u2.map(|v| (v / self.n as f64).sqrt())
    }
    fn coverage(&self) -> [f64; 2] {
        self.covered.map(|v| v as f64 / self.n as f64)
    }
}

/// Site of a position on the unrotated synthetic lattice.
fn site(p: [f64; 2], origin: [f64; 2], s: f64) -> (i64, i64) {
    (
        ((p[0] - origin[0]) / s).round() as i64,
        ((p[1] - origin[1]) / s).round() as i64,
    )
}

/// A 768 x 768 scene, 12 px pitch (4096 sites), σ = 1.6 px, read noise 12 counts, a BOS-like
/// displacement bump (|d| up to 2 px) whose blur makes AR reach ~3 at its centre (~600 dots
/// with AR >= 1.2), and a 10-image no-flow stack; reference position = the single reference
/// image.
///
/// What u_d predicts: with `e = d - d_true = e_grad - e_ref`, `var(e) = σ_ref² (1 + AR²)`, and
/// `u_d = u_ref sqrt(1 + AR²)` where `u_ref² ~ σ_ref² χ²_9 / 9` is estimated from K = 10
/// independent images. So `mean(u_d²)` is an unbiased estimate of `mean(var(e))` (the RMS test),
/// and per dot `e / u_d = z / sqrt(χ²_9 / 9)` is Student's t with 9 degrees of freedom: the
/// expected fraction with `|e| <= u_d` is `P(|t_9| <= 1) = 0.6566`, not the 0.6827 of a known
/// σ (the 24 % relative standard error of u_ref dilutes the coverage). The common-mode
/// removal estimates one shift per image from ~4000 dots: negligible. Standard error of the
/// fraction over ~3900 dots: 0.76 % per axis; tolerance ±3 % (the issue's).
///
/// Why 12 px and not the sample's 8-10 px: u_d holds the noise only, not the fit stage's
/// systematic errors. At 10 px pitch the most blurred dots (σ' up to 2.6 px) overlap their
/// neighbours enough that the default two neighbour-subtraction passes leave a bias: measured
/// RMS error / RMS u_d = 1.14 over the dots with AR >= 1.2 (1.05-1.10 with 6 passes; the whole
/// set stays at 1.02), against 1.01-1.03 at 12 px.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "statistical, ~10 s in release: cargo test --release (CI runs it)"
)]
fn u_d_predicts_the_displacement_error() {
    let (all, high, max_ar) = u_d_errors(0.0, ArVariant::Notes);
    check_u_d("read noise, notes AR", &all, &high, max_ar, 300);
}

/// The same scene under read + shot noise (the sample's gain, 0.6 counts per count: the noise
/// model then comes from the stack with its gain) with `ar_variant = "bounds"`: u_d still
/// predicts the error (with the NOTES formula it over-states it for the blurred, dimmer dots,
/// see `bounds_ar_predicts_the_scatter_ratio_under_shot_noise`).
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "statistical, ~10 s in release: cargo test --release (CI runs it)"
)]
fn u_d_predicts_the_displacement_error_under_shot_noise_with_bounds_ar() {
    let (all, high, max_ar) = u_d_errors(0.6, ArVariant::Bounds);
    // (fewer dots reach AR 1.2 than with the formula, which over-states it here)
    check_u_d("shot noise, bounds AR", &all, &high, max_ar, 250);
}

/// The displacement errors of the scene described at [`u_d_predicts_the_displacement_error`]
/// (camera gain `gain`: 0 is read noise only) against u_d with the amplification ratio
/// `variant`: every usable dot, the dots with AR >= 1.2, and the largest AR.
fn u_d_errors(gain: f64, variant: ArVariant) -> (Errors, Errors, f64) {
    const K: usize = 10;
    let mut sc = SceneConfig {
        width: 768,
        height: 768,
        ..Default::default()
    };
    sc.lattice.spacing = 12.0;
    sc.seed = 3;
    sc.noise.gain = gain;
    let flow = FlowConfig {
        displacement: DisplacementField::GaussianBump {
            centre: [384.0, 384.0],
            amplitude: 317.0,
            width: 96.0,
        },
        blur: 5000.0,
        conserve_intensity: true,
    };
    let reference = Scene::reference(&sc).unwrap();
    let gradient = Scene::gradient(&sc, &flow).unwrap();
    let mut pc = PipelineConfig::default();
    pc.detect.spacing = Some(sc.lattice.spacing);
    pc.uncertainty.ar_variant = variant;
    let c = campaign(pc);
    let ctx = ReferenceContext::from_images(
        &c.plan,
        reference.image.clone(),
        None,
        stack(&sc, K).unwrap(),
    )
    .unwrap();
    assert_eq!(ctx.stack_summary().unwrap().images, K);
    let res = process_image(&ctx, &c.plan, &gradient.image, Path::new("g.tif")).unwrap();

    let origin = [(sc.width / 2) as f64, (sc.height / 2) as f64];
    let s = sc.lattice.spacing;
    let truth: HashMap<(i64, i64), usize> = reference
        .truth
        .iter()
        .enumerate()
        .map(|(k, t)| (site([t.params.x0, t.params.y0], origin, s), k))
        .collect();
    let bad = DotFlags::BORDER | DotFlags::MASKED | DotFlags::MISSING;
    let (mut all, mut high) = (Errors::default(), Errors::default());
    let mut max_ar: f64 = 0.0;
    for d in res
        .dots
        .iter()
        .filter(|d| d.valid && !d.flags.intersects(bad))
    {
        let (Some(p), Some(disp), Some(u_d), Some(ar)) =
            (d.reference_position, d.displacement, d.u_d, d.ar)
        else {
            continue;
        };
        let Some(&k) = truth.get(&site(p, origin, s)) else {
            continue;
        };
        let (tr, tg) = (&reference.truth[k], &gradient.truth[k]);
        if tr.flags.intersects(bad) || tg.flags.intersects(bad) {
            continue;
        }
        let e = [
            disp[0] - (tg.params.x0 - tr.params.x0),
            disp[1] - (tg.params.y0 - tr.params.y0),
        ];
        all.add(e, u_d);
        if ar[0].min(ar[1]) >= 1.2 {
            high.add(e, u_d);
        }
        max_ar = max_ar.max(ar[0]).max(ar[1]);
    }
    (all, high, max_ar)
}

/// The acceptance statistics: RMS error / RMS u_d within 10 % (also over the strongly blurred
/// dots alone, more than `min_high` of them), coverage of |e| <= u_d within 3 % of Student's t_9
/// value.
fn check_u_d(what: &str, all: &Errors, high: &Errors, max_ar: f64, min_high: usize) {
    const K: usize = 10;
    let expected = t_coverage(1.0, K - 1);
    eprintln!(
        "{what}: all dots ({}): rms error {:?}, rms u_d {:?}, coverage {:?} (expected {expected:.4})",
        all.n,
        all.rms_error(),
        all.rms_predicted(),
        all.coverage()
    );
    eprintln!(
        "AR >= 1.2 ({} dots, max AR {max_ar:.2}): rms error {:?}, rms u_d {:?}, coverage {:?}",
        high.n,
        high.rms_error(),
        high.rms_predicted(),
        high.coverage()
    );
    assert!(all.n > 3800, "{} dots", all.n);
    assert!(
        high.n > min_high && max_ar > 1.8,
        "{} dots, max AR {max_ar}",
        high.n
    );
    for a in 0..2 {
        let r = all.rms_error()[a] / all.rms_predicted()[a];
        assert!(
            (r - 1.0).abs() < 0.10,
            "axis {a}: rms error / rms u_d = {r}"
        );
        let cov = all.coverage()[a];
        assert!((cov - expected).abs() < 0.03, "axis {a}: coverage {cov}");
        // the strongly blurred dots alone (~600, standard error of the ratio ~3 %)
        let r = high.rms_error()[a] / high.rms_predicted()[a];
        assert!((r - 1.0).abs() < 0.10, "axis {a}, AR >= 1.2: ratio {r}");
    }
}

/// The scatter of the gradient positions over the scatter of the reference positions, over
/// `reps` noise realisations of the same pair, pooled over the dots (each dot's variance about
/// its own mean), against the mean AR the pipeline predicts.
///
/// Every dot of the scene gets the same shape change: an affine displacement field of tiny
/// Jacobian `M` with a large blur `b`, so `Σ' = Σ + b M Mᵀ` is the same everywhere. With
/// `M = λ [[1, c], [c, 1]]`, `M Mᵀ = λ² [[1 + c², 2c], [2c, 1 + c²]]`: `c = 0` grows the dot
/// (ρ' = 0), `c = ±1` gives `ρ' = ±b'/(σ² + b')`, `b' = 2 b λ²`.
fn scatter_ratio(
    rho_grad: Option<f64>,
    growth: f64,
    gain: f64,
    reps: usize,
    variant: ArVariant,
) -> ([f64; 2], [f64; 2], [f64; 2]) {
    let sigma = 1.2;
    let mut sc = SceneConfig {
        width: 512,
        height: 512,
        ..Default::default()
    };
    sc.lattice.spacing = 16.0; // dots up to 3.6 px wide along the diagonal stay apart
    sc.dots.sigma_x = sigma;
    sc.dots.sigma_y = sigma;
    sc.noise.gain = gain;
    sc.seed = 11;
    let lambda = 1e-3;
    let s2 = sigma * sigma;
    let (matrix, blur) = match rho_grad {
        None => (
            [[lambda, 0.0], [0.0, lambda]],
            growth * s2 / (lambda * lambda),
        ),
        Some(rho) => {
            let c = rho.signum();
            let bp = rho.abs() * s2 / (1.0 - rho.abs());
            (
                [[lambda, c * lambda], [c * lambda, lambda]],
                bp / (2.0 * lambda * lambda),
            )
        }
    };
    let flow = FlowConfig {
        displacement: DisplacementField::Affine {
            centre: [256.0, 256.0],
            offset: [0.3, -0.2],
            matrix,
        },
        blur,
        conserve_intensity: true,
    };
    let reference = Scene::reference(&sc).unwrap();
    let gradient = Scene::gradient(&sc, &flow).unwrap();
    let mut pc = PipelineConfig::default();
    pc.detect.spacing = Some(sc.lattice.spacing);
    pc.output.quantities = Quantities::Amplification;
    pc.uncertainty.ar_variant = variant;
    let c = campaign(pc);
    let ctx =
        ReferenceContext::from_images(&c.plan, reference.image.clone(), None, vec![]).unwrap();
    let n = ctx.fits().len();
    let mut ref_pos = vec![Vec::new(); n];
    let mut grad_pos = vec![Vec::new(); n];
    let (mut ar_sum, mut ar_n, mut rho_sum) = ([0.0; 2], 0usize, 0.0);
    let seeds = 1000..1000 + reps as u64;
    for r in seeds {
        // the reference-side context stays fixed; fresh noise on both images
        let img_r = add_noise(&sc, &reference.mean, r).unwrap();
        let img_g = add_noise(&sc, &gradient.mean, r + 100_000).unwrap();
        let rr = process_image(&ctx, &c.plan, &img_r, Path::new("r.tif")).unwrap();
        let rg = process_image(&ctx, &c.plan, &img_g, Path::new("g.tif")).unwrap();
        for i in 0..n {
            let (a, b) = (&rr.dots[i], &rg.dots[i]);
            let bad = DotFlags::BORDER | DotFlags::MASKED;
            if !(a.valid && b.valid) || a.flags.intersects(bad) || b.flags.intersects(bad) {
                continue;
            }
            let (fa, fb) = (a.gradient.unwrap(), b.gradient.unwrap());
            ref_pos[i].push([fa.params.x0, fa.params.y0]);
            grad_pos[i].push([fb.params.x0, fb.params.y0]);
            if let Some(ar) = b.ar {
                ar_sum[0] += ar[0];
                ar_sum[1] += ar[1];
                rho_sum += fb.params.rho;
                ar_n += 1;
            }
        }
    }
    let var = |v: &[[f64; 2]], a: usize| {
        let m = v.iter().map(|p| p[a]).sum::<f64>() / v.len() as f64;
        v.iter().map(|p| (p[a] - m).powi(2)).sum::<f64>()
    };
    let (mut num, mut den) = ([0.0; 2], [0.0; 2]);
    for i in 0..n {
        if ref_pos[i].len() == reps {
            for a in 0..2 {
                num[a] += var(&grad_pos[i], a);
                den[a] += var(&ref_pos[i], a);
            }
        }
    }
    let measured = [0, 1].map(|a| (num[a] / den[a]).sqrt());
    let predicted = ar_sum.map(|v| v / ar_n as f64);
    let rho = rho_sum / ar_n as f64;
    (measured, predicted, [rho, ar_n as f64 / reps as f64])
}

/// AR against the measured scatter ratio, within 5 %, for a pure size change and for
/// elongated dots with ρ' = +0.4 and -0.8. ~900 dots x 16 realisations: the standard error of
/// the measured ratio is about 1.2 %.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "statistical, ~10 s in release: cargo test --release (CI runs it)"
)]
fn ar_predicts_the_scatter_ratio() {
    for (rho, growth) in [(None, 1.0), (Some(0.4), 0.0), (Some(-0.8), 0.0)] {
        let (m, p, [fitted_rho, dots]) = scatter_ratio(rho, growth, 0.0, 16, ArVariant::Notes);
        eprintln!(
            "rho' {rho:?} (fitted {fitted_rho:.3}), {dots:.0} dots: measured {m:.4?}, AR {p:.4?}, ratio {:.4?}",
            [m[0] / p[0], m[1] / p[1]]
        );
        if let Some(r) = rho {
            assert!((fitted_rho - r).abs() < 0.02, "{fitted_rho}");
        }
        assert!(dots > 800.0);
        for a in 0..2 {
            assert!(
                (m[a] / p[a] - 1.0).abs() < 0.05,
                "rho' {rho:?}, axis {a}: measured {} vs AR {}",
                m[a],
                p[a]
            );
        }
    }
}

/// Under read + shot noise (the sample's noise is shot-noise dominated at the dot peaks) the
/// NOTES.md §2 formula, derived for the same signal-independent noise in both images,
/// over-states the scatter ratio of the blurred (dimmer) dots; the `bounds` variant (the ratio of
/// the two fits' own bounds under the estimated noise model) predicts it within 5 %, and so it
/// does under read noise alone. Prints both.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "statistical, ~20 s in release: cargo test --release (CI runs it)"
)]
fn bounds_ar_predicts_the_scatter_ratio_under_shot_noise() {
    for (gain, rho, growth) in [
        (0.6, None, 1.0),
        (0.6, Some(0.4), 0.0),
        (0.6, Some(-0.8), 0.0),
        (0.0, Some(-0.8), 0.0),
    ] {
        let (m, p, [_, dots]) = scatter_ratio(rho, growth, gain, 16, ArVariant::Bounds);
        let (_, notes, _) = scatter_ratio(rho, growth, gain, 2, ArVariant::Notes);
        eprintln!(
            "gain {gain}, rho' {rho:?}: measured {m:.4?}; bounds AR {p:.4?} (measured / AR {:.4?}); \
             NOTES AR {notes:.4?} (measured / AR {:.4?})",
            [m[0] / p[0], m[1] / p[1]],
            [m[0] / notes[0], m[1] / notes[1]]
        );
        assert!(dots > 800.0);
        for a in 0..2 {
            assert!(
                (m[a] / p[a] - 1.0).abs() < 0.05,
                "gain {gain}, rho' {rho:?}, axis {a}: measured {} vs bounds AR {}",
                m[a],
                p[a]
            );
        }
    }
}
