//! Plain timing harness (also for `valgrind --tool=callgrind`): fits the same 64 noisy 9x9
//! windows over and over with one configuration and prints µs per fit and mean iterations.
//!
//! `cargo run --release -p bostrack-fit --example fit_speed -- [auto|point|integrated] [elliptical|axis_aligned|circular] [fast|lm_crate|iwc|tpg] [fits] [half]`

use bostrack_core::{Gaussian2D, NoiseModel, Window};
use bostrack_fit::{Estimator, FitConfig, FitSampling, Fitter, Solver, WindowSamples};
use bostrack_model::{ModelKind, render};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, d: &str| args.get(i).cloned().unwrap_or_else(|| d.to_string());
    let sampling = match arg(1, "auto").as_str() {
        "point" => FitSampling::Point,
        "integrated" => FitSampling::Integrated,
        _ => FitSampling::Auto,
    };
    let model = match arg(2, "elliptical").as_str() {
        "axis_aligned" => ModelKind::AxisAligned,
        "circular" => ModelKind::Circular,
        _ => ModelKind::Elliptical,
    };
    let (estimator, solver) = match arg(3, "fast").as_str() {
        "lm_crate" => (Estimator::Lsg, Solver::LmCrate),
        "iwc" => (Estimator::Iwc, Solver::Fast),
        "tpg" => (Estimator::Tpg, Solver::Fast),
        _ => (Estimator::Lsg, Solver::Fast),
    };
    let n: usize = arg(4, "100000").parse().unwrap_or(100_000);
    let half: usize = arg(5, "4").parse().unwrap_or(4);
    let mut cfg = FitConfig {
        model,
        sampling,
        estimator,
        solver,
        bound: estimator == Estimator::Lsg,
        ..Default::default()
    };
    if let Some(t) = std::env::var("FIT_TOL").ok().and_then(|t| t.parse().ok()) {
        cfg.tolerance = t;
    }
    let mut rng = StdRng::seed_from_u64(7);
    let side = 2 * half + 1;
    let w = Window::new(0, 0, side, side);
    let (sy, rho) = match model {
        ModelKind::Elliptical => (1.2, 0.3),
        ModelKind::AxisAligned => (1.2, 0.0),
        ModelKind::Circular => (1.5, 0.0),
    };
    let data: Vec<Vec<f64>> = (0..64)
        .map(|_| {
            let g = Gaussian2D {
                x0: half as f64 + rng.random_range(-0.5..0.5),
                y0: half as f64 + rng.random_range(-0.5..0.5),
                amplitude: 800.0,
                sigma_x: 1.5,
                sigma_y: sy,
                rho,
                background: 100.0,
            };
            let mut v = render(&g, w, sampling.image_model());
            for x in v.iter_mut() {
                let z: f64 = rng.sample(StandardNormal);
                *x += 20.0 * z;
            }
            v
        })
        .collect();
    let noise = NoiseModel::read(20.0);
    let mut fitter = Fitter::new(&cfg);
    let start = [half as f64, half as f64];
    let mut iters = 0u64;
    let mut ok = 0usize;
    let t = Instant::now();
    for k in 0..n {
        let v = &data[k % 64];
        let s = WindowSamples {
            window: w,
            values: v,
            keep: None,
            saturation: None,
        };
        let f = fitter.fit_samples(&s, start, None, &noise);
        iters += f.iterations as u64;
        ok += f.status.is_ok() as usize;
    }
    let dt = t.elapsed().as_secs_f64();
    println!(
        "{:?} {:?} {:?} {:?} {side}x{side}: {:.3} us/fit, {:.0} fits/s, mean iterations {:.2}, ok {}/{}",
        sampling,
        model,
        estimator,
        solver,
        dt * 1e6 / n as f64,
        n as f64 / dt,
        iters as f64 / n as f64,
        ok,
        n
    );
}
