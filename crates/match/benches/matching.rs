//! Matching and validation of ~12k dots (`common::field`: a 110 x 110 lattice of spacing 8 px
//! moved by a smooth field of up to ~2 px plus 0.03 px noise).
//!
//! `cargo bench -p bostrack-match --bench matching`
//!
//! First a table of minimum wall times over 30 runs with their ratios to baselines measured in
//! the same run (kiddo's kd-tree build over the 12k gradient dots, and that build plus one
//! nearest-neighbour query per reference dot), so that results from a loaded or another
//! machine compare; then the criterion measurements.
use bostrack_match::{
    MatchConfig, NearestConfig, ValidationConfig, match_dots, match_points, validate,
};
use criterion::Criterion;
use std::hint::black_box;

#[path = "common/mod.rs"]
mod common;

fn ratio_table(f: &common::Field) {
    let (r, g) = (&f.reference, &f.gradient);
    let plain = NearestConfig {
        iterations: 0,
        ..NearestConfig::for_spacing(common::SPACING)
    };
    let default = NearestConfig::for_spacing(common::SPACING);
    let mcfg = MatchConfig::for_spacing(common::SPACING);
    let vcfg = ValidationConfig::default();
    let build = common::min_ms(30, || {
        black_box(common::baseline_build(g));
    });
    let kd = common::min_ms(30, || {
        black_box(common::baseline_kd(r, g));
    });
    println!(
        "{} reference x {} gradient dots; baselines: kd-tree build {build:.3} ms, build + {} nearest queries {kd:.3} ms",
        r.len(),
        g.len(),
        r.len()
    );
    type Row<'a> = (&'static str, Box<dyn Fn() + 'a>);
    let rows: [Row; 4] = [
        (
            "match_dots (grid index)",
            Box::new(|| {
                drop(black_box(
                    match_dots(&f.reference_dots, &f.gradient_dots, &mcfg).unwrap(),
                ))
            }),
        ),
        (
            "validate (median test)",
            Box::new(|| drop(black_box(validate(r, &f.displacement, &vcfg).unwrap()))),
        ),
        (
            "match_points, plain",
            Box::new(|| drop(black_box(match_points(r, g, &plain).unwrap()))),
        ),
        (
            "match_points, predictor",
            Box::new(|| drop(black_box(match_points(r, g, &default).unwrap()))),
        ),
    ];
    for (name, op) in &rows {
        let t = common::min_ms(30, op);
        println!(
            "{name:26} min {t:6.3} ms = {:5.2} x build, {:5.2} x build + queries",
            t / build,
            t / kd
        );
    }
}

fn benches(c: &mut Criterion, f: &common::Field) {
    let (r, g) = (&f.reference, &f.gradient);
    c.bench_function("baseline_kdtree_build_12k", |b| {
        b.iter(|| common::baseline_build(black_box(g)))
    });
    c.bench_function("baseline_kdtree_build_and_12k_nearest", |b| {
        b.iter(|| common::baseline_kd(black_box(r), black_box(g)))
    });
    let mcfg = MatchConfig::for_spacing(common::SPACING);
    c.bench_function("match_dots_12k_grid_index", |b| {
        b.iter(|| {
            match_dots(
                black_box(&f.reference_dots),
                black_box(&f.gradient_dots),
                &mcfg,
            )
            .unwrap()
        })
    });
    let vcfg = ValidationConfig::default();
    c.bench_function("validate_12k_median_test", |b| {
        b.iter(|| validate(black_box(r), black_box(&f.displacement), &vcfg).unwrap())
    });
    let plain = NearestConfig {
        iterations: 0,
        ..NearestConfig::for_spacing(common::SPACING)
    };
    c.bench_function("match_points_12k_plain", |b| {
        b.iter(|| match_points(black_box(r), black_box(g), &plain).unwrap())
    });
    let default = NearestConfig::for_spacing(common::SPACING);
    c.bench_function("match_points_12k_with_predictor", |b| {
        b.iter(|| match_points(black_box(r), black_box(g), &default).unwrap())
    });
}

fn main() {
    let f = common::field();
    let m = match_dots(
        &f.reference_dots,
        &f.gradient_dots,
        &MatchConfig::for_spacing(common::SPACING),
    )
    .unwrap();
    assert_eq!(m.pairs.len(), f.reference.len());
    assert_eq!(m.grid_mismatches(), 0);
    ratio_table(&f);
    let mut c = Criterion::default().configure_from_args();
    benches(&mut c, &f);
    c.final_summary();
}
