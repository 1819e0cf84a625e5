//! Fitting one window: loading its pixels, the start, the estimators and the solvers.

use crate::config::{AUTO_SIGMA, Estimator, FitConfig, FitSampling, Solver};
use crate::eval::{
    IB, IT, IU, IV, IX, IY, Kind, Theta, Workspace, conditional_sigma, evaluate,
    gaussian_from_theta, gl_order, normal_equations, pixel_blur, pixel_unblur,
    quadrature_tolerance, theta_from_gaussian,
};
use crate::lmcrate::solve_lm_crate;
use crate::solver::{Bounds, Outcome, position_bound, solve_fast};
use crate::start::{moments, three_point};
use bostrack_core::{
    DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex, Image, Mask, NoiseModel, Window,
};
use bostrack_model::Sampling;

/// A least-squares fit whose Cramér-Rao bound in x or y exceeds this (px) carries no position
/// information (no dot, or pure noise): its status is `Singular`.
pub(crate) const MAX_BOUND_PX: f64 = 1.0;

/// The samples of one window, for data that is not in an [`Image`] (synthetic windows,
/// a caller's own buffers).
#[derive(Clone, Copy, Debug)]
pub struct WindowSamples<'a> {
    /// Where the samples are: `values[j * window.width + i]` is pixel
    /// `(window.x + i, window.y + j)`.
    pub window: Window,
    /// Row-major samples, `window.len()` of them (non-finite samples are left out and flagged).
    pub values: &'a [f64],
    /// `false` = masked out (same layout as `values`); `None` keeps every pixel.
    pub keep: Option<&'a [bool]>,
    /// Samples at or above this level are saturated (left out and flagged).
    pub saturation: Option<f64>,
}

/// Tolerance (standard deviations) of intermediate fits: they only model a neighbour's tail
/// in the next pass (~4 % of its peak at the real sample's pitch) and are its start, refitted
/// there; the step below the tolerance is taken, so what is left is of second order. (Issue
/// 17: 0.3 until session 13; at 1.0 bench/trackpy's σ 0.3 px and peak-SNR-6 scenes took 3 %
/// fewer instructions, the real reference 2 %; the crowded campaigns' checks, the
/// error-against-time table's touching and 8 px lattice scenes and the real reference's
/// positions (median change 3e-4 of the bound, largest 0.24, no flag) unchanged.)
const INTERMEDIATE_TOLERANCE: f64 = 1.0;

/// A reusable fitter: the configuration plus scratch buffers, so that fitting many windows
/// allocates nothing per dot (the levenberg-marquardt crate path excepted).
///
/// ```
/// use bostrack_core::{Gaussian2D, NoiseModel, Window};
/// use bostrack_fit::{FitConfig, Fitter, WindowSamples};
/// use bostrack_model::{render, Sampling};
/// let truth = Gaussian2D { x0: 4.3, y0: 3.8, amplitude: 900.0, sigma_x: 1.5, sigma_y: 1.2, rho: 0.3, background: 100.0 };
/// let window = Window::new(0, 0, 9, 9);
/// let values = render(&truth, window, Sampling::Integrated);
/// let mut fitter = Fitter::new(&FitConfig::default());
/// let s = WindowSamples { window, values: &values, keep: None, saturation: None };
/// let fit = fitter.fit_samples(&s, [4.0, 4.0], None, &NoiseModel::read(10.0));
/// assert!(fit.status.is_ok());
/// // default `auto` sampling: the pixel-blurred Gaussian (exact to the second moment)
/// assert!((fit.params.x0 - 4.3).abs() < 1e-4 && (fit.params.rho - 0.3).abs() < 2e-3);
/// ```
#[derive(Debug, Clone)]
pub struct Fitter {
    cfg: FitConfig,
    kind: Kind,
    pub(crate) ws: Workspace,
    /// An intermediate fit (refitted later from its solution): no reweighting to the solution.
    pub(crate) intermediate: bool,
    /// The start is a fit of the same dot (weights there are right): no reweighting check.
    pub(crate) warm: bool,
    /// What the last least-squares fit of this fitter left beside its record.
    pub(crate) last: LastFit,
    /// The shape (σx, σy, ρ) at which a least-squares fit that fails (singular, left its window, not finite) is fitted again
    /// with its shape held (position, amplitude, background free; `SHAPE_FIXED`).
    pub(crate) fixed_shape: Option<[f64; 3]>,
}

/// The amplitude, in its standard deviations, below which a fit with its shape held is no dot
/// (a singular fit of a window the detector found a dot in).
const FIXED_SHAPE_MIN_Z: f64 = 5.0;

/// Below this start σ (px) of an intermediate fit its 3 × 3 block is looked at for a narrow
/// dot ([`Fitter::solve_auto`]); much above it the block cuts off the tails of a σ 0.75 px dot
/// (at 0.8 bench/trackpy's σ 0.75 px scene took 4 % more instructions).
const NARROW_START_SIGMA: f64 = 0.65;

/// The largest |ρ| the one-step estimate of a fit made with ρ held at 0 reports.
const RHO_ONE_STEP_MAX: f64 = 0.9;

/// A lattice site the detector found no dot at holds one where a dot of the image's median
/// shape centred at the site's predicted position has an amplitude of this many standard
/// deviations (a linear fit: standard normal without a dot, 2.3e-4 per empty site)...
const PRESENCE_SITE_MIN_Z: f64 = 3.5;

/// ... or where the fit of such a dot with its position free in the window reaches this many
/// (the prediction may be off; the search over positions raises the false-alarm rate, measured
/// in `crates/pipeline/tests/faint.rs`).
const PRESENCE_MIN_Z: f64 = 4.5;

/// Whether θ has the shape (σx, σy, ρ) of `g`.
fn same_shape(g: &Gaussian2D, theta: &Theta) -> bool {
    let h = gaussian_from_theta(theta);
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(1.0);
    close(g.sigma_x, h.sigma_x) && close(g.sigma_y, h.sigma_y) && close(g.rho, h.rho)
}

