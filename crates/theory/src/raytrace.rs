//! A ray tracer of one BOS dot image (paper Eqs. 3 and 8): many rays over the aperture cone,
//! each deflected by the local density gradient of a quadratic density field, landing on the
//! sensor and deposited as a pixel-integrated Gaussian spot of the reference dot's sigma.
//!
//! It shares no formula with the effective model beyond the physics: landing points come from
//! geometry (a ray from the dot, bent in the slab, traced back straight from the camera to the
//! target plane and imaged with magnification M), so comparing its moments with
//! [`crate::predict`] checks Eqs. 18, 25-26 and the cross term, and shows where they fail.

use crate::TheoryError;
use crate::error::invalid;
use crate::optics::{Aperture, camera_gradient, camera_hessian, cone_angle_geometric};
use crate::setup::{Design, PathGeometry, Setup};
use bostrack_core::{Gaussian2D, Window};
use bostrack_model::{Sampling, render};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_4, PI, SQRT_2};

/// How a ray crosses the slab.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Propagation {
    /// One deflection at the slab's mid-plane, `ε = K Δz ∇⊥ρ(t_mid) / n0`, from the gradient
    /// where the straight ray crosses that plane: the paper's per-ray model (Eq. 6, 8).
    #[default]
    ThinSlab,
    /// The paraxial ray equation `d²t/ds² = ∇⊥n / n`, `n = n0 + K (ρ - ρ_c)`, integrated
    /// through the slab (velocity Verlet, `steps` steps): the ray bends inside the slab, sees
    /// the gradient where it actually is, and sees the field's variation along the path.
    Slab { steps: usize },
}

/// Ray-tracing parameters. Defaults in brackets.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RayTraceConfig {
    /// Number of rays \[40 000; at most 10 000 000\]; rounded up to a square: the aperture is
    /// stratified into `n × n` cells with one jittered ray each.
    pub rays: usize,
    /// Seed of the jitter \[0\]. The same seed gives the same image.
    pub seed: u64,
    /// How rays cross the slab \[thin_slab\].
    pub propagation: Propagation,
    /// Ray-angle distribution [none: the setup's `optics.aperture`].
    pub aperture: Option<Aperture>,
    /// Half-width of the rendered window (px) \[none: enough for every ray plus 5 σ_ref\].
    pub half_width_px: Option<usize>,
}

impl Default for RayTraceConfig {
    fn default() -> Self {
        RayTraceConfig {
            rays: 40_000,
            seed: 0,
            propagation: Propagation::ThinSlab,
            aperture: None,
            half_width_px: None,
        }
    }
}

/// Moments of a dot image (px).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DotMoments {
    /// Centroid.
    pub x0: f64,
    pub y0: f64,
    /// Standard deviations and correlation from the second central moments.
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
    /// Excess kurtosis `μ4 / σ⁴ - 3` of the x and y marginals (0 for a Gaussian, -1.2 for a
    /// uniform distribution, -1 for a uniform disc).
    pub excess_kurtosis_x: f64,
    pub excess_kurtosis_y: f64,
}

/// A ray-traced dot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RayTrace {
    /// The rendered window and its pixel-integrated values (counts above background,
    /// row-major); they sum to `captured · exposure`.
    pub window: Window,
    pub image: Vec<f64>,
    /// Rays traced (a square number).
    pub rays: usize,
    /// Sigma of each ray's spot: the reference dot's (diffraction and printed dot) (px).
    pub spot_sigma: f64,
    /// Exposure α0 shared by the rays (counts·px²).
    pub exposure: f64,
    /// Moments of the ray landing points alone (no spot): `sigma` is the blur.
    pub landing: DotMoments,
    /// Moments of the continuous dot: landing points convolved with the spot (the spot adds
    /// `σ_ref²` to the variances, nothing to the cross moment, and no fourth cumulant). This is
    /// what Eqs. 18-26 predict.
    pub dot: DotMoments,
    /// Moments measured on the pixels, with Sheppard's corrections for the unit pixel box
    /// (second moments less `1/12`, fourth `μ4 - μ2/2 + 7/240`).
    pub image_moments: DotMoments,
    /// Relative L2 distance `‖image - G‖ / ‖image‖` to the pixel-integrated Gaussian `G` with
    /// the moments `dot` and the exposure: 0 for a Gaussian dot, grows as the aperture's shape
    /// shows through.
    pub gaussian_residual: f64,
    /// Fraction of the exposure inside the window.
    pub captured: f64,
}

