//! The amplification ratio measured: the scatter of fitted positions of a blurred gradient dot
//! over that of its reference dot, against the formulas (NOTES.md §2, the published variant,
//! and the NOTES formula on pixel-blurred shapes).

use crate::PaperError;
use crate::error::invalid;
use crate::stats::{Running, mean_se, median, min_max, mix};
use crate::study::fit_config;
use bostrack_core::{FitStatus, Gaussian2D, NoiseModel, Window};
use bostrack_displacement::pixel_blurred;
use bostrack_fit::{Fitter, WindowSamples};
use bostrack_model::{ArVariant, ModelKind, Sampling, amplification_ratio, crlb, render};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// The amplification-ratio study: one circular reference dot, and a grid of gradient dots
/// (the same dot blurred: correlation ρ, aspect ratio σx/σy, peak intensity ratio
/// `I0_grad / I0_ref`), each fitted many times under the same white noise; the measured AR is
/// the ratio of the Monte Carlo standard deviations of the fitted positions.
///
/// A gradient dot with aspect ratio `a` and correlation ρ has `σy = b σ_ref`, `σx = a b σ_ref`,
/// with the smallest `b ≥ 1` for which its covariance minus the reference's is positive
/// semi-definite, so that it is a genuine blur of the reference dot (the blur's own shape
/// is free). Both dots sit at the same sub-pixel position; windows are ±`ceil(window_sigmas σ)`
/// per axis (at least ±3 px).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArStudyConfig {
    /// Sigma of the reference dot (px) \[1.5\].
    pub sigma_ref: f64,
    /// Peak of the reference dot above background (counts) \[1000\].
    pub amplitude_ref: f64,
    /// Background (counts) \[100\].
    pub background: f64,
    /// Noise σn as a fraction of the reference peak, the same in both images \[0.05\].
    pub noise_fraction: f64,
    /// Correlations of the gradient dot \[−0.9 to 0.9 in steps of 0.3\].
    pub rhos: Vec<f64>,
    /// Aspect ratios σx/σy of the gradient dot \[1, 1.5, 2, 3\].
    pub aspects: Vec<f64>,
    /// Peak ratios `I0_grad / I0_ref` \[0.3, 0.65, 1\].
    pub intensity_ratios: Vec<f64>,
    /// Position of both dots (px) \[(0.2, −0.3)\].
    pub position_px: [f64; 2],
    /// Window half-widths in sigmas \[4\].
    pub window_sigmas: f64,
    /// Noise realisations per gradient dot \[2000\].
    pub realisations: usize,
    /// Noise realisations of the reference dot (shared by every case) \[20000\].
    pub reference_realisations: usize,
    pub seed: u64,
}

impl Default for ArStudyConfig {
    fn default() -> Self {
        ArStudyConfig {
            sigma_ref: 1.5,
            amplitude_ref: 1000.0,
            background: 100.0,
            noise_fraction: 0.05,
            rhos: vec![-0.9, -0.6, -0.3, 0.0, 0.3, 0.6, 0.9],
            aspects: vec![1.0, 1.5, 2.0, 3.0],
            intensity_ratios: vec![0.3, 0.65, 1.0],
            position_px: [0.2, -0.3],
            window_sigmas: 4.0,
            realisations: 2000,
            reference_realisations: 20_000,
            seed: 1,
        }
    }
}