/// Beside a least-squares record: the window's χ² and how far the fit moved from its hint.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LastFit {
    /// `Σ w r²` at the solution (weights of the noise model; NaN if not a least-squares fit).
    pub chi2: f64,
    /// Used pixels minus free parameters.
    pub dof: usize,
    /// Mahalanobis length `sqrt(Δᵀ F Δ)` of the change from the hint (or the parameters the
    /// neighbours saw, [`Fitter::fit_loaded_seen`]) to the solution (F the Fisher matrix at the
    /// solution; the change in standard deviations); infinite without one.
    pub moved: f64,
    /// The Fisher matrix of the free parameters at the solution, when it is that of the
    /// point-sampled model of θ (the pixel-blurred dot for `auto`, θ itself for `point`): what
    /// the neighbour iteration needs to predict how far a change of the neighbours moves the dot.
    pub point_fisher: Option<[[f64; 7]; 7]>,
    /// An intermediate fit of a narrow dot made with ρ held at 0 (`Fitter::solve_integrated`):
    /// its ρ (0) says nothing of the dot's; the value is ρ one Gauss-Newton step from there
    /// (NaN: none), which the held shape's median takes.
    pub rho_held: Option<f64>,
}

impl Default for LastFit {
    fn default() -> Self {
        LastFit {
            chi2: f64::NAN,
            dof: 0,
            moved: f64::INFINITY,
            point_fisher: None,
            rho_held: None,
        }
    }
}

/// Down to this conditional σ (px) an intermediate fit takes the pixel-blurred point model
/// whatever the dot's width (`Fitter::solve_auto`); below, where that model is far from the
/// pixel-integrated one (σ 0.3 px: the final fits then ended elsewhere), it fits as a final
/// fit does. bench/trackpy's σ 0.75 scene: 1.62 → 1.29 G instructions for `locate`, the final
/// positions the same to a median 0, a maximum 0.06 of the bound (σ 0.3: a median 0.003, a
/// maximum 1.1 for one of 2,621 dots, whose shape the window barely determines).
const INTERMEDIATE_BLUR_SIGMA: f64 = 0.5;

impl Fitter {
    pub fn new(cfg: &FitConfig) -> Fitter {
        Fitter {
            cfg: cfg.clone(),
            kind: Kind::from_model(cfg.model),
            ws: Workspace::default(),
            intermediate: false,
            warm: false,
            last: LastFit::default(),
            fixed_shape: None,
        }
    }

    pub fn config(&self) -> &FitConfig {
        &self.cfg
    }

    /// Fits the dot in `window` of `img` (see [`crate::fit_window`]).
    pub fn fit_window(
        &mut self,
        img: &Image,
        mask: Option<&Mask>,
        window: Window,
        start: [f64; 2],
        hint: Option<&Gaussian2D>,
        noise: &NoiseModel,
    ) -> DotFit {
        let flags = self.load_image(img, mask, window);
        self.fit_loaded(flags, start, hint, noise, false)
    }

    /// Fits the dot in a window given as samples.
    pub fn fit_samples(
        &mut self,
        s: &WindowSamples,
        start: [f64; 2],
        hint: Option<&Gaussian2D>,
        noise: &NoiseModel,
    ) -> DotFit {
        let flags = self.load_samples(s);
        self.fit_loaded(flags, start, hint, noise, false)
    }

    /// Loads the window's pixels into the workspace; returns the window flags.
    pub(crate) fn load_image(
        &mut self,
        img: &Image,
        mask: Option<&Mask>,
        window: Window,
    ) -> DotFlags {
        self.load_image_less(img, mask, window, None)
    }

    /// [`Fitter::load_image`] less `less` (an image of the same width, row-major: a canvas of
    /// the neighbours) over the kept pixels, in the same pass: each loaded value `v` becomes
    /// `v − keep · c`, as a subtraction after the load would make it (`1 · c` is `c`, so a kept
    /// pixel's value is `v − c` exactly).
    pub(crate) fn load_image_less(
        &mut self,
        img: &Image,
        mask: Option<&Mask>,
        window: Window,
        less: Option<&[f64]>,
    ) -> DotFlags {
        let ws = &mut self.ws;
        let (iw, ih) = (img.width(), img.height());
        if mask.is_some_and(|m| !m.matches(img)) {
            ws.resize(window.x, window.y, 0, 0);
            ws.n_used = 0;
            return DotFlags::MASKED;
        }
        let Some(c) = window.clip(iw, ih) else {
            ws.resize(window.x, window.y, 0, 0);
            ws.n_used = 0;
            return DotFlags::BORDER;
        };
        let mut flags = DotFlags::NONE;
        if c != window
            || c.x == 0
            || c.y == 0
            || c.x as usize + c.width == iw
            || c.y as usize + c.height == ih
        {
            flags |= DotFlags::BORDER;
        }
        ws.resize(c.x, c.y, c.width, c.height);
        let mut n_used = 0;
        // (below: saturated; +∞ without a level; NaN and ±∞ are never below it and above −∞)
        let level = img.meta.saturation.unwrap_or(f64::INFINITY);
        let (x0, cw) = (c.x as usize, c.width);
        for j in 0..c.height {
            let y = c.y as usize + j;
            let row = &img.row(y)[x0..x0 + cw];
            let mask_row = mask.map(|m| &m.as_slice()[y * iw + x0..][..cw]);
            let less_row = less.map(|l| &l[y * iw + x0..][..cw]);
            let k0 = j * cw;
            let (data, keep) = (&mut ws.data[k0..k0 + cw], &mut ws.keep[k0..k0 + cw]);
            // one pass per row, no branch per pixel: a pixel is usable below the saturation
            // level, finite and kept by the mask; its value less the canvas, or 0 with weight 0
            // (NaN and ±∞ are never below the level and above −∞)
            // (counts: a sum of the tests vectorises, a test with an early exit does not)
            let mut used = 0usize;
            for i in 0..cw {
                let v = row[i];
                let ok = (v < level) & (v > f64::NEG_INFINITY) & mask_row.is_none_or(|m| m[i]);
                let c = less_row.map_or(0.0, |l| l[i]);
                data[i] = if ok { v - c } else { 0.0 };
                keep[i] = if ok { 1.0 } else { 0.0 };
                used += usize::from(ok);
            }
            n_used += used;
            if used < cw {
                // (rare: which problems the row has)
                for (i, &v) in row.iter().enumerate() {
                    if !v.is_finite() {
                        flags |= DotFlags::NAN_PIXELS;
                    } else if mask_row.is_some_and(|m| !m[i]) {
                        flags |= DotFlags::MASKED;
                    } else if img.is_saturated(v) {
                        flags |= DotFlags::SATURATED;
                    }
                }
            }
        }
        ws.n_used = n_used;
        flags
    }

