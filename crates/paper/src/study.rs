//! The Monte Carlo of the paper's Sec. 3: draws, rendering, noise, fits, and the comparison
//! of the fitted positions' scatter with Eq. 35 and with the exact bound.

use crate::PaperError;
use crate::config::{GeometryRange, NoiseReference, Rendering, StudyConfig};
use crate::stats::{Running, mean_se, median, min_max, mix};
use bostrack_core::{FitStatus, Gaussian2D, NoiseModel, Window};
use bostrack_fit::{FitConfig, Fitter, WindowSamples};
use bostrack_model::{ModelKind, Sampling, crlb, render};
use bostrack_theory::{
    Geometry, Hessian, Prediction, Propagation, RayTraceConfig, Setup, TheoryFlags, View, eq35,
    eq35_rho, predict, ray_trace,
};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Stream index that separates the ray tracer's jitter from the draw's parameters and noise.
const RAY_STREAM: u64 = 0x5241_5953;

/// The random parameters of one draw.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DrawParams {
    pub f_number: f64,
    /// ζ: the particle depth (volumetric) or `Z_D` (BOS), m.
    pub zeta_m: f64,
    /// `[ρxx, ρxy, ρyy]` (kg/m⁵), flow frame.
    pub hessian_kg_m5: [f64; 3],
    pub pitch_deg: f64,
    pub yaw_deg: f64,
    /// Sub-pixel position of the undeflected dot (px).
    pub position_px: [f64; 2],
}

/// One draw of a study: its parameters, the model's prediction, the rendered dot, the three
/// predictions of the position scatter and the Monte Carlo measurement. Lengths in px.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DrawRow {
    pub draw: usize,
    pub f_number: f64,
    /// Particle depth ζ (volumetric) or `Z_D` (BOS), m.
    pub zeta_m: f64,
    pub hxx: f64,
    pub hxy: f64,
    pub hyy: f64,
    pub pitch_deg: f64,
    pub yaw_deg: f64,
    /// Undeflected dot position (px).
    pub pos_x: f64,
    pub pos_y: f64,
    /// Reference (unblurred) sigma: diffraction and printed dot.
    pub sigma_ref: f64,
    /// Blur standard deviations `sqrt(Σ_blur,xx)`, `sqrt(Σ_blur,yy)` (Eq. 25-26).
    pub blur_x: f64,
    pub blur_y: f64,
    /// The predicted effective dot (Eq. 11-29, with ρ).
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
    /// Its peak above background (Eq. 29) and exposure (counts·px²).
    pub peak: f64,
    pub exposure: f64,
    /// The model's flags (`bostrack_theory::TheoryFlags`, `a|b`).
    pub flags: String,
    /// Half-width of the fit window (px).
    pub window_half: usize,
    /// Fraction of the exposure inside the window.
    pub captured: f64,
    /// Ray-traced: `‖image − G‖/‖image‖` against the Gaussian with the traced moments (0 for
    /// the effective-model rendering).
    pub gaussian_residual: f64,
    /// True centroid: the mean landing point of the rays (ray-traced) or the model's centre.
    pub truth_x: f64,
    pub truth_y: f64,
    /// Noise standard deviation (counts).
    pub sigma_n: f64,
    /// Whether the noise-free fit converged; its parameters (NaN if not) and its position
    /// error (px).
    pub nf_ok: bool,
    pub nf_sigma_x: f64,
    pub nf_sigma_y: f64,
    pub nf_rho: f64,
    pub nf_amplitude: f64,
    pub nf_bias_x: f64,
    pub nf_bias_y: f64,
    /// The paper's model: Eq. 35 as printed, with the predicted sigmas, the exposure and σn.
    pub eq35_x: f64,
    pub eq35_y: f64,
    /// Eq. 35 generalised to ρ (NOTES.md §2).
    pub eq35_rho_x: f64,
    pub eq35_rho_y: f64,
    /// Exact bound: `bostrack_model::crlb` (pixel-integrated, 7 free parameters) of the
    /// Gaussian fitted to the noise-free image, over the fit window, noise σn (NaN if that
    /// fit failed or the Fisher matrix is singular).
    pub bound_x: f64,
    pub bound_y: f64,
    /// The same bound for the *predicted* effective Gaussian instead of the fitted one.
    pub bound_model_x: f64,
    pub bound_model_y: f64,
    /// Monte Carlo: fits used, failures (not converged, or error above `max_error_px`),
    /// sample standard deviation and mean of the position error (fit − truth).
    pub fits_ok: usize,
    pub failures: usize,
    /// Fits among `fits_ok` that the fit engine marked `Singular` (a least-squares minimum
    /// where the position bound at the estimate exceeds 1 px, typically σ collapsed on an
    /// undersampled dot), used when `include_singular` is set.
    pub singular: usize,
    pub std_x: f64,
    pub std_y: f64,
    pub bias_x: f64,
    pub bias_y: f64,
}

