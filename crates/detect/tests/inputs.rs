//! Bad input gives a clear error, never a panic; hints and polarity; the configuration format.

mod common;

use bostrack_core::{DotFlags, Image, ImageMeta, Mask};
use bostrack_detect::{DetectConfig, DetectError, LatticeKind, Polarity, detect, track};
use bostrack_synth::Scene;
use common::{Case, scene_config, score};

fn scene(spacing: f64, diameter: f64, angle: f64, seed: u64) -> Scene {
    let c = Case {
        spacing,
        diameter,
        angle_deg: angle,
        noise: 0.03,
        hexagonal: false,
        mask: false,
        seed,
    };
    Scene::reference(&scene_config(&c)).unwrap()
}

/// Deterministic pseudo-random noise (xorshift), uniform in [-0.5, 0.5).
fn noise_image(w: usize, h: usize, level: f64, amp: f64) -> Image {
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    Image::from_fn(w, h, |_, _| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        level + amp * ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5)
    })
}

#[test]
fn an_image_without_dots_is_an_error() {
    let img = noise_image(256, 256, 100.0, 40.0);
    let err = detect(&img, None, &DetectConfig::default()).unwrap_err();
    assert!(
        matches!(
            err,
            DetectError::NoLattice { .. } | DetectError::TooFewDots { .. }
        ),
        "{err}"
    );
    assert!(err.to_string().starts_with("in-memory image: "), "{err}");
}

#[test]
fn a_constant_image_is_an_error() {
    let img = Image::from_fn(128, 128, |_, _| 321.0);
    assert!(matches!(
        detect(&img, None, &DetectConfig::default()),
        Err(DetectError::NoContrast { .. })
    ));
    let nan = Image::from_fn(64, 64, |_, _| f64::NAN);
    assert!(matches!(
        detect(&nan, None, &DetectConfig::default()),
        Err(DetectError::NoContrast { .. })
    ));
}

#[test]
fn a_mask_that_keeps_nothing_is_an_error() {
    let sc = scene(8.0, 5.0, 0.0, 1);
    let none = Mask::from_fn(256, 256, |_, _| false);
    let err = detect(&sc.image, Some(&none), &DetectConfig::default()).unwrap_err();
    assert_eq!(
        err,
        DetectError::EmptyMask {
            image: "in-memory image".into()
        }
    );
    let det = detect(&sc.image, None, &DetectConfig::default()).unwrap();
    assert!(matches!(
        track(&sc.image, Some(&none), &det, &DetectConfig::default()),
        Err(DetectError::EmptyMask { .. })
    ));
    let small = Mask::all(100, 256);
    assert!(matches!(
        detect(&sc.image, Some(&small), &DetectConfig::default()),
        Err(DetectError::MaskSize { .. })
    ));
}

#[test]
fn sizes_and_configuration_are_checked() {
    let tiny = Image::from_fn(16, 40, |x, y| (x * y) as f64);
    assert!(matches!(
        detect(&tiny, None, &DetectConfig::default()),
        Err(DetectError::ImageTooSmall { .. })
    ));
    let sc = scene(8.0, 5.0, 0.0, 2);
    for cfg in [
        DetectConfig {
            spacing: Some(-1.0),
            ..Default::default()
        },
        DetectConfig {
            diameter: Some(f64::NAN),
            ..Default::default()
        },
        DetectConfig {
            map_degree: 7,
            ..Default::default()
        },
        DetectConfig {
            search_radius: 0.8,
            ..Default::default()
        },
        DetectConfig {
            faint_ratio: 0.01,
            ..Default::default()
        },
    ] {
        assert!(
            matches!(
                detect(&sc.image, None, &cfg),
                Err(DetectError::InvalidConfig { .. })
            ),
            "{cfg:?}"
        );
    }
    let det = detect(&sc.image, None, &DetectConfig::default()).unwrap();
    let other = Image::from_fn(200, 256, |x, _| x as f64);
    assert!(matches!(
        track(&other, None, &det, &DetectConfig::default()),
        Err(DetectError::ReferenceSize { .. })
    ));
    // A file name appears in the message when the image came from a file.
    let mut named = Image::from_fn(128, 128, |_, _| 5.0);
    named.meta = ImageMeta {
        source: Some("/data/run3/ref.tif".into()),
        ..ImageMeta::synthetic(16)
    };
    let err = detect(&named, None, &DetectConfig::default()).unwrap_err();
    assert_eq!(
        err.to_string(),
        "/data/run3/ref.tif: no contrast (constant image or no finite sample)"
    );
}