impl ArStudyConfig {
    /// Checks every number; the error names the field.
    pub fn validate(&self) -> Result<(), PaperError> {
        let pos = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(invalid(field, format!("must be finite and > 0, got {v}")))
            }
        };
        pos("sigma_ref", self.sigma_ref)?;
        pos("amplitude_ref", self.amplitude_ref)?;
        pos("noise_fraction", self.noise_fraction)?;
        if !self.background.is_finite() {
            return Err(invalid("background", "must be finite"));
        }
        if self.rhos.is_empty() || self.rhos.iter().any(|r| r.is_nan() || r.abs() >= 0.99) {
            return Err(invalid("rhos", "must be a non-empty list in (-0.99, 0.99)"));
        }
        if self.aspects.is_empty()
            || self
                .aspects
                .iter()
                .any(|a| !(a.is_finite() && *a >= 1.0 && *a <= 10.0))
        {
            return Err(invalid("aspects", "must be a non-empty list in [1, 10]"));
        }
        if self.intensity_ratios.is_empty()
            || self
                .intensity_ratios
                .iter()
                .any(|r| !(r.is_finite() && *r > 0.0 && *r <= 10.0))
        {
            return Err(invalid(
                "intensity_ratios",
                "must be a non-empty list in (0, 10]",
            ));
        }
        if !self.position_px.iter().all(|v| v.is_finite()) {
            return Err(invalid("position_px", "must be finite"));
        }
        if !(self.window_sigmas.is_finite() && (2.0..=10.0).contains(&self.window_sigmas)) {
            return Err(invalid("window_sigmas", "must be in 2..=10"));
        }
        if self.realisations < 3 || self.reference_realisations < 3 {
            return Err(invalid("realisations", "both must be at least 3"));
        }
        Ok(())
    }

    /// The gradient dot of a case (above background `self.background`).
    pub fn gradient_dot(&self, rho: f64, aspect: f64, intensity_ratio: f64) -> Gaussian2D {
        // eigenvalues of [[a², ρa], [ρa, 1]]
        let a = aspect;
        let half_sum = 0.5 * (a * a + 1.0);
        let half_diff = 0.5 * (a * a - 1.0);
        let lmin = half_sum - (half_diff * half_diff + rho * rho * a * a).sqrt();
        let b = (1.0 / lmin.max(1e-12).sqrt()).max(1.0);
        Gaussian2D {
            x0: self.position_px[0],
            y0: self.position_px[1],
            amplitude: intensity_ratio * self.amplitude_ref,
            sigma_x: a * b * self.sigma_ref,
            sigma_y: b * self.sigma_ref,
            rho,
            background: self.background,
        }
    }

    /// The reference dot.
    pub fn reference_dot(&self) -> Gaussian2D {
        Gaussian2D::circular(
            self.position_px[0],
            self.position_px[1],
            self.amplitude_ref,
            self.sigma_ref,
            self.background,
        )
    }

    fn window(&self, g: &Gaussian2D) -> Window {
        let half = |s: f64| (self.window_sigmas * s).ceil().clamp(3.0, 60.0) as i64;
        let (hx, hy) = (half(g.sigma_x), half(g.sigma_y));
        let (cx, cy) = (g.x0.round() as i64, g.y0.round() as i64);
        Window::new(
            cx - hx,
            cy - hy,
            (2 * hx + 1) as usize,
            (2 * hy + 1) as usize,
        )
    }
}

/// Monte Carlo of one dot: standard deviations of the fitted position, fits used and failed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DotScatter {
    pub std_x: f64,
    pub std_y: f64,
    /// Exact bound of the dot over its window (px).
    pub bound_x: f64,
    pub bound_y: f64,
    pub fits_ok: usize,
    pub failures: usize,
    pub window_w: usize,
    pub window_h: usize,
}

/// One gradient dot of the amplification-ratio study. `ar_*` are `[x, y]` pairs flattened.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArRow {
    pub rho: f64,
    pub aspect: f64,
    pub intensity_ratio: f64,
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub amplitude: f64,
    pub window_w: usize,
    pub window_h: usize,
    pub fits_ok: usize,
    pub failures: usize,
    /// Monte Carlo standard deviation of the gradient dot's fitted position (px).
    pub std_x: f64,
    pub std_y: f64,
    /// Measured AR: gradient std over reference std.
    pub ar_mc_x: f64,
    pub ar_mc_y: f64,
    /// NOTES.md §2 on the true (fitted, noise-free) shapes.
    pub ar_notes_x: f64,
    pub ar_notes_y: f64,
    /// The published variant (intensity inside the root, inverted ρ factor).
    pub ar_published_x: f64,
    pub ar_published_y: f64,
    /// NOTES.md §2 on the pixel-blurred shapes (covariance + I/12, volume kept;
    /// `bostrack_displacement::pixel_blurred`).
    pub ar_pixel_x: f64,
    pub ar_pixel_y: f64,
    /// Ratio of the exact bounds (pixel-integrated, 7 parameters, each dot over its window).
    pub ar_bound_x: f64,
    pub ar_bound_y: f64,
}

