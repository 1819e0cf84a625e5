//! The setup → prediction chain against hand-computed values and the limits of paper Sec. 2.3.

use bostrack_theory::*;
use std::f64::consts::PI;

const SETUP: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../testdata/crlb-setup.toml"
);

fn testdata() -> Setup {
    let text = std::fs::read_to_string(SETUP).expect("testdata/crlb-setup.toml");
    Setup::from_toml(&text).expect("the example setup is valid")
}

/// A setup with round numbers: M = 0.1, f/8, Z_D = 0.4 m, Δz = 0.04 m, 10 µm pixels,
/// reference dot 4σ = 6 px, K = 2e-4, n0 = 1.
fn round_setup() -> Setup {
    Setup::from_toml(
        r#"
        [optics]
        f_number = 8.0
        magnification = 0.1
        pixel_pitch_um = 10.0
        diffraction_diameter_px = 6.0
        cone_angle = "geometric"
        [geometry]
        kind = "bos"
        z_d_m = 0.4
        delta_z_m = 0.04
        [camera]
        peak_counts = 800.0
        read_noise_counts = 8.0
        [constants]
        gladstone_dale_m3_kg = 2e-4
        n0 = 1.0
        "#,
    )
    .unwrap()
}

fn rel(a: f64, b: f64) -> f64 {
    (a / b - 1.0).abs()
}

#[test]
fn testdata_setup_parses_and_predicts() {
    let s = testdata();
    assert_eq!(s.optics.f_number, 11.0);
    assert_eq!(s.flow.hessian_kg_m5.xx, 12000.0);
    let p = predict(&s).unwrap();
    // Eq. 5: 0.105 / (1.5 - 0.105); Eq. 6: M K Z_D Δz / (n0 d_r)
    let m = 0.105 / 1.395;
    assert!(rel(p.magnification, m) < 1e-12);
    let sens = m * 0.225e-3 * 0.5 * 0.05 / 1.000278 / 6.5e-6;
    assert!(rel(p.sensitivity_px, sens) < 1e-12);
    assert!(rel(p.shift_x, -40.0 * sens) < 1e-12 && rel(p.shift_y, -15.0 * sens) < 1e-12);
    // reference dot: diffraction 2.44 f# (M+1) λ and the printed 0.4 mm dot, in quadrature
    let d_diff = 2.44 * 11.0 * (1.0 + m) * 532e-9 / 6.5e-6;
    let d_dot = m * 0.4e-3 / 6.5e-6;
    assert!(rel(p.diffraction_diameter_px, d_diff) < 1e-12);
    assert!(rel(p.reference_diameter_px, d_diff.hypot(d_dot)) < 1e-12);
    // a heated plume: a shift of a few px, blur along x mostly, a mild correlation
    assert!(p.shift_x < -2.0 && p.sigma_x > p.sigma_y && p.sigma_y > p.reference.sigma_x);
    assert!(p.rho > 0.0 && p.rho < 0.2);
    assert!(p.flags.is_empty(), "{}", p.flags);
    // the bound grows, and the closed form is a few % under the exact bound (pixel
    // integration, NOTES.md §3)
    assert!(p.crlb_x > p.crlb_ref_x && p.ar_x > p.ar_y && p.ar_y > 1.0);
    for (e, c) in [
        (p.crlb_x, p.eq35_x),
        (p.crlb_y, p.eq35_y),
        (p.crlb_ref_x, p.eq35_ref),
    ] {
        assert!(e > c && rel(e, c) < 0.06, "exact {e} closed {c}");
    }
    // exposure conserved (Eq. 28)
    assert!(rel(p.gradient.volume(), p.exposure) < 1e-12);
    assert!(rel(p.reference.volume(), p.exposure) < 1e-12);
    assert!(rel(p.reference.amplitude, 1000.0) < 1e-12);
}

