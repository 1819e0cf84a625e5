//! Acceptance of the density field (issue 15) on synthetic campaigns whose displacement field is
//! the gradient of a Gaussian density bump (synth's `gaussian_bump`), seen through a plausible
//! BOS setup: the recovered ρ − ρ_ref against the analytic field, WLS against Poisson, and the
//! coverage of the exact per-node uncertainty u_ρ.
//!
//! The scene: 576 × 576 px, a lattice of 12 px pitch rotated by 15° (the integration follows
//! the lattice's own steps), σ = 1.6 px, read and shot noise, a 10-image no-flow stack; the bump
//! 60 px (5 lattice steps) wide with at most 1 px of displacement (it falls to 4e-5 of its peak
//! at the Dirichlet ring, the edge of the image), blurred so that AR grows from 1 at the edge
//! to about 2 at the centre.
//!
//! Statistics. The errors of ρ at neighbouring nodes are strongly correlated (each node's error
//! is an integral of many gradient errors along paths from the Dirichlet ring, and neighbours
//! share most of them), so one frame holds only a handful of independent samples of
//! `|ρ − ρ_true| ≤ u_ρ`, and a binomial standard error over the nodes would be far too small.
//! The test therefore draws 12 independent campaigns (own seed: reference, stack and frame;
//! frames of one campaign would share the reference image's noise) and takes the standard error
//! of a coverage from the spread of the per-campaign coverages, `sd / √12` (about 0.018;
//! printed with `--nocapture`).
//!
//! u_ρ holds two parts in quadrature (bostrack-density): the exact covariance of the noise
//! (`u_noise`) and the estimate |δ| of the discretisation error. The error splits the same way,
//! measured separately (`examples/density_coverage.rs` does the same over more campaigns):
//! - the **discretisation error**: the same nodes, weights and positions integrated from the
//!   exact gradients. It is deterministic: the fourth-order stencils' truncation `h⁴ ρ⁽⁵⁾/5` on
//!   a bump 5 lattice steps wide, RMS 0.10 u_noise, at most 0.75 u_noise (third-order stencils:
//!   0.34, at most 1.95). Its estimate |δ| (the next order's stencil on the solution) from the
//!   exact gradients misses it by 0.035 u_noise RMS; from the measured ones it is noisier
//!   (RMS 0.20 u_noise), which makes u_ρ about 2 % larger than u_noise on average.
//! - the **noise part**, ρ less the integral of the exact gradients, against u_noise: its
//!   coverage must be consistent with 0.683 (within 3 standard errors). The fits' small coherent
//!   displacement bias (~1e-3 px, about 0.2 u_noise once integrated) stays in it
//!   (0.668 ± 0.010 over 36 campaigns).
//!
//! The coverage of the total error against u_ρ must be consistent with 0.683 (within 3
//! standard errors; 0.675 ± 0.010 over 36 campaigns); the discretisation error must stay below
//! 0.2 u_noise RMS and its estimate must track it (RMS of `|δ| − |error|` below half the
//! error's RMS); the RMS of the noise part's standardised error must lie within
//! [0.9, 1.15], and that of the total error below that of the displacements, `(d − d_true)/u_d`
//! (1.13: u_d is estimated from a 10-image stack, Student's t₉ has RMS √(9/7) = 1.134). Weights
//! `1/u_d²` taken dot by dot would carry that estimation noise into the integration (the dots
//! whose u_d came out small get too much weight, and `(AᵀWA)⁻¹` under-states: coverage 0.61,
//! RMS z 1.19); the pipeline pools u_d over each dot's 5 × 5 lattice neighbourhood in units of
//! its exact bound (`density::pool_uncertainties`; the pooled u_d has RMS z 1.00).
//!
//! A band over the left third is 2.2× dimmer (u_d larger there) and the blur makes AR grow to
//! about 2 at the centre: with u_d varying across the field WLS must be at least as accurate as
//! Poisson (it is ~11 % better here: RMS error 0.192 % against 0.216 % of the peak).
//!
//! `cargo test --release -p bostrack-pipeline --test density -- --nocapture` prints the numbers.

