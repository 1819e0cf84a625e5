//! Experiment-design sweeps: invariants of each sweep and the direction of the trade-offs.

use bostrack_theory::*;

fn testdata() -> Setup {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/crlb-setup.toml"
    );
    Setup::from_toml(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn rel(a: f64, b: f64) -> f64 {
    (a / b - 1.0).abs()
}

#[test]
fn f_number_sweep() {
    let s = testdata();
    let f = [4.0, 5.6, 8.0, 11.0, 16.0, 22.0];
    let rows = sweep_f_number(&s, &f, ExposureScaling::Fixed).unwrap();
    assert_eq!(rows.len(), f.len());
    let base = predict(&s).unwrap();
    let at11 = &rows[3];
    assert_eq!(
        (at11.crlb_x, at11.ar_x, at11.sigma_x),
        (base.crlb_x, base.ar_x, base.sigma_x)
    );
    for w in rows.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        // the shift does not depend on the aperture; the geometric cone ∝ 1/f#; the diffraction
        // spot grows; the blur and the amplification shrink
        assert_eq!((a.shift_x, a.shift_y), (b.shift_x, b.shift_y));
        assert!(b.reference_diameter_px > a.reference_diameter_px);
        assert!(
            b.sigma_x.powi(2) - b.reference_diameter_px.powi(2) / 16.0
                < a.sigma_x.powi(2) - a.reference_diameter_px.powi(2) / 16.0
        );
        assert!(b.ar_x < a.ar_x && b.ar_y < a.ar_y && b.rho < a.rho);
        assert_eq!(a.exposure, b.exposure);
    }
    // at fixed exposure the bound has a minimum: blur dominates at small f#, diffraction at large
    let best = rows
        .iter()
        .min_by(|a, b| a.crlb_x.total_cmp(&b.crlb_x))
        .unwrap();
    assert!(
        best.f_number > 4.0 && best.f_number < 22.0,
        "best f/{}",
        best.f_number
    );
    // at fixed illumination the exposure falls as 1/f#² and the reference bound grows with f#
    let dim = sweep_f_number(&s, &f, ExposureScaling::Aperture).unwrap();
    for (r, fnum) in dim.iter().zip(f) {
        assert!(rel(r.exposure * fnum * fnum, base.exposure * 121.0) < 1e-12);
    }
    assert!(dim.windows(2).all(|w| w[1].crlb_ref_x > w[0].crlb_ref_x));
    assert!(sweep_f_number(&s, &[8.0, -1.0], ExposureScaling::Fixed).is_err());
}

#[test]
fn z_d_sweep_at_fixed_sensitivity() {
    let s = testdata();
    let base = predict(&s).unwrap();
    let z = [0.2, 0.3, 0.5, 0.7, 0.9, 1.2];
    let rows = sweep_z_d(&s, &z, ZdHold::Sensitivity, ExposureScaling::Fixed).unwrap();
    let mz = base.magnification * 0.5;
    for (r, zd) in rows.iter().zip(z) {
        assert_eq!(r.z_d_m, Some(zd));
        assert!(rel(r.m_z_d_m.unwrap(), mz) < 1e-12);
        assert!(rel(r.shift_x, base.shift_x) < 1e-12 && rel(r.shift_y, base.shift_y) < 1e-12);
    }
    assert_eq!(rows[2].crlb_x, base.crlb_x);
    // the diffraction spot shrinks as M+1 falls; with the geometric cone the blur std is
    // S (Z_D Δθ0) ∝ M Z_D / ((1+M) f#): it grows slowly as M falls (with Eq. 24 the gradient
    // term, K Δz (gx + gy) Z_D / (2 n0), grows with Z_D and works against it)
    let blur = |r: &SweepRow| r.sigma_x.powi(2) - r.reference_diameter_px.powi(2) / 16.0;
    assert!(
        rows.windows(2)
            .all(|w| w[1].reference_diameter_px < w[0].reference_diameter_px)
    );
    let mut g = s.clone();
    g.optics.cone_angle = ConeAngleModel::Geometric;
    let rows = sweep_z_d(&g, &z, ZdHold::Sensitivity, ExposureScaling::Fixed).unwrap();
    for w in rows.windows(2) {
        assert!(blur(&w[1]) > blur(&w[0]));
        let m = |r: &SweepRow| r.magnification / (1.0 + r.magnification);
        let ratio = (blur(&w[1]) / blur(&w[0])).sqrt()
            / (m(&w[1]) * w[1].z_d_m.unwrap() / (m(&w[0]) * w[0].z_d_m.unwrap()));
        assert!((ratio - 1.0).abs() < 1e-9, "{ratio}");
    }
    // the slab must stay between target and lens
    assert!(sweep_z_d(&s, &[1.49], ZdHold::Sensitivity, ExposureScaling::Fixed).is_err());
    assert!(sweep_z_d(&s, &[0.01], ZdHold::Sensitivity, ExposureScaling::Fixed).is_err());
    let mut v = s.clone();
    v.geometry = Geometry::Volumetric { depth_m: 0.001 };
    assert!(matches!(
        sweep_z_d(&v, &[0.5], ZdHold::Sensitivity, ExposureScaling::Fixed),
        Err(TheoryError::Unsupported(_))
    ));
}

/// Sec. 2.3: a larger sensitivity M·Z_D moves the dot further but blurs it more; the shift over
/// its uncertainty peaks at an intermediate Z_D.
#[test]
fn z_d_sweep_at_fixed_magnification_has_an_optimum() {
    let s = testdata();
    let z = [0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 1.2];
    let rows = sweep_z_d(&s, &z, ZdHold::Magnification, ExposureScaling::Fixed).unwrap();
    let base = predict(&s).unwrap();
    for (r, zd) in rows.iter().zip(z) {
        assert_eq!(r.magnification, base.magnification);
        assert!(rel(r.shift_x, base.shift_x * zd / 0.5) < 1e-12);
        assert!(rel(r.u_d_x, r.crlb_x.hypot(r.crlb_ref_x)) < 1e-15);
    }
    assert!(rows.windows(2).all(|w| w[1].crlb_x > w[0].crlb_x));
    let best = rows
        .iter()
        .max_by(|a, b| a.snr_x.total_cmp(&b.snr_x))
        .unwrap();
    let zbest = best.z_d_m.unwrap();
    assert!(zbest > 0.1 && zbest < 1.2, "optimum at {zbest}");
    assert!(rows[0].snr_x < best.snr_x && rows[6].snr_x < best.snr_x);
}
