//! Minimum wall time over repeated runs of matching and validation of ~12k dots (a
//! load-robust figure on a shared machine), with the ratio to kiddo's kd-tree build plus 12k
//! nearest queries timed in the same run; or one run of a single operation, for an
//! instruction count:
//!
//! `cargo run --release -p bostrack-match --example match_timing`
//! `valgrind --tool=callgrind target/release/examples/match_timing dots` (or `median`,
//! `plain`, `predictor`, `baseline`, `none`: the data set-up alone, to subtract)
use bostrack_match::{
    MatchConfig, NearestConfig, ValidationConfig, match_dots, match_points, validate,
};
use std::hint::black_box;

#[path = "../benches/common/mod.rs"]
mod common;

type Op<'a> = (&'static str, Box<dyn Fn() + 'a>);

fn main() {
    let f = common::field();
    let (r, g) = (&f.reference, &f.gradient);
    let plain = NearestConfig {
        iterations: 0,
        ..NearestConfig::for_spacing(common::SPACING)
    };
    let default = NearestConfig::for_spacing(common::SPACING);
    let mcfg = MatchConfig::for_spacing(common::SPACING);
    let vcfg = ValidationConfig::default();
    let ops: Vec<Op> = vec![
        (
            "baseline",
            Box::new(|| {
                black_box(common::baseline_kd(r, g));
            }),
        ),
        (
            "dots",
            Box::new(|| {
                drop(black_box(
                    match_dots(&f.reference_dots, &f.gradient_dots, &mcfg).unwrap(),
                ))
            }),
        ),
        (
            "median",
            Box::new(|| drop(black_box(validate(r, &f.displacement, &vcfg).unwrap()))),
        ),
        (
            "plain",
            Box::new(|| drop(black_box(match_points(r, g, &plain).unwrap()))),
        ),
        (
            "predictor",
            Box::new(|| drop(black_box(match_points(r, g, &default).unwrap()))),
        ),
    ];
    let only = std::env::args().nth(1);
    let mut base = f64::NAN;
    for (name, op) in &ops {
        match &only {
            Some(o) if o == name => op(),
            Some(_) => {}
            None => {
                let t = common::min_ms(30, op);
                if *name == "baseline" {
                    base = t;
                }
                println!(
                    "{name:10} {} x {} points: min {t:.3} ms ({:.2} x baseline)",
                    r.len(),
                    g.len(),
                    t / base
                );
            }
        }
    }
}
