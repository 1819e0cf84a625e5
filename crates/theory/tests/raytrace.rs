//! The ray tracer against the effective model: convergence where the model's assumptions hold,
//! and the direction in which it fails where they do not (docs/theory.md, ray-tracing table).

use bostrack_theory::*;

fn testdata() -> Setup {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/crlb-setup.toml"
    );
    let mut s = Setup::from_toml(&std::fs::read_to_string(path).unwrap()).unwrap();
    // the tracer's cone is geometric; compare like with like unless a test says otherwise
    s.optics.cone_angle = ConeAngleModel::Geometric;
    s
}

fn trace(s: &Setup, rays: usize, propagation: Propagation) -> RayTrace {
    ray_trace(
        s,
        &RayTraceConfig {
            rays,
            propagation,
            ..Default::default()
        },
    )
    .unwrap()
}

fn rel(a: f64, b: f64) -> f64 {
    (a / b - 1.0).abs()
}

/// Largest relative error of the traced dot's (σx, σy) and absolute error of (x0, y0, ρ)
/// against the prediction.
fn errors(p: &Prediction, m: &DotMoments) -> (f64, f64) {
    let rel_sigma = rel(m.sigma_x, p.sigma_x).max(rel(m.sigma_y, p.sigma_y));
    let abs = (m.x0 - p.shift_x)
        .abs()
        .max((m.y0 - p.shift_y).abs())
        .max((m.rho - p.rho).abs());
    (rel_sigma, abs)
}

#[test]
fn deterministic_for_a_seed() {
    let s = testdata();
    let cfg = RayTraceConfig {
        rays: 2500,
        seed: 7,
        ..Default::default()
    };
    let a = ray_trace(&s, &cfg).unwrap();
    let b = ray_trace(&s, &cfg).unwrap();
    assert_eq!(a, b);
    let c = ray_trace(&s, &RayTraceConfig { seed: 8, ..cfg }).unwrap();
    assert_ne!(a.image, c.image);
    assert_eq!(a.rays, 2500);
    // 2000 rays are rounded up to a 45 x 45 grid
    assert_eq!(
        ray_trace(&s, &RayTraceConfig { rays: 2000, ..cfg })
            .unwrap()
            .rays,
        2025
    );
}

/// Where the assumptions hold (quadratic field, straight rays through a thin slab, the
/// model's aperture distribution), the traced moments converge to Eqs. 18, 25-26 and the
/// cross term, for both pupils, and the pixels carry the same moments.
#[test]
fn converges_to_the_effective_model() {
    for aperture in [Aperture::Square, Aperture::Circular] {
        let mut s = testdata();
        s.optics.aperture = aperture;
        let p = predict(&s).unwrap();
        assert!(p.rho > 0.05, "a correlated dot: {}", p.rho);
        let coarse = trace(&s, 100, Propagation::ThinSlab);
        let fine = trace(&s, 40_000, Propagation::ThinSlab);
        let (ec, _) = errors(&p, &coarse.dot);
        let (es, ea) = errors(&p, &fine.dot);
        assert!(es < 2e-4 && ea < 2e-4, "{aperture:?}: {es} {ea}");
        assert!(es < ec, "more rays, closer: {es} vs {ec}");
        // pixel moments (Sheppard-corrected) agree with the continuous ones
        let (ei, eia) = errors(&p, &fine.image_moments);
        assert!(ei < 3e-4 && eia < 3e-4, "{ei} {eia}");
        let (k, ki) = (
            fine.dot.excess_kurtosis_x,
            fine.image_moments.excess_kurtosis_x,
        );
        assert!(
            k < -0.03 && (k - ki).abs() < 1e-3,
            "kurtosis {k} vs pixels {ki}"
        );
        assert!((fine.captured - 1.0).abs() < 1e-9);
        // a mildly blurred dot is close to Gaussian
        assert!(fine.gaussian_residual < 0.02, "{}", fine.gaussian_residual);
    }
}

