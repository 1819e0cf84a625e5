//! `pair_dot` and `to_row` against hand-computed values.

use bostrack_core::{DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex};
use bostrack_displacement::{
    ArShapes, ArVariant, COLUMNS, DisplacementConfig, PairInput, Quantities, ReferencePosition,
    ReferenceSource, ReferenceStats, pair_dot, pair_dot_at, pair_dots, pixel_blurred, to_row,
    write_row,
};
use bostrack_model::amplification_ratio;

fn fit(x0: f64, y0: f64, amplitude: f64, sx: f64, sy: f64, rho: f64) -> DotFit {
    DotFit {
        index: GridIndex::new(7, -2),
        params: Gaussian2D {
            x0,
            y0,
            amplitude,
            sigma_x: sx,
            sigma_y: sy,
            rho,
            background: 100.0,
        },
        crlb_x: 0.012,
        crlb_y: 0.015,
        rms: 3.0,
        iterations: 5,
        status: FitStatus::Converged,
        flags: DotFlags::NONE,
    }
}

/// The default configuration with the closed-form amplification ratio of NOTES.md §2.
fn notes() -> DisplacementConfig {
    DisplacementConfig {
        ar_variant: ArVariant::Notes,
        ..DisplacementConfig::default()
    }
}

fn stats(images: usize, u: [f64; 2]) -> ReferenceStats {
    ReferenceStats {
        images,
        mean: Some([50.01, 60.02]),
        u: Some(u),
    }
}

/// A pair of `r` and `g` with stack statistics (K = 10, u_ref = [0.02, 0.03]).
fn input_with<'a>(r: &'a DotFit, g: &'a DotFit) -> PairInput<'a> {
    PairInput {
        reference: Some(r),
        gradient: Some(g),
        stack: Some(stats(10, [0.02, 0.03])),
        flags: DotFlags::NONE,
    }
}

#[test]
fn full_pair_single_image_reference() {
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.2, 0.0);
    let g = fit(50.5, 59.75, 600.0, 2.5, 1.2, 0.6);
    let input = input_with(&r, &g);
    let p = pair_dot(&input, &notes()).unwrap();
    assert_eq!(p.index, GridIndex::new(7, -2));
    assert_eq!(p.reference_source, Some(ReferenceSource::Fit));
    assert_eq!(p.displacement, Some([0.5, -0.25]));
    // AR by hand (NOTES.md §2)
    let i = 1000.0 / 600.0;
    let rho = (1.0f64 / (1.0 - 0.36)).powf(0.25);
    let arx = i * (2.5f64 / 1.5).sqrt() * rho;
    let ary = i * (1.5f64 / 2.5).sqrt() * rho;
    let ar = p.ar.unwrap();
    assert!((ar[0] - arx).abs() < 1e-12 && (ar[1] - ary).abs() < 1e-12);
    let ug = p.u_grad.unwrap();
    assert!((ug[0] - arx * 0.02).abs() < 1e-15 && (ug[1] - ary * 0.03).abs() < 1e-15);
    let ud = p.u_d.unwrap();
    assert!((ud[0] - (0.02f64.powi(2) + ug[0].powi(2)).sqrt()).abs() < 1e-15);
    assert!((ud[1] - (0.03f64.powi(2) + ug[1].powi(2)).sqrt()).abs() < 1e-15);
    assert!(p.valid && p.flags.is_empty());
}

#[test]
fn stack_mean_reference_divides_by_sqrt_k() {
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.5, 0.0);
    let g = fit(50.5, 60.5, 1000.0, 1.5, 1.5, 0.0); // AR = 1
    let cfg = DisplacementConfig {
        reference_position: ReferencePosition::StackMean,
        ..DisplacementConfig::default()
    };
    let input = PairInput {
        reference: Some(&r),
        gradient: Some(&g),
        stack: Some(stats(9, [0.03, 0.03])),
        flags: DotFlags::NONE,
    };
    let p = pair_dot(&input, &cfg).unwrap();
    assert_eq!(p.reference_source, Some(ReferenceSource::StackMean));
    assert_eq!(p.reference_position, Some([50.01, 60.02]));
    let d = p.displacement.unwrap();
    assert!((d[0] - 0.49).abs() < 1e-12 && (d[1] - 0.48).abs() < 1e-12);
    // u_d = sqrt((0.03/3)² + 0.03²)
    let want = (0.01f64.powi(2) + 0.03f64.powi(2)).sqrt();
    assert!((p.u_d.unwrap()[0] - want).abs() < 1e-15);
    // no stack mean for this dot: falls back to the fit, and says so
    let input = PairInput {
        stack: Some(ReferenceStats {
            images: 0,
            mean: None,
            u: None,
        }),
        ..input
    };
    let p = pair_dot(&input, &cfg).unwrap();
    assert_eq!(p.reference_source, Some(ReferenceSource::Fit));
    assert_eq!(p.displacement, Some([0.5, 0.5]));
    assert_eq!(p.u_d, None);
}