#[test]
fn formulas_against_hand_values() {
    let mut s = round_setup();
    s.flow.gradient_kg_m4 = [50.0, -20.0, 7.0];
    s.flow.hessian_kg_m5 = Hessian {
        xx: 30000.0,
        xy: 10000.0,
        yy: -5000.0,
        ..Default::default()
    };
    let p = predict(&s).unwrap();
    // S = 0.1 * 2e-4 * 0.4 * 0.04 / 1 / 1e-5 = 0.032 px per kg/m^4
    assert!(rel(p.sensitivity_px, 0.032) < 1e-12);
    assert!(rel(p.shift_x, -1.6) < 1e-12 && rel(p.shift_y, 0.64) < 1e-12);
    // Δθ0 = M/((1+M) f#) = 0.1/(1.1 * 8)
    let cone = 0.1 / 8.8;
    assert!(rel(p.cone_angle_rad, cone) < 1e-12);
    // Eq. 25/26: (1/12) (S ℓ Δθ0)² (...) with ℓ = Z_D = 0.4
    let k = (0.032 * 0.4 * cone).powi(2) / 12.0;
    let (bxx, bxy, byy) = (k * (9e8 + 1e8), k * 1e4 * 25000.0, k * (1e8 + 2.5e7));
    let (sxx, syy) = (1.5f64.powi(2) + bxx, 1.5f64.powi(2) + byy);
    assert!(rel(p.sigma_x, sxx.sqrt()) < 1e-12 && rel(p.sigma_y, syy.sqrt()) < 1e-12);
    assert!(rel(p.rho, bxy / (sxx * syy).sqrt()) < 1e-12);
    // Eq. 29 with Eq. 27: the exposure 2π 800 1.5² is conserved
    let e = 2.0 * PI * 800.0 * 2.25;
    assert!(rel(p.exposure, e) < 1e-12);
    assert!(
        rel(
            p.peak,
            e / (2.0 * PI * sxx.sqrt() * syy.sqrt() * (1.0 - p.rho * p.rho).sqrt())
        ) < 1e-12
    );
    // Eq. 35 generalised (NOTES.md §2)
    let b = 2.0 * (2.0 * PI).sqrt() * 8.0 / e;
    let f = (1.0 - p.rho * p.rho).powf(0.25);
    assert!(rel(p.eq35_x, b * sxx.powf(0.75) * syy.powf(0.25) * f) < 1e-12);
    assert!(rel(p.eq35_printed_y, b * syy.powf(0.75) * sxx.powf(0.25)) < 1e-12);
    assert!(rel(p.eq35_ref, b * 2.25) < 1e-12);
    // AR of NOTES.md §2 written out
    let ar_x = (800.0 / p.peak)
        * (sxx.sqrt() / 1.5 * 1.5 / syy.sqrt()).sqrt()
        * (1.0 / (1.0 - p.rho * p.rho)).powf(0.25);
    assert!(rel(p.ar_x, ar_x) < 1e-12);
}

#[test]
fn zero_derivatives_give_the_reference_dot() {
    let p = predict(&testdata().reference()).unwrap();
    assert_eq!((p.shift_x, p.shift_y), (0.0, 0.0));
    assert_eq!(p.blur_covariance, [0.0; 3]);
    assert_eq!(
        (p.sigma_x, p.sigma_y, p.rho),
        (p.reference.sigma_x, p.reference.sigma_y, 0.0)
    );
    assert_eq!((p.ar_x, p.ar_y), (1.0, 1.0));
    assert_eq!((p.ar_exact_x, p.ar_exact_y), (1.0, 1.0));
    assert_eq!(p.gradient, p.reference);
    assert!(p.flags.is_empty());
}

/// Paper Sec. 2.3: a linear density field translates the dot; the bound is the reference's.
#[test]
fn linear_field_is_a_pure_translation() {
    let mut s = testdata();
    s.flow.hessian_kg_m5 = Hessian::default();
    let p = predict(&s).unwrap();
    // Eq. 24's gradient term changes the cone, but there is no curvature to blur with
    assert!(p.cone_angle_rad < p.cone_angle_geometric_rad);
    assert_eq!(p.blur_covariance, [0.0; 3]);
    assert_eq!(
        (p.sigma_x, p.sigma_y, p.rho),
        (p.reference.sigma_x, p.reference.sigma_y, 0.0)
    );
    assert_eq!((p.ar_x, p.ar_y), (1.0, 1.0));
    assert_eq!((p.eq35_x, p.eq35_y), (p.eq35_ref, p.eq35_ref));
    // the exact bound differs only through the sub-pixel phase of the shifted dot
    assert!(rel(p.crlb_x, p.crlb_ref_x) < 0.01 && rel(p.crlb_y, p.crlb_ref_y) < 0.01);
    // an integer shift (3 px, 0 px) gives exactly the reference's bound
    let mut s = round_setup();
    s.flow.gradient_kg_m4 = [-3.0 / 0.032, 0.0, 0.0];
    let p = predict(&s).unwrap();
    assert!((p.shift_x - 3.0).abs() < 1e-12);
    assert!(rel(p.crlb_x, p.crlb_ref_x) < 1e-9 && rel(p.crlb_y, p.crlb_ref_y) < 1e-9);
}

