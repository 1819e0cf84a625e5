//! Acceptance on synthetic targets with exact truth (bostrack-synth).

mod common;

use bostrack_detect::{DetectConfig, LatticeKind, detect};
use bostrack_synth::Scene;
use common::{Case, scene_config, score};

fn check(c: &Case) -> Result<(), String> {
    let scene = Scene::reference(&scene_config(c)).map_err(|e| e.to_string())?;
    let mut cfg = DetectConfig::default();
    if c.hexagonal {
        cfg.lattice = LatticeKind::Hexagonal;
    }
    let det = detect(&scene.image, scene.mask.as_ref(), &cfg).map_err(|e| format!("{c:?}: {e}"))?;
    // The rough centre must identify its dot unambiguously (within a quarter spacing).
    let tol = 0.25 * c.spacing;
    let sc = score(&det, &scene, tol);
    eprintln!(
        "s {:5.1} d {:5.2} a {:4.0} noise {:.2}: est spacing {:.3} d {:.2}; found {}/{} defects {}/{} spurious {}; centre error median {:.3} max {:.3}",
        c.spacing,
        c.diameter,
        c.angle_deg,
        c.noise,
        det.spacing,
        det.diameter,
        sc.found,
        sc.expected,
        sc.defects_found,
        sc.defects,
        sc.spurious,
        sc.median_error,
        sc.worst_error
    );
    // The rough centre (the fit stage refines it) is within a tenth of a pixel or so.
    if sc.found != sc.expected || sc.spurious != 0 || sc.median_error > 0.2 {
        return Err(format!(
            "{c:?}: found {}/{} spurious {} (spacing {:.3}, diameter {:.2}, stats {:?})\n  {}",
            sc.found,
            sc.expected,
            sc.spurious,
            det.spacing,
            det.diameter,
            det.stats,
            sc.problems
                .iter()
                .take(8)
                .cloned()
                .collect::<Vec<_>>()
                .join("\n  ")
        ));
    }
    Ok(())
}

/// The grid: spacing 4-30 px x diameter from 1.5 px to 0.9 spacing x rotation 0-90° x read noise
/// up to 10 % of the amplitude, with vignetting, 5 % missing dots, 1 % defects and a mask.
#[test]
fn square_lattices_over_the_parameter_grid() {
    let angles = [0.0, 17.0, 44.0, 63.0, 90.0, 31.0, 8.0];
    let mut failures = Vec::new();
    let mut n = 0;
    for (si, &spacing) in [4.0, 6.0, 8.0, 12.0, 18.0, 30.0].iter().enumerate() {
        for (di, frac) in [0.0, 0.5, 1.0].iter().enumerate() {
            let dmin: f64 = 1.5;
            // d = 4σ from 1.5 px to 0.9 spacing.
            let dmax = 0.9 * spacing;
            let diameter = dmin + frac * (dmax - dmin);
            for (ni, &noise) in [0.02f64, 0.1].iter().enumerate() {
                // Read noise as a fraction of the dot's peak pixel; 10 % only from d = 2.5 px:
                // a 1.5 px dot centred on a pixel corner then has a matched-filter
                // signal-to-noise ratio of about 5, and about 0.5 % of such dots fall below the
                // detection threshold (4).
                let noise = if diameter < 2.5 {
                    noise.min(0.05)
                } else {
                    noise
                };
                n += 1;
                let k = si * 6 + di * 2 + ni;
                let c = Case {
                    spacing,
                    diameter,
                    angle_deg: angles[k % angles.len()],
                    noise,
                    hexagonal: false,
                    mask: true,
                    seed: k as u64,
                };
                if let Err(e) = check(&c) {
                    failures.push(e);
                }
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {n} cases failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn hexagonal_lattices() {
    let mut failures = Vec::new();
    for (k, (spacing, diameter, angle)) in [
        (8.0, 5.0, 0.0),
        (12.0, 3.0, 23.0),
        (6.0, 4.5, 51.0),
        (20.0, 12.0, 77.0),
    ]
    .into_iter()
    .enumerate()
    {
        let c = Case {
            spacing,
            diameter,
            angle_deg: angle,
            noise: 0.05,
            hexagonal: true,
            mask: true,
            seed: 100 + k as u64,
        };
        if let Err(e) = check(&c) {
            failures.push(e);
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