    pub(crate) fn load_samples(&mut self, s: &WindowSamples) -> DotFlags {
        let ws = &mut self.ws;
        let win = s.window;
        if s.values.len() != win.len() || s.keep.is_some_and(|k| k.len() != win.len()) {
            ws.resize(win.x, win.y, 0, 0);
            ws.n_used = 0;
            return DotFlags::NONE;
        }
        ws.resize(win.x, win.y, win.width, win.height);
        let mut flags = DotFlags::NONE;
        let mut n_used = 0;
        for (k, &v) in s.values.iter().enumerate() {
            let usable = if !v.is_finite() {
                flags |= DotFlags::NAN_PIXELS;
                false
            } else if s.keep.is_some_and(|keep| !keep[k]) {
                flags |= DotFlags::MASKED;
                false
            } else if s.saturation.is_some_and(|sat| v >= sat) {
                flags |= DotFlags::SATURATED;
                false
            } else {
                true
            };
            ws.data[k] = if usable { v } else { 0.0 };
            ws.keep[k] = if usable { 1.0 } else { 0.0 };
            n_used += usable as usize;
        }
        ws.n_used = n_used;
        flags
    }

    /// Fits the pixels loaded in the workspace. `held_first`: the dot's full fit failed in the
    /// pass before (singular, left its window, not finite), so a least-squares fit holds the
    /// shape first (at [`Fitter::fixed_shape`]) and fits all parameters only where that finds
    /// no dot.
    pub(crate) fn fit_loaded(
        &mut self,
        flags: DotFlags,
        start: [f64; 2],
        hint: Option<&Gaussian2D>,
        noise: &NoiseModel,
        held_first: bool,
    ) -> DotFit {
        self.fit_loaded_seen(flags, start, hint, hint, noise, held_first)
    }

    /// [`Fitter::fit_loaded`] from `hint`, its move ([`LastFit::moved`]) measured from `seen`
    /// instead (the dot as its neighbours saw it, where the start is another value).
    pub(crate) fn fit_loaded_seen(
        &mut self,
        flags: DotFlags,
        start: [f64; 2],
        hint: Option<&Gaussian2D>,
        seen: Option<&Gaussian2D>,
        noise: &NoiseModel,
        held_first: bool,
    ) -> DotFit {
        self.last = LastFit::default();
        let ws = &mut self.ws;
        let centre = [
            ws.wx as f64 + 0.5 * (ws.w as f64 - 1.0),
            ws.wy as f64 + 0.5 * (ws.h as f64 - 1.0),
        ];
        let start = if start.iter().all(|v| v.is_finite()) {
            start
        } else {
            centre
        };
        let bounds = Bounds::for_window(ws.wx, ws.wy, ws.w, ws.h);
        let needed = match self.cfg.estimator {
            Estimator::Lsg => self.kind.n_free() + 1,
            Estimator::Iwc => 1,
            Estimator::Tpg => 5,
        };
        if ws.n_used < needed {
            return failed(FitStatus::TooFewPixels, flags, nan_params(start));
        }
        match self.cfg.estimator {
            Estimator::Iwc => {
                let Some(m) = moments(ws, start, self.cfg.sampling.image_model()) else {
                    return failed(FitStatus::Singular, flags, nan_params(start));
                };
                let g = gaussian_from_theta(&m.theta());
                self.cheap_record(g, flags, noise)
            }
            Estimator::Tpg => match three_point(ws, start) {
                Ok(t) => {
                    if !bounds.inside(&t) {
                        return failed(FitStatus::LeftWindow, flags, nan_params(start));
                    }
                    let mut g = gaussian_from_theta(&t);
                    let mut rec = self.cheap_record(g, flags, noise);
                    g.rho = f64::NAN; // not estimated
                    rec.params = g;
                    rec
                }
                Err(status) => failed(status, flags, nan_params(start)),
            },
            Estimator::Lsg => {
                // a dot whose full fit failed before: its shape held first (issue 17: at σ
                // 0.3 px half the dots' full fits fail, each after ~12 iterations, twice)
                let held_tried = held_first && self.fixed_shape.is_some();
                let held = match self.fixed_shape {
                    Some(shape) if held_tried => self.solve_fixed_shape(
                        start,
                        hint,
                        &bounds,
                        noise,
                        shape,
                        FIXED_SHAPE_MIN_Z,
                    ),
                    _ => None,
                };
                let (out, shape_fixed) = match held {
                    Some(out) => (out, true),
                    // (the held shape, tried and failed, is not tried again after the free fit)
                    None => self.solve_free(start, hint, &bounds, noise, !held_tried),
                };
                let kind = if shape_fixed {
                    Kind::FixedShape
                } else {
                    self.kind
                };
                self.last = LastFit {
                    rho_held: out.rho_held.filter(|_| !shape_fixed),
                    chi2: out.cost,
                    dof: self
                        .ws
                        .n_used
                        .saturating_sub(kind.n_free() - usize::from(out.rho_held.is_some())),
                    moved: match seen {
                        // (a shape held at another value than the one seen: moved by more than
                        // its free parameters say)
                        Some(h)
                            if out.status.is_ok()
                                && (!shape_fixed || same_shape(h, &out.theta)) =>
                        {
                            let (from, to) = (theta_from_gaussian(h), out.theta);
                            let mut d = [0.0; 7];
                            // the dot as its neighbours see it: without its background
                            for (k, &p) in kind.free().iter().enumerate() {
                                d[k] = if p == IB { 0.0 } else { to[p] - from[p] };
                            }
                            crate::solver::quad_form(&out.fisher, &d, kind.n_free())
                                .max(0.0)
                                .sqrt()
                        }
                        _ => f64::INFINITY,
                    },
                    // (a held shape: its Fisher matrix is of other parameters than the model's)
                    point_fisher: (out.status.is_ok()
                        && !shape_fixed
                        && match self.cfg.sampling {
                            FitSampling::Point => true,
                            FitSampling::Auto => conditional_sigma(&out.theta) >= AUTO_SIGMA,
                            FitSampling::Integrated => false,
                        })
                    .then_some(out.fisher),
                };
                if shape_fixed {
                    return self.lsg_record(&out, flags | DotFlags::SHAPE_FIXED);
                }
                self.lsg_record(&out, flags)
            }
        }
    }

