//! Prints the prediction for testdata/crlb-setup.toml and the design sweeps of docs/theory.md.
//!
//! `cargo run --release -p bostrack-theory --example design_table`

use bostrack_theory::*;

fn main() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../testdata/crlb-setup.toml"
    );
    let s = Setup::from_toml(&std::fs::read_to_string(path).unwrap()).unwrap();
    let p = predict(&s).unwrap();
    println!("## Prediction for testdata/crlb-setup.toml\n");
    println!("| quantity | value |");
    println!("|---|---|");
    println!("| magnification M | {:.5} |", p.magnification);
    println!("| sensitivity S (px per kg/m⁴) | {:.5} |", p.sensitivity_px);
    println!(
        "| cone angle geometric / Eq. 24 (mrad) | {:.3} / {:.3} |",
        1e3 * p.cone_angle_geometric_rad,
        1e3 * p.cone_angle_rad
    );
    println!(
        "| diffraction / reference diameter (px) | {:.3} / {:.3} |",
        p.diffraction_diameter_px, p.reference_diameter_px
    );
    println!("| shift x, y (px) | {:.4}, {:.4} |", p.shift_x, p.shift_y);
    println!(
        "| σx, σy (px), ρ | {:.4}, {:.4}, {:.4} |",
        p.sigma_x, p.sigma_y, p.rho
    );
    println!(
        "| peak reference / gradient (counts) | {:.1} / {:.1} |",
        p.reference.amplitude, p.peak
    );
    println!(
        "| exact bound x, y (px) | {:.5}, {:.5} |",
        p.crlb_x, p.crlb_y
    );
    println!(
        "| exact bound of the reference (px) | {:.5} |",
        p.crlb_ref_x
    );
    println!(
        "| Eq. 35 (ρ-generalised) x, y (px) | {:.5}, {:.5} |",
        p.eq35_x, p.eq35_y
    );
    println!("| Eq. 36 reference (px) | {:.5} |", p.eq35_ref);
    println!("| AR x, y (NOTES §2) | {:.4}, {:.4} |", p.ar_x, p.ar_y);
    println!(
        "| AR x, y (ratio of exact bounds) | {:.4}, {:.4} |",
        p.ar_exact_x, p.ar_exact_y
    );
    println!(
        "| displacement gradient xx (px/px) | {:.4} |",
        p.displacement_gradient[0][0]
    );
    println!("| flags | {} |", p.flags);

    println!("\n## Bound against f-number (fixed exposure / fixed illumination)\n");
    println!(
        "| f# | σx, σy (px) | ρ | AR x | exact bound x, fixed exposure (px) | exact bound x, fixed illumination (px) | flags |"
    );
    println!("|---|---|---|---|---|---|---|");
    let f = [2.8, 4.0, 5.6, 8.0, 11.0, 16.0, 22.0, 32.0];
    let fixed = sweep_f_number(&s, &f, ExposureScaling::Fixed).unwrap();
    let lit = sweep_f_number(&s, &f, ExposureScaling::Aperture).unwrap();
    for (a, b) in fixed.iter().zip(&lit) {
        println!(
            "| {} | {:.3}, {:.3} | {:.3} | {:.3} | {:.5} | {:.5} | {} |",
            a.f_number, a.sigma_x, a.sigma_y, a.rho, a.ar_x, a.crlb_x, b.crlb_x, a.flags
        );
    }

    println!(
        "\n## Bound against Z_D at fixed sensitivity M·Z_D = {:.4} m (fixed exposure)\n",
        p.magnification * 0.5
    );
    println!("| Z_D (m) | M | shift x (px) | σx (px) | exact bound x (px) | AR x | flags |");
    println!("|---|---|---|---|---|---|---|");
    let z = [0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 1.2];
    for r in sweep_z_d(&s, &z, ZdHold::Sensitivity, ExposureScaling::Fixed).unwrap() {
        println!(
            "| {} | {:.4} | {:.3} | {:.4} | {:.5} | {:.3} | {} |",
            r.z_d_m.unwrap(),
            r.magnification,
            r.shift_x,
            r.sigma_x,
            r.crlb_x,
            r.ar_x,
            r.flags
        );
    }

    println!("\n## Bound against Z_D at fixed magnification (the sensitivity grows with Z_D)\n");
    println!(
        "| Z_D (m) | shift x (px) | σx (px) | exact bound x (px) | u_d x (px) | shift / u_d (x) | flags |"
    );
    println!("|---|---|---|---|---|---|---|");
    for r in sweep_z_d(&s, &z, ZdHold::Magnification, ExposureScaling::Fixed).unwrap() {
        println!(
            "| {} | {:.3} | {:.3} | {:.5} | {:.5} | {:.0} | {} |",
            r.z_d_m.unwrap(),
            r.shift_x,
            r.sigma_x,
            r.crlb_x,
            r.u_d_x,
            r.snr_x,
            r.flags
        );
    }
}