/// Trace a BOS dot through the setup's density field (quadratic: the setup's first and second
/// derivatives about the point where the chief ray crosses the slab's mid-plane), as seen
/// through its viewing angles (the field is rotated into the camera frame; the target stays
/// perpendicular to the line of sight). Uses the *geometric* cone angle: the gradient term of
/// Eq. 24 is not physics the tracer can reproduce (see docs/theory.md).
pub fn ray_trace(setup: &Setup, cfg: &RayTraceConfig) -> Result<RayTrace, TheoryError> {
    let d = Design::from_setup(setup)?;
    let PathGeometry::Bos { z_d, delta_z } = d.geometry else {
        return Err(TheoryError::Unsupported(
            "the ray tracer traces BOS geometries only (geometry.kind = \"bos\")".into(),
        ));
    };
    if cfg.rays == 0 || cfg.rays > 10_000_000 {
        return Err(invalid(
            "rays",
            format!("must be in 1..=10000000, got {}", cfg.rays),
        ));
    }
    if let Propagation::Slab { steps } = cfg.propagation
        && !(1..=100_000).contains(&steps)
    {
        return Err(invalid(
            "propagation.steps",
            format!("must be in 1..=100000, got {steps}"),
        ));
    }
    let aperture = cfg.aperture.unwrap_or(d.aperture);
    let cone = cone_angle_geometric(d.f_number, d.m);
    let g3 = camera_gradient(&d.rotation, d.gradient);
    let h3 = camera_hessian(&d.rotation, &d.hessian).matrix();
    let (k, n0) = (d.k, d.n0);
    // density relative to the slab centre, at transverse t and longitudinal camera coordinate
    // zc (z points from the camera to the target: a point at distance s from the target has
    // zc = Z_D - s), and its transverse gradient
    let field = |t: [f64; 2], zc: f64| -> (f64, [f64; 2]) {
        let p = [t[0], t[1], zc];
        let mut grad = [0.0; 3];
        let mut rho = 0.0;
        for i in 0..3 {
            let hp: f64 = (0..3).map(|j| h3[i][j] * p[j]).sum();
            grad[i] = g3[i] + hp;
            rho += p[i] * (g3[i] + 0.5 * hp);
        }
        (rho, [grad[0], grad[1]])
    };

    // landing points (px)
    let side = (cfg.rays as f64).sqrt().ceil() as usize;
    let n = side * side;
    let mut rng = StdRng::seed_from_u64(cfg.seed);
    let to_px = d.m / d.pitch_m;
    let mut pts = Vec::with_capacity(n);
    for i in 0..side {
        for j in 0..side {
            let u = (i as f64 + rng.random::<f64>()) / side as f64 - 0.5;
            let v = (j as f64 + rng.random::<f64>()) / side as f64 - 0.5;
            let th = match aperture {
                Aperture::Square => [cone * u, cone * v],
                Aperture::Circular => {
                    let c = concentric_disc(2.0 * u, 2.0 * v);
                    [0.5 * cone * c[0], 0.5 * cone * c[1]]
                }
            };
            let app = match cfg.propagation {
                Propagation::ThinSlab => {
                    let t = [z_d * th[0], z_d * th[1]];
                    let (_, gr) = field(t, 0.0);
                    // deflected at the mid-plane, then traced back straight to the target plane
                    let out = [
                        th[0] + k * delta_z * gr[0] / n0,
                        th[1] + k * delta_z * gr[1] / n0,
                    ];
                    [t[0] - out[0] * z_d, t[1] - out[1] * z_d]
                }
                Propagation::Slab { steps } => {
                    let h = delta_z / steps as f64;
                    let mut s = z_d - 0.5 * delta_z;
                    let mut t = [s * th[0], s * th[1]];
                    let mut v = th;
                    let accel = |t: [f64; 2], s: f64| {
                        let (rho, gr) = field(t, z_d - s);
                        let nn = n0 + k * rho;
                        [k * gr[0] / nn, k * gr[1] / nn]
                    };
                    let mut a = accel(t, s);
                    for _ in 0..steps {
                        v = [v[0] + 0.5 * h * a[0], v[1] + 0.5 * h * a[1]];
                        t = [t[0] + h * v[0], t[1] + h * v[1]];
                        s += h;
                        a = accel(t, s);
                        v = [v[0] + 0.5 * h * a[0], v[1] + 0.5 * h * a[1]];
                    }
                    [t[0] - v[0] * s, t[1] - v[1] * s]
                }
            };
            pts.push([
                d.position[0] + to_px * app[0],
                d.position[1] + to_px * app[1],
            ]);
        }
    }
    let sigma = d.sigma_ref();
    let exposure = d.exposure();
    let landing = sample_moments(&pts);
    let (vx, vy) = (landing.sigma_x.powi(2), landing.sigma_y.powi(2));
    let dvx = vx + sigma * sigma;
    let dvy = vy + sigma * sigma;
    let dot = DotMoments {
        x0: landing.x0,
        y0: landing.y0,
        sigma_x: dvx.sqrt(),
        sigma_y: dvy.sqrt(),
        rho: landing.rho * landing.sigma_x * landing.sigma_y / (dvx * dvy).sqrt(),
        excess_kurtosis_x: landing.excess_kurtosis_x * (vx / dvx).powi(2),
        excess_kurtosis_y: landing.excess_kurtosis_y * (vy / dvy).powi(2),
    };

    // window and rendering
    let window = match cfg.half_width_px {
        Some(h) => Window::centred(landing.x0, landing.y0, h),
        None => {
            let reach = pts
                .iter()
                .map(|p| (p[0] - landing.x0).abs().max((p[1] - landing.y0).abs()))
                .fold(0.0, f64::max);
            let half = (reach + 5.0 * sigma).ceil() as usize + 1;
            if half > 500 {
                return Err(invalid(
                    "half_width_px",
                    format!("the dot spreads over ±{half} px; give a half-width of at most 500"),
                ));
            }
            Window::centred(landing.x0, landing.y0, half)
        }
    };
    let image = deposit(&pts, sigma, exposure / n as f64, window);
    let image_moments = image_moments(&image, window);
    let total: f64 = image.iter().sum();
    let model = Gaussian2D {
        x0: dot.x0,
        y0: dot.y0,
        amplitude: exposure
            / (2.0 * PI * dot.sigma_x * dot.sigma_y * (1.0 - dot.rho * dot.rho).sqrt()),
        sigma_x: dot.sigma_x,
        sigma_y: dot.sigma_y,
        rho: dot.rho,
        background: 0.0,
    };
    let g = render(&model, window, Sampling::Integrated);
    let num: f64 = image.iter().zip(&g).map(|(a, b)| (a - b).powi(2)).sum();
    let den: f64 = image.iter().map(|a| a * a).sum();
    Ok(RayTrace {
        window,
        image,
        rays: n,
        spot_sigma: sigma,
        exposure,
        landing,
        dot,
        image_moments,
        gaussian_residual: (num / den).sqrt(),
        captured: total / exposure,
    })
}