    /// Whether the pixels loaded in the workspace hold a dot near `start` (a lattice site where
    /// the detector found none): a least-squares fit with the shape held at
    /// [`Fitter::fixed_shape`] (the image's median dot) whose amplitude at the site reaches
    /// [`PRESENCE_SITE_MIN_Z`] standard deviations, or that converges with its position free and
    /// an amplitude of at least [`PRESENCE_MIN_Z`], with a position bound within a pixel;
    /// then the full fit from there ([`Fitter::fit_loaded`], which holds the shape again where
    /// the full fit is singular). `None`: no dot (or no least-squares fit, no median shape).
    pub(crate) fn fit_loaded_present(
        &mut self,
        flags: DotFlags,
        start: [f64; 2],
        noise: &NoiseModel,
    ) -> Option<DotFit> {
        let shape = self.fixed_shape?;
        let ws = &self.ws;
        if self.cfg.estimator != Estimator::Lsg
            || ws.n_used <= Kind::FixedShape.n_free()
            || !start.iter().all(|v| v.is_finite())
        {
            return None;
        }
        let bounds = Bounds::for_window(ws.wx, ws.wy, ws.w, ws.h);
        // a dot at the lattice site itself (a linear fit), or anywhere in the window at a higher
        // bar (the lattice's prediction may be off)
        let at_site = self
            .amplitude_z_at(start, &bounds, noise, shape)
            .is_some_and(|z| z >= PRESENCE_SITE_MIN_Z);
        let min_z = if at_site { 0.0 } else { PRESENCE_MIN_Z };
        let held = self.solve_fixed_shape(start, None, &bounds, noise, shape, min_z)?;
        let g = gaussian_from_theta(&held.theta);
        let fit = self.fit_loaded(flags, [g.x0, g.y0], Some(&g), noise, false);
        fit.status.is_ok().then_some(fit)
    }

    /// A dot of shape `shape` held at `at` with its amplitude and background fitted on the
    /// loaded window (a linear fit): the model of a lattice site outside the image whose light
    /// reaches into it. `reach`: a window holding `at` (the unclipped window of the site), the
    /// fit's bounds. `None` unless the amplitude reaches [`PRESENCE_SITE_MIN_Z`] standard
    /// deviations (no dot printed there) and the fit converged.
    pub(crate) fn fit_loaded_ghost(
        &mut self,
        at: [f64; 2],
        reach: Window,
        noise: &NoiseModel,
        shape: [f64; 3],
    ) -> Option<Gaussian2D> {
        if self.cfg.estimator != Estimator::Lsg
            || self.ws.n_used <= Kind::Linear.n_free()
            || !at.iter().all(|v| v.is_finite())
        {
            return None;
        }
        let bounds = Bounds::for_window(reach.x, reach.y, reach.width, reach.height);
        let hint = Gaussian2D {
            x0: at[0],
            y0: at[1],
            sigma_x: shape[0],
            sigma_y: shape[1],
            rho: shape[2],
            amplitude: 1.0,
            background: crate::start::background(&mut self.ws),
        };
        let (out, z) = self.solve_held(
            Kind::Linear,
            at,
            Some(&hint),
            Some(at),
            &bounds,
            noise,
            shape,
        )?;
        (out.status.is_ok() && z >= PRESENCE_SITE_MIN_Z).then(|| gaussian_from_theta(&out.theta))
    }

    /// The amplitude of a dot of shape `shape` centred at `at`, in its standard deviations
    /// (amplitude and background fitted: a linear fit, whose z is standard normal where there
    /// is no dot); `None` where that cannot be fitted.
    fn amplitude_z_at(
        &mut self,
        at: [f64; 2],
        bounds: &Bounds,
        noise: &NoiseModel,
        shape: [f64; 3],
    ) -> Option<f64> {
        let (out, z) = self.solve_held(Kind::Linear, at, None, Some(at), bounds, noise, shape)?;
        out.status.is_ok().then_some(z)
    }

    /// The least-squares fit with every parameter free, from `hint` (or the start's moments,
    /// and from those again where the hint's fit fails); with `fallback`, where that is
    /// singular, leaves its window or is not finite, with the shape held at
    /// [`Fitter::fixed_shape`] (`true`: held).
    fn solve_free(
        &mut self,
        start: [f64; 2],
        hint: Option<&Gaussian2D>,
        bounds: &Bounds,
        noise: &NoiseModel,
        fallback: bool,
    ) -> (Outcome, bool) {
        let theta0 = self.start_theta(start, hint, bounds);
        let mut out = self.solve(theta0, bounds, noise, hint.is_some());
        // a warm start that went wrong: once more from the moments. Not where it converged
        // to a minimum whose position bound exceeds a pixel: the dot's own last fit led
        // there, the start is not what failed (issue 17: at σ 0.3 px 689 of 2,622 dots took
        // ~10 evaluations for it, 84 found a free shape; with the shape held instead the RMS
        // error fell from 0.617 to 0.605 of the bound); nor where the moments are the start
        // just tried (pass 1 starts from the window's moment record: 587 dots' same solve
        // again, ~6 evaluations each)
        if hint.is_some() && !out.status.is_ok() && !out.unbounded {
            let theta1 = self.start_theta(start, None, bounds);
            let repeat = same_start(&theta0, &theta1)
                && (self.cfg.sampling != FitSampling::Auto
                    || self.integrated_at_start(&theta0, true)
                        == self.integrated_at_start(&theta1, false));
            if !repeat {
                let again = self.solve(theta1, bounds, noise, false);
                out = Outcome {
                    iterations: out.iterations + again.iterations,
                    ..again
                };
            }
        }
        if fallback
            && matches!(
                out.status,
                FitStatus::Singular | FitStatus::LeftWindow | FitStatus::NonFinite
            )
            && let Some(shape) = self.fixed_shape
            && let Some(again) =
                self.solve_fixed_shape(start, hint, bounds, noise, shape, FIXED_SHAPE_MIN_Z)
        {
            let out = Outcome {
                iterations: out.iterations + again.iterations,
                ..again
            };
            return (out, true);
        }
        (out, false)
    }