/// Statistics over a group of draws, both axes pooled (each draw contributes its x and its y
/// value). Offsets and ratios compare the Monte Carlo standard deviation with a prediction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroupSummary {
    /// `all` or `f/8`, …
    pub label: String,
    pub draws: usize,
    /// Range of the predicted sigmas (px).
    pub sigma_min: f64,
    pub sigma_max: f64,
    /// Largest blur standard deviation (px) and its largest ratio to the reference sigma.
    pub blur_max: f64,
    pub blur_over_ref_max: f64,
    /// Draws flagged `non_gaussian` by the model.
    pub non_gaussian: usize,
    /// Mean Monte Carlo standard deviation (px).
    pub mc_std_mean: f64,
    /// Mean of Eq. 35 (px).
    pub eq35_mean: f64,
    /// Monte Carlo std − Eq. 35 (px): mean, its standard error, median.
    pub offset_eq35_mean: f64,
    pub offset_eq35_se: f64,
    pub offset_eq35_median: f64,
    /// Monte Carlo std − Eq. 35 with ρ (px), mean.
    pub offset_eq35_rho_mean: f64,
    /// Median of `std / Eq. 35 − 1`.
    pub eq35_rel_median: f64,
    /// Mean exact bound (px).
    pub bound_mean: f64,
    /// Median of `std / bound − 1` (signed) and of its absolute value.
    pub bound_rel_median: f64,
    pub bound_abs_rel_median: f64,
    /// Mean of `(std / bound)²` (the variance ratio; 1 for an efficient estimator) and its
    /// standard error.
    pub var_ratio_mean: f64,
    pub var_ratio_se: f64,
    /// Median of `std / bound_model − 1`: the bound of the *predicted* Gaussian.
    pub bound_model_rel_median: f64,
    /// Fits used, failed, and used although marked `Singular`.
    pub fits: usize,
    pub failures: usize,
    pub singular: usize,
}

/// The result of [`run_study`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudyResult {
    pub config: StudyConfig,
    /// One row per draw, in draw order.
    pub rows: Vec<DrawRow>,
    /// All draws, then one group per f-number (ascending).
    pub groups: Vec<GroupSummary>,
    /// Relative standard error of a standard deviation estimated from `realisations`
    /// samples, `1 / sqrt(2 (n − 1))`: the scatter expected of `std / bound` per draw and axis.
    pub expected_rel_error: f64,
    /// Draws whose noise-free fit failed (their exact bound is NaN).
    pub noise_free_failures: usize,
    /// Wall time (s) and rayon threads: not part of the deterministic result.
    pub wall_s: f64,
    pub threads: usize,
}

impl StudyResult {
    /// The summary of all draws.
    pub fn overall(&self) -> &GroupSummary {
        &self.groups[0]
    }
}

