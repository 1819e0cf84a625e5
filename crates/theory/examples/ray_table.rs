//! Prints the ray-tracing tables of docs/theory.md: the traced dot's moments against the
//! effective model where its assumptions hold, and where they fail.
//!
//! `cargo run --release -p bostrack-theory --example ray_table`

use bostrack_theory::*;

fn testdata() -> Setup {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/crlb-setup.toml"
    );
    let mut s = Setup::from_toml(&std::fs::read_to_string(path).unwrap()).unwrap();
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
    a / b - 1.0
}

fn main() {
    let slab = Propagation::Slab { steps: 64 };
    let base = testdata();
    let p = predict(&base).unwrap();
    println!(
        "## Convergence with the number of rays (testdata/crlb-setup.toml, thin slab, square pupil, geometric cone)\n"
    );
    println!("| rays | σx rel. error | σy rel. error | ρ error | x0 error (px) |");
    println!("|---|---|---|---|---|");
    for rays in [100, 400, 2_500, 10_000, 40_000, 160_000] {
        let r = trace(&base, rays, Propagation::ThinSlab);
        println!(
            "| {} | {:+.1e} | {:+.1e} | {:+.1e} | {:+.1e} |",
            r.rays,
            rel(r.dot.sigma_x, p.sigma_x),
            rel(r.dot.sigma_y, p.sigma_y),
            r.dot.rho - p.rho,
            r.dot.x0 - p.shift_x
        );
    }

    println!("\n## Where the assumptions hold (40 000 rays)\n");
    println!(
        "| case | model x0, y0 | traced x0, y0 | model σx, σy, ρ | traced σx, σy, ρ | Gaussian residual |"
    );
    println!("|---|---|---|---|---|---|");
    let mut circ = base.clone();
    circ.optics.aperture = Aperture::Circular;
    let mut view = base.clone();
    view.view = View {
        pitch_deg: -10.0,
        yaw_deg: 20.0,
        roll_deg: 30.0,
    };
    view.flow.gradient_kg_m4[2] = 25.0;
    view.flow.hessian_kg_m5 = Hessian {
        xx: 12000.0,
        xy: 4000.0,
        yy: 3000.0,
        zz: 5000.0,
        xz: -3000.0,
        yz: 2000.0,
    };
    for (name, s, prop) in [
        (
            "example setup, square pupil, thin slab",
            &base,
            Propagation::ThinSlab,
        ),
        (
            "example setup, round pupil, thin slab",
            &circ,
            Propagation::ThinSlab,
        ),
        ("example setup, slab integrated (64 steps)", &base, slab),
        (
            "viewing angles (-10°, 20°, 30°), ρ_z terms, thin slab",
            &view,
            Propagation::ThinSlab,
        ),
    ] {
        let p = predict(s).unwrap();
        let r = trace(s, 40_000, prop);
        println!(
            "| {name} | {:.4}, {:.4} | {:.4}, {:.4} | {:.4}, {:.4}, {:.4} | {:.4}, {:.4}, {:.4} | {:.4} |",
            p.shift_x,
            p.shift_y,
            r.dot.x0,
            r.dot.y0,
            p.sigma_x,
            p.sigma_y,
            p.rho,
            r.dot.sigma_x,
            r.dot.sigma_y,
            r.dot.rho,
            r.gaussian_residual
        );
    }

    println!(
        "\n## Breakdown 1: Eq. 24's gradient term (example setup, ∂ρ/∂y = 15 kg/m⁴, thin slab, 10 000 rays)\n"
    );
    println!(
        "| ∂ρ/∂x (kg/m⁴) | Eq. 24 cone (rad) | model σx (paper) | model σx (geometric cone) | traced σx | flags |"
    );
    println!("|---|---|---|---|---|---|");
    for gx in [40.0, 400.0, 800.0, 1100.0, 1500.0] {
        let mut s = base.clone();
        s.flow.gradient_kg_m4 = [gx, 15.0, 0.0];
        let geo = predict(&s).unwrap();
        s.optics.cone_angle = ConeAngleModel::Paper;
        let p = predict(&s).unwrap();
        let r = trace(&s, 10_000, Propagation::ThinSlab);
        println!(
            "| {gx} | {:.5} | {:.4} | {:.4} | {:.4} | {} |",
            p.cone_angle_rad, p.sigma_x, geo.sigma_x, r.dot.sigma_x, p.flags
        );
    }

    println!(
        "\n## Breakdown 2: thick slab with curvature (Z_D = 0.5 m, only ρxx, slab integrated, 64 steps, 10 000 rays)\n"
    );
    println!(
        "| Δz (m) | ρxx (kg/m⁵) | K ρxx Z_D Δz / n0 | model blur σ (px) | traced blur σ (px) | traced / model |"
    );
    println!("|---|---|---|---|---|---|");
    for dz in [0.05, 0.1, 0.3, 0.5, 0.8] {
        for hxx in [12000.0, -12000.0] {
            let mut s = base.clone();
            s.flow.gradient_kg_m4 = [0.0; 3];
            s.geometry = Geometry::Bos {
                z_d_m: 0.5,
                delta_z_m: dz,
            };
            s.flow.hessian_kg_m5 = Hessian {
                xx: hxx,
                ..Default::default()
            };
            let p = predict(&s).unwrap();
            let r = trace(&s, 10_000, slab);
            let b = p.blur_covariance[0].sqrt();
            println!(
                "| {dz} | {hxx} | {:+.3} | {:.4} | {:.4} | {:.4} |",
                0.225e-3 * hxx * 0.5 * dz / 1.000278,
                b,
                r.landing.sigma_x,
                r.landing.sigma_x / b
            );
        }
    }

    println!(
        "\n## Breakdown 3: the gradient varies along the line of sight (example setup without other curvature, ρxz only, slab integrated, 64 steps, 2 500 rays)\n"
    );
    println!(
        "| ρxz (kg/m⁵) | Δz (m) | model x0 | traced x0 | traced - model | (M K/(n0 d_r)) ρxz Δz³/12 |"
    );
    println!("|---|---|---|---|---|---|");
    for (hxz, dz) in [(5000.0, 0.05), (-5000.0, 0.05), (5000.0, 0.2)] {
        let mut s = base.clone();
        s.geometry = Geometry::Bos {
            z_d_m: 0.5,
            delta_z_m: dz,
        };
        s.flow.hessian_kg_m5 = Hessian {
            xz: hxz,
            ..Default::default()
        };
        let p = predict(&s).unwrap();
        let r = trace(&s, 2_500, slab);
        let lever = p.magnification * 0.225e-3 / (1.000278 * 6.5e-6) * hxz * dz * dz * dz / 12.0;
        println!(
            "| {hxz} | {dz} | {:.4} | {:.4} | {:+.4} | {:+.4} |",
            p.shift_x,
            r.dot.x0,
            r.dot.x0 - p.shift_x,
            lever
        );
    }

    println!(
        "\n## Breakdown 4: strong curvature, non-Gaussian dot (example setup, ρxx only, thin slab, 40 000 rays)\n"
    );
    println!(
        "| ρxx (kg/m⁵) | blur σ / σ_ref | model σx | traced σx | excess kurtosis (x) | Gaussian residual | flags |"
    );
    println!("|---|---|---|---|---|---|---|");
    for hxx in [6000.0, 12000.0, 25000.0, 50000.0, 100000.0, 200000.0] {
        let mut s = base.clone();
        s.flow.hessian_kg_m5 = Hessian {
            xx: hxx,
            ..Default::default()
        };
        let p = predict(&s).unwrap();
        let r = trace(&s, 40_000, Propagation::ThinSlab);
        println!(
            "| {hxx} | {:.2} | {:.4} | {:.4} | {:.3} | {:.4} | {} |",
            p.blur_covariance[0].sqrt() / p.reference.sigma_x,
            p.sigma_x,
            r.dot.sigma_x,
            r.dot.excess_kurtosis_x,
            r.gaussian_residual,
            p.flags
        );
    }
}