use bostrack_density::{IntegrationConfig, Method, Node, NodeStatus, integrate};
use bostrack_pipeline::{PipelineConfig, Plan, ReferenceContext, frame_nodes, integrate_frame};
use bostrack_synth::{DisplacementField, FlowConfig, Scene, SceneConfig, stack};
use std::path::Path;

#[path = "common/bump.rs"]
mod bump;
use bump::{AMPLITUDE, config};

/// A plan whose files are placeholders (the images are handed over in memory).
fn plan(cfg: PipelineConfig, dir: &Path) -> Plan {
    plan_in(cfg, dir).unwrap()
}

fn plan_in(cfg: PipelineConfig, dir: &Path) -> Result<Plan, bostrack_pipeline::ConfigError> {
    for d in ["gradient", "stack"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    for f in ["reference.tif", "gradient/g.tif", "stack/s.tif"] {
        std::fs::write(dir.join(f), b"").unwrap();
    }
    let mut cfg = cfg;
    cfg.input.dir = ".".into();
    Plan::from_config(cfg, &dir.join("pipeline.toml"))
}

/// Per method: squared errors, squared standardised errors, covered count, count.
#[derive(Default, Debug, Clone, Copy)]
struct Tally {
    e2: f64,
    z2: f64,
    covered: usize,
    n: usize,
}

/// Mean and standard error (spread between campaigns / √campaigns) of per-campaign values.
fn mean_and_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    (mean, sd / n.sqrt())
}