/// Runs a study: every draw in parallel (rayon, one [`Fitter`] per task), each with its own
/// random stream derived from `cfg.seed` and the draw index, so the result does not depend on
/// the number of threads.
///
/// Per draw: [`draw_params`] → the setup → `bostrack_theory::predict` (the effective dot:
/// shift, σx, σy, ρ, peak) → the noise-free image over the fit window (ray-traced or the
/// effective Gaussian, [`Rendering`]) → σn = `noise_fraction` × the [`NoiseReference`] → one
/// noise-free fit (the best-fitting effective Gaussian of the rendered image, whose exact
/// bound is the reference) → `realisations` fits of the image plus white Gaussian noise σn,
/// each started at the pixel nearest the true centroid with no shape hint (the fit engine's
/// own moment start) → the sample standard deviation of `fit − truth` per axis.
pub fn run_study(cfg: &StudyConfig) -> Result<StudyResult, PaperError> {
    cfg.validate()?;
    let t0 = Instant::now();
    let fit_cfg = fit_config();
    let rows = (0..cfg.draws)
        .into_par_iter()
        .map_init(|| Fitter::new(&fit_cfg), |f, i| run_draw(cfg, i, f))
        .collect::<Result<Vec<_>, _>>()?;
    let wall_s = t0.elapsed().as_secs_f64();
    let mut groups = vec![summarise("all", rows.iter())];
    let mut fs: Vec<f64> = cfg.f_numbers.clone();
    fs.sort_by(f64::total_cmp);
    fs.dedup();
    for f in fs {
        groups.push(summarise(
            &format!("f/{f}"),
            rows.iter().filter(|r| r.f_number == f),
        ));
    }
    Ok(StudyResult {
        config: cfg.clone(),
        noise_free_failures: rows.iter().filter(|r| !r.nf_ok).count(),
        rows,
        groups,
        expected_rel_error: 1.0 / (2.0 * (cfg.realisations as f64 - 1.0)).sqrt(),
        wall_s,
        threads: rayon::current_num_threads(),
    })
}

/// The fit: the engine's defaults (7 free parameters, pixel-integrated, fast Levenberg-Marquardt,
/// converged at steps below 1e-3 standard deviations), without the bound (not needed).
pub(crate) fn fit_config() -> FitConfig {
    FitConfig {
        bound: false,
        ..FitConfig::default()
    }
}

/// The random parameters of draw `index` and the random stream that continues into its noise.
pub fn draw_params(cfg: &StudyConfig, index: usize) -> (DrawParams, StdRng) {
    let mut rng = StdRng::seed_from_u64(mix(cfg.seed, index as u64));
    let mut uniform = |r: [f64; 2]| {
        if r[1] > r[0] {
            rng.random_range(r[0]..r[1])
        } else {
            r[0]
        }
    };
    let h = cfg.hessian_kg_m5;
    let hessian_kg_m5 = [uniform(h), uniform(h), uniform(h)];
    let zeta_m = match cfg.geometry {
        GeometryRange::Volumetric { depth_mm } => 1e-3 * uniform(depth_mm),
        GeometryRange::Bos { z_d_m, .. } => uniform(z_d_m),
    };
    let pitch_deg = uniform(cfg.view_deg);
    let yaw_deg = uniform(cfg.view_deg);
    let position_px = [uniform([-0.5, 0.5]), uniform([-0.5, 0.5])];
    let f_number = cfg.f_numbers[rng.random_range(0..cfg.f_numbers.len())];
    (
        DrawParams {
            f_number,
            zeta_m,
            hessian_kg_m5,
            pitch_deg,
            yaw_deg,
            position_px,
        },
        rng,
    )
}