/// The AR formula (continuum, NOTES.md §2) against the ratio of exact discrete bounds of the
/// predicted pixel-integrated dots: within a few % for well-sampled dots (σ_ref = 1.5-2 px).
#[test]
fn ar_formula_matches_the_ratio_of_exact_bounds() {
    let mut worst: f64 = 0.0;
    for d_px in [6.0, 8.0] {
        for h in [
            Hessian {
                xx: 20000.0,
                ..Default::default()
            },
            Hessian {
                xx: 40000.0,
                yy: 10000.0,
                ..Default::default()
            },
            Hessian {
                xx: 25000.0,
                xy: 20000.0,
                yy: 15000.0,
                ..Default::default()
            },
            Hessian {
                xx: -30000.0,
                xy: 12000.0,
                yy: 30000.0,
                ..Default::default()
            },
        ] {
            let mut s = round_setup();
            s.optics.diffraction_diameter_px = Some(d_px);
            s.flow.gradient_kg_m4 = [12.3, -4.1, 0.0];
            s.flow.hessian_kg_m5 = h;
            let p = predict(&s).unwrap();
            assert!(p.ar_x > 1.05, "a visible blur: {}", p.ar_x);
            for (f, e) in [(p.ar_x, p.ar_exact_x), (p.ar_y, p.ar_exact_y)] {
                worst = worst.max(rel(f, e));
                assert!(rel(f, e) < 0.03, "d {d_px} {h:?}: formula {f} exact {e}");
            }
        }
    }
    eprintln!("largest |AR formula / AR exact - 1| = {worst:.4}");
}

#[test]
fn viewing_direction_rotates_gradient_and_hessian() {
    let mut s = round_setup();
    s.flow.gradient_kg_m4 = [50.0, 0.0, 0.0];
    s.flow.hessian_kg_m5 = Hessian {
        xx: 30000.0,
        ..Default::default()
    };
    let head_on = predict(&s).unwrap();
    // roll 90°: the camera's y axis is the flow's -x
    s.view.roll_deg = 90.0;
    let p = predict(&s).unwrap();
    assert!((p.shift_x).abs() < 1e-12 && (p.shift_y + head_on.shift_x).abs() < 1e-12);
    assert!(rel(p.sigma_y, head_on.sigma_x) < 1e-12 && rel(p.sigma_x, head_on.sigma_y) < 1e-12);
    // yaw θ: the camera sees cos θ ∂ρ/∂x - sin θ ∂ρ/∂z and cos²θ ρxx
    let th = 25f64.to_radians();
    s.view = View {
        yaw_deg: 25.0,
        ..Default::default()
    };
    s.flow.gradient_kg_m4 = [50.0, 0.0, 20.0];
    let p = predict(&s).unwrap();
    assert!(rel(p.gradient_camera[0], th.cos() * 50.0 - th.sin() * 20.0) < 1e-12);
    assert!(rel(p.hessian_camera[0], th.cos().powi(2) * 30000.0) < 1e-12);
}

#[test]
fn volumetric_geometry_uses_the_printed_eq6() {
    let mut s = round_setup();
    s.geometry = Geometry::Volumetric { depth_m: 0.002 };
    s.flow.gradient_kg_m4 = [1000.0, 0.0, 0.0];
    s.flow.hessian_kg_m5 = Hessian {
        xx: 5000.0,
        ..Default::default()
    };
    let p = predict(&s).unwrap();
    // S = M K ζ² / (n0 d_r) = 0.1 * 2e-4 * 4e-6 / 1e-5
    assert!(rel(p.sensitivity_px, 8e-6) < 1e-12);
    let cone: f64 = 0.1 / 8.8;
    let k = (8e-6 * 0.002 * cone).powi(2) / 12.0 * 5000f64.powi(2);
    assert!(rel(p.blur_covariance[0], k) < 1e-12);
}

#[test]
fn paper_cone_angle_and_its_clamp() {
    let mut s = round_setup();
    s.flow.hessian_kg_m5 = Hessian {
        xx: 30000.0,
        ..Default::default()
    };
    s.optics.cone_angle = ConeAngleModel::Paper;
    // Eq. 24: Δθ0 - K Δz (gx + gy) / (2 n0) = 0.1/8.8 - 2e-4 * 0.04 / 2 * 1000
    s.flow.gradient_kg_m4 = [600.0, 400.0, 0.0];
    let p = predict(&s).unwrap();
    assert!((p.cone_angle_rad - (0.1 / 8.8 - 4e-3)).abs() < 1e-15);
    assert!(
        p.flags.contains(TheoryFlags::CONE_CORRECTED)
            && !p.flags.contains(TheoryFlags::CONE_CLAMPED)
    );
    s.flow.gradient_kg_m4 = [3000.0, 0.0, 0.0];
    let p = predict(&s).unwrap();
    assert!(p.flags.contains(TheoryFlags::CONE_CLAMPED));
    assert_eq!((p.cone_angle_rad, p.blur_covariance), (0.0, [0.0; 3]));
    // the geometric model ignores the first derivatives
    s.optics.cone_angle = ConeAngleModel::Geometric;
    let p = predict(&s).unwrap();
    assert!(p.flags.is_empty() && p.blur_covariance[0] > 0.0);
}