/// How well one AR formula matches, over every case and both axes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArFormulaSummary {
    /// `notes`, `published`, `notes_pixel_blurred`, `exact_bound_ratio`.
    pub formula: String,
    /// Against the Monte Carlo AR: median |formula / measured − 1|, mean of
    /// `formula / measured − 1` with its standard error, and the largest |…|.
    pub mc_abs_rel_median: f64,
    pub mc_rel_mean: f64,
    pub mc_rel_se: f64,
    pub mc_abs_rel_max: f64,
    /// Against the ratio of exact bounds (no Monte Carlo noise): median and largest
    /// |formula / ratio − 1|.
    pub bound_abs_rel_median: f64,
    pub bound_abs_rel_max: f64,
}

/// The result of [`run_ar_study`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArResult {
    pub config: ArStudyConfig,
    pub reference: DotScatter,
    pub rows: Vec<ArRow>,
    pub formulas: Vec<ArFormulaSummary>,
    /// Relative standard error expected of one measured AR:
    /// `sqrt(1/(2(n−1)) + 1/(2(n_ref−1)))`.
    pub expected_rel_error: f64,
    pub wall_s: f64,
    pub threads: usize,
}

/// Fits `n` noisy images of `g` over its window; every case has its own random stream.
fn scatter(
    cfg: &ArStudyConfig,
    g: &Gaussian2D,
    n: usize,
    stream: u64,
    fitter: &mut Fitter,
) -> DotScatter {
    let window = cfg.window(g);
    let clean = render(g, window, Sampling::Integrated);
    let sigma_n = cfg.noise_fraction * cfg.amplitude_ref;
    let noise = NoiseModel::read(sigma_n);
    let bound = crlb(
        g,
        window,
        &noise,
        Sampling::Integrated,
        ModelKind::Elliptical,
    )
    .map_or([f64::NAN; 2], |b| [b.std[0], b.std[1]]);
    let mut rng = StdRng::seed_from_u64(mix(cfg.seed, stream));
    let start = [g.x0.round(), g.y0.round()];
    let mut vals = vec![0.0; clean.len()];
    let (mut ex, mut ey) = (Running::default(), Running::default());
    let mut failures = 0;
    for _ in 0..n {
        for (v, c) in vals.iter_mut().zip(&clean) {
            let z: f64 = rng.sample(StandardNormal);
            *v = c + sigma_n * z;
        }
        let s = WindowSamples {
            window,
            values: &vals,
            keep: None,
            saturation: None,
        };
        let f = fitter.fit_samples(&s, start, None, &noise);
        let (dx, dy) = (f.params.x0 - g.x0, f.params.y0 - g.y0);
        let usable = f.status.is_ok() || f.status == FitStatus::Singular;
        if usable && dx.abs() <= 1.0 && dy.abs() <= 1.0 {
            ex.push(dx);
            ey.push(dy);
        } else {
            failures += 1;
        }
    }
    DotScatter {
        std_x: ex.std(),
        std_y: ey.std(),
        bound_x: bound[0],
        bound_y: bound[1],
        fits_ok: ex.count(),
        failures,
        window_w: window.width,
        window_h: window.height,
    }
}

