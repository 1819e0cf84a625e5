//! Is the excess over the bound at low SNR the estimator's or the solver's? Fits the same noisy
//! windows (integrated data and model, read noise, 20,000 realisations) once from the usual
//! centroid start and once from the true parameters, and prints RMS / exact bound for both.
//! Equal numbers mean the least-squares estimate itself is above the bound (small-sample
//! inefficiency), not the path the solver takes to it.
//!
//! `cargo run --release -p bostrack-fit --example ls_from_truth`

use bostrack_core::{Gaussian2D, NoiseModel, Window};
use bostrack_fit::{FitConfig, FitSampling, Fitter, WindowSamples};
use bostrack_model::{ModelKind, Sampling, add_dot};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
fn main() {
    let n = 20000;
    for (sx, sy, rho, snr) in [
        (0.8, 0.8, -0.8, 10.0),
        (0.8, 0.8, 0.5, 10.0),
        (1.5, 1.5, 0.0, 10.0),
    ] {
        for truth_start in [false, true] {
            for s in [FitSampling::Integrated] {
                let mut rng = StdRng::seed_from_u64(5);
                let w = Window::new(0, 0, 9, 9);
                let noise = NoiseModel::read(20.0);
                let mut f = Fitter::new(&FitConfig {
                    sampling: s,
                    ..Default::default()
                });
                let (mut a, mut b, mut k, mut fail) = (0.0, 0.0, 0.0, 0);
                let mut vals = vec![0.0; 81];
                for _ in 0..n {
                    let g = Gaussian2D {
                        x0: 4.0 + rng.random_range(-0.5..0.5),
                        y0: 4.0 + rng.random_range(-0.5..0.5),
                        amplitude: 20.0 * snr,
                        sigma_x: sx,
                        sigma_y: sy,
                        rho,
                        background: 100.0,
                    };
                    vals.iter_mut().for_each(|v| *v = 100.0);
                    add_dot(&g, w, Sampling::Integrated, &mut vals);
                    for v in vals.iter_mut() {
                        let z: f64 = rng.sample(StandardNormal);
                        *v += 20.0 * z;
                    }
                    let bd = bostrack_model::crlb(
                        &g,
                        w,
                        &noise,
                        Sampling::Integrated,
                        ModelKind::Elliptical,
                    )
                    .unwrap();
                    let smp = WindowSamples {
                        window: w,
                        values: &vals,
                        keep: None,
                        saturation: None,
                    };
                    let r = if truth_start {
                        f.fit_samples(&smp, [g.x0, g.y0], Some(&g), &noise)
                    } else {
                        f.fit_samples(&smp, [4.0, 4.0], None, &noise)
                    };
                    let (dx, dy) = (r.params.x0 - g.x0, r.params.y0 - g.y0);
                    if !(r.status.is_ok() && dx.abs() < 1.0 && dy.abs() < 1.0) {
                        fail += 1;
                        continue;
                    }
                    a += (dx / bd.std[0]).powi(2);
                    b += (dy / bd.std[1]).powi(2);
                    k += 1.0;
                }
                println!(
                    "{sx} {sy} {rho} snr {snr} truth_start {truth_start} {s:?}: rms/bound {:.3} {:.3} fail {fail}",
                    (a / k).sqrt(),
                    (b / k).sqrt()
                );
            }
        }
    }
}
