//! Speed of one fit: fits per second for window sizes 5, 9, 13, each model, each sampling
//! (`auto`, the default, `point`, `integrated`),
//! the fast solver and the levenberg-marquardt crate, and the cheap estimators.
//!
//! `CARGO_TARGET_DIR=/work/targets/fit cargo bench -p bostrack-fit --bench fit`

use bostrack_core::{Gaussian2D, NoiseModel, Window};
use bostrack_fit::{Estimator, FitConfig, FitSampling, Fitter, Solver, WindowSamples};
use bostrack_model::{ModelKind, Sampling, render};
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use std::hint::black_box;
use std::time::Duration;

const N_WINDOWS: usize = 64;

/// 64 noisy windows of a dot (sigma 1.5/1.2, rho 0.3, peak SNR 40) at random sub-pixel offsets.
fn windows(half: usize, sampling: Sampling, model: ModelKind) -> Vec<(Window, Vec<f64>)> {
    let mut rng = StdRng::seed_from_u64(7);
    let side = 2 * half + 1;
    let w = Window::new(0, 0, side, side);
    (0..N_WINDOWS)
        .map(|_| {
            let (sy, rho) = match model {
                ModelKind::Elliptical => (1.2, 0.3),
                ModelKind::AxisAligned => (1.2, 0.0),
                ModelKind::Circular => (1.5, 0.0),
            };
            let g = Gaussian2D {
                x0: half as f64 + rng.random_range(-0.5..0.5),
                y0: half as f64 + rng.random_range(-0.5..0.5),
                amplitude: 800.0,
                sigma_x: 1.5,
                sigma_y: sy,
                rho,
                background: 100.0,
            };
            let mut v = render(&g, w, sampling);
            for x in v.iter_mut() {
                let z: f64 = rng.sample(StandardNormal);
                *x += 20.0 * z;
            }
            (w, v)
        })
        .collect()
}

fn run(c: &mut Criterion, group: &str, cfgs: &[(String, FitConfig, usize)]) {
    let mut g = c.benchmark_group(group);
    g.warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
        .sample_size(20);
    g.throughput(Throughput::Elements(N_WINDOWS as u64));
    let noise = NoiseModel::read(20.0);
    for (name, cfg, half) in cfgs {
        let data = windows(*half, cfg.sampling.image_model(), cfg.model);
        let mut fitter = Fitter::new(cfg);
        let start = [*half as f64, *half as f64];
        g.bench_with_input(BenchmarkId::from_parameter(name), &data, |b, data| {
            b.iter(|| {
                for (w, v) in data {
                    let s = WindowSamples {
                        window: *w,
                        values: v,
                        keep: None,
                        saturation: None,
                    };
                    black_box(fitter.fit_samples(&s, start, None, &noise));
                }
            })
        });
    }
    g.finish();
}

fn model_name(m: ModelKind) -> &'static str {
    m.as_str()
}

fn benches(c: &mut Criterion) {
    let base = FitConfig {
        bound: true,
        ..Default::default()
    };
    // solver x sampling x model on 9x9
    let mut cfgs = Vec::new();
    for sampling in [
        FitSampling::Auto,
        FitSampling::Point,
        FitSampling::Integrated,
    ] {
        for model in [
            ModelKind::Elliptical,
            ModelKind::AxisAligned,
            ModelKind::Circular,
        ] {
            for solver in [Solver::Fast, Solver::LmCrate] {
                let name = format!(
                    "{}/{}/{}/9x9",
                    solver.as_str(),
                    sampling.as_str(),
                    model_name(model)
                );
                cfgs.push((
                    name,
                    FitConfig {
                        model,
                        sampling,
                        solver,
                        ..base.clone()
                    },
                    4,
                ));
            }
        }
    }
    run(c, "fit_9x9", &cfgs);
    // window size, elliptical
    let mut cfgs = Vec::new();
    for half in [2, 4, 6] {
        for sampling in [
            FitSampling::Auto,
            FitSampling::Point,
            FitSampling::Integrated,
        ] {
            for solver in [Solver::Fast, Solver::LmCrate] {
                let side = 2 * half + 1;
                let name = format!(
                    "{}/{}/elliptical/{side}x{side}",
                    solver.as_str(),
                    sampling.as_str()
                );
                cfgs.push((
                    name,
                    FitConfig {
                        sampling,
                        solver,
                        ..base.clone()
                    },
                    half,
                ));
            }
        }
    }
    run(c, "fit_window_size", &cfgs);
    // cheap estimators (no bound computation, so the estimator alone is timed)
    let mut cfgs = Vec::new();
    for est in [Estimator::Iwc, Estimator::Tpg] {
        cfgs.push((
            format!("{}/9x9", est.as_str()),
            FitConfig {
                estimator: est,
                bound: false,
                ..base.clone()
            },
            4,
        ));
    }
    cfgs.push((
        "lsg-fast-point-nobound/9x9".into(),
        FitConfig {
            sampling: Sampling::Point.into(),
            bound: false,
            ..base.clone()
        },
        4,
    ));
    run(c, "estimators", &cfgs);
}

criterion_group!(fit, benches);
criterion_main!(fit);