#[test]
fn quantities_skip_what_is_not_requested() {
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.5, 0.0);
    let g = fit(50.5, 60.5, 500.0, 1.5, 1.5, 0.0);
    let input = PairInput {
        reference: Some(&r),
        gradient: Some(&g),
        stack: Some(stats(9, [0.03, 0.03])),
        flags: DotFlags::NONE,
    };
    let only_d = DisplacementConfig {
        quantities: Quantities::Displacement,
        ..DisplacementConfig::default()
    };
    let p = pair_dot(&input, &only_d).unwrap();
    assert!(p.displacement.is_some() && p.ar.is_none() && p.u_ref.is_none() && p.u_d.is_none());
    let with_ar = DisplacementConfig {
        quantities: Quantities::AmplificationRatio,
        ..notes()
    };
    let p = pair_dot(&input, &with_ar).unwrap();
    assert_eq!(p.ar, Some([2.0, 2.0]));
    assert!(p.u_ref.is_none() && p.u_grad.is_none());
    // no stack: AR and CRLB, no u
    let p = pair_dot(
        &PairInput {
            stack: None,
            ..input
        },
        &DisplacementConfig::default(),
    )
    .unwrap();
    assert!(p.ar.is_some() && p.u_ref.is_none() && p.u_d.is_none() && p.valid);
    let row = to_row(&p);
    assert_eq!(row[18], "0.012000"); // crlb_x_ref still reported
    assert!(row[22..28].iter().all(String::is_empty));
}

#[test]
fn variants_and_shapes_are_named_options() {
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.5, 0.0);
    let g = fit(50.5, 60.5, 500.0, 2.0, 1.5, 0.8);
    let input = PairInput {
        reference: Some(&r),
        gradient: Some(&g),
        stack: None,
        flags: DotFlags::NONE,
    };
    let published = DisplacementConfig {
        ar_variant: ArVariant::Published,
        ..DisplacementConfig::default()
    };
    let p = pair_dot(&input, &published).unwrap();
    assert_eq!(
        p.ar.unwrap(),
        amplification_ratio(&r.params, &g.params, ArVariant::Published)
    );
    let blurred = DisplacementConfig {
        ar_shapes: ArShapes::PixelBlurred,
        ..notes()
    };
    let p = pair_dot(&input, &blurred).unwrap();
    assert_eq!(
        p.ar.unwrap(),
        amplification_ratio(
            &pixel_blurred(&r.params),
            &pixel_blurred(&g.params),
            ArVariant::Notes
        )
    );
    // the ratio of the bounds takes no shapes: the pixel blur does not change it
    let bounds = DisplacementConfig {
        ar_variant: ArVariant::Bounds,
        ..blurred
    };
    assert_eq!(pair_dot(&input, &bounds).unwrap().ar, Some([1.0, 1.0]));
    // the pixel blur keeps the volume and adds 1/12 px² to the variances
    let b = pixel_blurred(&g.params);
    assert!((b.volume() - g.params.volume()).abs() < 1e-9 * g.params.volume());
    assert!((b.sigma_x.powi(2) - (4.0 + 1.0 / 12.0)).abs() < 1e-12);
    assert!((b.rho * b.sigma_x * b.sigma_y - 0.8 * 2.0 * 1.5).abs() < 1e-12);
}