/// The setup the model predicts for a draw (the paper's geometry: volumetric or BOS).
pub fn draw_setup(cfg: &StudyConfig, p: &DrawParams) -> Setup {
    let mut s = cfg.base.clone();
    s.optics.f_number = p.f_number;
    s.geometry = match cfg.geometry {
        GeometryRange::Volumetric { .. } => Geometry::Volumetric { depth_m: p.zeta_m },
        GeometryRange::Bos { delta_z_m, .. } => Geometry::Bos {
            z_d_m: p.zeta_m,
            delta_z_m,
        },
    };
    s.flow.gradient_kg_m4 = [0.0; 3];
    s.flow.hessian_kg_m5 = Hessian {
        xx: p.hessian_kg_m5[0],
        xy: p.hessian_kg_m5[1],
        yy: p.hessian_kg_m5[2],
        ..Hessian::default()
    };
    s.view = View {
        pitch_deg: p.pitch_deg,
        yaw_deg: p.yaw_deg,
        roll_deg: 0.0,
    };
    s.camera.position_px = p.position_px;
    s
}

/// The setup the ray tracer traces (it traces BOS slabs only): a volumetric draw at depth ζ
/// becomes the thin slab with `Z_D = Δz = |ζ|` (smallest 1 nm), which has the same `ζ²`
/// sensitivity, lever ζ and path ζ as Eq. 6 as printed (tested).
pub fn trace_setup(setup: &Setup) -> Setup {
    let mut s = setup.clone();
    if let Geometry::Volumetric { depth_m } = s.geometry {
        let z = depth_m.abs().max(1e-9);
        s.geometry = Geometry::Bos {
            z_d_m: z,
            delta_z_m: z,
        };
    }
    s
}

/// The noise-free image of a draw: window, values above background, truth, captured
/// fraction and Gaussian residual.
struct Rendered {
    window: Window,
    image: Vec<f64>,
    truth: [f64; 2],
    captured: f64,
    gaussian_residual: f64,
}

fn render_draw(
    cfg: &StudyConfig,
    index: usize,
    setup: &Setup,
    pred: &Prediction,
    half: usize,
) -> Result<Rendered, PaperError> {
    match cfg.rendering {
        Rendering::RayTraced { rays } => {
            let rt = ray_trace(
                &trace_setup(setup),
                &RayTraceConfig {
                    rays,
                    seed: mix(cfg.seed ^ RAY_STREAM, index as u64),
                    propagation: Propagation::ThinSlab,
                    aperture: None,
                    half_width_px: Some(half),
                },
            )
            .map_err(|source| PaperError::Setup {
                draw: index,
                source,
            })?;
            Ok(Rendered {
                window: rt.window,
                truth: [rt.landing.x0, rt.landing.y0],
                captured: rt.captured,
                gaussian_residual: rt.gaussian_residual,
                image: rt.image,
            })
        }
        Rendering::EffectiveModel => {
            let g = Gaussian2D {
                background: 0.0,
                ..pred.gradient
            };
            let window = Window::centred(g.x0, g.y0, half);
            let image = render(&g, window, Sampling::Integrated);
            Ok(Rendered {
                window,
                truth: [g.x0, g.y0],
                captured: image.iter().sum::<f64>() / pred.exposure,
                gaussian_residual: 0.0,
                image,
            })
        }
    }
}

/// The exact bound `[std x0, std y0]` of a Gaussian over a window (NaN if singular).
fn exact(g: &Gaussian2D, window: Window, noise: &NoiseModel) -> [f64; 2] {
    crlb(
        g,
        window,
        noise,
        Sampling::Integrated,
        ModelKind::Elliptical,
    )
    .map_or([f64::NAN; 2], |b| [b.std[0], b.std[1]])
}