#[test]
fn flags_mark_strained_assumptions() {
    // a 2.4 px diffraction spot without printed dots: undersampled
    let mut s = testdata();
    s.optics.dot_diameter_mm = 0.0;
    assert!(
        predict(&s)
            .unwrap()
            .flags
            .contains(TheoryFlags::UNDERSAMPLED)
    );
    // strong curvature: the blur exceeds the reference dot (non-Gaussian) and the field
    // stretches the dot (lensing)
    let mut s = testdata();
    s.flow.hessian_kg_m5.xx = 60000.0;
    let f = predict(&s).unwrap().flags;
    assert!(
        f.contains(TheoryFlags::NON_GAUSSIAN | TheoryFlags::LENSING),
        "{f}"
    );
    // f/1.4 at 1:1: a wide cone
    let mut s = round_setup();
    s.optics.f_number = 1.4;
    s.optics.magnification = Some(1.0);
    assert!(predict(&s).unwrap().flags.contains(TheoryFlags::WIDE_CONE));
    // a huge blur caps the exact bound's window
    let mut s = round_setup();
    s.flow.hessian_kg_m5.xx = 3e6;
    let p = predict(&s).unwrap();
    assert!(p.flags.contains(TheoryFlags::WINDOW_CAPPED) && p.window.width == 101);
}

#[test]
fn bad_setups_are_errors_naming_the_field() {
    let err = |text: &str| Setup::from_toml(text).unwrap_err();
    match err("[optics]\nf_number = -2.0") {
        TheoryError::InvalidSetup { field, .. } => assert_eq!(field, "optics.f_number"),
        e => panic!("{e}"),
    }
    assert!(matches!(
        err("[optics]\nfnumber = 2.0"),
        TheoryError::Toml(_)
    ));
    assert!(matches!(
        err("[geometry]\nkind = \"bos\"\nz_d_m = 0.5\ndelta_z_m = 0.05\nzd = 1"),
        TheoryError::Toml(_)
    ));
    assert!(matches!(
        err("[flow.hessian_kg_m5]\nxxx = 1.0"),
        TheoryError::Toml(_)
    ));
    match err("[geometry]\nkind = \"bos\"\nz_d_m = 1.6\ndelta_z_m = 0.05") {
        TheoryError::InvalidSetup { field, .. } => assert_eq!(field, "geometry.z_d_m"),
        e => panic!("{e}"),
    }
    match err("[optics]\nfocal_length_mm = 2000.0") {
        TheoryError::InvalidSetup { field, .. } => assert_eq!(field, "optics.target_distance_m"),
        e => panic!("{e}"),
    }
    match err("[flow]\ngradient_kg_m4 = [1.0, nan, 0.0]") {
        TheoryError::InvalidSetup { field, .. } => assert_eq!(field, "flow.gradient_kg_m4[1]"),
        e => panic!("{e}"),
    }
    assert!(
        err("[camera]\nwindow_half_px = 0")
            .to_string()
            .contains("window_half_px")
    );
    // defaults are valid, and the error message names the field
    assert!(Setup::default().validate().is_ok());
    assert!(
        err("[camera]\nread_noise_counts = 0.0")
            .to_string()
            .contains("camera.read_noise_counts")
    );
}

#[test]
fn exposure_or_peak() {
    let mut s = round_setup();
    s.camera.exposure_counts = Some(5000.0);
    s.flow.hessian_kg_m5.xx = 30000.0;
    let p = predict(&s).unwrap();
    assert_eq!(p.exposure, 5000.0);
    assert!(rel(p.reference.amplitude, 5000.0 / (2.0 * PI * 2.25)) < 1e-12);
    // shot noise raises the exact bound, not the closed form
    let q = predict(&Setup {
        camera: Camera {
            gain: 2.0,
            ..s.camera.clone()
        },
        ..s.clone()
    })
    .unwrap();
    assert!(q.crlb_x > p.crlb_x * 1.1 && q.eq35_x == p.eq35_x);
}

#[test]
fn setup_and_prediction_serialise() {
    let text = toml::to_string(&testdata()).unwrap();
    assert_eq!(Setup::from_toml(&text).unwrap(), testdata());
    let mut s = testdata();
    s.optics.dot_diameter_mm = 0.0;
    let p = predict(&s).unwrap();
    assert!(p.flags.contains(TheoryFlags::UNDERSAMPLED));
    let text = toml::to_string(&p).unwrap();
    assert!(text.contains(&format!("flags = \"{}\"", p.flags)), "{text}");
}
