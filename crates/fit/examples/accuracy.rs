//! Accuracy of the least-squares fit against the exact Cramér-Rao bound, and the bias of a
//! point-sampled model on pixel-integrated dots.
//!
//! `cargo run --release -p bostrack-fit --example accuracy -- [realisations, default 2000]`
//!
//! Part 1: elliptical fits (the default `auto` and the `integrated` model on integrated data,
//! and point on point) over a
//! grid of sigma 0.8-3 px, |rho| <= 0.8, peak SNR 10 and 50, read noise; RMS error / bound and
//! bias per axis. Part 2: the default fit (auto: pixel-integrated below 1 px) for sigma
//! 0.5-0.8 px. Part 3: zero-noise position and sigma bias of a point-sampled and of the default
//! fit on pixel-integrated dots (x0 = +0.25 px off a pixel centre) against sigma.

use bostrack_core::{Gaussian2D, NoiseModel, Window};
use bostrack_fit::study::{AccuracyCase, accuracy};
use bostrack_fit::{FitConfig, FitSampling, Fitter, WindowSamples};
use bostrack_model::{Sampling, render};

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(2000);
    println!(
        "# {n} realisations per case; stat. error of rms/bound ~ {:.3}",
        1.0 / (2.0 * n as f64).sqrt()
    );
    println!(
        "render     fit        sx   sy   rho   snr  half  rms/bound_x rms/bound_y  bias_x(px)  bias_y(px)  +-bias     iter fail"
    );
    let mut worst: f64 = 0.0;
    let mut worst_bias: f64 = 0.0;
    let mut seed = 1;
    for (sampling, fit_sampling) in [
        (Sampling::Integrated, FitSampling::Auto),
        (Sampling::Integrated, FitSampling::Integrated),
        (Sampling::Point, FitSampling::Point),
    ] {
        for (sx, sy) in [(0.8, 0.8), (1.5, 1.5), (3.0, 3.0), (1.5, 0.8), (3.0, 1.5)] {
            for rho in [0.0, 0.5, -0.8] {
                for snr in [10.0, 50.0] {
                    let half = (2.5 * f64::max(sx, sy)).ceil().max(4.0) as usize;
                    let case = AccuracyCase {
                        sigma_x: sx,
                        sigma_y: sy,
                        rho,
                        amplitude: 20.0 * snr,
                        noise: 20.0,
                        half,
                        render: sampling,
                        fit: FitConfig {
                            sampling: fit_sampling,
                            ..Default::default()
                        },
                    };
                    seed += 1;
                    let r = accuracy(&case, n, seed);
                    worst = worst.max(r.rms_over_bound_x).max(r.rms_over_bound_y);
                    worst_bias = worst_bias.max(r.bias_x.abs()).max(r.bias_y.abs());
                    println!(
                        "{:10} {:10} {sx:4} {sy:4} {rho:5} {snr:4} {half:5} {:11.3} {:11.3} {:11.5} {:11.5} {:8.5} {:5.2} {}",
                        name(sampling),
                        fit_sampling.as_str(),
                        r.rms_over_bound_x,
                        r.rms_over_bound_y,
                        r.bias_x,
                        r.bias_y,
                        r.bias_err_x.max(r.bias_err_y),
                        r.mean_iterations,
                        r.failures
                    );
                }
            }
        }
    }
    println!("# part 1 worst rms/bound {worst:.3}, worst |bias| {worst_bias:.5} px");
    let mut worst: f64 = 0.0;
    for s in [0.5, 0.6, 0.7, 0.8] {
        for rho in [0.0, 0.5] {
            for snr in [10.0, 20.0, 50.0, 100.0] {
                let case = AccuracyCase {
                    sigma_x: s,
                    sigma_y: s,
                    rho,
                    amplitude: 20.0 * snr,
                    noise: 20.0,
                    half: 4,
                    render: Sampling::Integrated,
                    fit: FitConfig::default(),
                };
                seed += 1;
                let r = accuracy(&case, n, seed);
                if snr >= 20.0 {
                    worst = worst.max(r.rms_over_bound_x).max(r.rms_over_bound_y);
                }
                println!(
                    "integrated auto       {s:4} {s:4} {rho:5} {snr:4}     4 {:11.3} {:11.3} {:11.5} {:11.5} {:8.5} {:5.2} {}",
                    r.rms_over_bound_x,
                    r.rms_over_bound_y,
                    r.bias_x,
                    r.bias_y,
                    r.bias_err_x.max(r.bias_err_y),
                    r.mean_iterations,
                    r.failures
                );
            }
        }
    }
    println!(
        "# part 2 (sigma 0.5-0.8, integrated data, default (auto) fit, peak SNR >= 20) worst rms/bound {worst:.3}"
    );
    println!(
        "# part 3: zero noise, dot at +0.25 px in x, +0.10 px in y from a pixel centre, integrated data"
    );
    println!("sigma  point_bias_x  point_bias_y  point_sigma/true  auto_bias_x  auto_sigma/true");
    for s in [0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.5, 2.0] {
        let g = Gaussian2D {
            x0: 4.25,
            y0: 4.1,
            amplitude: 1000.0,
            sigma_x: s,
            sigma_y: s,
            rho: 0.0,
            background: 100.0,
        };
        let w = Window::new(0, 0, 9, 9);
        let v = render(&g, w, Sampling::Integrated);
        let s_in = WindowSamples {
            window: w,
            values: &v,
            keep: None,
            saturation: None,
        };
        let nm = NoiseModel::read(1.0);
        let p = Fitter::new(&FitConfig {
            sampling: Sampling::Point.into(),
            ..Default::default()
        })
        .fit_samples(&s_in, [4.0, 4.0], None, &nm);
        let i = Fitter::new(&FitConfig::default()).fit_samples(&s_in, [4.0, 4.0], None, &nm);
        println!(
            "{s:5} {:13.2e} {:13.2e} {:17.4} {:12.2e} {:15.6}",
            p.params.x0 - g.x0,
            p.params.y0 - g.y0,
            p.params.sigma_x / s,
            i.params.x0 - g.x0,
            i.params.sigma_x / s
        );
    }
}

fn name(s: Sampling) -> &'static str {
    match s {
        Sampling::Point => "point",
        Sampling::Integrated => "integrated",
    }
}