fn run_draw(cfg: &StudyConfig, index: usize, fitter: &mut Fitter) -> Result<DrawRow, PaperError> {
    let (p, mut rng) = draw_params(cfg, index);
    let setup = draw_setup(cfg, &p);
    let pred = predict(&setup).map_err(|source| PaperError::Setup {
        draw: index,
        source,
    })?;
    let sigma_max = pred.sigma_x.max(pred.sigma_y);
    let half = (cfg.window_sigmas * sigma_max).ceil().clamp(3.0, 50.0) as usize;
    let r = render_draw(cfg, index, &setup, &pred, half)?;
    let background = setup.camera.background_counts;
    let clean: Vec<f64> = r.image.iter().map(|v| v + background).collect();
    let level = match cfg.noise_reference {
        NoiseReference::ModelPeak => pred.peak,
        NoiseReference::BrightestPixel => r.image.iter().copied().fold(0.0, f64::max),
        NoiseReference::ReferencePeak => pred.reference.amplitude,
    };
    let sigma_n = cfg.noise_fraction * level;
    let noise = NoiseModel::read(sigma_n);
    let start = [r.truth[0].round(), r.truth[1].round()];
    let window = r.window;
    fn samples(window: Window, values: &[f64]) -> WindowSamples<'_> {
        WindowSamples {
            window,
            values,
            keep: None,
            saturation: None,
        }
    }

    // the best-fitting effective Gaussian of the noise-free image, and its exact bound
    let nf = fitter.fit_samples(&samples(window, &clean), start, None, &noise);
    let nf_ok = nf.status.is_ok();
    let bound = if nf_ok {
        exact(&nf.params, r.window, &noise)
    } else {
        [f64::NAN; 2]
    };
    let bound_model = exact(&pred.gradient, r.window, &noise);
    let e35 = eq35(sigma_n, pred.exposure, pred.sigma_x, pred.sigma_y);
    let e35r = eq35_rho(sigma_n, pred.exposure, pred.sigma_x, pred.sigma_y, pred.rho);

    // Monte Carlo
    let mut vals = vec![0.0; clean.len()];
    let (mut ex, mut ey) = (Running::default(), Running::default());
    let (mut failures, mut singular) = (0, 0);
    for _ in 0..cfg.realisations {
        for (v, c) in vals.iter_mut().zip(&clean) {
            let z: f64 = rng.sample(StandardNormal);
            *v = c + sigma_n * z;
        }
        let f = fitter.fit_samples(&samples(window, &vals), start, None, &noise);
        let (dx, dy) = (f.params.x0 - r.truth[0], f.params.y0 - r.truth[1]);
        let usable = f.status.is_ok() || (cfg.include_singular && f.status == FitStatus::Singular);
        // NaN errors fail the comparison
        if usable && dx.abs() <= cfg.max_error_px && dy.abs() <= cfg.max_error_px {
            ex.push(dx);
            ey.push(dy);
            singular += usize::from(f.status == FitStatus::Singular);
        } else {
            failures += 1;
        }
    }

    let nan_if = |ok: bool, v: f64| if ok { v } else { f64::NAN };
    Ok(DrawRow {
        draw: index,
        f_number: p.f_number,
        zeta_m: p.zeta_m,
        hxx: p.hessian_kg_m5[0],
        hxy: p.hessian_kg_m5[1],
        hyy: p.hessian_kg_m5[2],
        pitch_deg: p.pitch_deg,
        yaw_deg: p.yaw_deg,
        pos_x: p.position_px[0],
        pos_y: p.position_px[1],
        sigma_ref: pred.reference.sigma_x,
        blur_x: pred.blur_covariance[0].max(0.0).sqrt(),
        blur_y: pred.blur_covariance[2].max(0.0).sqrt(),
        sigma_x: pred.sigma_x,
        sigma_y: pred.sigma_y,
        rho: pred.rho,
        peak: pred.peak,
        exposure: pred.exposure,
        flags: pred.flags.to_string(),
        window_half: half,
        captured: r.captured,
        gaussian_residual: r.gaussian_residual,
        truth_x: r.truth[0],
        truth_y: r.truth[1],
        sigma_n,
        nf_ok,
        nf_sigma_x: nan_if(nf_ok, nf.params.sigma_x),
        nf_sigma_y: nan_if(nf_ok, nf.params.sigma_y),
        nf_rho: nan_if(nf_ok, nf.params.rho),
        nf_amplitude: nan_if(nf_ok, nf.params.amplitude),
        nf_bias_x: nan_if(nf_ok, nf.params.x0 - r.truth[0]),
        nf_bias_y: nan_if(nf_ok, nf.params.y0 - r.truth[1]),
        eq35_x: e35[0],
        eq35_y: e35[1],
        eq35_rho_x: e35r[0],
        eq35_rho_y: e35r[1],
        bound_x: bound[0],
        bound_y: bound[1],
        bound_model_x: bound_model[0],
        bound_model_y: bound_model[1],
        fits_ok: ex.count(),
        failures,
        singular,
        std_x: ex.std(),
        std_y: ey.std(),
        bias_x: ex.mean(),
        bias_y: ey.mean(),
    })
}

