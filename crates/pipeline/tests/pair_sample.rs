//! The pair pipeline on the real sample campaign (`testdata/bos-sample.toml`): everything runs,
//! the noise model comes from the no-flow stack, and the per-dot bound of the reference fits
//! agrees with the scatter measured over the stack.
//!
//! Release build only (the stack alone is 10 x 12k fits): CI runs it with `--release`.
//! `cargo test --release -p bostrack-pipeline --test pair_sample -- --nocapture` prints the
//! measurements.

use bostrack_pipeline::{Plan, ReferenceContext, process_frame};
use std::path::Path;

/// The flow region of the sample (its README): rows ~700-860, columns ~380-640.
fn in_flow(x: f64, y: f64) -> bool {
    (380.0..=640.0).contains(&x) && (700.0..=860.0).contains(&y)
}

fn median(mut v: Vec<f64>) -> f64 {
    assert!(!v.is_empty());
    bostrack_core::median(&mut v)
}

fn p99(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * 0.99).round() as usize]
}

#[test]
#[cfg_attr(debug_assertions, ignore = "release build only (cargo test --release)")]
fn real_sample_pair_runs_and_the_bound_agrees_with_the_stack() {
    let Some(_) = bostrack_io::bos_sample_dir() else {
        return;
    };
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/bos-sample.toml");
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    let frame = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
    let s = &frame.summary;

    // the noise model comes from the stack, and the stack was fitted
    assert_eq!(ctx.noise().1, "stack");
    let stack = ctx.stack_summary().expect("stack statistics");
    assert_eq!(stack.images, 10);
    assert!(s.stack_note.is_none());

    // everything that was fitted in the reference is matched (a few dots lost at most)
    let matched_fraction = s.counts.matched as f64 / s.counts.reference_fitted as f64;
    eprintln!("counts: {:?}", s.counts);
    eprintln!("matched fraction: {matched_fraction:.4}");
    assert!(matched_fraction > 0.98, "{matched_fraction}");
    assert!(s.counts.valid as f64 > 0.95 * s.counts.reference_fitted as f64);

    // no dot whose centre lies outside the mask is valid (before the `outside_mask` flag, 19
    // such dots were valid and counted while the figures drew them as "outside mask")
    let mask = ctx.mask().expect("the sample's mask");
    let outside = |p: [f64; 2]| !mask.keeps_point(p[0], p[1]);
    let flagged = frame
        .dots
        .iter()
        .filter(|d| d.flags.contains(bostrack_core::DotFlags::OUTSIDE_MASK))
        .count();
    let valid_outside = frame
        .dots
        .iter()
        .filter(|d| d.valid && d.reference_position.is_some_and(outside))
        .count();
    eprintln!(
        "dots flagged outside_mask: {flagged}; valid with the centre outside: {valid_outside}"
    );
    assert_eq!(valid_outside, 0);
    assert!(flagged >= 10, "{flagged}");

    // AR inside and outside the flow region
    let mut ar_in = Vec::new();
    let mut ar_out = Vec::new();
    for d in frame.dots.iter().filter(|d| d.valid) {
        let (Some(p), Some(ar)) = (d.reference_position, d.ar) else {
            continue;
        };
        let v = if in_flow(p[0], p[1]) {
            &mut ar_in
        } else {
            &mut ar_out
        };
        v.extend(ar);
    }
    let (ar_in_med, ar_in_99) = (median(ar_in.clone()), p99(ar_in.clone()));
    let (ar_out_med, ar_out_99) = (median(ar_out.clone()), p99(ar_out.clone()));
    eprintln!(
        "AR inside the flow: median {ar_in_med:.4}, p99 {ar_in_99:.4} ({} values); outside: median {ar_out_med:.4}, p99 {ar_out_99:.4} ({} values)",
        ar_in.len(),
        ar_out.len()
    );
    // outside the flow the dots are the same in both images: AR = 1 up to fit noise
    assert!((ar_out_med - 1.0).abs() < 0.02, "{ar_out_med}");
    // inside, the blur of the flow makes the gradient dots worse
    assert!(ar_in_med > ar_out_med, "{ar_in_med} vs {ar_out_med}");

    // the `bounds` variant on the same pairs: the ratio of the two fits' own bounds under the
    // stack's read + shot noise model (the closed form assumes signal-independent noise)
    let (mut b_in, mut b_out) = (Vec::new(), Vec::new());
    for d in frame.dots.iter().filter(|d| d.valid && d.ar.is_some()) {
        let (Some(r), Some(g), Some(p)) = (d.reference, d.gradient, d.reference_position) else {
            continue;
        };
        let b = bostrack_model::bound_ratio([r.crlb_x, r.crlb_y], [g.crlb_x, g.crlb_y]);
        let v = if in_flow(p[0], p[1]) {
            &mut b_in
        } else {
            &mut b_out
        };
        v.extend(b.into_iter().filter(|x| x.is_finite()));
    }
    let (b_in_med, b_out_med) = (median(b_in.clone()), median(b_out.clone()));
    eprintln!(
        "bounds AR inside the flow: median {b_in_med:.4}, p99 {:.4}; outside: median {b_out_med:.4}, p99 {:.4}",
        p99(b_in.clone()),
        p99(b_out.clone())
    );
    assert!((b_out_med - 1.0).abs() < 0.02, "{b_out_med}");
    assert!(b_in_med > b_out_med, "{b_in_med} vs {b_out_med}");

    // the per-dot bound of the reference fits against the stack's u_ref: the same quantity
    // measured two ways (the bound from the fitted shape and the noise model, the scatter from
    // 10 independent images), per axis, over the dots that have both. Measured: u_ref/crlb =
    // 0.94 in x, 1.10 in y. Why they differ: (1) the median of a sample std from K = 10 is
    // sqrt(median(χ²_9)/9) = 0.963 of σ, so the medians compare as 0.963 at best; (2) the
    // excess in y is spatial: median u_ref_y/crlb_y over a 4x4 grid of regions runs from 0.92
    // (centre, bottom) to 1.43 (top right), i.e. the stack images move relative to each other
    // by more than a translation (a small rotation/deformation, which common-mode removal of a
    // per-image shift does not take out); (3) the noise model is a straight line through a
    // variance-vs-mean curve that is not straight (bostrack-fit README), which sets the bound
    // a few % high where the x scatter is below it.
    let u_ref = ctx.u_ref();
    for axis in 0..2 {
        let mut crlb = Vec::new();
        let mut u = Vec::new();
        for (f, u_i) in ctx.fits().iter().zip(&u_ref) {
            if let Some(u_i) = u_i
                && f.status.is_ok()
            {
                let c = if axis == 0 { f.crlb_x } else { f.crlb_y };
                if c.is_finite() {
                    crlb.push(c);
                    u.push(u_i[axis]);
                }
            }
        }
        let (mc, mu) = (median(crlb.clone()), median(u.clone()));
        let ratio = mu / mc;
        eprintln!(
            "axis {axis}: median crlb {mc:.5} px, median u_ref {mu:.5} px, ratio {ratio:.3} ({} dots)",
            crlb.len()
        );
        assert!(
            (ratio - 1.0).abs() < 0.25,
            "axis {axis}: u_ref/crlb = {ratio}"
        );
    }

    eprintln!("reference stages: {:?}", ctx.timings().stages);
    eprintln!("frame stages: {:?}", s.times.stages);
    eprintln!("noise: {:?}", s.noise);
    eprintln!("stack: {:?}", s.stack);
    eprintln!("medians: {:?}", s.medians);
}
