//! The pair pipeline on the real sample (`testdata/bos-sample.toml`, 1024 x 1024, ~12k dots):
//!
//! - `pair/fast`: the reference side without a stack (decode, noise from the reference image,
//!   detection, fits) plus one frame (decode, tracking, fits, matching, validation, AR);
//! - `pair/lm_crate`: the same with `[fit] solver = "lm_crate"` (the levenberg-marquardt crate);
//! - `stack/fast`: the reference side with the 10-image no-flow stack (decode, noise model,
//!   detection and fits of the reference, then tracking + fits + matching of every stack image
//!   and the per-dot scatter).
//!
//! Before criterion runs, one timed run of each prints its stage wall times and the
//! lm_crate / fast ratio (same process, same load).
//!
//! `cargo bench -p bostrack-pipeline --bench pair` (skips without the sample data).

use bostrack_fit::Solver;
use bostrack_pipeline::{
    PipelineConfig, Plan, Quantities, ReferenceContext, load_config, process_frame,
};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

fn sample_plan(edit: impl FnOnce(&mut PipelineConfig)) -> Option<Plan> {
    bostrack_io::bos_sample_dir()?;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/bos-sample.toml");
    let mut cfg = load_config(&path).unwrap();
    edit(&mut cfg);
    Some(Plan::from_config(cfg, &path).unwrap())
}

fn pair_plan(solver: Solver) -> Option<Plan> {
    sample_plan(|c| {
        c.input.stack_dir = "".into();
        c.output.quantities = Quantities::Amplification;
        c.fit.solver = solver;
    })
}

/// Reference side + one frame; returns the valid dot count (so nothing is optimised away).
fn run_pair(plan: &Plan) -> usize {
    let ctx = ReferenceContext::prepare(plan).unwrap();
    let r = process_frame(&ctx, plan, &plan.gradients[0]).unwrap();
    r.summary.counts.valid
}

fn timed(plan: &Plan, label: &str) -> f64 {
    let t = Instant::now();
    let ctx = ReferenceContext::prepare(plan).unwrap();
    let r = process_frame(&ctx, plan, &plan.gradients[0]).unwrap();
    let s = t.elapsed().as_secs_f64();
    eprintln!("{label}: {s:.3} s wall");
    eprintln!("  reference stages: {:?}", ctx.timings().stages);
    eprintln!("  frame stages:     {:?}", r.summary.times.stages);
    s
}

fn bench(c: &mut Criterion) {
    let (Some(fast), Some(lm)) = (pair_plan(Solver::Fast), pair_plan(Solver::LmCrate)) else {
        return;
    };
    let stack = sample_plan(|_| {}).unwrap();
    eprintln!(
        "rayon threads: {}, load average: {}",
        rayon::current_num_threads(),
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .trim()
    );
    let tf = timed(&fast, "pair, fast solver");
    let tl = timed(&lm, "pair, lm_crate solver");
    eprintln!("pair: lm_crate / fast = {:.2}", tl / tf);
    timed(&stack, "reference side with the 10-image stack + one frame");

    let mut g = c.benchmark_group("pair");
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    g.bench_function("fast", |b| b.iter(|| black_box(run_pair(&fast))));
    g.bench_function("lm_crate", |b| b.iter(|| black_box(run_pair(&lm))));
    g.finish();

    let mut g = c.benchmark_group("stack");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.bench_function("fast", |b| {
        b.iter(|| black_box(ReferenceContext::prepare(&stack).unwrap().fits().len()))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