    /// A least-squares fit of `kind` (`FixedShape` or `Linear`) from the start's moments (or
    /// `hint`) with the shape set to `shape` (σx, σy, ρ) and, with `at`, the centre there; the
    /// outcome and its amplitude in standard deviations (`None`: no amplitude variance).
    #[allow(clippy::too_many_arguments)]
    fn solve_held(
        &mut self,
        kind: Kind,
        start: [f64; 2],
        hint: Option<&Gaussian2D>,
        at: Option<[f64; 2]>,
        bounds: &Bounds,
        noise: &NoiseModel,
        shape: [f64; 3],
    ) -> Option<(Outcome, f64)> {
        let t = self.start_theta(start, hint, bounds);
        let mut g = gaussian_from_theta(&t);
        if let Some([x, y]) = at {
            (g.x0, g.y0) = (x, y);
        }
        (g.sigma_x, g.sigma_y, g.rho) = (shape[0], shape[1], shape[2]);
        let mut theta0 = theta_from_gaussian(&g);
        if at.is_none() {
            bounds.project(&mut theta0);
        }
        let saved = std::mem::replace(&mut self.kind, kind);
        let out = self.solve(theta0, bounds, noise, false);
        self.kind = saved;
        // the amplitude's row among the free parameters
        let k = kind.free().iter().position(|&p| p == crate::eval::IA)?;
        let mut e = [0.0; 7];
        e[k] = 1.0;
        let var = crate::solver::solve_damped(&out.fisher, &e, kind.n_free(), 0.0)?[k];
        (var > 0.0).then(|| {
            let z = out.theta[crate::eval::IA] / var.sqrt();
            (out, z)
        })
    }

    /// The fit again from its start with the shape held at `shape` (σx, σy, ρ): position,
    /// amplitude and background only. `None` unless that converges with a position bound
    /// within a pixel and an amplitude of at least `min_z` standard deviations (an empty window
    /// does not become a dot).
    fn solve_fixed_shape(
        &mut self,
        start: [f64; 2],
        hint: Option<&Gaussian2D>,
        bounds: &Bounds,
        noise: &NoiseModel,
        shape: [f64; 3],
        min_z: f64,
    ) -> Option<Outcome> {
        let (out, z) =
            self.solve_held(Kind::FixedShape, start, hint, None, bounds, noise, shape)?;
        (out.status.is_ok() && z >= min_z).then_some(out)
    }

    /// `fitted_start`: `theta0` is a fit of the dot (the pass before), whose sigma is the dot's
    /// own, not a window's moments (`auto` sampling decides at it).
    fn solve(
        &mut self,
        theta0: Theta,
        bounds: &Bounds,
        noise: &NoiseModel,
        fitted_start: bool,
    ) -> Outcome {
        let mut out = match self.cfg.sampling {
            FitSampling::Point => self.solve_with(theta0, bounds, noise, Sampling::Point),
            FitSampling::Integrated => self.solve_integrated(theta0, bounds, noise),
            FitSampling::Auto => self.solve_auto(theta0, bounds, noise, fitted_start),
        };
        if self.kind == Kind::Linear {
            // (no position among the free parameters)
            return out;
        }
        out.bound = position_bound(&out.fisher, self.kind.n_free());
        // a fit whose position bound exceeds a pixel holds no position information: no dot
        if out.status.is_ok()
            && !out
                .bound
                .is_some_and(|b| b[0] <= MAX_BOUND_PX && b[1] <= MAX_BOUND_PX)
        {
            out.status = FitStatus::Singular;
            out.unbounded = true;
        }
        out
    }

    /// [`FitSampling::Auto`]: the pixel-blurred point model while the dot is wide enough, the
    /// pixel-integrated model from where it is not.
    fn solve_auto(
        &mut self,
        theta0: Theta,
        bounds: &Bounds,
        noise: &NoiseModel,
        fitted_start: bool,
    ) -> Outcome {
        let start_sigma = conditional_sigma(&theta0);
        let intermediate = self.intermediate && start_sigma >= INTERMEDIATE_BLUR_SIGMA;
        // a dot on a pixel edge has window moments up to ~0.6 px wide where its σ is 0.3: a
        // start from its 3 × 3 block decides (issue 17: at σ 0.3 px those dots took the
        // pixel-blurred fit and then the integrated one, ~14 evaluations, in pass 1)
        if intermediate && self.holds_rho() && start_sigma < NARROW_START_SIGMA {
            // (where the block gives no profile the start keeps its σ, ≥ 0.5 px with ρ = 0)
            let t = self.rho_held_start(theta0, bounds);
            if conditional_sigma(&t) < INTERMEDIATE_BLUR_SIGMA {
                return self.solve_rho_held(t, bounds, noise);
            }
        }
        if self.integrated_at_start(&theta0, fitted_start) {
            return self.solve_integrated(theta0, bounds, noise);
        }
        let mut blurred = pixel_blur(&theta0);
        bounds.project(&mut blurred);
        let out = self.solve_with(blurred, bounds, noise, Sampling::Point);
        let sharp = pixel_unblur(&out.theta);
        if intermediate {
            if out.status.is_ok()
                && let Some(t) = sharp
            {
                return Outcome { theta: t, ..out };
            }
            // (a blurred fit that failed or has no unblurred dot, from a start the final fit
            // would not have tried it from)
            if start_sigma < 0.7 * AUTO_SIGMA {
                return self.solve_with(theta0, bounds, noise, Sampling::Integrated);
            }
        }
        match sharp {
            Some(t) if conditional_sigma(&t) >= AUTO_SIGMA => Outcome { theta: t, ..out },
            _ if !out.status.is_ok() => Outcome {
                theta: sharp.unwrap_or([f64::NAN; 7]),
                ..out
            },
            _ => {
                // narrower than the approximation allows: the integrated model from here
                let mut t = sharp.unwrap_or(theta0);
                bounds.project(&mut t);
                self.kind.constrain(&mut t);
                let again = self.solve_with(t, bounds, noise, Sampling::Integrated);
                Outcome {
                    iterations: out.iterations + again.iterations,
                    ..again
                }
            }
        }
    }