#[test]
fn density_of_a_gaussian_bump_campaign() {
    let dir = tempfile::tempdir().unwrap();
    let plan = plan(config(), dir.path());
    let dp = plan.density.clone().unwrap();
    // ρ − ρ_ref of the bump: d_px = −(S / (pitch · m_plane)) ∇_px ρ and d = A ∇_px φ
    let peak = AMPLITUDE * dp.pitch_m / dp.sensitivity_m * dp.pitch_m / dp.magnification_density;
    let truth = |p: [f64; 2]| dp.reference_density + bump::density_deficit(p, peak);
    let campaigns = 12;
    let mut tally = [Tally::default(); 2];
    // per campaign (WLS): coverage of the total error, of its noise part, and the coverage the
    // discretisation error predicts
    let (mut per_campaign, mut per_noise) = (Vec::new(), Vec::new());
    let (mut noise, mut trunc_z2, mut miss_z2, mut delta_z2) = (Tally::default(), 0.0, 0.0, 0.0);
    let mut max_ar = 0.0f64;
    let (mut disp_z2, mut disp_n) = (0.0, 0usize);
    for seed in 0..campaigns {
        let res = bump::run(&plan, seed);
        let physical = res.physical.as_ref().unwrap();
        // the displacement errors against the truth, standardised by u_d: what the density
        // inherits (u_ρ is exact given u_d, see bostrack-density's Monte Carlo test)
        for d in res.dots.iter().filter(|d| d.valid) {
            let t = bump::displacement(d.reference_position.unwrap());
            let (e, u) = (d.displacement.unwrap(), d.u_d.unwrap());
            disp_z2 += ((e[0] - t[0]) / u[0]).powi(2) + ((e[1] - t[1]) / u[1]).powi(2);
            disp_n += 2;
        }
        for d in res.dots.iter().filter(|d| d.valid) {
            if let Some(ar) = d.ar {
                max_ar = max_ar.max(ar[0]).max(ar[1]);
            }
        }
        // the discretisation error: the exact gradients on the same nodes (weights, positions)
        let (nodes, node_of) = frame_nodes(&res.dots, physical, None, Path::new("g.tif")).unwrap();
        let mut exact: Vec<Node> = nodes.clone();
        let per_px = dp.pitch_m / dp.sensitivity_m;
        for (d, &k) in res.dots.iter().zip(&node_of) {
            if k != usize::MAX {
                let t = bump::displacement(d.reference_position.unwrap());
                exact[k].gradient = [-t[0] * per_px, -t[1] * per_px];
            }
        }
        let icfg = IntegrationConfig {
            reference_density: dp.reference_density,
            ..IntegrationConfig::default()
        };
        let discretised = integrate(&exact, &icfg).unwrap();
        // the pipeline's field (the same nodes), with the parts of u_ρ
        let measured = integrate(&nodes, &icfg).unwrap();
        let wls = res.density.as_ref().unwrap();
        let mut t_noise = Tally::default();
        for (d, (&k, (rho, u, status))) in res.dots.iter().zip(node_of.iter().zip(&wls.nodes)) {
            if *status != Some(NodeStatus::Solved) {
                continue;
            }
            // u_ρ = the noise's u and the truncation estimate |δ| in quadrature
            let (u, delta) = (u.unwrap(), measured.nodes[k].u_truncation.unwrap());
            assert!((measured.nodes[k].u_rho.unwrap() - u).abs() <= 1e-12 * u);
            let u_noise = (u * u - delta * delta).sqrt();
            let smooth = &discretised.nodes[k];
            let trunc = smooth.rho.unwrap() - truth(d.reference_position.unwrap());
            let e = rho.unwrap() - smooth.rho.unwrap();
            t_noise.z2 += (e / u_noise).powi(2);
            t_noise.covered += usize::from(e.abs() <= u_noise);
            t_noise.n += 1;
            trunc_z2 += (trunc / u_noise).powi(2);
            // the estimate from the exact gradients against the error it estimates
            miss_z2 += ((smooth.u_truncation.unwrap() - trunc.abs()) / u_noise).powi(2);
            delta_z2 += (delta / u_noise).powi(2);
        }
        per_noise.push(t_noise.covered as f64 / t_noise.n as f64);
        noise.z2 += t_noise.z2;
        noise.covered += t_noise.covered;
        noise.n += t_noise.n;
        let mut covered = 0.0;
        for (m, method) in [Method::Wls, Method::Poisson].into_iter().enumerate() {
            let field = if method == Method::Wls {
                res.density.clone().unwrap()
            } else {
                let mut p = dp.clone();
                p.method = method;
                integrate_frame(&p, &res.dots, physical, None, Path::new("g.tif")).unwrap()
            };
            let s = field.summary.clone();
            assert_eq!(s.islands_without_reference, 0);
            assert!(s.solved > 1000, "{s:?}");
            let mut t = Tally::default();
            for (d, (rho, u, status)) in res.dots.iter().zip(&field.nodes) {
                if *status != Some(bostrack_density::NodeStatus::Solved) {
                    continue;
                }
                let e = rho.unwrap() - truth(d.reference_position.unwrap());
                let u = u.unwrap();
                t.e2 += e * e;
                t.z2 += (e / u).powi(2);
                t.covered += usize::from(e.abs() <= u);
                t.n += 1;
            }
            let rms = (t.e2 / t.n as f64).sqrt() / peak;
            eprintln!(
                "campaign {seed} {}: rms error {:.2} % of the peak ({peak:.4} kg/m3), rms z {:.2}, coverage {:.3}, median u_rho {:.2e}",
                method.name(),
                100.0 * rms,
                (t.z2 / t.n as f64).sqrt(),
                t.covered as f64 / t.n as f64,
                s.median_u_rho.unwrap()
            );
            assert!(rms < 0.02, "{}: rms error {rms} of the peak", method.name());
            if method == Method::Wls {
                covered = t.covered as f64 / t.n as f64;
            }
            let all = &mut tally[m];
            all.e2 += t.e2;
            all.z2 += t.z2;
            all.covered += t.covered;
            all.n += t.n;
        }
        per_campaign.push(covered);
    }
    let [wls, poisson] = tally;
    let (coverage, se) = mean_and_se(&per_campaign);
    let (noise_coverage, noise_se) = mean_and_se(&per_noise);
    let z_rms = (wls.z2 / wls.n as f64).sqrt();
    let noise_z = (noise.z2 / noise.n as f64).sqrt();
    let trunc_z = (trunc_z2 / noise.n as f64).sqrt();
    let miss_z = (miss_z2 / noise.n as f64).sqrt();
    let delta_z = (delta_z2 / noise.n as f64).sqrt();
    let rms = |t: &Tally| (t.e2 / t.n as f64).sqrt() / peak;
    let disp_z = (disp_z2 / disp_n as f64).sqrt();
    eprintln!(
        "pooled: displacement rms z {disp_z:.3}; max AR {max_ar:.2}; rms error WLS {:.3} %, Poisson {:.3} % of the peak; Poisson coverage {:.3}, rms z {:.3}",
        100.0 * rms(&wls),
        100.0 * rms(&poisson),
        poisson.covered as f64 / poisson.n as f64,
        (poisson.z2 / poisson.n as f64).sqrt()
    );
    eprintln!(
        "WLS coverage (mean of {campaigns} campaigns ± standard error between them): total {coverage:.3} ± {se:.3} (rms z {z_rms:.3}); noise part {noise_coverage:.3} ± {noise_se:.3} (rms z {noise_z:.3}, against u_noise); discretisation error rms {trunc_z:.3} u_noise, its estimate |delta| rms {delta_z:.3} u_noise (from the exact gradients: rms of |delta| - |error| {miss_z:.3} u_noise)"
    );
    assert!(max_ar > 1.6, "the blur does not vary AR enough: {max_ar}");
    assert!(rms(&wls) <= rms(&poisson), "WLS less accurate than Poisson");
    // u_ρ holds the noise: its part of the error covers as a normal error does
    assert!(
        (noise_coverage - 0.683).abs() < 3.0 * noise_se,
        "noise part coverage {noise_coverage} ± {noise_se}"
    );
    assert!((0.9..1.15).contains(&noise_z), "noise part rms z {noise_z}");
    // the fourth-order stencils' discretisation error is small, and u_ρ's estimate of it
    // tracks it (from the exact gradients, where it is the only error)
    assert!(trunc_z < 0.2, "discretisation error rms {trunc_z} u_noise");
    assert!(
        miss_z < 0.5 * trunc_z,
        "truncation estimate: rms of |delta| - |error| {miss_z}, error {trunc_z}"
    );
    // the total error against u_ρ (noise and discretisation): the acceptance
    assert!(
        (coverage - 0.683).abs() < 3.0 * se,
        "coverage {coverage} ± {se}"
    );
    // pooled weights: the density does not inherit the t₉ noise of the per-dot u_d
    assert!(
        z_rms < disp_z,
        "rms z: density {z_rms}, displacement {disp_z}"
    );
}