/// Shirley & Chiu's concentric map of the square `[-1, 1]²` onto the unit disc (area
/// preserving, so stratification survives).
fn concentric_disc(a: f64, b: f64) -> [f64; 2] {
    if a == 0.0 && b == 0.0 {
        return [0.0, 0.0];
    }
    let (r, phi) = if a.abs() > b.abs() {
        (a, FRAC_PI_4 * (b / a))
    } else {
        (b, 2.0 * FRAC_PI_4 - FRAC_PI_4 * (a / b))
    };
    [r * phi.cos(), r * phi.sin()]
}

/// Mean, covariance and marginal excess kurtosis of points (population moments).
fn sample_moments(pts: &[[f64; 2]]) -> DotMoments {
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p[0]).sum::<f64>() / n;
    let my = pts.iter().map(|p| p[1]).sum::<f64>() / n;
    let (mut xx, mut xy, mut yy, mut x4, mut y4) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in pts {
        let (dx, dy) = (p[0] - mx, p[1] - my);
        xx += dx * dx;
        xy += dx * dy;
        yy += dy * dy;
        x4 += dx.powi(4);
        y4 += dy.powi(4);
    }
    let (xx, xy, yy, x4, y4) = (xx / n, xy / n, yy / n, x4 / n, y4 / n);
    let kurt = |m4: f64, m2: f64| if m2 > 0.0 { m4 / (m2 * m2) - 3.0 } else { 0.0 };
    let (sx, sy) = (xx.sqrt(), yy.sqrt());
    DotMoments {
        x0: mx,
        y0: my,
        sigma_x: sx,
        sigma_y: sy,
        rho: if sx > 0.0 && sy > 0.0 {
            xy / (sx * sy)
        } else {
            0.0
        },
        excess_kurtosis_x: kurt(x4, xx),
        excess_kurtosis_y: kurt(y4, yy),
    }
}