/// Viewing angles: the field is rotated into the camera frame (Eq. 9-10) by both the model and
/// the tracer; the tracer evaluates the full 3-D quadratic field, including its z terms.
#[test]
fn converges_with_viewing_angles() {
    let mut s = testdata();
    s.view = View {
        pitch_deg: -10.0,
        yaw_deg: 20.0,
        roll_deg: 30.0,
    };
    s.flow.gradient_kg_m4[2] = 25.0;
    s.flow.hessian_kg_m5 = Hessian {
        xx: 12000.0,
        xy: 4000.0,
        yy: 3000.0,
        zz: 5000.0,
        xz: -3000.0,
        yz: 2000.0,
    };
    let p = predict(&s).unwrap();
    let head_on = predict(&Setup {
        view: View::default(),
        ..s.clone()
    })
    .unwrap();
    assert!(
        (p.shift_y - head_on.shift_y).abs() > 1.0,
        "the view matters"
    );
    let r = trace(&s, 40_000, Propagation::ThinSlab);
    let (es, ea) = errors(&p, &r.dot);
    assert!(es < 2e-4 && ea < 2e-4, "{es} {ea}");
}

/// Integrating the ray equation through the slab: for the example setup (50 mm slab) the
/// thin-slab model holds to 0.2 %; the field's variation along the line of sight adds the
/// lever-weighted term `(M K / (n0 d_r)) ρxz Δz³ / 12` to the shift, which the mid-plane
/// gradient of Eq. 6 misses.
#[test]
fn slab_integration_and_the_lever_weighted_path_average() {
    let s = testdata();
    let p = predict(&s).unwrap();
    let r = trace(&s, 10_000, Propagation::Slab { steps: 32 });
    let (es, ea) = errors(&p, &r.dot);
    assert!(es < 2e-3 && ea < 0.005, "{es} {ea}");
    // ρxz alone (with curvature across the line of sight as well, the rays bent by ρxz see
    // ρxx: the extra shift is then 3.6 % smaller here)
    let mut v = s.clone();
    v.flow.hessian_kg_m5 = Hessian {
        xz: 5000.0,
        ..Default::default()
    };
    let pv = predict(&v).unwrap();
    assert_eq!(pv.shift_x, p.shift_x, "the model ignores ρxz");
    let rv = trace(&v, 2_500, Propagation::Slab { steps: 32 });
    let extra = pv.magnification * 0.225e-3 / (1.000278 * 6.5e-6) * 5000.0 * 0.05f64.powi(3) / 12.0;
    let got = rv.dot.x0 - pv.shift_x;
    assert!(rel(got, extra) < 0.005, "extra shift {got} vs {extra}");
    // the thin-slab tracer evaluates the mid-plane only and misses it too
    let tv = trace(&v, 2_500, Propagation::ThinSlab);
    assert!((tv.dot.x0 - pv.shift_x).abs() < 1e-3);
}

/// Breakdown 1 (Eq. 24, NOTES.md §4): strong first derivatives shrink the paper's cone angle
/// until it is clamped, so the model's blur vanishes; the traced blur does not depend on the
/// first derivatives at all.
#[test]
fn eq24_cone_term_under_predicts_the_blur() {
    let mut s = testdata();
    s.optics.cone_angle = ConeAngleModel::Paper;
    let mut last_paper = f64::INFINITY;
    let mut traced = Vec::new();
    for gx in [40.0, 400.0, 800.0, 1500.0] {
        s.flow.gradient_kg_m4 = [gx, 15.0, 0.0];
        let p = predict(&s).unwrap();
        let geo = predict(&Setup {
            optics: Optics {
                cone_angle: ConeAngleModel::Geometric,
                ..s.optics.clone()
            },
            ..s.clone()
        })
        .unwrap();
        let r = trace(&s, 2_500, Propagation::ThinSlab);
        // the tracer follows the geometric cone, whatever the gradient
        assert!(
            rel(r.dot.sigma_x, geo.sigma_x) < 2e-3,
            "gx {gx}: {} vs {}",
            r.dot.sigma_x,
            geo.sigma_x
        );
        // the paper's blur shrinks as the gradient grows, below the traced one
        assert!(p.sigma_x < last_paper && p.sigma_x <= r.dot.sigma_x);
        last_paper = p.sigma_x;
        traced.push(r.dot.sigma_x);
        if gx == 1500.0 {
            assert!(p.flags.contains(TheoryFlags::CONE_CLAMPED));
            assert_eq!(p.sigma_x, p.reference.sigma_x);
            assert!(r.dot.sigma_x > 1.1 * p.sigma_x);
        }
    }
    assert!(traced.iter().all(|t| rel(*t, traced[0]) < 2e-3));
}