    /// Whether [`Fitter::solve_auto`] fits the integrated model from `theta0` directly (else
    /// the pixel-blurred point model first, deciding at its solution).
    fn integrated_at_start(&self, theta0: &Theta, fitted_start: bool) -> bool {
        let start_sigma = conditional_sigma(theta0);
        // an intermediate fit (a neighbour model and the start of the next pass, which fits
        // the integrated model where the dot is narrow) takes the pixel-blurred point model
        // down to INTERMEDIATE_BLUR_SIGMA whatever width it ends at: a fraction of the
        // integrated model's cost
        let intermediate = self.intermediate && start_sigma >= INTERMEDIATE_BLUR_SIGMA;
        // the start (moments of a window that may truncate the dot) can under-state sigma: the
        // decision is taken at the solution, with a lower bar for trying the fast model; a
        // held shape (a ghost's linear fit, a fit with its shape fixed) ends at its start's
        // sigma, and a start that is a fit of the dot (the pass before) is at its sigma, so
        // the decision is taken there (issue 17: the σ 0.75 px scene's final pass fitted the
        // blurred model again, then the integrated one from its answer; its ghosts likewise)
        let held = matches!(self.kind, Kind::Linear | Kind::FixedShape);
        let bar = if held || fitted_start {
            AUTO_SIGMA
        } else {
            0.7 * AUTO_SIGMA
        };
        !intermediate && start_sigma < bar
    }

    /// The pixel-integrated model from `theta0`. An intermediate fit of a narrow elliptical
    /// dot (conditional σ at the start below [`INTERMEDIATE_BLUR_SIGMA`]) holds ρ at 0: the
    /// axis-aligned model's closed-form erf moments instead of the quadrature's nodes, and a
    /// shape of five parameters where the seven are barely determined; the full model from the
    /// next pass on, from this fit. Its Fisher matrix is the elliptical model's at the
    /// solution (one more evaluation, also in closed form at ρ = 0), so the position bound and
    /// the later passes' looks see the full model's. Issue 17, bench/trackpy's σ 0.3 px
    /// scene: 1.69 → 1.22 G instructions for `locate`, RMS error 0.600 → 0.581 of the bound.
    fn solve_integrated(&mut self, theta0: Theta, bounds: &Bounds, noise: &NoiseModel) -> Outcome {
        // (with `neighbour_passes = 1` pass 1's fits are the final ones: the full model there)
        if !(self.holds_rho() && conditional_sigma(&theta0) < INTERMEDIATE_BLUR_SIGMA) {
            return self.solve_with(theta0, bounds, noise, Sampling::Integrated);
        }
        let t0 = self.rho_held_start(theta0, bounds);
        self.solve_rho_held(t0, bounds, noise)
    }

    /// The start of [`Fitter::solve_rho_held`]: `theta0` with ρ = 0, its centre and σ from the
    /// 3 × 3 block where that gives a profile ([`crate::start::narrow_start`]), projected.
    fn rho_held_start(&self, theta0: Theta, bounds: &Bounds) -> Theta {
        let mut t = theta0;
        t[IT] = 0.0;
        crate::start::narrow_start(&self.ws, &mut t);
        bounds.project(&mut t);
        t
    }

    /// Whether an integrated fit of a narrow dot holds ρ at 0 ([`Fitter::solve_integrated`]).
    fn holds_rho(&self) -> bool {
        self.intermediate && self.cfg.neighbour_passes > 1 && self.kind == Kind::Elliptical
    }

    /// The axis-aligned integrated fit from `t0` (ρ = 0), with the elliptical model's Fisher
    /// matrix at its solution and, in `Outcome::rho_held`, ρ one Gauss-Newton step from there
    /// (the fit keeps ρ = 0).
    fn solve_rho_held(&mut self, t0: Theta, bounds: &Bounds, noise: &NoiseModel) -> Outcome {
        self.kind = Kind::AxisAligned;
        let mut out = self.solve_with(t0, bounds, noise, Sampling::Integrated);
        self.kind = Kind::Elliptical;
        let pass = evaluate(
            &mut self.ws,
            &out.theta,
            Sampling::Integrated,
            Kind::Elliptical,
            noise,
        );
        let mut rho = f64::NAN;
        if pass.finite {
            let (nm, g) = normal_equations(Kind::Elliptical, &out.theta, &pass);
            out.fisher = nm;
            // ρ: one Gauss-Newton step of the full model from the solution at ρ = 0, for the
            // held shape's median (not the fit's: as the next pass's start it cost that pass
            // 5 % more instructions at σ 0.3 px)
            rho = crate::solver::solve_damped(&nm, &g, 7, 0.0)
                .map(|step| Kind::Elliptical.apply_step(&out.theta, &step)[IT].tanh())
                .filter(|r| r.is_finite())
                .map_or(f64::NAN, |r| r.clamp(-RHO_ONE_STEP_MAX, RHO_ONE_STEP_MAX));
        } else if out.status.is_ok() {
            out.status = FitStatus::NonFinite;
        }
        out.rho_held = Some(rho);
        out
    }