#[test]
fn unmatched_failed_and_flagged_pairs() {
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.5, 0.0);
    let mut failed = fit(f64::NAN, 60.0, 1000.0, 1.5, 1.5, 0.0);
    failed.status = FitStatus::NonFinite;
    let g = fit(50.5, 60.5, 1000.0, 1.5, 1.5, 0.0);
    let cfg = DisplacementConfig::default();

    // no gradient partner
    let p = pair_dot(
        &PairInput {
            reference: Some(&r),
            gradient: None,
            stack: Some(stats(10, [0.02, 0.02])),
            flags: DotFlags::NONE,
        },
        &cfg,
    )
    .unwrap();
    assert!(!p.valid && p.flags.contains(DotFlags::UNMATCHED));
    assert!(p.displacement.is_none() && p.ar.is_none() && p.u_d.is_none());
    assert_eq!(p.u_ref, Some([0.02, 0.02])); // a property of the reference dot
    let row = to_row(&p);
    assert_eq!(row[2], "50.000000");
    assert!(row[4].is_empty() && row[6].is_empty());
    assert_eq!(row[28], "false");
    assert_eq!(row[29], "unmatched");

    // failed gradient fit: fit_failed, nothing from it in the row, never "NaN"
    let p = pair_dot(
        &PairInput {
            reference: Some(&r),
            gradient: Some(&failed),
            stack: None,
            flags: DotFlags::NONE,
        },
        &cfg,
    )
    .unwrap();
    assert!(!p.valid && p.flags.contains(DotFlags::FIT_FAILED));
    assert!(
        to_row(&p)
            .iter()
            .all(|s| !s.contains("NaN") && !s.contains("inf"))
    );

    // a flag from validation makes it invalid, a border flag does not
    let mut gb = g;
    gb.flags = DotFlags::BORDER;
    let p = pair_dot(
        &PairInput {
            reference: Some(&r),
            gradient: Some(&gb),
            stack: None,
            flags: DotFlags::NONE,
        },
        &cfg,
    )
    .unwrap();
    assert!(p.valid && p.flags == DotFlags::BORDER);
    // cells reused from a full row (a valid pair) hold exactly the next row's text: the empty
    // fields of an unmatched pair are emptied
    let full = to_row(&p);
    let mut cells = full.clone();
    let unmatched = pair_dot(
        &PairInput {
            reference: Some(&r),
            gradient: None,
            stack: None,
            flags: DotFlags::NONE,
        },
        &cfg,
    )
    .unwrap();
    write_row(&unmatched, &mut cells);
    assert_eq!(cells, to_row(&unmatched));
    assert!(cells[4].is_empty() && !full[4].is_empty());
    write_row(&p, &mut cells);
    assert_eq!(cells, full);
    let p = pair_dot(
        &PairInput {
            reference: Some(&r),
            gradient: Some(&g),
            stack: None,
            flags: DotFlags::OUTLIER,
        },
        &cfg,
    )
    .unwrap();
    assert!(!p.valid && p.displacement.is_some());
    assert_eq!(to_row(&p)[29], "outlier");

    // nothing at all
    let none = PairInput {
        reference: None,
        gradient: None,
        stack: None,
        flags: DotFlags::NONE,
    };
    assert!(pair_dot(&none, &cfg).is_none());
    assert_eq!(pair_dots([none], &cfg).len(), 0);
}

#[test]
fn row_matches_columns_and_is_deterministic() {
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.2, -0.1);
    let g = fit(50.123_456_789, 59.9, 800.0, 1.6, 1.3, 0.2);
    let input = input_with(&r, &g);
    let p = pair_dot(&input, &DisplacementConfig::default()).unwrap();
    let row = to_row(&p);
    assert_eq!(row.len(), COLUMNS.len());
    assert_eq!(COLUMNS[0], "i");
    assert_eq!(COLUMNS[29], "flags");
    let find = |name: &str| row[COLUMNS.iter().position(|c| *c == name).unwrap()].clone();
    assert_eq!(find("i"), "7");
    assert_eq!(find("j"), "-2");
    assert_eq!(find("x_grad"), "50.123457");
    assert_eq!(find("dx"), "0.123457");
    assert_eq!(find("rho_ref"), "-0.100000");
    assert_eq!(find("amp_grad"), "800.000000");
    assert_eq!(find("crlb_y_grad"), "0.015000");
    assert_eq!(find("u_ref_y"), "0.030000");
    assert_eq!(find("valid"), "true");
    assert_eq!(find("flags"), "");
    assert_eq!(
        to_row(&pair_dot(&input, &DisplacementConfig::default()).unwrap()),
        row
    );
}