/// A campaign folder with placeholder files and `pipeline.toml` = `text` after the `[input]`
/// lines; the plan or its error.
fn plan_of(text: &str) -> Result<Plan, bostrack_pipeline::ConfigError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pipeline.toml");
    std::fs::write(&path, text).unwrap();
    plan_in(bostrack_pipeline::load_config(&path)?, dir.path())
}

/// Missing or non-physical optics, a density field behind the lens's focal point, [density]
/// without [optics], a setup the measurement cannot use: each a clear error naming the key.
#[test]
fn bad_optical_setups_are_clear_errors() {
    let good = "[optics]\npixel_pitch_um = 6.5\nfocal_length_mm = 105.0\ntarget_distance_m = 1.5\n\
                [geometry]\nkind = \"bos\"\nz_d_m = 0.5\ndelta_z_m = 0.05\n";
    let p = plan_of(good).unwrap();
    let d = p.density.unwrap();
    assert!((d.magnification - 0.105 / 1.395).abs() < 1e-12);
    assert!((d.magnification_density - 0.105 / 0.895).abs() < 1e-12);
    // without the sections: nothing of it
    assert!(plan_of("").unwrap().density.is_none());
    let cases: [(String, &str, &str); 9] = [
        // u_d needs a no-flow stack
        (
            format!("[input]\nstack_dir = \"\"\n{good}"),
            "input.stack_dir",
            "no-flow stack",
        ),
        (
            good.replace("pixel_pitch_um = 6.5\n", ""),
            "optics.pixel_pitch_um",
            "missing",
        ),
        (
            good.replace("focal_length_mm = 105.0\n", ""),
            "optics.magnification",
            "missing",
        ),
        (good.replace("z_d_m = 0.5\n", ""), "z_d_m", "missing"),
        (
            good.replace("z_d_m = 0.5", "z_d_m = -0.5"),
            "geometry.z_d_m",
            "> 0",
        ),
        (
            good.replace("target_distance_m = 1.5", "target_distance_m = -1.5"),
            "optics.target_distance_m",
            "> 0",
        ),
        // Z_D >= Z_B: the slab behind the lens
        (
            good.replace("z_d_m = 0.5", "z_d_m = 1.6"),
            "geometry",
            "between the target and the lens",
        ),
        (
            "[density]\nmethod = \"poisson\"\n".into(),
            "optics",
            "densities need the optical setup",
        ),
        (
            format!("{good}[output]\nquantities = \"displacement\"\n"),
            "output.quantities",
            "uncertainty",
        ),
    ];
    for (text, key, words) in cases {
        let e = plan_of(&text).unwrap_err().to_string();
        assert!(e.contains(key) && e.contains(words), "{key}: {e}");
        assert!(e.contains("pipeline.toml"), "{e}");
    }
    // a quiescent-gas mask that is not there
    let e = plan_of(&format!(
        "{good}[density]\nreference_mask = \"quiet.png\"\n"
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("density.reference_mask") && e.contains("quiet.png"),
        "{e}"
    );
}

/// No Dirichlet node in a frame (a quiescent-gas mask over no valid dot): the frame fails with
/// a clear message and nothing of it is written.
#[test]
fn a_frame_without_a_dirichlet_node_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let camp = dir.path();
    let sc = SceneConfig {
        width: 96,
        height: 96,
        ..Default::default()
    };
    let flow = FlowConfig {
        displacement: DisplacementField::Uniform { dx: 0.2, dy: 0.0 },
        ..Default::default()
    };
    std::fs::create_dir_all(camp.join("gradient")).unwrap();
    std::fs::create_dir_all(camp.join("stack")).unwrap();
    bostrack_io::write_tiff_u16(
        &camp.join("reference.tif"),
        &Scene::reference(&sc).unwrap().image,
    )
    .unwrap();
    bostrack_io::write_tiff_u16(
        &camp.join("gradient/f1.tif"),
        &Scene::gradient(&sc, &flow).unwrap().image,
    )
    .unwrap();
    for (k, img) in stack(&sc, 3).unwrap().iter().enumerate() {
        bostrack_io::write_tiff_u16(&camp.join(format!("stack/s{k}.tif")), img).unwrap();
    }
    // a mask that keeps only a few pixels between four dots (one every 8 px from (0, 0))
    let between = |v: usize| (3..5).contains(&v);
    let quiet = bostrack_core::Image::from_fn(96, 96, |x, y| {
        if between(x) && between(y) {
            65535.0
        } else {
            0.0
        }
    });
    bostrack_io::write_tiff_u16(&camp.join("quiet.tif"), &quiet).unwrap();
    std::fs::write(
        camp.join("pipeline.toml"),
        "[detect]\nspacing = 8.0\n[optics]\npixel_pitch_um = 6.5\nmagnification = 0.1\n\
         [geometry]\nkind = \"bos\"\nz_d_m = 0.5\ndelta_z_m = 0.05\n\
         [density]\nreference_mask = \"quiet.tif\"\n",
    )
    .unwrap();
    let plan = Plan::load(&camp.join("pipeline.toml")).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    let e = match bostrack_pipeline::process_frame(&ctx, &plan, &plan.gradients[0]) {
        Err(e) => e,
        Ok(r) => panic!("integrated: {:?}", r.summary.density),
    };
    let e = e.to_string();
    assert!(
        e.contains("no Dirichlet node") && e.contains("quiet.tif") && e.contains("f1.tif"),
        "{e}"
    );
    assert!(!camp.join("out/f1").exists());
}