/// Runs the amplification-ratio study (rayon over the cases, deterministic for a seed).
pub fn run_ar_study(cfg: &ArStudyConfig) -> Result<ArResult, PaperError> {
    cfg.validate()?;
    let t0 = Instant::now();
    let mut cases = Vec::new();
    for &rho in &cfg.rhos {
        for &aspect in &cfg.aspects {
            for &ir in &cfg.intensity_ratios {
                cases.push((rho, aspect, ir));
            }
        }
    }
    let fit_cfg = fit_config();
    let reference = cfg.reference_dot();
    // task 0 is the reference dot, task k + 1 the k-th case
    let scatters: Vec<DotScatter> = (0..=cases.len())
        .into_par_iter()
        .map_init(
            || Fitter::new(&fit_cfg),
            |f, k| {
                if k == 0 {
                    scatter(cfg, &reference, cfg.reference_realisations, 0, f)
                } else {
                    let (rho, aspect, ir) = cases[k - 1];
                    scatter(
                        cfg,
                        &cfg.gradient_dot(rho, aspect, ir),
                        cfg.realisations,
                        k as u64,
                        f,
                    )
                }
            },
        )
        .collect();
    let rs = scatters[0];
    let rows: Vec<ArRow> = cases
        .iter()
        .zip(&scatters[1..])
        .map(|(&(rho, aspect, ir), s)| {
            let g = cfg.gradient_dot(rho, aspect, ir);
            let notes = amplification_ratio(&reference, &g, ArVariant::Notes);
            let published = amplification_ratio(&reference, &g, ArVariant::Published);
            let pixel = amplification_ratio(
                &pixel_blurred(&reference),
                &pixel_blurred(&g),
                ArVariant::Notes,
            );
            ArRow {
                rho,
                aspect,
                intensity_ratio: ir,
                sigma_x: g.sigma_x,
                sigma_y: g.sigma_y,
                amplitude: g.amplitude,
                window_w: s.window_w,
                window_h: s.window_h,
                fits_ok: s.fits_ok,
                failures: s.failures,
                std_x: s.std_x,
                std_y: s.std_y,
                ar_mc_x: s.std_x / rs.std_x,
                ar_mc_y: s.std_y / rs.std_y,
                ar_notes_x: notes[0],
                ar_notes_y: notes[1],
                ar_published_x: published[0],
                ar_published_y: published[1],
                ar_pixel_x: pixel[0],
                ar_pixel_y: pixel[1],
                ar_bound_x: s.bound_x / rs.bound_x,
                ar_bound_y: s.bound_y / rs.bound_y,
            }
        })
        .collect();
    let formulas = [
        (
            "notes",
            (|r: &ArRow| [r.ar_notes_x, r.ar_notes_y]) as fn(&ArRow) -> [f64; 2],
        ),
        ("published", |r| [r.ar_published_x, r.ar_published_y]),
        ("notes_pixel_blurred", |r| [r.ar_pixel_x, r.ar_pixel_y]),
        ("exact_bound_ratio", |r| [r.ar_bound_x, r.ar_bound_y]),
    ]
    .iter()
    .map(|(name, f)| {
        let mc: Vec<f64> = rows
            .iter()
            .flat_map(|r| {
                let v = f(r);
                [v[0] / r.ar_mc_x - 1.0, v[1] / r.ar_mc_y - 1.0]
            })
            .collect();
        let bound: Vec<f64> = rows
            .iter()
            .flat_map(|r| {
                let v = f(r);
                [v[0] / r.ar_bound_x - 1.0, v[1] / r.ar_bound_y - 1.0]
            })
            .collect();
        let (mc_rel_mean, mc_rel_se) = mean_se(mc.iter().copied());
        ArFormulaSummary {
            formula: name.to_string(),
            mc_abs_rel_median: median(mc.iter().map(|v| v.abs())),
            mc_rel_mean,
            mc_rel_se,
            mc_abs_rel_max: min_max(mc.iter().map(|v| v.abs())).1,
            bound_abs_rel_median: median(bound.iter().map(|v| v.abs())),
            bound_abs_rel_max: min_max(bound.iter().map(|v| v.abs())).1,
        }
    })
    .collect();
    let n = cfg.realisations as f64;
    let nr = cfg.reference_realisations as f64;
    Ok(ArResult {
        config: cfg.clone(),
        reference: rs,
        rows,
        formulas,
        expected_rel_error: (0.5 / (n - 1.0) + 0.5 / (nr - 1.0)).sqrt(),
        wall_s: t0.elapsed().as_secs_f64(),
        threads: rayon::current_num_threads(),
    })
}