#[test]
fn a_square_target_is_not_taken_for_a_hexagonal_one() {
    let sc = scene(8.0, 5.0, 10.0, 3);
    let cfg = DetectConfig {
        lattice: LatticeKind::Hexagonal,
        ..Default::default()
    };
    match detect(&sc.image, None, &cfg) {
        Err(DetectError::LatticeMismatch { angle_deg, .. }) => {
            assert!((angle_deg - 90.0).abs() < 2.0)
        }
        other => panic!("{other:?}"),
    }
}

/// The spacing hint is a prior: wrong by a factor 2 either way, the image wins, with the same
/// result as without a hint, and the ratio is reported.
#[test]
fn a_spacing_hint_wrong_by_two_still_works() {
    let sc = scene(9.0, 5.5, 21.0, 4);
    let plain = detect(&sc.image, None, &DetectConfig::default()).unwrap();
    assert!((plain.spacing - 9.0).abs() < 0.02);
    for (hint, ratio) in [(18.0, 0.5), (4.5, 2.0)] {
        let det = detect(
            &sc.image,
            None,
            &DetectConfig {
                spacing: Some(hint),
                ..Default::default()
            },
        )
        .unwrap();
        assert!(
            (det.spacing - plain.spacing).abs() < 1e-3,
            "hint {hint}: {}",
            det.spacing
        );
        assert_eq!(det.seeds.len(), plain.seeds.len());
        assert!(
            det.seeds
                .iter()
                .zip(&plain.seeds)
                .all(|(a, b)| a.index == b.index)
        );
        let r = det.stats.spacing_hint_ratio.unwrap();
        assert!((r - ratio).abs() < 0.01, "{r}");
    }
    // A wrong diameter hint only changes the first filter: the size is measured.
    let det = detect(
        &sc.image,
        None,
        &DetectConfig {
            diameter: Some(11.0),
            ..Default::default()
        },
    )
    .unwrap();
    assert!((det.diameter - 5.5).abs() < 0.3, "{}", det.diameter);
    assert_eq!(det.stats.found, plain.stats.found);
}

/// Dark dots on a bright background: the inverted image with `polarity = "dark"` gives the same
/// seeds as the original.
#[test]
fn dark_dots_on_a_bright_background() {
    let sc = scene(7.0, 4.0, 33.0, 5);
    let bright = detect(&sc.image, None, &DetectConfig::default()).unwrap();
    let inverted = Image::from_fn(256, 256, |x, y| 5000.0 - sc.image.get(x, y));
    let cfg = DetectConfig {
        polarity: Polarity::Dark,
        ..Default::default()
    };
    let dark = detect(&inverted, None, &cfg).unwrap();
    assert_eq!(dark.seeds.len(), bright.seeds.len());
    for (a, b) in dark.seeds.iter().zip(&bright.seeds) {
        assert_eq!(a.index, b.index);
        // Equal up to the f32 rounding of the dot map (the inverted image has another offset).
        assert!(
            (a.centre[0] - b.centre[0]).abs() < 1e-3 && (a.centre[1] - b.centre[1]).abs() < 1e-3
        );
    }
    // Without the polarity the inverted image's "dots" are the gaps between dots: a lattice
    // shifted by half a cell, not the dots.
    if let Ok(wrong) = detect(&inverted, None, &DetectConfig::default()) {
        let sc_wrong = score(&wrong, &sc, 0.25 * 7.0);
        assert_eq!(sc_wrong.found, 0);
    }
}