    fn solve_with(
        &mut self,
        theta0: Theta,
        bounds: &Bounds,
        noise: &NoiseModel,
        sampling: Sampling,
    ) -> Outcome {
        let tolerance = self.tolerance();
        // the Gauss-Legendre order of the integrated model, fixed for the solve from its start
        self.ws.gl_n = gl_order(
            theta0[IU].min(theta0[IV]).exp(),
            quadrature_tolerance(&theta0, noise),
        );
        let out = match self.cfg.solver {
            Solver::Fast => solve_fast(
                &mut self.ws,
                theta0,
                self.kind,
                sampling,
                noise,
                bounds,
                self.cfg.max_iterations,
                tolerance,
                !(self.intermediate || self.warm),
            ),
            Solver::LmCrate => solve_lm_crate(
                &mut self.ws,
                theta0,
                self.kind,
                sampling,
                noise,
                bounds,
                self.cfg.max_iterations,
                tolerance,
            ),
        };
        self.ws.gl_n = 0;
        out
    }

    /// The convergence tolerance: the configured one, or for an intermediate fit (a neighbour
    /// model that is refitted later) at least [`INTERMEDIATE_TOLERANCE`].
    fn tolerance(&self) -> f64 {
        if self.intermediate {
            self.cfg.tolerance.max(INTERMEDIATE_TOLERANCE)
        } else {
            self.cfg.tolerance
        }
    }

    /// Start of the least-squares fit: the hint's shape at `start` if given, otherwise the
    /// thresholded centroid and corrected second moments; projected into the bounds.
    fn start_theta(
        &mut self,
        start: [f64; 2],
        hint: Option<&Gaussian2D>,
        bounds: &Bounds,
    ) -> Theta {
        let ws = &mut self.ws;
        let mut t = match hint.filter(|h| h.is_valid()) {
            Some(h) => {
                let mut t = theta_from_gaussian(h);
                t[IX] = start[0];
                t[IY] = start[1];
                t
            }
            None => match moments(ws, start, self.cfg.sampling.image_model()) {
                Some(m) => m.theta(),
                None => {
                    // no pixel above the background: a unit dot at the start
                    let bg = crate::start::background(ws);
                    [
                        start[0],
                        start[1],
                        1.0,
                        0.0,
                        0.0,
                        0.0,
                        if bg.is_finite() { bg } else { 0.0 },
                    ]
                }
            },
        };
        bounds.project(&mut t);
        self.kind.constrain(&mut t);
        t[IX] = t[IX].clamp(bounds.x_lo, bounds.x_hi);
        t[IY] = t[IY].clamp(bounds.y_lo, bounds.y_hi);
        if !t[IB].is_finite() {
            t[IB] = 0.0;
        }
        t
    }

    fn lsg_record(&self, out: &Outcome, mut flags: DotFlags) -> DotFit {
        let ws = &self.ws;
        let mut status = out.status;
        let mut params = gaussian_from_theta(&out.theta);
        if !out.theta.iter().all(|v| v.is_finite()) || !params.is_valid() {
            status = FitStatus::NonFinite;
            params = nan_params([params.x0, params.y0]);
        }
        if out.at_bound {
            flags |= DotFlags::AT_BOUND;
        }
        if !status.is_ok() {
            flags |= DotFlags::FIT_FAILED;
        }
        let (crlb_x, crlb_y) = match out.bound {
            Some(b) if self.cfg.bound && status != FitStatus::NonFinite => (b[0], b[1]),
            _ => (f64::NAN, f64::NAN),
        };
        let rms = if ws.n_used > 0 {
            (out.ssr / ws.n_used as f64).sqrt()
        } else {
            f64::NAN
        };
        DotFit {
            index: GridIndex::new(0, 0),
            params,
            crlb_x,
            crlb_y,
            rms,
            iterations: out.iterations,
            status,
            flags,
        }
    }

    /// Record of IWC/TPG: the bound from `bostrack_model::crlb_masked` at the estimate, rms of
    /// the estimate's model over the used pixels.
    fn cheap_record(&self, g: Gaussian2D, flags: DotFlags, noise: &NoiseModel) -> DotFit {
        let ws = &self.ws;
        let win = Window::new(ws.wx, ws.wy, ws.w, ws.h);
        let keep = |x: i64, y: i64| {
            let (i, j) = (x - ws.wx, y - ws.wy);
            i >= 0
                && j >= 0
                && (i as usize) < ws.w
                && (j as usize) < ws.h
                && ws.keep[j as usize * ws.w + i as usize] > 0.0
        };
        let (crlb_x, crlb_y) = if self.cfg.bound && g.is_valid() {
            match bostrack_model::crlb_masked(
                &g,
                win,
                noise,
                self.cfg.sampling.image_model(),
                self.cfg.model,
                &keep,
            ) {
                Some(b) => (b.std[0], b.std[1]),
                None => (f64::NAN, f64::NAN),
            }
        } else {
            (f64::NAN, f64::NAN)
        };
        let status = if g.x0.is_finite() && g.y0.is_finite() {
            FitStatus::Converged
        } else {
            FitStatus::NonFinite
        };
        let mut flags = flags;
        if !status.is_ok() {
            flags |= DotFlags::FIT_FAILED;
        }
        DotFit {
            index: GridIndex::new(0, 0),
            params: g,
            crlb_x,
            crlb_y,
            rms: f64::NAN,
            iterations: 0,
            status,
            flags,
        }
    }
}

/// Parameters of a failed estimate: NaN everywhere (the status says why).
fn nan_params(_start: [f64; 2]) -> Gaussian2D {
    Gaussian2D {
        x0: f64::NAN,
        y0: f64::NAN,
        amplitude: f64::NAN,
        sigma_x: f64::NAN,
        sigma_y: f64::NAN,
        rho: f64::NAN,
        background: f64::NAN,
    }
}