#[test]
fn default_ar_is_the_ratio_of_the_bounds() {
    assert_eq!(DisplacementConfig::default().ar_variant, ArVariant::Bounds);
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.5, 0.0);
    let mut g = fit(50.5, 60.5, 500.0, 2.0, 1.5, 0.3);
    (g.crlb_x, g.crlb_y) = (0.03, 0.021);
    let input = input_with(&r, &g);
    let p = pair_dot(&input, &DisplacementConfig::default()).unwrap();
    let ar = p.ar.unwrap();
    assert!((ar[0] - 0.03 / 0.012).abs() < 1e-12 && (ar[1] - 0.021 / 0.015).abs() < 1e-12);
    // not the closed form of the shapes
    let closed = pair_dot(&input, &notes()).unwrap().ar.unwrap();
    assert!((closed[0] - ar[0]).abs() > 0.1, "{closed:?} {ar:?}");
    let ug = p.u_grad.unwrap();
    assert!((ug[0] - ar[0] * 0.02).abs() < 1e-15 && (ug[1] - ar[1] * 0.03).abs() < 1e-15);
    // without a bound there is no AR (and no u_grad, u_d), but the displacement stays valid
    g.crlb_x = f64::NAN;
    let p = pair_dot(&input_with(&r, &g), &DisplacementConfig::default()).unwrap();
    assert!(p.ar.is_none() && p.u_grad.is_none() && p.u_d.is_none());
    assert!(p.valid && p.displacement.is_some());
}

#[test]
fn unconverged_and_residual_fits_are_not_valid_by_default() {
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.5, 0.0);
    let g = fit(50.5, 60.5, 1000.0, 1.5, 1.5, 0.0);
    let default = DisplacementConfig::default();
    for flag in [DotFlags::UNCONVERGED, DotFlags::RESIDUAL] {
        assert!(DisplacementConfig::DEFAULT_INVALID_IF.contains(flag));
        // on either side of the pair
        for (rf, gf) in [(flag, DotFlags::NONE), (DotFlags::NONE, flag)] {
            let (mut r, mut g) = (r, g);
            (r.flags, g.flags) = (rf, gf);
            let p = pair_dot(&input_with(&r, &g), &default).unwrap();
            assert!(!p.valid && p.flags == flag, "{flag}");
            // the quantities are still computed and reported
            assert!(p.displacement.is_some() && p.u_d.is_some());
            // a configuration that keeps the flag keeps the dot valid
            let mut invalid_if = DisplacementConfig::DEFAULT_INVALID_IF;
            invalid_if.remove(flag);
            let keep = DisplacementConfig {
                invalid_if,
                ..default
            };
            assert!(
                pair_dot(&input_with(&r, &g), &keep).unwrap().valid,
                "{flag}"
            );
        }
    }
}

#[test]
fn pair_dot_at_a_records_index_is_pair_dot() {
    let r = fit(50.0, 60.0, 1000.0, 1.5, 1.3, 0.2);
    let mut g = fit(50.4, 59.7, 800.0, 1.7, 1.4, 0.1);
    g.index = GridIndex::new(7, -2);
    let mut failed = fit(f64::NAN, 60.0, 1000.0, 1.5, 1.5, 0.0);
    failed.status = FitStatus::NonFinite;
    let configs = [
        DisplacementConfig::default(),
        notes(),
        DisplacementConfig {
            quantities: Quantities::Displacement,
            ..DisplacementConfig::default()
        },
    ];
    for cfg in &configs {
        for (reference, gradient) in [
            (Some(&r), Some(&g)),
            (Some(&r), None),
            (None, Some(&g)),
            (Some(&r), Some(&failed)),
        ] {
            for stack in [None, Some(stats(10, [0.02, 0.03]))] {
                let input = PairInput {
                    reference,
                    gradient,
                    stack,
                    flags: DotFlags::MASKED,
                };
                let index = reference.or(gradient).unwrap().index;
                // (by their printed form: a failed fit's NaN is not equal to itself)
                assert_eq!(
                    format!("{:?}", pair_dot(&input, cfg)),
                    format!("{:?}", Some(pair_dot_at(&input, index, cfg)))
                );
            }
        }
    }
    // neither record: `pair_dot` has no pair, `pair_dot_at` an unmatched dot without quantities
    let none = PairInput {
        reference: None,
        gradient: None,
        stack: None,
        flags: DotFlags::NONE,
    };
    assert_eq!(pair_dot(&none, &configs[0]), None);
    let p = pair_dot_at(&none, GridIndex::new(1, 2), &configs[0]);
    assert!(p.flags.contains(DotFlags::UNMATCHED) && !p.valid && p.displacement.is_none());
}