fn summarise<'a>(label: &str, rows: impl Iterator<Item = &'a DrawRow> + Clone) -> GroupSummary {
    let pooled =
        |f: &dyn Fn(&DrawRow) -> [f64; 2]| -> Vec<f64> { rows.clone().flat_map(f).collect() };
    let std = pooled(&|r| [r.std_x, r.std_y]);
    let e35 = pooled(&|r| [r.eq35_x, r.eq35_y]);
    let e35r = pooled(&|r| [r.eq35_rho_x, r.eq35_rho_y]);
    let bound = pooled(&|r| [r.bound_x, r.bound_y]);
    let bound_model = pooled(&|r| [r.bound_model_x, r.bound_model_y]);
    let diff = |a: &[f64], b: &[f64]| -> Vec<f64> { a.iter().zip(b).map(|(a, b)| a - b).collect() };
    let ratio =
        |a: &[f64], b: &[f64]| -> Vec<f64> { a.iter().zip(b).map(|(a, b)| a / b - 1.0).collect() };
    let off = diff(&std, &e35);
    let (offset_eq35_mean, offset_eq35_se) = mean_se(off.iter().copied());
    let rel_bound = ratio(&std, &bound);
    let var_ratio: Vec<f64> = std
        .iter()
        .zip(&bound)
        .map(|(s, b)| (s / b).powi(2))
        .collect();
    let (var_ratio_mean, var_ratio_se) = mean_se(var_ratio.iter().copied());
    let (sigma_min, _) = min_max(rows.clone().map(|r| r.sigma_x.min(r.sigma_y)));
    let (_, sigma_max) = min_max(rows.clone().map(|r| r.sigma_x.max(r.sigma_y)));
    let (_, blur_max) = min_max(rows.clone().map(|r| r.blur_x.max(r.blur_y)));
    let (_, blur_over_ref_max) =
        min_max(rows.clone().map(|r| r.blur_x.max(r.blur_y) / r.sigma_ref));
    let non_gaussian = rows
        .clone()
        .filter(|r| {
            TheoryFlags::parse(&r.flags).is_ok_and(|f| f.contains(TheoryFlags::NON_GAUSSIAN))
        })
        .count();
    GroupSummary {
        label: label.to_string(),
        draws: rows.clone().count(),
        sigma_min,
        sigma_max,
        blur_max,
        blur_over_ref_max,
        non_gaussian,
        mc_std_mean: mean_se(std.iter().copied()).0,
        eq35_mean: mean_se(e35.iter().copied()).0,
        offset_eq35_mean,
        offset_eq35_se,
        offset_eq35_median: median(off.iter().copied()),
        offset_eq35_rho_mean: mean_se(diff(&std, &e35r)).0,
        eq35_rel_median: median(ratio(&std, &e35)),
        bound_mean: mean_se(bound.iter().copied()).0,
        bound_rel_median: median(rel_bound.iter().copied()),
        bound_abs_rel_median: median(rel_bound.iter().map(|v| v.abs())),
        var_ratio_mean,
        var_ratio_se,
        bound_model_rel_median: median(ratio(&std, &bound_model)),
        fits: rows.clone().map(|r| r.fits_ok).sum(),
        failures: rows.clone().map(|r| r.failures).sum(),
        singular: rows.clone().map(|r| r.singular).sum(),
    }
}