fn failed(status: FitStatus, flags: DotFlags, params: Gaussian2D) -> DotFit {
    DotFit {
        index: GridIndex::new(0, 0),
        params,
        crlb_x: f64::NAN,
        crlb_y: f64::NAN,
        rms: f64::NAN,
        iterations: 0,
        status,
        flags: flags | DotFlags::FIT_FAILED,
    }
}

/// Fits one dot in `window` of `img` with `cfg`'s estimator, starting near `start` (px).
///
/// Pixels that are non-finite (flag `NAN_PIXELS`), masked (`MASKED`) or saturated
/// (`SATURATED`, from `img.meta.saturation`) are left out; a window cut by the image edge is
/// clipped and flagged `BORDER` (also when it merely touches the edge). `hint`, if valid,
/// gives the starting shape (its centre is replaced by `start`); otherwise the fit starts from
/// the thresholded centroid and the corrected second moments. The record's `index` is (0, 0):
/// [`crate::fit_dots`] fills it from the seed.
///
/// Never panics and never returns a NaN without a failure status. A mask of another size than
/// the image leaves no usable pixel (`TooFewPixels`, `MASKED`).
pub fn fit_window(
    img: &Image,
    mask: Option<&Mask>,
    window: Window,
    start: [f64; 2],
    hint: Option<&Gaussian2D>,
    cfg: &FitConfig,
    noise: &NoiseModel,
) -> DotFit {
    Fitter::new(cfg).fit_window(img, mask, window, start, hint, noise)
}

/// Whether two starts are the same to rounding (the moment start of a window and the moment
/// record passed as a hint, through `ln`/`exp` and `atanh`/`tanh`): a solve from either takes
/// the same path.
fn same_start(a: &Theta, b: &Theta) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (x - y).abs() <= 1e-12 * x.abs().max(y.abs()).max(1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bostrack_core::{Image, ImageMeta, Mask};
    use rand::{RngExt, SeedableRng};

    /// `load_image` (whole usable rows copied at once, the others pixel by pixel) against the
    /// rule of every pixel: a NaN or ±∞ sample, a masked pixel or one at the saturation level
    /// is left out (0, keep 0) with its flag; windows at or over the image's edges are flagged
    /// BORDER. `load_image_less` is the same load with a canvas subtracted, to the bit.
    #[test]
    fn loaded_windows_follow_the_pixel_rule() {
        let (w, h) = (41, 33);
        let mut rng = rand::rngs::StdRng::seed_from_u64(12345);
        let data: Vec<f64> = (0..w * h)
            .map(|_| match rng.random_range(0..200u32) {
                0 => f64::NAN,
                1 => f64::INFINITY,
                2 => f64::NEG_INFINITY,
                3 => 4095.0,
                4 => 5000.0,
                _ => rng.random_range(100.0..3100.0),
            })
            .collect();
        let img = Image::new(w, h, data, ImageMeta::synthetic(12)).unwrap(); // saturated at 4095
        let keep: Vec<bool> = (0..w * h)
            .map(|_| rng.random_range(0.0..1.0) > 0.01)
            .collect();
        let mask = Mask::new(w, h, keep).unwrap();
        // a canvas of neighbours to load less (`load_image_less`)
        let canvas: Vec<f64> = (0..w * h).map(|_| rng.random_range(-50.0..400.0)).collect();
        let mut f = Fitter::new(&FitConfig::default());
        let mut rows_checked = 0;
        for (x, y, ww, wh, border) in [
            (3, 4, 13, 13, false),
            (-5, -4, 13, 13, true),
            (33, 25, 13, 13, true),
            (0, 0, 41, 33, true),
            (10, 10, 7, 5, false),
        ] {
            for m in [None, Some(&mask)] {
                let win = Window::new(x, y, ww, wh);
                let flags = f.load_image(&img, m, win);
                let c = win.clip(w, h).unwrap();
                assert_eq!(flags.contains(DotFlags::BORDER), border, "window {win:?}");
                let mut want = DotFlags::NONE;
                let mut used = 0;
                assert_eq!((f.ws.w, f.ws.h), (c.width, c.height));
                for j in 0..c.height {
                    for i in 0..c.width {
                        let (px, py) = (c.x as usize + i, c.y as usize + j);
                        let v = img.row(py)[px];
                        let ok = if !v.is_finite() {
                            want |= DotFlags::NAN_PIXELS;
                            false
                        } else if m.is_some_and(|m| !m.keeps(px, py)) {
                            want |= DotFlags::MASKED;
                            false
                        } else if v >= 4095.0 {
                            want |= DotFlags::SATURATED;
                            false
                        } else {
                            true
                        };
                        let k = j * c.width + i;
                        assert_eq!(f.ws.keep[k], if ok { 1.0 } else { 0.0 });
                        assert_eq!(f.ws.data[k], if ok { v } else { 0.0 });
                        used += usize::from(ok);
                    }
                    rows_checked += 1;
                }
                assert_eq!(f.ws.n_used, used);
                let mut got = flags;
                got.remove(DotFlags::BORDER);
                assert_eq!(got, want, "window {win:?}");
                // loaded less the canvas in the same pass: bit for bit the load, then
                // `data −= keep · canvas` pixel by pixel
                let (data, keep, n_used) = (f.ws.data.clone(), f.ws.keep.clone(), f.ws.n_used);
                let less_flags = f.load_image_less(&img, m, win, Some(&canvas));
                assert_eq!(less_flags, flags);
                assert_eq!(f.ws.n_used, n_used);
                for j in 0..c.height {
                    for i in 0..c.width {
                        let k = j * c.width + i;
                        let cv = canvas[(c.y as usize + j) * w + c.x as usize + i];
                        assert_eq!(f.ws.keep[k].to_bits(), keep[k].to_bits());
                        let want = data[k] - keep[k] * cv;
                        assert_eq!(f.ws.data[k].to_bits(), want.to_bits(), "window {win:?}");
                    }
                }
            }
        }
        assert!(rows_checked > 100);
    }
}