/// Non-finite pixels are left out and flagged, not propagated.
#[test]
fn non_finite_pixels_are_flagged() {
    let sc = scene(8.0, 5.0, 0.0, 6);
    let mut img = sc.image.clone();
    for x in 100..104 {
        img.data_mut()[130 * 256 + x] = f64::NAN;
    }
    img.data_mut()[20 * 256 + 20] = f64::INFINITY;
    let det = detect(&img, None, &DetectConfig::default()).unwrap();
    let flagged: Vec<_> = det
        .seeds
        .iter()
        .filter(|s| s.flags.contains(DotFlags::NAN_PIXELS))
        .collect();
    assert!(
        !flagged.is_empty() && flagged.len() <= 6,
        "{}",
        flagged.len()
    );
    assert!(
        det.seeds
            .iter()
            .all(|s| s.centre.iter().all(|v| v.is_finite()))
    );
    assert!(det.contrast.iter().all(|c| c.is_finite()));
}

#[test]
fn the_configuration_reads_from_toml_and_rejects_unknown_keys() {
    let cfg: DetectConfig =
        toml::from_str("spacing = 8.0\nlattice = \"hexagonal\"\npolarity = \"dark\"\n").unwrap();
    assert_eq!(cfg.spacing, Some(8.0));
    assert_eq!(cfg.lattice, LatticeKind::Hexagonal);
    assert_eq!(cfg.polarity, Polarity::Dark);
    assert_eq!(cfg.min_snr, DetectConfig::default().min_snr);
    assert!(toml::from_str::<DetectConfig>("spacing = 8.0\nspcaing = 3.0\n").is_err());
    let empty: DetectConfig = toml::from_str("").unwrap();
    assert_eq!(empty, DetectConfig::default());
}

/// A mask that cuts the lattice: the found dots with a lattice neighbour inside the image but
/// outside the mask are flagged `roi_edge`, in `detect` and in `track`; the others, and every
/// dot without a mask, are not.
#[test]
fn dots_next_to_the_masked_region_are_flagged() {
    let s = scene(10.0, 5.0, 0.0, 7);
    let (w, h) = (s.image.width(), s.image.height());
    let edge = 0.4 * h as f64;
    let mask = Mask::from_fn(w, h, |_, y| y as f64 >= edge);
    let cfg = DetectConfig::default();
    let flagged = |seeds: &[bostrack_core::Seed]| -> Vec<[f64; 2]> {
        seeds
            .iter()
            .filter(|d| d.flags.contains(DotFlags::ROI_EDGE))
            .map(|d| d.centre)
            .collect()
    };
    let det = detect(&s.image, None, &cfg).unwrap();
    assert!(flagged(&det.seeds).is_empty());
    let det = detect(&s.image, Some(&mask), &cfg).unwrap();
    for (what, seeds) in [
        ("detect", det.seeds.clone()),
        (
            "track",
            track(&s.image, Some(&mask), &det, &cfg).unwrap().seeds,
        ),
    ] {
        let found: Vec<_> = seeds
            .iter()
            .filter(|d| !d.flags.contains(DotFlags::MISSING))
            .collect();
        let edge_row = |d: &&&bostrack_core::Seed| d.centre[1] < edge + det.spacing - 0.5;
        let in_edge_row = found.iter().filter(edge_row).count();
        let marked = flagged(&seeds);
        assert!(
            in_edge_row >= 8,
            "{what}: {in_edge_row} dots in the first kept row"
        );
        // every dot of the first kept row, and no other
        assert_eq!(marked.len(), in_edge_row, "{what}: {marked:?}");
        assert!(
            marked.iter().all(|c| c[1] < edge + det.spacing - 0.5),
            "{what}: {marked:?}"
        );
    }
}