/// Breakdown 2: a thick slab with curvature. Rays bend inside the slab and see the gradient
/// where they are, not where the straight ray would be: a field with a density minimum
/// (ρxx > 0, a diverging lens) spreads the rays further and blurs more than predicted; a
/// maximum (converging) blurs less. The error grows with K ρxx Δz².
#[test]
fn thick_curved_slab_departs_from_the_thin_model() {
    let mut s = testdata();
    s.flow.gradient_kg_m4 = [0.0; 3];
    let blur_ratio = |s: &Setup| {
        let p = predict(s).unwrap();
        let r = trace(s, 2_500, Propagation::Slab { steps: 64 });
        r.landing.sigma_x / p.blur_covariance[0].sqrt()
    };
    let mut above: Vec<(f64, f64)> = Vec::new();
    for dz in [0.05, 0.3, 0.8] {
        s.geometry = Geometry::Bos {
            z_d_m: 0.5,
            delta_z_m: dz,
        };
        s.flow.hessian_kg_m5 = Hessian {
            xx: 12000.0,
            ..Default::default()
        };
        let plus = blur_ratio(&s);
        s.flow.hessian_kg_m5.xx = -12000.0;
        let minus = blur_ratio(&s);
        if dz > 0.1 {
            assert!(plus > 1.0 && minus < 1.0, "dz {dz}: {plus} {minus}");
        }
        above.push((plus - 1.0, minus - 1.0));
    }
    let [(p0, m0), (p1, m1), (p2, m2)] = above[..] else {
        unreachable!()
    };
    assert!(p0.abs() < 0.005 && m0.abs() < 0.005, "{above:?}");
    assert!(
        p1 > 0.02 && m1 < -0.002 && p2 > 0.2 && m2 < -0.01,
        "{above:?}"
    );
}

/// Breakdown 3: strong second derivatives. The moments still follow the model (a quadratic
/// field maps the aperture linearly), but the dot takes the aperture's shape: the excess
/// kurtosis heads for the uniform distribution's -1.2 and the Gaussian no longer fits.
#[test]
fn strong_curvature_makes_the_dot_non_gaussian() {
    let mut s = testdata();
    let mut residuals = Vec::new();
    for hxx in [6000.0, 25000.0, 100000.0] {
        s.flow.hessian_kg_m5 = Hessian {
            xx: hxx,
            ..Default::default()
        };
        let p = predict(&s).unwrap();
        let r = trace(&s, 10_000, Propagation::ThinSlab);
        let (es, _) = errors(&p, &r.dot);
        assert!(es < 1e-3, "moments hold: {es}");
        let ratio = (p.blur_covariance[0]).sqrt() / p.reference.sigma_x;
        assert_eq!(p.flags.contains(TheoryFlags::NON_GAUSSIAN), ratio > 1.0);
        residuals.push((ratio, r.gaussian_residual, r.dot.excess_kurtosis_x));
    }
    let [(r0, g0, k0), (r1, g1, k1), (r2, g2, k2)] = residuals[..] else {
        unreachable!()
    };
    assert!(r0 < 0.5 && g0 < 0.002 && k0 > -0.02, "{residuals:?}");
    assert!(r1 > 1.0 && g1 > 0.04 && k1 < -0.3, "{residuals:?}");
    assert!(r2 > 4.0 && g2 > 0.2 && k2 < -1.0, "{residuals:?}");
    assert!(g0 < g1 && g1 < g2);
}

#[test]
fn bad_requests_are_errors() {
    let mut s = testdata();
    assert!(
        ray_trace(
            &s,
            &RayTraceConfig {
                rays: 0,
                ..Default::default()
            }
        )
        .is_err()
    );
    assert!(
        ray_trace(
            &s,
            &RayTraceConfig {
                propagation: Propagation::Slab { steps: 0 },
                ..Default::default()
            }
        )
        .is_err()
    );
    s.geometry = Geometry::Volumetric { depth_m: 0.001 };
    assert!(matches!(
        ray_trace(&s, &RayTraceConfig::default()),
        Err(TheoryError::Unsupported(_))
    ));
    let cfg: RayTraceConfig =
        toml::from_str("rays = 100\npropagation = { kind = \"slab\", steps = 8 }").unwrap();
    assert_eq!(cfg.propagation, Propagation::Slab { steps: 8 });
    assert!(toml::from_str::<RayTraceConfig>("ray = 100").is_err());
}