/// Pixel-integrated isotropic Gaussian spots of weight `w` (their integral) at every point,
/// over `window`: per spot, one erf difference per column and per row, then their outer
/// product (the spot is separable). Equals `bostrack_model::add_dot` with a circular dot of
/// amplitude `w / (2π σ²)` (tested).
fn deposit(pts: &[[f64; 2]], sigma: f64, w: f64, window: Window) -> Vec<f64> {
    let (wd, ht) = (window.width, window.height);
    let mut out = vec![0.0; wd * ht];
    let mut ex = vec![0.0; wd];
    let mut ey = vec![0.0; ht];
    let s = 1.0 / (SQRT_2 * sigma);
    let edges = |start: i64, len: usize, c: f64, e: &mut [f64]| {
        let mut lo = libm::erf((start as f64 - 0.5 - c) * s);
        for (i, v) in e.iter_mut().enumerate().take(len) {
            let hi = libm::erf((start as f64 + i as f64 + 0.5 - c) * s);
            *v = 0.5 * (hi - lo);
            lo = hi;
        }
    };
    for p in pts {
        edges(window.x, wd, p[0], &mut ex);
        edges(window.y, ht, p[1], &mut ey);
        for (r, &fy) in ey.iter().enumerate() {
            if fy < 1e-300 {
                continue;
            }
            let f = w * fy;
            for (o, &fx) in out[r * wd..(r + 1) * wd].iter_mut().zip(&ex) {
                *o += f * fx;
            }
        }
    }
    out
}

/// Centroid and Sheppard-corrected moments of a window's pixel values.
fn image_moments(img: &[f64], w: Window) -> DotMoments {
    let mut s0 = 0.0;
    let (mut sx, mut sy) = (0.0, 0.0);
    for r in 0..w.height {
        for c in 0..w.width {
            let v = img[r * w.width + c];
            s0 += v;
            sx += v * (w.x + c as i64) as f64;
            sy += v * (w.y + r as i64) as f64;
        }
    }
    let (mx, my) = (sx / s0, sy / s0);
    let (mut xx, mut xy, mut yy, mut x4, mut y4) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for r in 0..w.height {
        for c in 0..w.width {
            let v = img[r * w.width + c];
            let dx = (w.x + c as i64) as f64 - mx;
            let dy = (w.y + r as i64) as f64 - my;
            xx += v * dx * dx;
            xy += v * dx * dy;
            yy += v * dy * dy;
            x4 += v * dx.powi(4);
            y4 += v * dy.powi(4);
        }
    }
    let (xx, yy) = (xx / s0, yy / s0);
    let vx = xx - 1.0 / 12.0;
    let vy = yy - 1.0 / 12.0;
    let kurt = |m4: f64, m2: f64, v: f64| {
        if v > 0.0 {
            (m4 / s0 - 0.5 * m2 + 7.0 / 240.0) / (v * v) - 3.0
        } else {
            0.0
        }
    };
    let (sx, sy) = (vx.max(0.0).sqrt(), vy.max(0.0).sqrt());
    DotMoments {
        x0: mx,
        y0: my,
        sigma_x: sx,
        sigma_y: sy,
        rho: if sx > 0.0 && sy > 0.0 {
            xy / s0 / (sx * sy)
        } else {
            0.0
        },
        excess_kurtosis_x: kurt(x4, xx, vx),
        excess_kurtosis_y: kurt(y4, yy, vy),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bostrack_model::add_dot;

    #[test]
    fn deposit_matches_the_model_crate() {
        let w = Window::new(-6, -5, 13, 12);
        let pts = [[0.3, -0.45], [1.7, 2.2]];
        let img = deposit(&pts, 1.1, 250.0, w);
        let mut want = vec![0.0; w.len()];
        for p in pts {
            let g = Gaussian2D::circular(p[0], p[1], 250.0 / (2.0 * PI * 1.21), 1.1, 0.0);
            add_dot(&g, w, Sampling::Integrated, &mut want);
        }
        for (a, b) in img.iter().zip(&want) {
            assert!((a - b).abs() < 1e-9 * 250.0, "{a} vs {b}");
        }
    }

    #[test]
    fn concentric_map_is_uniform_on_the_disc() {
        // the map of a fine grid has the disc's moments: E[x²] = 1/4, E[x⁴] = 1/8, in the disc
        let m = 400;
        let (mut x2, mut x4, mut xy, mut out) = (0.0, 0.0, 0.0, 0usize);
        for i in 0..m {
            for j in 0..m {
                let a = 2.0 * (i as f64 + 0.5) / m as f64 - 1.0;
                let b = 2.0 * (j as f64 + 0.5) / m as f64 - 1.0;
                let p = concentric_disc(a, b);
                x2 += p[0] * p[0];
                x4 += p[0].powi(4);
                xy += p[0] * p[1];
                out += usize::from(p[0].hypot(p[1]) > 1.0 + 1e-12);
            }
        }
        let n = (m * m) as f64;
        assert_eq!(out, 0);
        assert!(
            (x2 / n - 0.25).abs() < 1e-3 && (x4 / n - 0.125).abs() < 1e-3 && (xy / n).abs() < 1e-6
        );
    }
}
