//! Fitting every dot of an image, in parallel, with the neighbours' tails subtracted.

use crate::FitError;
use crate::config::{AUTO_SIGMA, Estimator, FitConfig, FitSampling, Neighbours};
use crate::error::check_mask;
use crate::eval::{IA, theta_from_gaussian};
use crate::fit::Fitter;
use crate::joint::JointDot;
use bostrack_core::{
    DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex, GridTable, Image, Mask, NoiseModel, Seed,
    Window,
};
use bostrack_model::Sampling;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Sigmas beyond which a neighbour's dot is taken as zero (exp(-12.5) ≈ 4e-6 of its peak).
const REACH_SIGMAS: f64 = 5.0;

/// Margin (px) added to a ghost's 5σ reach when deciding whether any seed's window could see
/// it ([`Iteration::ghosts`]).
const GHOST_MARGIN: f64 = 2.0;

/// Fits every seed's window (rayon over dots; the output is in the order of `seeds`).
///
/// Seeds flagged `MISSING` are looked for by their fit once (least squares; see
/// `Fitter::fit_loaded_present`): where no dot is found they keep status `NotFitted`; every
/// record carries its seed's flags (less `MISSING` where a dot was found) and grid index. With [`Neighbours::Subtract`] (the default, least-squares
/// estimator only) the dots are fitted jointly with their neighbours by a block-Jacobi
/// iteration with an active set: a dot is fitted to its window minus the fitted dots (without
/// background) of its neighbours, each over the pixels of its 5σ box (rendered once per pass
/// into an image-sized canvas, from which a window takes its values and adds its own dot back,
/// or, when few dots are left to refit, rendered into the window), and starts from its previous
/// fit. Pass 1 starts from the moment estimates, pass 2 refits every dot (the two colours of
/// the lattice's checkerboard one after the other, red-black); from pass 3 on only the dots
/// whose neighbours moved enough to move them by more than `cfg.neighbour_tolerance` of their
/// standard deviations are updated, one colour per pass, until none is left or
/// `cfg.neighbour_passes` passes were made (then dots still moving are flagged `UNCONVERGED`).
/// Such a dot is first looked at: one Gauss-Newton step from its last fit, with that fit's
/// Fisher matrix, on its window with the neighbours' current models subtracted. Below the
/// tolerance it is left as it is; up to 2 standard deviations the step is taken (what a refit
/// would return, to second order in a step of ~1 % of σ: on the real gradient frame 98.5 % of
/// the updates); beyond, or where the step leaves the model's range, it is refitted.
/// Lattice sites just outside the image are modelled as ghosts (see [`FitConfig::ghosts`]). Every least-squares
/// record gets the χ² test of its window residual (flag `RESIDUAL`, see
/// [`FitConfig::residual_false_alarm`]). Seeds closer than 1.5 px are taken as the same dot
/// found twice and not subtracted from each other. The result does not depend on the number of
/// threads.
pub fn fit_dots(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
) -> Result<Vec<DotFit>, FitError> {
    fit_dots_report(img, mask, seeds, cfg, noise).map(|r| r.0)
}

/// How the neighbour iteration of [`fit_dots_report`] / [`refit_dots_report`] went.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PassReport {
    /// Passes made (0 without neighbour subtraction).
    pub passes: u32,
    /// Dots refitted in each pass.
    pub refits: Vec<usize>,
    /// Whether the iteration stopped because no dot was left to refit (rather than at
    /// `neighbour_passes`; true without neighbour subtraction).
    pub converged: bool,
    /// Dots flagged `UNCONVERGED`.
    pub unconverged: usize,
    /// Sweeps of the linearised iteration that replaced the passes after the first (0: none;
    /// see [`NeighbourTails::coupled`]).
    pub linear_sweeps: u32,
    /// Of the `refits`, the dots updated by one Gauss-Newton step from their last fit (or, in
    /// the first pass of a coupled stack image, from the prior) instead of a fit: a predicted
    /// move of at most 2 standard deviations.
    pub linear_steps: usize,
}

impl PassReport {
    /// The report of a fit without neighbour subtraction (no passes).
    fn none() -> PassReport {
        PassReport {
            passes: 0,
            refits: Vec::new(),
            converged: true,
            unconverged: 0,
            linear_sweeps: 0,
            linear_steps: 0,
        }
    }
}

/// [`fit_dots`], with how its neighbour iteration went.
pub fn fit_dots_report(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
) -> Result<(Vec<DotFit>, PassReport), FitError> {
    fit_dots_inner(img, mask, seeds, cfg, noise, false).map(|(f, r, _)| (f, r))
}

/// `remember`: return the fits' [`FitMemory`] (an empty one without).
fn fit_dots_inner(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
    remember: bool,
) -> Result<(Vec<DotFit>, PassReport, FitMemory), FitError> {
    cfg.validate()?;
    check_mask(img, mask)?;
    if cfg.neighbours == Neighbours::None || cfg.estimator != Estimator::Lsg {
        let items: Vec<Item> = seeds
            .par_iter()
            .map_init(
                || Fitter::new(cfg),
                |f, s| {
                    let fit = fit_seed(f, img, mask, s, None, noise);
                    Item::from_fitter(fit, f, false)
                },
            )
            .collect();
        let memory = FitMemory::of(&items, remember, None);
        return Ok((finish(items, cfg), PassReport::none(), memory));
    }
    // first neighbour models: the moment estimates (IWC record), which stop at the saddle
    // towards a touching neighbour, whereas a plain least-squares fit of a window holding two
    // touching dots can converge to one wide blob over both
    let iwc = FitConfig {
        estimator: Estimator::Iwc,
        bound: false,
        ..cfg.clone()
    };
    let prev: Vec<DotFit> = seeds
        .par_iter()
        .map_init(
            || Fitter::new(&iwc),
            |f, s| fit_seed(f, img, mask, s, None, noise),
        )
        .collect();
    let mut canvas_buf = Vec::new();
    let mut it = Iteration::new(img, mask, seeds, cfg, noise);
    it.remember = remember;
    // one set of neighbour models through all passes, each dot's replaced where its new fit
    // passes the gate (see `Plausible`)
    let mut hood = Neighbourhood::new(&prev, seeds, cfg.sampling);
    // pass 1: every dot, from the moments, loose tolerance (a neighbour model for pass 2)
    let first = it.pass(
        &prev,
        PassKind {
            intermediate: true,
            warm: false,
            looked_at: false,
        },
        None,
        &hood,
        &mut canvas_buf,
    );
    let n_fit = fitted(seeds);
    if cfg.neighbour_passes == 1 {
        let report = PassReport {
            passes: 1,
            refits: vec![n_fit],
            converged: false,
            unconverged: 0,
            linear_sweeps: 0,
            linear_steps: 0,
        };
        let memory = FitMemory::of(&first, remember, None);
        return Ok((finish(first, cfg), report, memory));
    }
    // pass 2: every dot again, to the full tolerance (with the weights check)
    let fits: Vec<DotFit> = first.iter().map(|i| i.fit).collect();
    it.fixed_shape = median_shape_first(&first, &fits);
    hood.update(&first, cfg.sampling);
    hood.set_ghosts(it.ghosts(&fits, &hood));
    let (second, colour) = it.pass_red_black(&first, &fits, &mut hood, &mut canvas_buf);
    hood.update(&second, cfg.sampling);
    let fits: Vec<DotFit> = second.iter().map(|i| i.fit).collect();
    hood.set_ghosts(it.ghosts(&fits, &hood));
    Ok(it.converge(
        second,
        vec![n_fit, n_fit],
        hood,
        &mut canvas_buf,
        Some(colour),
        None,
    ))
}

/// Fits every seed's window starting from `prior` (one record per seed: fits of the same
/// dots in a similar image, e.g. the reference's fits moved by the camera's common shift, for
/// the images of a no-flow stack, or each moved by its own tracked displacement, for a
/// gradient frame).
///
/// With [`Neighbours::Subtract`] (least-squares estimator) the first pass fits each window
/// after subtracting the `prior` dots of its neighbours (from `tails` where given); then the
/// iteration goes on as in [`fit_dots`] (from pass 2 on, only dots whose neighbours moved
/// enough are updated), so the result converges to the same joint solution. Seeds flagged
/// `MISSING` are looked for as in [`fit_dots`] (their prior is neither a start nor a neighbour
/// model), and the first pass checks the weights at its solution (the prior may be a fit of
/// another image). Otherwise each
/// window is fitted once from its prior's shape. A prior that is not a usable fit makes its dot
/// start from the seed (and, as a neighbour, not be subtracted).
///
/// `tails`: the neighbours' tails rendered once ([`NeighbourTails`], from the unmoved prior);
/// used in the first pass for every window that is the one they were rendered for, instead of
/// rendering the `prior` neighbours again (the caller decides that `prior` moved little enough:
/// see [`NeighbourTails`]).
///
/// Errors: as [`fit_dots`], and [`FitError::InvalidConfig`] if `prior` and `seeds` differ in
/// length.
pub fn refit_dots(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
    prior: &[DotFit],
    tails: Option<&NeighbourTails>,
) -> Result<Vec<DotFit>, FitError> {
    refit_dots_report(img, mask, seeds, cfg, noise, prior, tails).map(|r| r.0)
}

/// [`refit_dots`], with how its neighbour iteration went.
pub fn refit_dots_report(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
    prior: &[DotFit],
    tails: Option<&NeighbourTails>,
) -> Result<(Vec<DotFit>, PassReport), FitError> {
    refit_dots_remembered(img, mask, seeds, cfg, noise, prior, tails, None)
}

/// What a fit of an image keeps for fitting another image of the same dots: per dot the
/// Fisher matrix of its last least-squares fit (point-model fits; see [`fit_dots_remembered`]).
#[derive(Clone, Debug, Default)]
pub struct FitMemory {
    looked: Vec<Option<Looked>>,
    /// The iteration's [`Links`] as it ended (`None` for fits without a neighbour iteration).
    links: Option<LinkMemory>,
    /// The neighbour iteration linearised at these fits ([`FitMemory::with_map`]), for the
    /// parts of a gradient frame that did not move.
    map: Option<std::sync::Arc<crate::coupling::Coupling>>,
    /// The neighbour models the iteration ended with, and the sampling they were made for: a
    /// frame's first models are these moved to its prior's positions where nothing else
    /// changed ([`NeighbourModel::moved_to`]).
    models: Option<KnownModels>,
}

/// Neighbour models of a fit's dots, by dot, made for `FitSampling` (see [`FitMemory`]).
type KnownModels = (FitSampling, std::sync::Arc<Vec<Option<NeighbourModel>>>);

impl FitMemory {
    /// The memory of `items` (an empty one unless `remember`: a copy of ~0.5 kB per dot);
    /// `steps`: the first steps of the iteration they come from ([`Kept::Prior`]).
    fn of(items: &[Item], remember: bool, steps: Option<&[Option<Looked>]>) -> FitMemory {
        if !remember {
            return FitMemory::default();
        }
        FitMemory {
            looked: items
                .iter()
                .map(|i| i.looked.as_ref().and_then(|k| k.resolve(steps)).cloned())
                .collect(),
            links: None,
            map: None,
            models: None,
        }
    }

    /// Dots remembered (the seeds of the fit).
    pub fn len(&self) -> usize {
        self.looked.len()
    }

    /// Whether no dot is remembered.
    pub fn is_empty(&self) -> bool {
        self.looked.is_empty()
    }

    /// The memory for images whose noise variances are `ratio` times those the fits were
    /// weighted with (a reference that is the mean of `K` no-flow images, fitted with the noise
    /// model divided by `K`, and single frames: `ratio = K`): every Fisher matrix divided by
    /// `ratio`.
    pub fn for_variance_ratio(&self, ratio: f64) -> FitMemory {
        FitMemory {
            looked: self
                .looked
                .iter()
                .map(|l| l.as_ref().map(|l| l.scaled(1.0 / ratio)))
                .collect(),
            // (the shares are the models' geometry, not their noise; the map is made with a
            // frame's noise)
            links: self.links.clone(),
            map: self.map.clone(),
            models: self.models.clone(),
        }
    }

    /// This memory with the linear coupling map of `tails` ([`NeighbourTails::coupled`], made
    /// from these fits, moved by at most a common shift, with a frame's noise model), or
    /// without a map where `tails` has none. [`refit_dots_remembered`] then solves the parts
    /// of a gradient frame that did not move on the map instead of refitting their dots in
    /// every pass (see there).
    pub fn with_map(mut self, tails: &NeighbourTails) -> FitMemory {
        self.map = tails.coupling.clone();
        self
    }

    /// This memory with the linear coupling map of `prior` (the fits it remembers, or those
    /// moved by a common shift) made for `img` (an image of the scene, for which pixels a fit
    /// may use) with the noise model of a frame: [`NeighbourTails::coupled`]'s map without its
    /// tails (see [`FitMemory::with_map`]). Without neighbour subtraction or least squares, or
    /// for `prior` of another length than `seeds`, the memory is returned without a map.
    pub fn linearised(
        self,
        prior: &[DotFit],
        seeds: &[Seed],
        cfg: &FitConfig,
        img: &Image,
        mask: Option<&Mask>,
        noise: &NoiseModel,
    ) -> FitMemory {
        let mut m = self;
        m.map = None;
        if prior.len() == seeds.len()
            && cfg.neighbours == Neighbours::Subtract
            && cfg.estimator == Estimator::Lsg
        {
            let hood = Neighbourhood::with_known(prior, seeds, cfg.sampling, m.models.as_ref());
            m.map = Some(std::sync::Arc::new(coupling_map(
                &hood, prior, cfg, img, mask, noise,
            )));
        }
        m
    }

    /// Whether the memory holds a linear coupling map.
    pub fn has_map(&self) -> bool {
        self.map.is_some()
    }
}

/// [`fit_dots_report`], with the [`FitMemory`] that lets [`refit_dots_remembered`] fit another
/// image of the same dots from these fits (a gradient frame from the reference) by one
/// Gauss-Newton step per dot where its dot is the same up to noise.
pub fn fit_dots_remembered(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
) -> Result<(Vec<DotFit>, PassReport, FitMemory), FitError> {
    fit_dots_inner(img, mask, seeds, cfg, noise, true)
}

/// [`refit_dots_report`] with the [`FitMemory`] of the fits `prior` was made from (in the same
/// seed order; ignored when of another length). Its first pass takes, for each dot whose prior
/// fit is remembered, one Gauss-Newton step from the prior with that fit's Fisher matrix where
/// the step is within 2 standard deviations of the position (the dot is the same up to noise:
/// outside a flow region), and fits the others; then the neighbour iteration as before.
/// With a coupled [`NeighbourTails`] the map's Fisher matrices are used instead.
#[allow(clippy::too_many_arguments)]
pub fn refit_dots_remembered(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
    prior: &[DotFit],
    tails: Option<&NeighbourTails>,
    memory: Option<&FitMemory>,
) -> Result<(Vec<DotFit>, PassReport), FitError> {
    cfg.validate()?;
    if prior.len() != seeds.len() {
        return Err(FitError::InvalidConfig(format!(
            "refit_dots: {} prior fits for {} seeds",
            prior.len(),
            seeds.len()
        )));
    }
    check_mask(img, mask)?;
    if cfg.neighbours == Neighbours::Subtract && cfg.estimator == Estimator::Lsg {
        // a site the detector found no dot at in this image is looked for, as in `fit_dots`,
        // not fitted from its prior (nor subtracted from its neighbours as one)
        let prior: Vec<DotFit> = prior
            .iter()
            .zip(seeds)
            .map(|(p, s)| {
                if s.flags.contains(DotFlags::MISSING) {
                    let mut p = *p;
                    p.status = FitStatus::NotFitted;
                    p
                } else {
                    *p
                }
            })
            .collect();
        let prior = &prior[..];
        let mut canvas_buf = Vec::new();
        let mut it = Iteration::new(img, mask, seeds, cfg, noise);
        it.fixed_shape = median_shape(prior);
        // with a linear coupling map: the neighbours of every window (tails or not) as the map
        // is linearised at
        let coupling = tails
            .and_then(|t| t.coupling.as_deref())
            .filter(|c| c.fits.len() == seeds.len() && cfg.neighbour_passes > 1);
        // a gradient frame with the reference's map: the dots that did not move are solved on
        // it after the first pass (see `Iteration::converge`)
        let frame_map = memory.and_then(|m| m.map.as_deref()).filter(|c| {
            cfg.frame_map
                && coupling.is_none()
                && c.fits.len() == seeds.len()
                && cfg.neighbour_passes > 1
        });
        it.first_steps = match (coupling, memory) {
            (Some(c), _) => Some(c.looked.as_slice()),
            (None, Some(m)) => Some(m.looked.as_slice()),
            (None, None) => None,
        };
        it.links_from = memory
            .filter(|_| coupling.is_none())
            .and_then(|m| m.links.as_ref());
        let known = memory.and_then(|m| m.models.as_ref());
        let first_fits = coupling.map_or(prior, |c| &c.fits);
        let mut hood = Neighbourhood::with_known(first_fits, seeds, cfg.sampling, known);
        hood.set_ghosts(it.ghosts(prior, &hood));
        let first = it.pass(
            prior,
            PassKind {
                intermediate: false,
                // (the prior is a fit of another image: its weights are checked at the solution;
                // with a coupling map the prior is the same scene's fit, one bound away, whose
                // weights differ by far less than the check looks for)
                warm: coupling.is_some(),
                looked_at: coupling.is_none(),
            },
            tails,
            &hood,
            &mut canvas_buf,
        );
        if let Some(c) = coupling {
            // the rest of the iteration on the linear map: no pixel work
            let fits: Vec<DotFit> = first.iter().map(|i| i.fit).collect();
            // (as `Plausible::model` admits a fit, without building its model)
            let admitted: Vec<bool> = fits
                .iter()
                .map(|f| hood.gate.admits(f) && f.params.is_valid() && f.params.amplitude > 0.0)
                .collect();
            if let Some(solved) = c.solve(&fits, &admitted) {
                let mut items = first;
                for (it, p) in items.iter_mut().zip(solved.params) {
                    if let Some(p) = p {
                        it.fit.params = p;
                    }
                }
                let report = PassReport {
                    passes: 1,
                    refits: vec![fitted(seeds)],
                    converged: true,
                    unconverged: 0,
                    linear_sweeps: solved.sweeps,
                    linear_steps: items.iter().filter(|i| i.stepped).count(),
                };
                return Ok((finish(items, cfg), report));
            }
        }
        hood.update(&first, cfg.sampling);
        let first_steps = first.iter().filter(|i| i.stepped).count();
        let hybrid = frame_map.map(|map| Hybrid { map, prior });
        let (fits, mut report, _) = it.converge(
            first,
            vec![fitted(seeds)],
            hood,
            &mut canvas_buf,
            None,
            hybrid,
        );
        report.linear_steps += first_steps;
        return Ok((fits, report));
    }
    let items: Vec<Item> = seeds
        .par_iter()
        .zip(prior)
        .map_init(
            || Fitter::new(cfg),
            |f, (s, p)| {
                let hint = p.status.is_ok().then_some(&p.params);
                let fit = fit_seed(f, img, mask, s, hint, noise);
                Item::from_fitter(fit, f, false)
            },
        )
        .collect();
    Ok((finish(items, cfg), PassReport::none()))
}

/// Fewer converged fits than this: no median shape to hold a singular fit's shape at.
const MIN_SHAPE_FITS: usize = 10;

/// The median σx, σy and ρ of the converged fits not at a bound (`None` with fewer than
/// [`MIN_SHAPE_FITS`]).
fn median_shape(fits: &[DotFit]) -> Option<[f64; 3]> {
    let good: Vec<&Gaussian2D> = fits
        .iter()
        .filter(|f| shapes_the_median(f))
        .map(|f| &f.params)
        .collect();
    if good.len() < MIN_SHAPE_FITS {
        return None;
    }
    let median = |get: fn(&Gaussian2D) -> f64| {
        bostrack_core::median(&mut good.iter().map(|g| get(g)).collect::<Vec<f64>>())
    };
    // (the three side by side)
    let ((sx, sy), rho) = rayon::join(
        || rayon::join(|| median(|g| g.sigma_x), || median(|g| g.sigma_y)),
        || held_rho(&mut good.iter().map(|g| g.rho).collect::<Vec<f64>>()),
    );
    Some([sx, sy, rho])
}

/// The held shape's ρ from the fits' values: their median, or 0 where that is within two of
/// its standard errors (1.2533 σ/√n, σ from the median absolute deviation) of 0: a lattice
/// whose dots show no correlation is held at none, and the held fits of narrow dots take the
/// separable closed-form model instead of the quadrature (issue 17: at σ 0.3 px the median
/// was −0.014 ± 0.012 and the held fits cost 6 % of the scene's instructions more).
fn held_rho(values: &mut [f64]) -> f64 {
    let m = bostrack_core::median(values);
    let mut dev: Vec<f64> = values.iter().map(|v| (v - m).abs()).collect();
    let sd = 1.4826 * bostrack_core::median(&mut dev);
    let se = 1.2533 * sd / (values.len() as f64).sqrt();
    if m.abs() <= 2.0 * se { 0.0 } else { m }
}

/// Whether a fit's shape enters [`median_shape`].
fn shapes_the_median(f: &DotFit) -> bool {
    f.status == FitStatus::Converged
        && !f
            .flags
            .intersects(DotFlags::AT_BOUND | DotFlags::SHAPE_FIXED)
        && f.params.is_valid()
}

/// [`median_shape`] of pass 1's records (`fits`: their fits), whose narrow dots were fitted with
/// ρ held at 0 (`Fitter::solve_integrated`): ρ's median then over the fits that fitted it, or
/// where fewer than [`MIN_SHAPE_FITS`] did, over the held fits' one-step estimates (one
/// Gauss-Newton step of the full model from their solution at ρ = 0). (Issue 17: on a σ 0.3 ×
/// 0.45 px, ρ 0.5 lattice the held fits had ρ 0 where every dot is narrow; the window moments'
/// median ρ was 0.35 once pass 1 started narrow dots from their 3 × 3 block.)
fn median_shape_first(first: &[Item], fits: &[DotFit]) -> Option<[f64; 3]> {
    let mut shape = median_shape(fits)?;
    let good = |i: &&Item| shapes_the_median(&i.fit);
    let fitted: Vec<f64> = first
        .iter()
        .filter(good)
        .filter(|i| i.rho_held.is_none())
        .map(|i| i.fit.params.rho)
        .collect();
    let mut rho: Vec<f64> = if fitted.len() >= MIN_SHAPE_FITS {
        fitted
    } else {
        first
            .iter()
            .filter(good)
            .filter_map(|i| i.rho_held.filter(|r| r.is_finite()))
            .collect()
    };
    if rho.len() >= MIN_SHAPE_FITS {
        shape[2] = held_rho(&mut rho);
    }
    Some(shape)
}

/// How many seeds are fitted (not flagged missing).
fn fitted(seeds: &[Seed]) -> usize {
    seeds
        .iter()
        .filter(|s| !s.flags.contains(DotFlags::MISSING))
        .count()
}

/// A dot's record in the iteration, with what its last fit left beside it.
#[derive(Clone, Debug)]
struct Item {
    fit: DotFit,
    /// Window χ² and its degrees of freedom (NaN / 0: not a least-squares fit).
    chi2: f64,
    dof: usize,
    /// How far the dot moved in its last refit (standard deviations; 0: not refitted).
    moved: f64,
    /// What later looks need of the last fit (point-model fits in an iteration's passes).
    looked: Option<Kept>,
    /// The last update was one Gauss-Newton step from the fit before ([`linear_step`]), not a
    /// fit.
    stepped: bool,
    /// A fit with ρ held at 0 (`LastFit::rho_held`).
    rho_held: Option<f64>,
}

impl Item {
    /// `looked_at`: keep the Fisher matrix for later looks.
    fn from_fitter(fit: DotFit, f: &Fitter, looked_at: bool) -> Item {
        let lsg = f.config().estimator == Estimator::Lsg && fit.status != FitStatus::NotFitted;
        Item {
            fit,
            chi2: if lsg { f.last.chi2 } else { f64::NAN },
            dof: if lsg { f.last.dof } else { 0 },
            moved: if lsg { f.last.moved } else { f64::INFINITY },
            rho_held: f.last.rho_held.filter(|_| lsg),
            looked: if lsg && looked_at {
                let n = crate::eval::Kind::from_model(f.config().model).n_free();
                f.last
                    .point_fisher
                    .and_then(|m| {
                        let ws = &f.ws;
                        Looked::new(&m, n, Window::new(ws.wx, ws.wy, ws.w, ws.h))
                    })
                    .map(|l| Kept::Own(std::sync::Arc::new(l)))
            } else {
                None
            },
            stepped: false,
        }
    }

    /// A record kept as it is (not fitted in this pass).
    fn kept(fit: DotFit) -> Item {
        Item {
            fit,
            chi2: f64::NAN,
            dof: 0,
            moved: 0.0,
            looked: None,
            stepped: false,
            rho_held: None,
        }
    }
}

/// What a record keeps for later looks: the matrices of its own last fit, or (a dot stepped
/// from its prior in a first pass) those its step took, the prior's, by the dot's index in the
/// iteration's first steps (`Iteration::first_steps`): a pointer's worth per dot instead of a
/// ~0.5 kB copy and an allocation each.
#[derive(Clone, Debug)]
enum Kept {
    Own(std::sync::Arc<Looked>),
    Prior(u32),
}

impl Kept {
    /// The matrices; `steps`: the iteration's first steps.
    fn resolve<'b>(&'b self, steps: Option<&'b [Option<Looked>]>) -> Option<&'b Looked> {
        match self {
            Kept::Own(l) => Some(l),
            Kept::Prior(i) => steps?.get(*i as usize)?.as_ref(),
        }
    }
}

/// What a later look at a dot needs of its last fit (point-model fits only, see
/// `LastFit::point_fisher`): the factor of the Fisher matrix of its free parameters and the
/// position block of its inverse, computed once per fit instead of once per look.
#[derive(Clone, Debug)]
pub(crate) struct Looked {
    factor: crate::solver::Factor,
    /// `(F⁻¹)₀₀, (F⁻¹)₀₁, (F⁻¹)₁₁`: the covariance of the position.
    position: [f64; 3],
    /// The window of the fit.
    window: Window,
}

impl Looked {
    pub(crate) fn new(fisher: &[[f64; 7]; 7], n: usize, window: Window) -> Option<Looked> {
        let factor = crate::solver::Factor::new(fisher, n, 0.0)?;
        let mut e = [0.0; 7];
        e[0] = 1.0;
        let cx = factor.solve(&e);
        e = [0.0; 7];
        e[1] = 1.0;
        let cy = factor.solve(&e);
        let position = [cx[0], 0.5 * (cx[1] + cy[0]), cy[1]];
        let det = position[0] * position[2] - position[1] * position[1];
        (det > 0.0 && det.is_finite()).then_some(Looked {
            factor,
            position,
            window,
        })
    }

    /// `dᵀ F d`.
    fn quad_form(&self, d: &[f64; 7]) -> f64 {
        self.factor.quad_form(d)
    }

    /// The same with the Fisher matrix times `f > 0`.
    fn scaled(&self, f: f64) -> Looked {
        Looked {
            factor: self.factor.scaled(f),
            position: self.position.map(|v| v / f),
            window: self.window,
        }
    }
}

/// A look at a dot whose neighbours changed ([`look`]).
struct Look {
    /// How far its position would move if refitted (standard deviations).
    moves: f64,
    /// The fit's point-model parameters (pixel-blurred for `auto`).
    theta: crate::eval::Theta,
    /// The Gauss-Newton step from them (free parameters), `vᵀδ` (what it lowers χ² by), and
    /// `Σ w r²`, `Σ r²` before it.
    step: [f64; 7],
    decrease: f64,
    chi2: f64,
    ssr: f64,
}

/// The parameters a [`look`] at `fit` evaluates the dot at (its point-model θ, pixel-blurred
/// for `auto`), `None` where a look cannot predict the refit (a fit at a bound, held in shape
/// or not converged, not in the point model's range, another window than `looked`'s).
fn look_theta(
    ws: &crate::eval::Workspace,
    fit: &DotFit,
    looked: &Looked,
    sampling: FitSampling,
    model: Option<&NeighbourModel>,
) -> Option<crate::eval::Theta> {
    if fit.status != FitStatus::Converged
        || fit
            .flags
            .intersects(DotFlags::AT_BOUND | DotFlags::SHAPE_FIXED)
        || Window::new(ws.wx, ws.wy, ws.w, ws.h) != looked.window
        || sampling == FitSampling::Integrated
    {
        return None;
    }
    // the dot's neighbour model, made of these very parameters with the same sampling, holds
    // the θ computed below where it is a point model (`NeighbourModel::new`: the pixel-blurred θ
    // exactly where the conditional σ allows the point model, as here; the θ itself with point
    // sampling): taken from there, without its ~10 calls of libm
    if let Some(m) = model
        && m.sampling == Sampling::Point
        && m.made_of(&fit.params)
    {
        return Some(m.theta);
    }
    if sampling != FitSampling::Auto {
        return Some(theta_from_gaussian(&fit.params));
    }
    let (cs, b) = crate::eval::blurred_of(&fit.params);
    (cs >= AUTO_SIGMA).then_some(b)
}

/// Adds `amp` times the rendering in `ws.tmp` (over the window) back to the data over the
/// pixels of `b` (where a [`Canvas`] holds the dot): what [`Canvas::add_back`] adds, from the
/// window's rendering instead of one of its own.
fn add_inside(ws: &mut crate::eval::Workspace, b: PixelBox, amp: f64) {
    let (wx, wy) = (ws.wx, ws.wy);
    let clip = |lo: usize, hi: usize, w0: i64, n: usize| {
        let a = (lo as i64 - w0).max(0);
        let z = (hi as i64 - w0).min(n as i64 - 1);
        (a <= z).then_some((a as usize, z as usize))
    };
    let (Some((i0, i1)), Some((j0, j1))) = (
        clip(b.x_lo, b.x_hi, wx, ws.w),
        clip(b.y_lo, b.y_hi, wy, ws.h),
    ) else {
        return;
    };
    for j in j0..=j1 {
        for k in j * ws.w + i0..=j * ws.w + i1 {
            ws.data[k] += ws.keep[k] * amp * ws.tmp[k];
        }
    }
}

/// How far (in standard deviations of its position: the Mahalanobis length of the position
/// part) the dot at `tb` (its fit's parameters from [`look_theta`], which also says where no
/// look is possible) would move if refitted to the window's data as loaded in `ws` (its
/// neighbours' current models subtracted): one Gauss-Newton step `F⁻¹ Σ w ∇μ r` from it, with
/// the Fisher matrix of `looked` (its fit's, or the map's at the reference's fit). At the last
/// fit's data the step is below the fit's tolerance (`[fit] tolerance`, 0.05 standard
/// deviations, or of second order after its last step), so what it measures is how far the
/// neighbours' changes since then pull the dot. `own_back`: the dot's pixel box on a canvas
/// whose subtraction left the dot's own model out of the window; added back from this
/// rendering. `None` where the step is not finite.
fn look(
    ws: &mut crate::eval::Workspace,
    tb: crate::eval::Theta,
    looked: &Looked,
    kind: crate::eval::Kind,
    noise: &NoiseModel,
    own_back: Option<PixelBox>,
) -> Option<Look> {
    use crate::eval::{IB, IX, IY};
    crate::eval::dot_factor(ws, &tb, Sampling::Point);
    let (amp, bg) = (tb[IA], tb[IB]);
    if let Some(b) = own_back {
        add_inside(ws, b, amp);
    }
    // Σ w r·basis (basis = E·{1, X, Y, X², XY, Y²}, 1), Σ w r² and Σ r², r = data − μ
    let n = ws.w * ws.h;
    let inp = crate::simd::LookIn {
        e: &ws.tmp[..n],
        d: &ws.data[..n],
        keep: &ws.keep[..n],
        w: ws.w,
        h: ws.h,
        amp,
        bg,
        x_first: ws.wx as f64 - tb[IX],
        y_first: ws.wy as f64 - tb[IY],
        read: noise.read_variance,
        gain: noise.gain,
        offset: noise.offset,
    };
    let crate::simd::LookSums { g, chi2, ssr } =
        crate::simd::column_sums(crate::simd::arch(), &inp, &mut ws.cols);
    let c = kind.coefficients(&tb, &crate::eval::Shape::of(&tb));
    let nf = kind.n_free();
    let mut v = [0.0; 7];
    for k in 0..nf {
        v[k] = (0..7).map(|b| c[k][b] * g[b]).sum();
    }
    let step = looked.factor.solve(&v);
    // the position part of the step, in its own (marginal) standard deviations
    let [a, b, c] = looked.position;
    let (dx, dy) = (step[0], step[1]);
    let m2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / (a * c - b * b);
    m2.is_finite().then(|| Look {
        moves: m2.max(0.0).sqrt(),
        theta: tb,
        step,
        decrease: (0..nf).map(|k| v[k] * step[k]).sum(),
        chi2,
        ssr,
    })
}

/// Predicted moves up to this many standard deviations of the position are made by one
/// Gauss-Newton step ([`linear_step`]) instead of a refit. The fit is linear over such a step:
/// a bound is ~1 % of σ on the real sample, so the step's second-order error is below 1e-3 of
/// the bound (on the real gradient frame 98.5 % of the refits moved less than 1 bound).
const LINEAR_STEP_MAX: f64 = 2.0;

/// The most a Gauss-Newton step may change a dot's position and shape (Mahalanobis length of
/// that part, standard deviations) to be taken: for noise alone that length exceeds 5 with a
/// probability of 0.2 % (χ with 5 degrees of freedom); a dot whose shape changed (the flow's
/// blur against a reference prior) goes beyond and is fitted.
const LINEAR_MOVE_MAX: f64 = 5.0;

/// The dot `fit` updated by the Gauss-Newton step of the [`look`] `l` at it (with `looked`):
/// what a refit would return to second order in the step, without another pass over the window.
/// Its χ² and rms are those of the linearised model at the new parameters (as the solver's last
/// step records them); `keep`: what the record keeps for later looks. `None` where a refit is
/// needed: a step that would leave the bounds or the point model's range.
fn linear_step(
    ws: &crate::eval::Workspace,
    fit: &DotFit,
    looked: &Looked,
    keep: Option<Kept>,
    l: &Look,
    kind: crate::eval::Kind,
    sampling: FitSampling,
) -> Option<Item> {
    use crate::eval::IB;
    let (next, bounds, params) = stepped(ws, l, kind, sampling)?;
    // (the unblurred dot's conditional σ, as `conditional_sigma` of its θ)
    let point = sampling != FitSampling::Auto
        || params.sigma_x.min(params.sigma_y) * (1.0 - params.rho * params.rho).max(0.0).sqrt()
            >= AUTO_SIGMA;
    if bounds.at_bound(&next) || !point || !params.is_valid() {
        return None;
    }
    // Σ w (r − Jδ)² = χ² − vᵀδ at the Gauss-Newton step (the unweighted sum scaled alike)
    let after = (l.chi2 - l.decrease).max(0.0);
    let ssr = if l.chi2 > 0.0 {
        l.ssr * after / l.chi2
    } else {
        l.ssr
    };
    // `d`: the dot as its neighbours see it, without its background (as `LastFit::moved`);
    // `shape`: its position and shape alone. A step that changes those by more than
    // LINEAR_MOVE_MAX (a dot blurred by the flow against its prior) is not linear enough:
    // fitted (the amplitude and the background enter the model linearly)
    let (mut d, mut shape) = (l.step, l.step);
    for (k, &p) in kind.free().iter().enumerate() {
        if p == IB {
            d[k] = 0.0;
        }
        if p == IB || p == IA {
            shape[k] = 0.0;
        }
    }
    if looked.quad_form(&shape).max(0.0).sqrt() > LINEAR_MOVE_MAX {
        return None;
    }
    let moved = looked.quad_form(&d).max(0.0).sqrt();
    let mut fit = *fit;
    fit.params = params;
    if ws.n_used > 0 {
        fit.rms = (ssr / ws.n_used as f64).sqrt();
    }
    Some(Item {
        fit,
        chi2: after,
        dof: ws.n_used.saturating_sub(kind.n_free()),
        moved,
        looked: keep,
        stepped: true,
        rho_held: None,
    })
}

/// Where the Gauss-Newton step of the look `l` leads: the point-model θ, the window's bounds
/// (which it lies inside) and the dot's parameters (unblurred for `auto`); `None` outside the
/// bounds or where no dot unblurs.
fn stepped(
    ws: &crate::eval::Workspace,
    l: &Look,
    kind: crate::eval::Kind,
    sampling: FitSampling,
) -> Option<(crate::eval::Theta, crate::solver::Bounds, Gaussian2D)> {
    let next = kind.apply_step(&l.theta, &l.step);
    let bounds = crate::solver::Bounds::for_window(ws.wx, ws.wy, ws.w, ws.h);
    if !bounds.inside(&next) {
        return None;
    }
    let params = if sampling == FitSampling::Auto {
        crate::eval::unblurred_params(&next)?
    } else {
        crate::eval::gaussian_from_theta(&next)
    };
    Some((next, bounds, params))
}

/// Where the Gauss-Newton step of the look `l` leads ([`stepped`]), as the start of a full fit;
/// `None` where it leaves the window's bounds or gives no valid dot (the prior is the start
/// then).
fn step_start(
    ws: &crate::eval::Workspace,
    l: &Look,
    kind: crate::eval::Kind,
    sampling: FitSampling,
) -> Option<Gaussian2D> {
    let (_, _, g) = stepped(ws, l, kind, sampling)?;
    (g.is_valid() && g.amplitude > 0.0).then_some(g)
}

/// The pull of a neighbour that moved by `moved` standard deviations and has `share` of its
/// squared profile in the window (infinite for a neighbour that was fitted anew, as a dot that
/// failed and recovered is, when it reaches the window at all).
fn pull_of(moved: f64, share: f64) -> f64 {
    if moved.is_finite() {
        moved * share.sqrt()
    } else if share > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

/// Which pass [`Iteration::pass`] is: `intermediate` (loose tolerance, no weights check: the
/// fits are refitted later), `warm` (the start is a least-squares fit of the same dot, the
/// weights at the start are right: no check).
#[derive(Clone, Copy)]
struct PassKind {
    intermediate: bool,
    warm: bool,
    /// Later passes look at these records (`predicted_move`): each keeps the neighbours it saw
    /// and its Fisher matrix. Without (the first pass of a coupled stack image, which the linear
    /// map finishes) nothing per dot is kept beside the fit: on the real stack those buffers
    /// were 12 MB per image, allocated, freed and their pages cleared again for every image.
    looked_at: bool,
}

/// The seed's colour on the lattice's checkerboard (`(i + j)` even) for the red-black passes:
/// a dot's four nearest neighbours have the other colour.
fn is_red(s: &Seed) -> bool {
    (s.index.i + s.index.j).rem_euclid(2) == 0
}

/// Fewer dots than this fraction of all refitted in a pass: their neighbours are rendered into
/// each window instead of the whole image into a canvas.
const CANVAS_FRACTION: f64 = 0.25;

/// Refits that did not move a dot less than the one before, after which it is frozen (not
/// refitted again; flagged `unconverged` if it or its neighbours' pull still moves).
const STRIKES: u8 = 3;

/// A dot still moving by more than this many times `neighbour_tolerance` when the passes stop
/// at their limit is flagged `UNCONVERGED`.
const UNCONVERGED_FACTOR: f64 = 5.0;

/// The block-Jacobi neighbour iteration over one image.
struct Iteration<'a> {
    img: &'a Image,
    mask: Option<&'a Mask>,
    seeds: &'a [Seed],
    cfg: &'a FitConfig,
    noise: &'a NoiseModel,
    /// Half the largest window side plus one (px): how far from a dot's centre the windows it
    /// may reach lie, beyond its own reach.
    half: i64,
    /// The shape at which a singular least-squares fit is fitted again with its shape held
    /// (`SHAPE_FIXED`): the median of the image's converged fits, from the second pass on.
    fixed_shape: Option<[f64; 3]>,
    /// For a first pass from prior fits: per dot, the Fisher matrix to take one Gauss-Newton
    /// step from its prior with instead of fitting it (the stack's coupling map, or the
    /// reference's own fits for a gradient frame: [`FitMemory`]).
    first_steps: Option<&'a [Option<Looked>]>,
    /// Whether [`Iteration::converge`] returns the fits' [`FitMemory`] (an empty one without).
    remember: bool,
    /// For an image of the same seeds as a remembered fit: that fit's [`Links`], which
    /// [`Iteration::converge`] starts from ([`Links::carried`]) instead of linking every dot.
    links_from: Option<&'a LinkMemory>,
}

impl<'a> Iteration<'a> {
    /// The matrices `kept` refers to.
    fn kept<'b>(&'b self, kept: Option<&'b Kept>) -> Option<&'b Looked> {
        kept?.resolve(self.first_steps)
    }

    fn new(
        img: &'a Image,
        mask: Option<&'a Mask>,
        seeds: &'a [Seed],
        cfg: &'a FitConfig,
        noise: &'a NoiseModel,
    ) -> Iteration<'a> {
        let half = seeds
            .iter()
            .map(|s| s.window.width.max(s.window.height))
            .max()
            .unwrap_or(0)
            / 2
            + 1;
        Iteration {
            img,
            mask,
            seeds,
            cfg,
            noise,
            half: half as i64,
            fixed_shape: None,
            first_steps: None,
            remember: false,
            links_from: None,
        }
    }

    /// The ghosts of the image (set into `hood` by the caller): every lattice site next to a
    /// fitted seed that holds no seed and whose centre lies outside the image, at the position
    /// extrapolated along the lattice from its neighbours' fits (the mean over the seeds next
    /// to it), modelled as a dot of the image's median shape with its amplitude and background
    /// fitted on the part of its window inside the image, the neighbours' models subtracted;
    /// kept where that amplitude is significant (a printed dot is there) and the gate admits
    /// it. Without them the windows along the image's edge hold light that no model accounts
    /// for (issue #13: the edge dots of a dense target failed the χ² test). None before the
    /// median shape is known.
    fn ghosts(&self, fits: &[DotFit], hood: &Neighbourhood) -> Vec<NeighbourModel> {
        let Some(shape) = self.fixed_shape.filter(|_| self.cfg.ghosts) else {
            return Vec::new();
        };
        let (w, h) = (self.img.width(), self.img.height());
        let sites = ghost_sites(self.seeds, fits, w, h);
        if sites.is_empty() {
            return Vec::new();
        }
        // (wider than a seed's window: a site a few px outside still shows its visible part)
        let half = (self.half + 2) as usize;
        let (img, mask, noise, cfg) = (self.img, self.mask, self.noise, self.cfg);
        // a ghost whose model could reach no seed's window is subtracted from none: not fitted
        // (its model's 5σ box, of the held shape, widened by a margin far above the rounding
        // of its fitted σ; at σ 0.3 px every ghost of bench/trackpy's scenes, 3 % of their
        // `locate`)
        let windows = Links::index(self.seeds);
        let seen = |at: [f64; 2], near: &mut Vec<usize>| {
            let (rx, ry) = (
                REACH_SIGMAS * shape[0] + GHOST_MARGIN,
                REACH_SIGMAS * shape[1] + GHOST_MARGIN,
            );
            if !(rx.is_finite() && ry.is_finite()) {
                return true;
            }
            let (x_lo, x_hi) = (floor_i64(at[0] - rx), floor_i64(at[0] + rx) + 1);
            let (y_lo, y_hi) = (floor_i64(at[1] - ry), floor_i64(at[1] + ry) + 1);
            let span = Window::new(
                x_lo,
                y_lo,
                (x_hi - x_lo + 1) as usize,
                (y_hi - y_lo + 1) as usize,
            );
            windows.near_unsorted(span, near);
            near.iter().any(|&k| {
                let w = self.seeds[k].window;
                w.x <= x_hi
                    && x_lo < w.x + w.width as i64
                    && w.y <= y_hi
                    && y_lo < w.y + w.height as i64
            })
        };
        sites
            .par_iter()
            .map_init(
                || (Fitter::new(cfg), Vec::new()),
                |(f, near), &(index, at)| {
                    if !seen(at, near) {
                        return None;
                    }
                    let reach = Window::centred(at[0].round(), at[1].round(), half);
                    let win = reach.clip(w, h)?;
                    f.load_image(img, mask, win);
                    hood.index.near_unsorted(win, near);
                    for &j in near.iter() {
                        let Some(m) = hood.models[j].as_ref() else {
                            continue;
                        };
                        if hood.is_ghost(j) || !m.reaches(win) {
                            continue;
                        }
                        let ws = &mut f.ws;
                        crate::eval::dot_factor(ws, &m.theta, m.sampling);
                        m.clip_to_box(ws);
                        let amp = m.theta[IA];
                        for k in 0..ws.len() {
                            ws.data[k] -= ws.keep[k] * amp * ws.tmp[k];
                        }
                    }
                    let params = f.fit_loaded_ghost(at, reach, noise, shape)?;
                    let fit = DotFit {
                        index,
                        params,
                        crlb_x: f64::NAN,
                        crlb_y: f64::NAN,
                        rms: f64::NAN,
                        iterations: 0,
                        status: FitStatus::Converged,
                        flags: DotFlags::NONE,
                    };
                    hood.gate.model(&fit, cfg.sampling)
                },
            )
            .collect::<Vec<Option<NeighbourModel>>>()
            .into_iter()
            .flatten()
            .collect()
    }

    /// Pass 2 of [`fit_dots`] in two halves: the dots of one colour of the lattice's
    /// checkerboard ((i + j) mod 2 = 0, `true` in the returned colours), then the others with
    /// the first half's new fits subtracted (`hood` updated to them), so that a dot's four
    /// nearest neighbours enter its fit already refitted (a Gauss-Seidel sweep in two parallel
    /// halves; on the real gradient frame 28 % fewer refits in the passes after it).
    /// `first`: the records of pass 1, whose fits are `fits`.
    fn pass_red_black(
        &self,
        first: &[Item],
        fits: &[DotFit],
        hood: &mut Neighbourhood,
        canvas_buf: &mut Vec<f64>,
    ) -> (Vec<Item>, Vec<bool>) {
        let kind = PassKind {
            intermediate: false,
            warm: false,
            looked_at: true,
        };
        let colour: Vec<bool> = self.seeds.iter().map(is_red).collect();
        let other: Vec<bool> = colour.iter().map(|c| !c).collect();
        let red = self.pass_with(
            fits,
            Some(&colour),
            kind,
            None,
            canvas_buf,
            false,
            hood,
            None,
        );
        let mut after = fits.to_vec();
        hood.apply(&red, |r| &r.fit, &mut after, self.cfg.sampling);
        let black = self.pass_with(
            &after,
            Some(&other),
            kind,
            None,
            canvas_buf,
            false,
            hood,
            None,
        );
        let items = red
            .into_iter()
            .zip(black)
            .zip(first)
            .map(|((r, b), f)| r.or(b).map_or_else(|| Item::kept(f.fit), |it| *it))
            .collect();
        (items, colour)
    }

    /// Passes from `passes + 1` on (`items`: the result of pass `passes`), each refitting only
    /// the dots whose neighbours moved by enough, until none is left or the pass limit; then the
    /// flags (`UNCONVERGED`, `RESIDUAL`).
    /// `halves`: the last pass refitted the dots marked `true` first and then the others with
    /// those new fits subtracted (red-black), so the others already saw the first half's moves.
    /// `hybrid`: a gradient frame's first pass with the reference's linear coupling map: the
    /// dots that did not move, and whose neighbours did not either, are solved on the map
    /// instead of being refitted (see [`Hybrid`]); the passes refit the others.
    fn converge(
        &self,
        mut items: Vec<Item>,
        mut refits: Vec<usize>,
        mut hood: Neighbourhood,
        canvas_buf: &mut Vec<f64>,
        mut halves: Option<Vec<bool>>,
        hybrid: Option<Hybrid>,
    ) -> (Vec<DotFit>, PassReport, FitMemory) {
        let tol = self.cfg.neighbour_tolerance;
        // dots whose refit moved them no less than the one before, for the third time (not
        // contracting: an oscillation or a cycle of failing and recovering fits), are not
        // refitted again
        let mut strikes = vec![0u8; items.len()];
        // each dot's move in its last refit (a dot looked at but not refitted keeps it)
        let mut last_move: Vec<f64> = items.iter().map(|it| it.moved).collect();
        let mut owed = vec![0.0f64; items.len()];
        let mut linear_steps = 0;
        // the fits (`hood`: their neighbour models, updated for the dots each pass refits)
        let mut fits: Vec<DotFit> = items.iter().map(|i| i.fit).collect();
        let mut near = Vec::new();
        // each seed's colour on the lattice's checkerboard ([`is_red`]), read every pass
        let red: Vec<bool> = self.seeds.iter().map(is_red).collect();
        // the records whose `moved` may be non-zero (all, until a pass's update below): the
        // passes then touch only those and the refitted records, not every record
        let mut movers: Vec<usize> = (0..items.len()).collect();
        let mut links = match self.links_from {
            Some(m) if m.fits(self.seeds) => Links::carried(m, self.seeds, &hood, &mut near),
            _ => Links::new(self.seeds, &hood),
        };
        // (only where the passes would refit much of the image: on a target whose dots barely
        // overlap they have little to do, and the map's set-up would cost more than it saves)
        let hybrid = hybrid.filter(|_| {
            let pulls = self.neighbour_pull(&items, &links, None, None, &movers);
            let owing = pulls.iter().filter(|&&p| p > tol).count();
            owing as f64 >= CANVAS_FRACTION * self.seeds.len() as f64
        });
        let mut hybrid = hybrid.and_then(|h| self.linear_part(h, &items, &hood, &links));
        if let Some(h) = hybrid.as_mut() {
            self.take_linear(
                h, &mut items, &mut fits, &mut hood, &mut links, &mut near, true,
            );
        }
        loop {
            let passes = refits.len() as u32;
            // the pull owed since each dot was last fitted or checked (small pulls add up)
            // (the map answers for the linear dots: their pulls are not computed, 0)
            let skip = hybrid.as_ref().map(|h| h.state.live.as_slice());
            let now = match halves.take() {
                None => self.neighbour_pull(&items, &links, None, skip, &movers),
                Some(first) => {
                    let second: Vec<bool> = first.iter().map(|f| !f).collect();
                    let of_first = self.neighbour_pull(&items, &links, Some(&first), skip, &movers);
                    let of_second =
                        self.neighbour_pull(&items, &links, Some(&second), skip, &movers);
                    of_first
                        .iter()
                        .zip(&of_second)
                        .zip(&first)
                        .map(|((a, b), &f)| if f { a + b } else { *b })
                        .collect()
                }
            };
            for (o, p) in owed.iter_mut().zip(&now) {
                *o += p;
            }
            if let Some(h) = &hybrid {
                // (the map answers for the linear dots)
                for (o, &l) in owed.iter_mut().zip(&h.state.live) {
                    if l {
                        *o = 0.0;
                    }
                }
            }
            let mut select: Vec<bool> = owed
                .iter()
                .zip(&strikes)
                .map(|(&p, &k)| p > tol && k < STRIKES)
                .collect();
            let mut count = select.iter().filter(|&&s| s).count();
            if count > 0 {
                // red-black ordering: each pass refits the dots of one colour of the lattice's
                // checkerboard ((i + j) mod 2, alternating), so that a dot's four nearest
                // neighbours enter its refit already refitted (a Gauss-Seidel sweep in two
                // parallel halves: 26 % fewer refits than Jacobi on the real gradient frame);
                // the other colour where this one has nothing left to do
                let mine: Vec<bool> = select
                    .iter()
                    .zip(&red)
                    .map(|(&x, &r)| x && r == passes.is_multiple_of(2))
                    .collect();
                let n_mine = mine.iter().filter(|&&s| s).count();
                if n_mine > 0 {
                    select = mine;
                    count = n_mine;
                }
            }
            if count == 0
                && let Some(h) = hybrid.as_mut()
                && h.rounds < HYBRID_ROUNDS
            {
                // the pixel dots settled: the linear dots again, with the pixel dots' fits now
                h.rounds += 1;
                for (i, f) in fits.iter().enumerate() {
                    if h.since[i] && hood.gate.admits(f) {
                        h.held[i] = *f;
                    }
                }
                let again = h.map.frame_again(&mut h.state, &h.held, &h.since);
                h.since.iter_mut().for_each(|s| *s = false);
                if again.is_some() {
                    let moved = self.take_linear(
                        h, &mut items, &mut fits, &mut hood, &mut links, &mut near, false,
                    );
                    movers = (0..items.len())
                        .filter(|&i| items[i].moved != 0.0)
                        .collect();
                    if moved > tol {
                        continue;
                    }
                } else {
                    // (sweeps that did not settle: the linear dots keep the last solution)
                    h.rounds = HYBRID_ROUNDS;
                }
            }
            if count == 0 || passes >= self.cfg.neighbour_passes {
                let mut unconverged = 0;
                let limit = UNCONVERGED_FACTOR * tol;
                for (((it, &p), &k), &pn) in items.iter_mut().zip(&owed).zip(&strikes).zip(&now) {
                    let f = k >= STRIKES;
                    // stopped at the limit, or frozen: dots that (or whose neighbours) still moved
                    let own = it.moved.is_finite() && it.moved > limit;
                    let moving = if f { pn > tol || own } else { p > limit || own };
                    if it.fit.status.is_ok() && moving && (count > 0 || f) {
                        it.fit.flags |= DotFlags::UNCONVERGED;
                        unconverged += 1;
                    }
                }
                let report = PassReport {
                    passes,
                    refits,
                    converged: count == 0 && unconverged == 0,
                    unconverged,
                    linear_sweeps: hybrid.as_ref().map_or(0, |h| h.state.sweeps),
                    linear_steps,
                };
                let mut memory = FitMemory::of(&items, self.remember, self.first_steps);
                if self.remember {
                    memory.links = Some(links.memory(self.seeds));
                    memory.models = Some((
                        self.cfg.sampling,
                        std::sync::Arc::new(hood.models[..self.seeds.len()].to_vec()),
                    ));
                }
                return (self.finish(items, &hood, &links), report, memory);
            }
            let windowed = (count as f64) < CANVAS_FRACTION * self.seeds.len() as f64;
            let next = self.pass_with(
                &fits,
                Some(&select),
                PassKind {
                    intermediate: false,
                    warm: true,
                    looked_at: true,
                },
                None,
                canvas_buf,
                windowed,
                &hood,
                Some(&items),
            );
            hood.apply(&next, |r| &r.fit, &mut fits, self.cfg.sampling);
            let changed = next.iter().enumerate().filter(|(_, n)| n.is_some());
            links.relink(self.seeds, &hood, changed.map(|(j, _)| j), &mut near, None);
            if let Some(h) = hybrid.as_mut() {
                for (s, n) in h.since.iter_mut().zip(&next) {
                    if n.is_some() {
                        *s = true;
                    }
                }
            }
            // the records of this pass: the selected ones owe nothing now; a refitted one takes
            // its new record (a move no smaller than its last, from pass 4 on, is a strike);
            // the others did not move (only the last movers can hold a move to clear)
            // (passes 1-3 start from the moments and loose fits)
            for (i, &sel) in select.iter().enumerate() {
                if sel {
                    owed[i] = 0.0;
                }
            }
            for &i in &movers {
                if next[i].is_none() {
                    items[i].moved = 0.0;
                }
            }
            movers.clear();
            let (mut steps, mut refitted) = (0, 0);
            for (i, n) in next.into_iter().enumerate() {
                let Some(n) = n else { continue };
                if passes >= 3 && n.moved > tol && n.moved >= last_move[i] {
                    strikes[i] += 1;
                }
                last_move[i] = n.moved;
                items[i] = *n;
                steps += usize::from(items[i].stepped);
                refitted += 1;
                movers.push(i);
            }
            linear_steps += steps;
            refits.push(refitted);
        }
    }

    /// The linear part of a gradient frame ([`Hybrid`]) from its first pass (`items`, whose
    /// neighbour models and links are `hood` and `links`), solved on the map; `None` where no
    /// dot is linear or the map does not settle (then every dot is refitted by the passes).
    fn linear_part<'m>(
        &self,
        start: Hybrid<'m>,
        items: &[Item],
        hood: &Neighbourhood,
        links: &Links,
    ) -> Option<Running<'m>> {
        let Hybrid { map, prior } = start;
        let n = self.seeds.len();
        let (w, h) = (self.img.width(), self.img.height());
        let first: Vec<DotFit> = items.iter().map(|i| i.fit).collect();
        // the frame's common shift from the base: the median move of the coupled dots
        let shift = crate::coupling::median2(
            (0..n)
                .filter(|&i| map.window(i).is_some() && first[i].status.is_ok())
                .map(|i| {
                    let (f, b) = (&first[i].params, &map.fits[i].params);
                    [f.x0 - b.x0, f.y0 - b.y0]
                }),
        )?;
        let usable = |f: &DotFit| {
            f.status.is_ok()
                && !f
                    .flags
                    .intersects(DotFlags::AT_BOUND | DotFlags::SHAPE_FIXED)
                && f.params.is_valid()
                && f.params.amplitude > 0.0
                && hood.gate.admits(f)
        };
        // near: fitted over the map's window, it and its prior within the map's linear reach
        let near: Vec<bool> = (0..n)
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                let f = &first[i];
                usable(f)
                    && prior[i].status.is_ok()
                    && map.window(i).is_some()
                    && map.window(i) == self.seeds[i].window.clip(w, h)
                    && map.near(i, &f.params, shift)
                    && map.near(i, &prior[i].params, shift)
            })
            .collect();
        // linear: near, with every neighbour (touching, or linked by the map) near too
        let linear: Vec<bool> = (0..n)
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                near[i]
                    && links.row(i).iter().all(|&(j, _)| near[j as usize])
                    && map.neighbours(i).iter().all(|&j| near[j as usize])
            })
            .collect();
        if !linear.iter().any(|&l| l) {
            return None;
        }
        // the other dots held at their current models (a fit the gate refused: its prior's)
        let held: Vec<DotFit> = (0..n)
            .map(|i| {
                if usable(&first[i]) {
                    first[i]
                } else {
                    prior[i]
                }
            })
            .collect();
        // (a fit's map parameters from its neighbour model where that was made of it: the same
        // θ, without its libm calls)
        let rep_of = |i: usize, g: &Gaussian2D, blurred: bool| {
            hood.models[i]
                .as_ref()
                .and_then(|m| m.map_rep(g, self.cfg.sampling, blurred))
                .unwrap_or_else(|| crate::coupling::rep(g, blurred))
        };
        let state = map.frame_start(&first, prior, linear, &held, rep_of)?;
        Some(Running {
            map,
            state,
            held,
            since: vec![false; n],
            rounds: 0,
        })
    }

    /// Writes the linear dots' solution, where it changed since last written, into `items`,
    /// `fits`, `hood` and `links`; the largest move it made (standard deviations). `first`:
    /// the first time (each linear dot's move then adds its first pass's, which its neighbours
    /// have not seen yet; otherwise the other dots' moves are set to 0: their pulls were
    /// counted).
    #[allow(clippy::too_many_arguments)]
    fn take_linear(
        &self,
        h: &mut Running,
        items: &mut [Item],
        fits: &mut [DotFit],
        hood: &mut Neighbourhood,
        links: &mut Links,
        near: &mut Vec<usize>,
        first: bool,
    ) -> f64 {
        let taken = h.map.frame_take(&mut h.state);
        // the new fits and their moves, by dot (no record is copied: the records take them
        // below, in parallel)
        let mut updates: Vec<Option<(DotFit, f64)>> = vec![None; items.len()];
        let mut most = 0.0f64;
        for (i, params, by) in taken {
            let it = &items[i];
            let mut fit = it.fit;
            fit.params = params;
            let moved = if first { it.moved + by } else { by };
            most = most.max(moved);
            updates[i] = Some((fit, moved));
        }
        hood.apply(&updates, |u| &u.0, fits, self.cfg.sampling);
        let changed = updates.iter().enumerate().filter(|(_, u)| u.is_some());
        links.relink(self.seeds, hood, changed.map(|(j, _)| j), near, None);
        items
            .par_iter_mut()
            .zip(&updates)
            .with_min_len(256)
            .for_each(|(it, u)| match u {
                Some((fit, moved)) => {
                    it.fit = *fit;
                    it.moved = *moved;
                }
                None if !first => it.moved = 0.0,
                None => {}
            });
        most
    }

    /// The final records: the joint bound where neighbours overlap the window (see
    /// [`crate::joint`]), then the χ² test ([`finish`]).
    /// `hood`: the neighbour models of `items`.
    fn finish(&self, mut items: Vec<Item>, hood: &Neighbourhood, links: &Links) -> Vec<DotFit> {
        if self.cfg.bound {
            let fits: Vec<DotFit> = items.iter().map(|i| i.fit).collect();
            let kind = crate::eval::Kind::from_model(self.cfg.model);
            let (w, h) = (self.img.width(), self.img.height());
            // each dot's overlapping neighbours (most dots of a sparse target have none): the
            // links' shares screen (they are a few passes old), the current models decide
            // (only the dots with a group: a record per dot, ~0.5 kB, cost its pages)
            let groups: Vec<(usize, JointDot, Vec<JointDot>)> = self
                .seeds
                .par_iter()
                .enumerate()
                .with_min_len(64)
                .filter_map(|(i, s)| {
                    let f = &fits[i];
                    if !f.crlb_x.is_finite() || absent(s, f) {
                        return None;
                    }
                    let win = s.window.clip(w, h)?;
                    let mut nbs = Vec::new();
                    for &(j, share) in links.row(i) {
                        let j = j as usize;
                        if share < SCREEN * crate::joint::MIN_SHARE {
                            continue;
                        }
                        let Some(m) = &hood.models[j] else { continue };
                        // (a neighbour whose own fit is not admitted as a model is left out)
                        if !m.reaches(win)
                            || !hood.gate.admits(&fits[j])
                            || m.share_in(win) < crate::joint::MIN_SHARE
                        {
                            continue;
                        }
                        let wj = self.seeds[j].window.clip(w, h);
                        if let Some(d) = wj.and_then(|wj| JointDot::new(&fits[j], wj, kind)) {
                            nbs.push(d);
                        }
                    }
                    if nbs.is_empty() {
                        return None;
                    }
                    Some((i, JointDot::new(f, win, kind)?, nbs))
                })
                .collect();
            if groups.is_empty() {
                return finish(items, self.cfg);
            }
            // which pixels a fit may use (read only for the few dots with a joint group: a
            // whole-image table cost more than all their bounds)
            let keep = |x: i64, y: i64| crate::joint::usable(self.img, self.mask, x, y);
            let bounds: Vec<Option<[f64; 2]>> = groups
                .par_iter()
                .map(|(_, dot, nbs)| crate::joint::joint_bound(kind, dot, nbs, self.noise, &keep))
                .collect();
            for ((i, _, _), b) in groups.iter().zip(bounds) {
                if let Some([bx, by]) = b {
                    items[*i].fit.crlb_x = bx;
                    items[*i].fit.crlb_y = by;
                }
            }
        }
        finish(items, self.cfg)
    }

    /// For every dot, the sum over its touching neighbours of how far each moved in its last
    /// refit (standard deviations) times the square root of the share of its squared profile
    /// that falls into this dot's window: an estimate of how far the dot would move if refitted
    /// now (Cauchy-Schwarz on the linearised fit), in its standard deviations.
    /// `only`: count the moves of these dots only (all without); `skip`: the dots whose pull is
    /// not asked for (0 for them). The sums run in each row's order, so they do not depend on
    /// the thread count.
    fn neighbour_pull(
        &self,
        items: &[Item],
        links: &Links,
        only: Option<&[bool]>,
        skip: Option<&[bool]>,
        movers: &[usize],
    ) -> Vec<f64> {
        // each dot's move where it counts, 0 where it does not: a compact copy, since the rows
        // read it at random (from the ~0.2 kB records, a cache miss per link), made from the
        // records that may have moved (`movers`: every other record's move is 0)
        let mut moves = vec![0.0f64; items.len()];
        for &j in movers {
            if only.is_none_or(|o| o[j]) {
                moves[j] = items[j].moved;
            }
        }
        let moving = |j: usize| moves.get(j).is_some_and(|&m| m != 0.0);
        self.seeds
            .par_iter()
            .enumerate()
            .with_min_len(256)
            .map(|(i, s)| {
                if skip.is_some_and(|k| k[i]) {
                    return 0.0;
                }
                let pull: f64 = links
                    .row(i)
                    .iter()
                    .filter(|&&(j, _)| moving(j as usize))
                    .map(|&(j, share)| pull_of(moves[j as usize], share))
                    .sum();
                // (a site without a dot is pulled by nothing; its record is read only where
                // something pulls)
                if pull != 0.0 && absent(s, &items[i].fit) {
                    0.0
                } else {
                    pull
                }
            })
            .collect()
    }

    /// A pass over every dot (those not fitted, flagged missing, keep their record).
    fn pass(
        &self,
        prev: &[DotFit],
        kind: PassKind,
        tails: Option<&NeighbourTails>,
        hood: &Neighbourhood,
        canvas_buf: &mut Vec<f64>,
    ) -> Vec<Item> {
        self.pass_with(prev, None, kind, tails, canvas_buf, false, hood, None)
            .into_iter()
            .zip(prev)
            .map(|(it, p)| it.map_or_else(|| Item::kept(*p), |it| *it))
            .collect()
    }

    /// One block-Jacobi pass: every selected dot (all without `select`) refitted after
    /// subtracting its neighbours' fits of `prev`; the others keep their record of `prev`.
    /// `windowed`: render each selected window's neighbours into it instead of a canvas.
    #[allow(clippy::too_many_arguments)]
    fn pass_with(
        &self,
        prev: &[DotFit],
        select: Option<&[bool]>,
        kind: PassKind,
        tails: Option<&NeighbourTails>,
        canvas_buf: &mut Vec<f64>,
        windowed: bool,
        hood: &Neighbourhood,
        check: Option<&[Item]>,
    ) -> Vec<Option<Box<Item>>> {
        let (img, mask, seeds, cfg, noise) =
            (self.img, self.mask, self.seeds, self.cfg, self.noise);
        // a first pass from prior fits: the Fisher matrices for its steps
        let steps = self
            .first_steps
            .filter(|l| check.is_none() && l.len() == seeds.len());
        // every dot apart (no model reaches another seed's window: a sparse target): nothing to
        // subtract, no canvas (at σ 0.3 and 0.75 px on bench/trackpy's 10 px lattice its
        // rendering, zeroing and adding back each dot's own model were ~5 % of `locate`)
        let apart = tails.is_none() && !windowed && hood.apart();
        // without rendered tails: every neighbour model once into one canvas
        let canvas = (tails.is_none() && !windowed && !apart).then(|| {
            Canvas::render(
                &hood.models,
                img.width(),
                img.height(),
                std::mem::take(canvas_buf),
            )
        });
        if canvas.is_some() {
            // (the canvas's subtractions read them: found here, before the parallel loop)
            hood.find_twins();
        }
        let fkind = crate::eval::Kind::from_model(cfg.model);
        let init = || {
            let mut f = Fitter::new(cfg);
            f.intermediate = kind.intermediate;
            f.warm = kind.warm;
            f.fixed_shape = self.fixed_shape;
            (f, Vec::new())
        };
        let refit = |(f, near): &mut (Fitter, Vec<usize>), i: usize, s: &Seed| -> Option<Item> {
            // a site the detector found no dot at is looked for once, in the first full
            // pass that knows the image's dot shape (see `Fitter::fit_loaded_present`);
            // where a dot is found it is fitted as every other from then on
            let empty = absent(s, &prev[i]);
            let look_for =
                empty && self.fixed_shape.is_some() && !kind.intermediate && check.is_none();
            if (empty && !look_for) || select.is_some_and(|sel| !sel[i]) {
                return None;
            }
            // (with a canvas: the window loaded less the canvas in one pass, the dot's
            // own model and its twins added back below)
            let flags = f.load_image_less(
                img,
                mask,
                s.window,
                canvas.as_ref().map(|c| c.values.as_slice()),
            );
            let own = &prev[i];
            let win = Window::new(f.ws.wx, f.ws.wy, f.ws.w, f.ws.h);
            // (the tails were rendered without the ghosts)
            let tails = tails.filter(|_| !hood.ghost_reaches(win, near));
            // a later pass: the look at the dot's last fit (left as it is below the
            // tolerance); a first pass from prior fits (a stack image, a gradient
            // frame): one Gauss-Newton step from the prior with its Fisher matrix (the
            // fit with the neighbours held, to second order)
            let from = match check.map(|c| &c[i]) {
                Some(item) => self.kept(item.looked.as_ref()).map(|l| {
                    (
                        item.fit,
                        l,
                        Some(cfg.neighbour_tolerance),
                        item.looked.clone(),
                    )
                }),
                None => steps
                    .and_then(|l| l[i].as_ref())
                    .filter(|_| !look_for)
                    .map(|l| {
                        let mut from = *own;
                        from.index = s.index;
                        from.flags = flags | s.flags;
                        // (the memory's matrix, not a copy of it)
                        let keep = kind.looked_at.then_some(Kept::Prior(i as u32));
                        (from, l, None, keep)
                    }),
            };
            // the parameters a look evaluates the dot at; with a canvas, where they are
            // those of the dot's own model there, the look adds that model back to the
            // window from its own rendering (the same dot: one rendering, not two)
            let look_at = from.as_ref().and_then(|(from, looked, ..)| {
                look_theta(&f.ws, from, looked, cfg.sampling, hood.models[i].as_ref())
            });
            let own_back = look_at.and(canvas.as_ref()).and_then(|c| {
                let m = hood.models[i].as_ref()?;
                (Some(m.theta) == look_at && m.sampling == Sampling::Point)
                    .then_some(c.boxes[i])
                    .flatten()
            });
            match (tails.and_then(|t| t.for_window(i, win)), &canvas) {
                (Some((sum, _)), _) => {
                    let ws = &mut f.ws;
                    for (k, v) in sum.iter().enumerate() {
                        ws.data[k] -= ws.keep[k] * v;
                    }
                }
                (None, Some(canvas)) => {
                    canvas.add_back_own(&mut f.ws, i, hood, own_back.is_none());
                }
                (None, None) if apart => {}
                (None, None) => {
                    for_each_neighbour(&mut f.ws, i, hood, near, |ws, amp| {
                        let n = ws.len();
                        for k in 0..n {
                            ws.data[k] -= ws.keep[k] * amp * ws.tmp[k];
                        }
                    });
                }
            }
            // (a first pass's dot that the step from its prior does not settle: its full fit
            // starts where that step leads, the prior's Gauss-Newton step, closer to the
            // solution than the prior: 3.5 → 2.8 iterations per fit on the real frame's 1,374)
            let mut stepped_start = None;
            if let Some((from, looked, still, keep)) = from {
                let l = look_at.and_then(|tb| look(&mut f.ws, tb, looked, fkind, noise, own_back));
                if l.as_ref().zip(still).is_some_and(|(l, t)| l.moves <= t) {
                    return None;
                }
                if let Some(l) = l.as_ref().filter(|l| l.moves <= LINEAR_STEP_MAX)
                    && let Some(stepped) =
                        linear_step(&f.ws, &from, looked, keep, l, fkind, cfg.sampling)
                {
                    return Some(stepped);
                }
                if check.is_none() {
                    stepped_start = l.and_then(|l| step_start(&f.ws, &l, fkind, cfg.sampling));
                }
            }
            // (`seen`: the dot as its neighbours saw it, its move measured from there)
            let seen = own.status.is_ok().then_some(own.params);
            let (start, hint) = match stepped_start {
                Some(g) => ([g.x0, g.y0], Some(g)),
                None if own.status.is_ok() => ([own.params.x0, own.params.y0], Some(own.params)),
                None => (s.centre, None),
            };
            let mut fit = if look_for {
                f.fit_loaded_present(flags, s.centre, noise)?
            } else {
                // (a full fit that failed in the pass before, when no median shape
                // was known to hold: the shape held first)
                let held_first = matches!(
                    own.status,
                    FitStatus::Singular | FitStatus::LeftWindow | FitStatus::NonFinite
                );
                f.fit_loaded_seen(
                    flags,
                    start,
                    hint.as_ref(),
                    seen.as_ref(),
                    noise,
                    held_first,
                )
            };
            fit.index = s.index;
            fit.flags |= s.flags;
            if fit.status.is_ok() {
                // (found by its fit at a site the detector called empty)
                fit.flags.remove(DotFlags::MISSING);
            }
            Some(Item::from_fitter(fit, f, kind.looked_at))
        };
        // (boxed: a pass's records of the dots it did not refit, most of them in the later
        // passes, are then a null pointer each instead of a whole record to move)
        let items: Vec<Option<Box<Item>>> = match select {
            // a later pass: only the selected dots (their records placed by index)
            Some(sel) => {
                let chosen: Vec<usize> = (0..seeds.len()).filter(|&i| sel[i]).collect();
                let done: Vec<Option<Box<Item>>> = chosen
                    .par_iter()
                    .map_init(init, |st, &i| refit(st, i, &seeds[i]).map(Box::new))
                    .collect();
                let mut all: Vec<Option<Box<Item>>> = Vec::new();
                all.resize_with(seeds.len(), || None);
                for (&i, it) in chosen.iter().zip(done) {
                    all[i] = it;
                }
                all
            }
            None => seeds
                .par_iter()
                .enumerate()
                .map_init(init, |st, (i, s)| refit(st, i, s).map(Box::new))
                .collect(),
        };
        if let Some(c) = canvas {
            *canvas_buf = c.values;
        }
        items
    }
}

/// How often a gradient frame's linear dots are solved again after the pixel dots settled
/// (each round the pixel dots next to them may owe pulls to their new solution).
const HYBRID_ROUNDS: u32 = 4;

/// The linear part of a gradient frame's neighbour iteration, before it starts: the
/// reference's linear coupling map ([`FitMemory::with_map`]) and the frame's prior (the
/// reference fits each moved by its tracked displacement).
///
/// A gradient frame differs from its reference by noise and a small common shift outside the
/// flow region; there the joint solution lies within the map's linear reach of the reference
/// fits, as a no-flow image's does, and the map gives it without refitting dots. After the
/// first pass every dot that was fitted over the map's window and lies, as its prior does,
/// within [`crate::coupling::Coupling::near`] of its base moved by the frame's common shift is
/// near; a near dot whose neighbours (touching its window, or linked by the map) are all near
/// is linear: solved on the map, with the other dots held at their current fits. The others
/// (the flow region, a ring of dots around it, dots whose fit or shape changed) are refitted
/// by the passes, with the linear dots' solution subtracted; when they settle the linear dots
/// are solved again with them held at their new fits, and the passes go on where those moves
/// pull, up to [`HYBRID_ROUNDS`] times.
struct Hybrid<'m> {
    map: &'m crate::coupling::Coupling,
    prior: &'m [DotFit],
}

/// A gradient frame's linear part while the iteration runs ([`Hybrid`]).
struct Running<'m> {
    map: &'m crate::coupling::Coupling,
    state: crate::coupling::FrameState,
    /// Per dot, the fit the map holds it at where it is not linear.
    held: Vec<DotFit>,
    /// The dots refitted since the linear dots were last solved.
    since: Vec<bool>,
    rounds: u32,
}

/// The records of the last pass with the χ² test applied (`RESIDUAL`). The noise model is
/// scaled by the median reduced χ² of the image's least-squares fits where that exceeds the
/// median of the χ² distribution (a noise model that is off for the whole image is not a
/// per-dot problem); a dot is flagged when its scaled χ² exceeds the `1 - residual_false_alarm`
/// quantile of the χ² distribution of its degrees of freedom.
fn finish(items: Vec<Item>, cfg: &FitConfig) -> Vec<DotFit> {
    let alpha = cfg.residual_false_alarm;
    let usable = |it: &Item| it.fit.status.is_ok() && it.chi2.is_finite() && it.dof > 0;
    if alpha <= 0.0 || !items.iter().any(usable) {
        return items.into_iter().map(|it| it.fit).collect();
    }
    // median of χ²/median(χ²_dof) over the usable fits
    // (each dot on its own in parallel, in dot order)
    let mut ratios: Vec<f64> = items
        .par_iter()
        .with_min_len(1024)
        .filter(|it| usable(it))
        .map(|it| it.chi2 / chi2_median(it.dof))
        .collect();
    let mid = ratios.len() / 2;
    let (_, m, _) = ratios.select_nth_unstable_by(mid, f64::total_cmp);
    let scale = m.max(1.0);
    let z = normal_upper_quantile(alpha);
    items
        .into_par_iter()
        .with_min_len(1024)
        .map(|it| {
            let mut fit = it.fit;
            if usable(&it) && it.chi2 / scale > chi2_quantile(it.dof, z) {
                fit.flags |= DotFlags::RESIDUAL;
            }
            fit
        })
        .collect()
}

/// Median of the χ² distribution with `k` degrees of freedom (Wilson-Hilferty).
fn chi2_median(k: usize) -> f64 {
    chi2_quantile(k, 0.0)
}

/// The quantile of the χ² distribution with `k` degrees of freedom at the standard normal
/// quantile `z` (Wilson-Hilferty: relative error below 1e-3 at the 0.999 quantile for k ≥ 10).
fn chi2_quantile(k: usize, z: f64) -> f64 {
    let k = k as f64;
    let c = 2.0 / (9.0 * k);
    k * (1.0 - c + z * c.sqrt()).max(0.0).powi(3)
}

/// `z` with `P(Z > z) = p` for a standard normal `Z` (bisection on `erfc`, to 1e-12).
fn normal_upper_quantile(p: f64) -> f64 {
    let (mut lo, mut hi) = (-40.0f64, 40.0f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if 0.5 * libm::erfc(mid / std::f64::consts::SQRT_2) > p {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-12 {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// The fits of a pass as neighbour models (`None`: not a usable fit), bucketed for finding the
/// neighbours of a window.
struct Neighbourhood<'a> {
    seeds: &'a [Seed],
    /// One model per seed, then the ghosts (see [`Iteration::ghosts`]): lattice sites outside
    /// the image whose light reaches into it, subtracted like any neighbour but never fitted
    /// as a dot nor reported.
    models: Vec<Option<NeighbourModel>>,
    index: NeighbourIndex,
    /// Which fits may model a neighbour (fixed from the first models).
    gate: Plausible,
    /// The seeds found twice ([`Twins`]), found before the first pass that subtracts from a
    /// canvas ([`Neighbourhood::find_twins`]).
    twins: std::sync::OnceLock<Twins>,
}

impl<'a> Neighbourhood<'a> {
    /// The models of `fits` (the first ones of an iteration: they also set the gate).
    fn new(fits: &[DotFit], seeds: &'a [Seed], sampling: FitSampling) -> Neighbourhood<'a> {
        Neighbourhood::with_known(fits, seeds, sampling, None)
    }

    /// [`Neighbourhood::new`], each model taken from `known` (the same dot's model in another
    /// fit of the same seeds, made for the same sampling) where only its position differs
    /// ([`NeighbourModel::moved_to`]: the same model, without its ~11 calls of libm).
    fn with_known(
        fits: &[DotFit],
        seeds: &'a [Seed],
        sampling: FitSampling,
        known: Option<&KnownModels>,
    ) -> Neighbourhood<'a> {
        let gate = Plausible::of(fits);
        let known = known
            .filter(|(s, k)| *s == sampling && k.len() == fits.len())
            .map(|(_, k)| k.as_slice());
        let models: Vec<Option<NeighbourModel>> = fits
            .par_iter()
            .enumerate()
            .map(|(i, f)| {
                if !gate.admits(f) {
                    return None;
                }
                known
                    .and_then(|k| k[i].as_ref()?.moved_to(f))
                    .or_else(|| NeighbourModel::new(f, sampling))
            })
            .collect();
        let index = NeighbourIndex::new(&models);
        Neighbourhood {
            seeds,
            models,
            index,
            gate,
            twins: std::sync::OnceLock::new(),
        }
    }

    /// Finds the seeds found twice ([`Twins`], in parallel) unless known: to be called before a
    /// parallel pass that reads them ([`Neighbourhood::twins_of`]), never from inside one. (A
    /// lazy parallel initialisation inside the pass deadlocked: a worker that initialises the
    /// cell steals, while it waits for its own parallel part, a dot of the pass that waits for
    /// the same cell.)
    fn find_twins(&self) {
        self.twins.get_or_init(|| Twins::of(self.seeds, true));
    }

    /// The seeds closer than 1.5 px to seed `i` ([`same_seed`]); found here, serially, when
    /// [`Neighbourhood::find_twins`] was not called (a serial initialisation cannot steal work:
    /// the other workers just wait for it).
    fn twins_of(&self, i: usize) -> &[(u32, u32)] {
        self.twins
            .get_or_init(|| Twins::of(self.seeds, false))
            .with(i)
    }

    /// Replaces a dot's model `m` by that of `fit` where the gate admits it (otherwise the dot
    /// keeps its last admitted model: a fit that failed or wandered off to a wide blob is not
    /// subtracted from its neighbours, which would spread the failure); `true` when the index
    /// must be rebuilt ([`Neighbourhood::reindex`]): the dot appeared, moved to another bucket
    /// or reaches further than the index looks.
    fn set(
        gate: &Plausible,
        index: &NeighbourIndex,
        m: &mut Option<NeighbourModel>,
        fit: &DotFit,
        sampling: FitSampling,
    ) -> bool {
        let Some(new) = gate.model(fit, sampling) else {
            return false;
        };
        let in_place = m
            .as_ref()
            .is_some_and(|a| index.key(a) == index.key(&new) && new.rx.max(new.ry) <= index.reach);
        *m = Some(new);
        !in_place
    }

    /// [`Neighbourhood::set`] for every record a pass refitted (`None`: kept), each new fit
    /// also written into `fits`.
    fn apply<T: Sync>(
        &mut self,
        refitted: &[Option<T>],
        fit_of: impl Fn(&T) -> &DotFit + Sync,
        fits: &mut [DotFit],
        sampling: FitSampling,
    ) {
        let (gate, index) = (&self.gate, &self.index);
        let n = refitted.len();
        let reindex = self.models[..n]
            .par_iter_mut()
            .zip(fits)
            .zip(refitted)
            .with_min_len(256)
            .map(|((m, f), r)| {
                let Some(r) = r else { return false };
                let fit = fit_of(r);
                *f = *fit;
                Self::set(gate, index, m, fit, sampling)
            })
            .reduce(|| false, |a, b| a || b);
        if reindex {
            self.reindex();
        }
    }

    /// [`Neighbourhood::set`] for every record of a pass, in parallel (each dot's model on its
    /// own; the index rebuilt once where any dot left its bucket).
    fn update(&mut self, items: &[Item], sampling: FitSampling) {
        let (gate, index) = (&self.gate, &self.index);
        let reindex = self.models[..items.len()]
            .par_iter_mut()
            .zip(items)
            .with_min_len(256)
            .map(|(m, it)| Self::set(gate, index, m, &it.fit, sampling))
            .reduce(|| false, |a, b| a || b);
        if reindex {
            self.reindex();
        }
    }

    /// Replaces the ghosts' models by `ghosts`.
    fn set_ghosts(&mut self, ghosts: Vec<NeighbourModel>) {
        let had = self.models.len() > self.seeds.len();
        self.models.truncate(self.seeds.len());
        if had || !ghosts.is_empty() {
            self.models.extend(ghosts.into_iter().map(Some));
            self.reindex();
        }
    }

    /// Whether a ghost's 5σ reach touches `win`.
    fn ghost_reaches(&self, win: Window, near: &mut Vec<usize>) -> bool {
        if self.models.len() == self.seeds.len() {
            return false;
        }
        self.index.near_unsorted(win, near);
        near.iter()
            .any(|&j| self.is_ghost(j) && self.models[j].as_ref().is_some_and(|m| m.reaches(win)))
    }

    /// Whether model `j` is a ghost.
    fn is_ghost(&self, j: usize) -> bool {
        j >= self.seeds.len()
    }

    /// Whether no model (a ghost's included) reaches the window of a seed other than its own
    /// (nor a seed found twice: [`Neighbourhood::touching`] on every seed's unclipped window
    /// finds nothing); stops at the first that does.
    fn apart(&self) -> bool {
        let mut near = Vec::new();
        self.seeds.iter().enumerate().all(|(i, s)| {
            let mut alone = true;
            self.touching(i, s.window, &mut near, |_, _, _| alone = false);
            alone
        })
    }

    /// Rebuilds the bucket index from the models.
    fn reindex(&mut self) {
        self.index = NeighbourIndex::new(&self.models);
    }

    /// Calls `f(j, model, same)` for every fitted dot `j ≠ i` whose 5σ reach touches `win`, in
    /// the index's bucket order (fixed by the models' positions: deterministic, not ascending;
    /// sorting the candidates cost 3 % of `locate` on the real sample); `same`: seed `j` is closer than 1.5 px to seed `i` (the same dot found
    /// twice, never subtracted).
    fn touching(
        &self,
        i: usize,
        win: Window,
        near: &mut Vec<usize>,
        mut f: impl FnMut(usize, &NeighbourModel, bool),
    ) {
        self.index.near_unsorted(win, near);
        for &j in near.iter() {
            let Some(m) = &self.models[j] else { continue };
            if j == i || !m.reaches(win) {
                continue;
            }
            let same = !self.is_ghost(j) && same_seed(&self.seeds[i], &self.seeds[j]);
            f(j, m, same);
        }
    }
}

/// The joint bound's groups are screened by the [`Links`]' shares at this fraction of
/// [`crate::joint::MIN_SHARE`]: between relinks a share at that level changes by a factor
/// below 2.5 (a move of 0.05 σ, a reach 5 % wider: each a factor ~1.5 at a share of 1e-2).
const SCREEN: f64 = 0.25;

/// Every dot's touching neighbours (fitted dots whose 5σ reach touches its seed window, not
/// the same dot found twice, no ghosts) with the share of their squared profile in that window
/// ([`NeighbourModel::share_in`]): the screening of [`Iteration::neighbour_pull`] and of the
/// joint bound's groups, computed once per iteration instead of once per pass (on the real
/// gradient frame the shares cost 34 ms of a 200 ms one-thread fit). A dot whose model moved
/// by more than [`RELINK`] of its σ (or changed its reach by that fraction, or appeared) since
/// it was linked is linked anew ([`Links::relink`]); smaller moves change its shares by less
/// than a screening needs.
struct Links {
    rows: LinkRows,
    /// Each dot's model as last linked: centre and reach (px).
    linked: Vec<Option<[f64; 4]>>,
    /// The seeds' windows, bucketed.
    windows: NeighbourIndex,
}

/// See [`Links`].
const RELINK: f64 = 0.05;

impl Links {
    fn new(seeds: &[Seed], hood: &Neighbourhood) -> Links {
        // blocks of seeds in parallel, each its rows in one buffer
        let blocks: Vec<RowBlock> = seeds
            .par_chunks(LINK_BLOCK)
            .enumerate()
            .map(|(b, block)| {
                let mut near = Vec::new();
                let (mut data, mut lens) = (Vec::new(), Vec::with_capacity(block.len()));
                for (k, s) in block.iter().enumerate() {
                    let from = data.len();
                    Links::row_of(b * LINK_BLOCK + k, s, hood, &mut near, &mut data);
                    lens.push((data.len() - from) as u32);
                }
                (data, lens)
            })
            .collect();
        let rows = LinkRows::from_blocks(&blocks, seeds.len());
        let linked = hood.models[..seeds.len()]
            .iter()
            .map(|m| m.as_ref().map(|m| [m.x0, m.y0, m.rx, m.ry]))
            .collect();
        Links {
            rows,
            linked,
            windows: Links::index(seeds),
        }
    }

    /// Seed `i`'s row linked from the current models, appended to `out`.
    fn row_of(
        i: usize,
        s: &Seed,
        hood: &Neighbourhood,
        near: &mut Vec<usize>,
        out: &mut Vec<(u32, f64)>,
    ) {
        hood.touching(i, s.window, near, |j, m, same| {
            if !same && !hood.is_ghost(j) {
                out.push((j as u32, m.share_in(s.window)));
            }
        });
    }

    /// The seeds' windows, bucketed.
    fn index(seeds: &[Seed]) -> NeighbourIndex {
        let keyed: Vec<Option<Keyed>> = seeds
            .par_iter()
            .with_min_len(1024)
            .map(|s| {
                let w = s.window;
                let half = 0.5 * w.width.max(w.height) as f64;
                let (x, y) = (
                    w.x as f64 + 0.5 * (w.width as f64 - 1.0),
                    w.y as f64 + 0.5 * (w.height as f64 - 1.0),
                );
                Some((NeighbourIndex::key_of(x, y), half))
            })
            .collect();
        NeighbourIndex::of_keys(&keyed)
    }

    /// The links of another image's iteration over the same seeds (`m`), brought to the
    /// current models as a pass brings its own ([`Links::relink`]): the rows of the seeds whose
    /// window is the one `m` was linked over are `m`'s, the others are linked anew; then every
    /// model that moved by more than [`RELINK`] since `m` linked it (or appeared, or is gone)
    /// is linked anew. On a gradient frame that is the flow region; elsewhere the reference's
    /// shares stand (the same rule as between two passes of one image).
    fn carried(
        m: &LinkMemory,
        seeds: &[Seed],
        hood: &Neighbourhood,
        near: &mut Vec<usize>,
    ) -> Links {
        let fresh: Vec<bool> = seeds
            .iter()
            .zip(&m.windows)
            .map(|(s, w)| s.window != *w)
            .collect();
        // the rows of the moved windows, linked anew (in parallel), into the remembered rows
        let anew: Vec<(usize, Vec<(u32, f64)>)> = seeds
            .par_iter()
            .enumerate()
            .filter(|&(i, _)| fresh[i])
            .map_init(Vec::new, |near, (i, s)| {
                let mut row = Vec::new();
                Links::row_of(i, s, hood, near, &mut row);
                (i, row)
            })
            .collect();
        let mut rows = m.rows.clone();
        for (i, row) in anew {
            rows.replace(i, &row);
        }
        let mut links = Links {
            rows,
            linked: m.linked.clone(),
            windows: Links::index(seeds),
        };
        links.relink(seeds, hood, 0..seeds.len(), near, Some(&fresh));
        links
    }

    /// The links as a [`LinkMemory`] for another image of `seeds`.
    fn memory(&self, seeds: &[Seed]) -> LinkMemory {
        LinkMemory {
            rows: self.rows.clone(),
            linked: self.linked.clone(),
            windows: seeds.iter().map(|s| s.window).collect(),
        }
    }

    fn row(&self, i: usize) -> &[(u32, f64)] {
        self.rows.row(i)
    }

    /// Links anew the dots of `changed` whose model moved too far (see [`Links`]): out of the
    /// rows of the windows its old model reached, into those its new one reaches; a dot whose
    /// model is gone is taken out of the rows. The rows marked in `current` (linked from the
    /// current models already) are left as they are.
    fn relink(
        &mut self,
        seeds: &[Seed],
        hood: &Neighbourhood,
        changed: impl Iterator<Item = usize>,
        near: &mut Vec<usize>,
        current: Option<&[bool]>,
    ) {
        // the windows a model of centre and reach `at` may touch
        let around = |at: [f64; 4]| {
            let (x0, y0) = ((at[0] - at[2]).floor(), (at[1] - at[3]).floor());
            Window::new(
                x0 as i64,
                y0 as i64,
                (at[0] + at[2] - x0).ceil() as usize + 1,
                (at[1] + at[3] - y0).ceil() as usize + 1,
            )
        };
        let skip = |i: usize| current.is_some_and(|c| c[i]);
        for j in changed {
            let model = hood.models[j].as_ref();
            let now = model.map(|m| [m.x0, m.y0, m.rx, m.ry]);
            let was = self.linked[j];
            if let Some(w) = was {
                if let Some(now) = now {
                    let sigma = REACH_SIGMAS.recip() * w[2].min(w[3]);
                    if (now[0] - w[0]).abs().max((now[1] - w[1]).abs()) <= RELINK * sigma
                        && (now[2] / w[2] - 1.0).abs().max((now[3] / w[3] - 1.0).abs()) <= RELINK
                    {
                        continue;
                    }
                }
                self.windows.near_unsorted(around(w), near);
                for &i in near.iter() {
                    if !skip(i) {
                        self.rows.remove(i, j as u32);
                    }
                }
            }
            self.linked[j] = now;
            let (Some(m), Some(now)) = (model, now) else {
                continue;
            };
            self.windows.near_unsorted(around(now), near);
            for &i in near.iter() {
                let s = &seeds[i];
                // (the rows the old model reached no longer hold j; a row linked from a model
                // within RELINK of the old one may lie just outside their reach and still hold
                // it: its entry is replaced, never doubled)
                if i != j && !skip(i) && m.reaches(s.window) && !same_seed(s, &seeds[j]) {
                    self.rows.set(i, (j as u32, m.share_in(s.window)));
                }
            }
        }
    }
}

/// A fit's [`Links`] as its iteration ended, for an image of the same seeds
/// ([`Links::carried`]): the rows, the models they were linked at and the seed windows they
/// were linked over.
#[derive(Clone, Debug, Default)]
struct LinkMemory {
    rows: LinkRows,
    linked: Vec<Option<[f64; 4]>>,
    windows: Vec<Window>,
}

impl LinkMemory {
    /// Whether these are links of `seeds`' dots (as many; the rows, models and windows are
    /// one per seed by construction, [`Links::memory`]).
    fn fits(&self, seeds: &[Seed]) -> bool {
        self.windows.len() == seeds.len()
    }
}

/// A block of rows: their entries one after the other, and each row's length.
type RowBlock = (Vec<(u32, f64)>, Vec<u32>);

/// Seeds per block of [`Links::new`] (each block's rows gathered in one buffer).
const LINK_BLOCK: usize = 256;

/// Free entries after each row of [`LinkRows`] when it is laid out: room for relinked
/// neighbours without moving the row.
const LINK_SPARE: usize = 2;

/// The rows of [`Links`] in one buffer (one allocation, not one per dot: the heap of ~12,000
/// small rows slowed the allocations that follow, and a copy is one `memcpy`): row `i` is
/// `data[start[i]..start[i] + len[i]]` with room for `cap[i]` entries; a row that outgrows its
/// room moves to the end of the buffer (its old room stays unused).
#[derive(Clone, Debug, Default)]
struct LinkRows {
    start: Vec<u32>,
    len: Vec<u32>,
    cap: Vec<u32>,
    data: Vec<(u32, f64)>,
}

impl LinkRows {
    /// The rows of `blocks` (each its rows' entries one after the other and their lengths), in
    /// order: `n` rows in all.
    fn from_blocks(blocks: &[RowBlock], n: usize) -> LinkRows {
        let total: usize = blocks.iter().map(|(d, _)| d.len()).sum::<usize>() + n * LINK_SPARE;
        let mut rows = LinkRows {
            start: Vec::with_capacity(n),
            len: Vec::with_capacity(n),
            cap: Vec::with_capacity(n),
            data: Vec::with_capacity(total),
        };
        for (data, lens) in blocks {
            let mut at = 0;
            for &l in lens {
                let l = l as usize;
                rows.start.push(rows.data.len() as u32);
                rows.len.push(l as u32);
                rows.cap.push((l + LINK_SPARE) as u32);
                rows.data.extend_from_slice(&data[at..at + l]);
                rows.data
                    .extend(std::iter::repeat_n((u32::MAX, 0.0), LINK_SPARE));
                at += l;
            }
        }
        rows
    }

    fn row(&self, i: usize) -> &[(u32, f64)] {
        let s = self.start[i] as usize;
        &self.data[s..s + self.len[i] as usize]
    }

    /// Appends `e` to row `i` (moving the row to the end of the buffer when it is full).
    fn push(&mut self, i: usize, e: (u32, f64)) {
        let (s, l) = (self.start[i] as usize, self.len[i] as usize);
        if l == self.cap[i] as usize {
            let cap = 2 * l + LINK_SPARE;
            let at = self.data.len();
            self.data.extend_from_within(s..s + l);
            self.data.resize(at + cap, (u32::MAX, 0.0));
            self.start[i] = at as u32;
            self.cap[i] = cap as u32;
        }
        let s = self.start[i] as usize;
        self.data[s + l] = e;
        self.len[i] += 1;
    }

    /// Neighbour `e.0`'s entry of row `i` made `e` (appended where the row has none).
    fn set(&mut self, i: usize, e: (u32, f64)) {
        let (s, l) = (self.start[i] as usize, self.len[i] as usize);
        match self.data[s..s + l].iter_mut().find(|x| x.0 == e.0) {
            Some(x) => *x = e,
            None => self.push(i, e),
        }
    }

    /// Removes neighbour `j` from row `i` (the order of the others kept).
    fn remove(&mut self, i: usize, j: u32) {
        let (s, l) = (self.start[i] as usize, self.len[i] as usize);
        let row = &mut self.data[s..s + l];
        let mut kept = 0;
        for k in 0..l {
            if row[k].0 != j {
                row[kept] = row[k];
                kept += 1;
            }
        }
        self.len[i] = kept as u32;
    }

    /// Row `i` made `entries`.
    fn replace(&mut self, i: usize, entries: &[(u32, f64)]) {
        self.len[i] = 0;
        for &e in entries {
            self.push(i, e);
        }
    }
}

/// The lattice sites for [`Iteration::ghosts`], in grid-index order: each site one step
/// (of the eight around a seed) from a seed with a usable fit, holding no seed, whose
/// position extrapolated from that seed and the seed on its other side (`2 p − q`, both
/// usable) lies outside the image's pixel area; the mean of those extrapolations.
fn ghost_sites(
    seeds: &[Seed],
    fits: &[DotFit],
    width: usize,
    height: usize,
) -> Vec<(GridIndex, [f64; 2])> {
    let at = GridTable::new(seeds.iter().map(|s| s.index));
    let usable = |k: usize| {
        let f = &fits[k];
        (f.status.is_ok() && f.params.is_valid()).then_some([f.params.x0, f.params.y0])
    };
    let outside = |p: [f64; 2]| {
        p[0] < -0.5 || p[1] < -0.5 || p[0] > width as f64 - 0.5 || p[1] > height as f64 - 0.5
    };
    // each seed's extrapolations past the image's edge, in parallel; summed per site below in
    // seed order (the sums of a serial loop, bit for bit)
    // (a site's grid index and one extrapolation of its position)
    type Guess = ((i32, i32), [f64; 2]);
    let found: Vec<Vec<Guess>> = seeds
        .par_iter()
        .enumerate()
        .with_min_len(256)
        .map(|(k, s)| {
            let mut out = Vec::new();
            let Some(p) = usable(k) else { return out };
            let (i, j) = (s.index.i, s.index.j);
            for (di, dj) in [
                (1, 0),
                (-1, 0),
                (0, 1),
                (0, -1),
                (1, 1),
                (1, -1),
                (-1, 1),
                (-1, -1),
            ] {
                let g = (i + di, j + dj);
                if at.get(GridIndex::new(g.0, g.1)).is_some() {
                    continue;
                }
                let Some(q) = at.get(GridIndex::new(i - di, j - dj)).and_then(usable) else {
                    continue;
                };
                let e = [2.0 * p[0] - q[0], 2.0 * p[1] - q[1]];
                if outside(e) {
                    out.push((g, e));
                }
            }
            out
        })
        .collect();
    let mut sites: BTreeMap<(i32, i32), ([f64; 2], u32)> = BTreeMap::new();
    for (g, e) in found.into_iter().flatten() {
        let v = sites.entry(g).or_insert(([0.0; 2], 0));
        v.0[0] += e[0];
        v.0[1] += e[1];
        v.1 += 1;
    }
    sites
        .into_iter()
        .map(|((i, j), (sum, n))| {
            let n = n as f64;
            (GridIndex::new(i, j), [sum[0] / n, sum[1] / n])
        })
        .collect()
}

/// Renders, into `ws.tmp` (unit amplitude, over its 5σ box) and one call of `f(ws, amplitude)`
/// each, every neighbour of seed `i` that is subtracted from its window; returns how many.
fn for_each_neighbour(
    ws: &mut crate::eval::Workspace,
    i: usize,
    hood: &Neighbourhood,
    near: &mut Vec<usize>,
    mut f: impl FnMut(&mut crate::eval::Workspace, f64),
) -> u32 {
    let win = Window::new(ws.wx, ws.wy, ws.w, ws.h);
    let mut count = 0;
    hood.touching(i, win, near, |_, m, same| {
        if !same {
            crate::eval::dot_factor(ws, &m.theta, m.sampling);
            m.clip_to_box(ws);
            f(ws, m.theta[IA]);
            count += 1;
        }
    });
    count
}

/// Least rows per band of a [`Canvas`] (bands are rendered in parallel, each in dot order, so
/// the canvas does not depend on the number of threads).
const BAND: usize = 32;

/// A rendering's buffers: the box's values and [`crate::eval::exp_grid`]'s two rows.
type RenderScratch = (Vec<f64>, Vec<f64>, Vec<f64>);

/// Every neighbour model of a pass rendered once over its 5σ box into an image-sized canvas.
/// A window then has its neighbours subtracted by reading the canvas and adding back its own
/// dot (and a seed found twice), instead of rendering each of its ~8 neighbours over it: on the
/// real sample a 17 × 17 box per dot and pass instead of ~8 windows of 9 × 9.
struct Canvas {
    /// Row-major, the image's width.
    values: Vec<f64>,
    /// Each model's pixel box (clipped to the image).
    boxes: Vec<Option<PixelBox>>,
}

/// Inclusive pixel ranges.
#[derive(Clone, Copy)]
struct PixelBox {
    x_lo: usize,
    x_hi: usize,
    y_lo: usize,
    y_hi: usize,
}

impl Canvas {
    /// Renders into `values` (any contents; resized to the image and zeroed band by band, a new
    /// buffer by its resize).
    fn render(
        models: &[Option<NeighbourModel>],
        width: usize,
        height: usize,
        mut values: Vec<f64>,
    ) -> Canvas {
        let boxes: Vec<Option<PixelBox>> = models
            .par_iter()
            .with_min_len(1024)
            .map(|m| m.as_ref().and_then(|m| m.pixel_box(width, height)))
            .collect();
        // (a new buffer is zeroed as it is filled, in parallel: its bands need not be zeroed
        // again; a serial resize of a 1-MP canvas was ~1 % of a gradient frame's instructions
        // on one thread)
        let zeroed = values.is_empty();
        if zeroed {
            values.par_extend(rayon::iter::repeat_n(0.0, width * height));
        } else {
            values.resize(width * height, 0.0);
        }
        if width == 0 || height == 0 {
            return Canvas { values, boxes };
        }
        if !zeroed {
            values
                .par_chunks_mut(BAND * width)
                .for_each(|chunk| chunk.fill(0.0));
        }
        // each model rendered once, whole, by the band its box starts in; a band's models also
        // reach into the next band (as many rows as the tallest box), so the even bands are
        // drawn first, each with the band below it, then the odd ones (a box that straddled
        // two bands was rendered twice, once per part: ~40 % more renderings on the real
        // sample)
        let band = boxes
            .iter()
            .flatten()
            .map(|b| b.y_hi - b.y_lo + 1)
            .max()
            .unwrap_or(1)
            .max(BAND);
        let mut bands: Vec<Vec<u32>> = vec![Vec::new(); height.div_ceil(band)];
        for (j, b) in boxes.iter().enumerate() {
            if let Some(b) = b {
                bands[b.y_lo / band].push(j as u32);
            }
        }
        let draw = |rows: &mut [f64], r0: usize, list: &[u32], bufs: &mut RenderScratch| {
            let (out, v, q) = bufs;
            for &j in list {
                let (Some(m), Some(b)) = (&models[j as usize], boxes[j as usize]) else {
                    continue;
                };
                let (bw, bh) = m.render(b, out, v, q);
                let amp = m.theta[IA];
                for (jj, e) in out[..bw * bh].chunks_exact(bw).enumerate() {
                    let at = (b.y_lo - r0 + jj) * width + b.x_lo;
                    for (c, e) in rows[at..at + bw].iter_mut().zip(e) {
                        *c += amp * e;
                    }
                }
            }
        };
        let pair = 2 * band * width;
        // the even bands (each with the one below it), then the odd ones
        values
            .par_chunks_mut(pair)
            .zip(bands.par_iter().step_by(2))
            .enumerate()
            .for_each_init(RenderScratch::default, |bufs, (k, (rows, list))| {
                draw(rows, 2 * k * band, list, bufs)
            });
        if bands.len() > 1 {
            values[band * width..]
                .par_chunks_mut(pair)
                .zip(bands[1..].par_iter().step_by(2))
                .enumerate()
                .for_each_init(RenderScratch::default, |bufs, (k, (rows, list))| {
                    draw(rows, (2 * k + 1) * band, list, bufs)
                });
        }
        Canvas { values, boxes }
    }

    /// After the window of seed `i` was loaded less the whole canvas
    /// ([`Fitter::load_image_less`]), adds back what [`for_each_neighbour`] does not subtract:
    /// the dot's own model and any seed closer than 1.5 px ([`Twins`]: no neighbour query per
    /// window). `own: false` leaves the dot's own model subtracted, for a caller that adds it
    /// back itself ([`look`]'s `own_back`).
    fn add_back_own(
        &self,
        ws: &mut crate::eval::Workspace,
        i: usize,
        hood: &Neighbourhood,
        own: bool,
    ) {
        let (w, h) = (ws.w, ws.h);
        if w == 0 || h == 0 {
            return;
        }
        let win = Window::new(ws.wx, ws.wy, w, h);
        if own {
            self.add_back(ws, i, &hood.models);
        }
        // (what `Neighbourhood::touching` calls "same", without searching the neighbours)
        for &(_, j) in hood.twins_of(i) {
            let j = j as usize;
            if hood.models[j].as_ref().is_some_and(|m| m.reaches(win)) {
                self.add_back(ws, j, &hood.models);
            }
        }
    }

    /// Adds model `j`'s part of the canvas over the workspace window back to its data.
    fn add_back(
        &self,
        ws: &mut crate::eval::Workspace,
        j: usize,
        models: &[Option<NeighbourModel>],
    ) {
        let (Some(m), Some(b)) = (&models[j], self.boxes[j]) else {
            return;
        };
        let (wx, wy) = (ws.wx as usize, ws.wy as usize);
        let part = PixelBox {
            x_lo: b.x_lo.max(wx),
            x_hi: b.x_hi.min(wx + ws.w - 1),
            y_lo: b.y_lo.max(wy),
            y_hi: b.y_hi.min(wy + ws.h - 1),
        };
        if part.x_lo > part.x_hi || part.y_lo > part.y_hi {
            return;
        }
        let (bw, bh) = m.render(part, &mut ws.tmp, &mut ws.v, &mut ws.q);
        let amp = m.theta[IA];
        for jj in 0..bh {
            let k0 = (part.y_lo - wy + jj) * ws.w + part.x_lo - wx;
            for ii in 0..bw {
                let k = k0 + ii;
                ws.data[k] += ws.keep[k] * amp * ws.tmp[jj * bw + ii];
            }
        }
    }
}

/// Largest move (px, per axis) of the prior fits for which [`refit_dots`] may use
/// [`NeighbourTails`] rendered before the move: a neighbour's tail at the window edge (~4 % of
/// its peak at the real sample's 8 px pitch, σ 1.6 px) then changes by less than 0.15 % of its
/// peak.
pub const TAILS_MAX_SHIFT: f64 = 0.02;

/// The neighbours' tails over every seed's (clipped) window, rendered once from prior fits:
/// for refitting several images of one scene (the no-flow stack) with [`refit_dots`] without
/// rendering every neighbour again for every image. Memory: one value per window pixel
/// (~8 MB for 12k dots in 9×9 windows).
#[derive(Clone, Debug)]
pub struct NeighbourTails {
    windows: Vec<Option<Window>>,
    start: Vec<usize>,
    values: Vec<f64>,
    count: Vec<u32>,
    /// The linearised neighbour iteration ([`NeighbourTails::coupled`]).
    coupling: Option<std::sync::Arc<crate::coupling::Coupling>>,
}

impl NeighbourTails {
    /// Renders, for every seed, the sum of its neighbours' prior dots (without background) over
    /// its window clipped to an image of `width × height` (the neighbours exactly as
    /// [`fit_dots`] subtracts them).
    pub fn new(
        prior: &[DotFit],
        seeds: &[Seed],
        cfg: &FitConfig,
        width: usize,
        height: usize,
    ) -> NeighbourTails {
        let hood = Neighbourhood::new(prior, seeds, cfg.sampling);
        NeighbourTails::render(&hood, prior.len(), cfg, width, height)
    }

    /// The tails of `hood`'s models (made from `n_prior` fits) over its seeds' windows.
    fn render(
        hood: &Neighbourhood,
        n_prior: usize,
        cfg: &FitConfig,
        width: usize,
        height: usize,
    ) -> NeighbourTails {
        let seeds = hood.seeds;
        // (a prior of another length: no tails, every window is rendered by `refit_dots`)
        let same_length = n_prior == seeds.len();
        let per_seed: Vec<(Option<Window>, Vec<f64>, u32)> = seeds
            .par_iter()
            .enumerate()
            .map_init(
                || (Fitter::new(cfg), Vec::new()),
                |(f, near), (i, s)| {
                    let Some(win) = s.window.clip(width, height) else {
                        return (None, Vec::new(), 0);
                    };
                    if s.flags.contains(DotFlags::MISSING) || !same_length {
                        return (None, Vec::new(), 0);
                    }
                    f.ws.resize(win.x, win.y, win.width, win.height);
                    let mut sum = vec![0.0; win.len()];
                    let count = for_each_neighbour(&mut f.ws, i, hood, near, |ws, amp| {
                        for (o, t) in sum.iter_mut().zip(&ws.tmp) {
                            *o += amp * t;
                        }
                    });
                    (Some(win), sum, count)
                },
            )
            .collect();
        let mut start = Vec::with_capacity(per_seed.len() + 1);
        let mut values = Vec::with_capacity(per_seed.iter().map(|p| p.1.len()).sum());
        let (mut windows, mut count) = (Vec::new(), Vec::new());
        start.push(0);
        for (w, v, c) in per_seed {
            values.extend_from_slice(&v);
            start.push(values.len());
            windows.push(w);
            count.push(c);
        }
        NeighbourTails {
            windows,
            start,
            values,
            count,
            coupling: None,
        }
    }

    /// [`NeighbourTails::new`] plus the neighbour iteration linearised at `prior` (the
    /// reference's fits, moved by the stack's common shift): for the images of a no-flow stack,
    /// whose joint solutions lie within about a bound of `prior`. [`refit_dots`] then makes its
    /// first pass (every dot with its neighbours held at `prior`) by one Gauss-Newton step from
    /// `prior` with the Fisher matrix of the dot's window computed here (with its fit's weights),
    /// where that step is within 2 of its standard deviations (else the dot is fitted, without
    /// checking the weights again at the solution: a model one bound away changes them far less
    /// than the check looks for; on the real stack the positions with and without the check
    /// agree to a median 4e-10, a 99th percentile 0.017 of the bound), and
    /// solves the rest of the neighbour iteration on the map instead of refitting dots: each
    /// dot's first-order response to its neighbours' changes, `F⁻¹ C` per overlapping neighbour
    /// (from the Fisher matrix of its window and the cross terms with the neighbour's model),
    /// computed here once for all images, solved by red-black Gauss-Seidel sweeps on the dots'
    /// parameter vectors (`src/coupling.rs`). The neighbours of every window in that first pass
    /// are those of `prior`. The records then carry the first pass's χ² and the bound of the dot
    /// alone (not the joint bound: a stack image's fits give positions only). Where the
    /// linearisation does not hold (a dot found in the image that `prior` did not model, or
    /// sweeps that do not settle) [`refit_dots`] runs the pixel iteration as without the map.
    /// `img`: an image of the scene, for which pixels a fit may use (inside, `mask`, not
    /// saturated); `noise` gives the weights.
    pub fn coupled(
        prior: &[DotFit],
        seeds: &[Seed],
        cfg: &FitConfig,
        img: &Image,
        mask: Option<&Mask>,
        noise: &NoiseModel,
    ) -> NeighbourTails {
        // (one neighbourhood of `prior` for the tails and the map)
        let hood = Neighbourhood::new(prior, seeds, cfg.sampling);
        let mut tails = NeighbourTails::render(&hood, prior.len(), cfg, img.width(), img.height());
        if prior.len() == seeds.len()
            && cfg.neighbours == Neighbours::Subtract
            && cfg.estimator == Estimator::Lsg
        {
            tails.coupling = Some(std::sync::Arc::new(coupling_map(
                &hood, prior, cfg, img, mask, noise,
            )));
        }
        tails
    }

    /// The tails over seed `i`'s window if it is `win`, with the number of neighbours.
    fn for_window(&self, i: usize, win: Window) -> Option<(&[f64], u32)> {
        (self.windows.get(i).copied().flatten() == Some(win)).then(|| {
            (
                &self.values[self.start[i]..self.start[i + 1]],
                self.count[i],
            )
        })
    }
}

/// Neighbours with a smaller share of their squared profile inside a window are left out of
/// the linear coupling map. Nearly every neighbour whose 5σ box reaches the window: a share is
/// no measure of the pull (on the real stack, leaving out shares below 1e-3 left the positions
/// a median 0.09 bound off); the map itself decides which links are kept (see
/// `coupling::MIN_LINK`).
const COUPLING_SHARE: f64 = 1e-7;

/// The linear coupling map of `prior` (see [`NeighbourTails::coupled`]); `hood`: its
/// neighbourhood.
fn coupling_map(
    hood: &Neighbourhood,
    prior: &[DotFit],
    cfg: &FitConfig,
    img: &Image,
    mask: Option<&Mask>,
    noise: &NoiseModel,
) -> crate::coupling::Coupling {
    let seeds = hood.seeds;
    let kind = crate::eval::Kind::from_model(cfg.model);
    let blurred = cfg.sampling.image_model() != Sampling::Point;
    let rep = |g: &Gaussian2D| crate::coupling::rep(g, blurred);
    let (w, h) = (img.width(), img.height());
    let keep = |x: i64, y: i64| crate::joint::usable(img, mask, x, y);
    // every dot once, in its clipped window (a neighbour's window is not used)
    let dots: Vec<Option<JointDot>> = seeds
        .par_iter()
        .zip(prior)
        .map(|(s, f)| JointDot::from_theta(rep(&f.params), s.window.clip(w, h)?, kind))
        .collect();
    type PerDot = Option<(
        (
            [f64; 7],
            Vec<(u32, [crate::simd::LinkColumn; crate::joint::NB])>,
        ),
        Option<Looked>,
    )>;
    let per_dot: Vec<PerDot> = seeds
        .par_iter()
        .enumerate()
        .map_init(Vec::new, |near, (i, s)| {
            hood.models[i].as_ref()?;
            if s.flags.contains(DotFlags::MISSING) {
                return None;
            }
            let win = s.window.clip(w, h)?;
            let mut idx = Vec::new();
            let mut nbs = Vec::new();
            hood.touching(i, win, near, |j, m, same| {
                if same || m.share_in(win) < COUPLING_SHARE {
                    return;
                }
                if let Some(d) = dots.get(j).copied().flatten() {
                    idx.push(j);
                    nbs.push(d);
                }
            });
            // (no neighbour, or no map: the dot keeps its first-pass fit, and its moves reach
            // its neighbours; its scale is not known)
            let alone = ([f64::NAN; 7], Vec::new());
            let dot = dots[i]?;
            let Some(c) = crate::joint::coupling(kind, &dot, &nbs, noise, &keep) else {
                return Some((alone, None));
            };
            let looked = Looked::new(&c.fisher, kind.n_free(), win);
            if nbs.is_empty() {
                return Some((alone, looked));
            }
            Some((
                (
                    c.scale,
                    idx.into_iter()
                        .zip(&c.m)
                        .map(|(j, m)| (j as u32, crate::coupling::Coupling::link(kind, m)))
                        .collect(),
                ),
                looked,
            ))
        })
        .collect();
    let (links, looked): (Vec<crate::coupling::DotLinks>, Vec<Option<Looked>>) = per_dot
        .into_iter()
        .map(|d| match d {
            Some((l, k)) => (Some(l), k),
            None => (None, None),
        })
        .unzip();
    crate::coupling::Coupling::new(
        kind,
        cfg.sampling,
        prior,
        seeds.iter().map(is_red).collect(),
        links,
        looked,
        seeds.iter().map(|s| s.window.clip(w, h)).collect(),
    )
}

/// Fits whose size exceeds this many times the median of an image's usable fits, or whose
/// amplitude exceeds [`MAX_AMPLITUDE_RATIO`] times theirs, do not model a neighbour.
const MAX_SIGMA_RATIO: f64 = 3.0;
/// See [`MAX_SIGMA_RATIO`].
const MAX_AMPLITUDE_RATIO: f64 = 20.0;

/// Which fits may be subtracted from their neighbours' windows: usable (`is_ok`), with a
/// positive amplitude, and neither much wider nor much brighter than the image's typical dot
/// (median over the usable fits of the first models). At low SNR a fit can wander off to a
/// wide blob whose amplitude is balanced by a negative background: subtracted over its 5σ box
/// such a model ruins every neighbour, whose fits then wander too, and the failure spreads
/// through the iteration (before this gate: 85 % of a peak-SNR-4.5 lattice after 40 passes).
#[derive(Clone, Copy, Debug)]
struct Plausible {
    max_sigma: f64,
    max_amplitude: f64,
}

impl Plausible {
    fn of(fits: &[DotFit]) -> Plausible {
        let usable = |f: &&DotFit| {
            f.status.is_ok()
                && f.params.is_valid()
                && f.params.amplitude > 0.0
                && f.params.amplitude.is_finite()
        };
        // (no usable fit: no bound)
        let median = |get: fn(&DotFit) -> f64| {
            let mut v: Vec<f64> = fits.iter().filter(usable).map(get).collect();
            let m = bostrack_core::median(&mut v);
            if m.is_nan() { f64::INFINITY } else { m }
        };
        // (the two medians side by side)
        let (sig, amp) = rayon::join(
            || median(|f| (f.params.sigma_x * f.params.sigma_y).sqrt()),
            || median(|f| f.params.amplitude),
        );
        Plausible {
            max_sigma: MAX_SIGMA_RATIO * sig,
            max_amplitude: MAX_AMPLITUDE_RATIO * amp,
        }
    }

    /// The neighbour model of `f` where the gate admits it.
    fn model(&self, f: &DotFit, sampling: FitSampling) -> Option<NeighbourModel> {
        self.admits(f)
            .then(|| NeighbourModel::new(f, sampling))
            .flatten()
    }

    fn admits(&self, f: &DotFit) -> bool {
        let g = &f.params;
        f.status.is_ok()
            && g.sigma_x <= self.max_sigma
            && g.sigma_y <= self.max_sigma
            && g.amplitude <= self.max_amplitude
    }
}

/// A fitted dot as it is subtracted from its neighbours' windows.
#[derive(Clone, Debug)]
struct NeighbourModel {
    /// Rendering parameters: the pixel-blurred dot with point sampling where `auto` sampling
    /// allows it (one `exp_grid`, no per-pixel correction), the fitted dot otherwise.
    theta: crate::eval::Theta,
    sampling: Sampling,
    /// Centre and 5σ reach (px).
    x0: f64,
    y0: f64,
    rx: f64,
    ry: f64,
    /// The parameters it was made of ([`NeighbourModel::made_of`]).
    params: Gaussian2D,
}

impl NeighbourModel {
    fn new(f: &DotFit, sampling: FitSampling) -> Option<NeighbourModel> {
        let g = &f.params;
        if !f.status.is_ok() || !g.is_valid() || g.amplitude.is_nan() || g.amplitude <= 0.0 {
            return None;
        }
        let (theta, sampling) = match sampling {
            FitSampling::Auto => match crate::eval::blurred_of(g) {
                (cs, b) if cs >= AUTO_SIGMA => (b, Sampling::Point),
                _ => (theta_from_gaussian(g), FitSampling::Auto.image_model()),
            },
            s => (theta_from_gaussian(g), s.image_model()),
        };
        Some(NeighbourModel {
            theta,
            sampling,
            x0: g.x0,
            y0: g.y0,
            rx: REACH_SIGMAS * g.sigma_x,
            ry: REACH_SIGMAS * g.sigma_y,
            params: *g,
        })
    }

    /// The linear map's parameters of `g` ([`crate::coupling::rep`]) where this model, made
    /// for `sampling`, was made of `g` (bit for bit) and its θ is that representation: a point
    /// model of `auto` (its θ pixel-blurred) for a `blurred` map, of `point` (θ itself)
    /// otherwise. `NeighbourModel::new` computes that θ as `rep` does, from the same `exp`,
    /// `exp` and `tanh`.
    fn map_rep(
        &self,
        g: &Gaussian2D,
        sampling: FitSampling,
        blurred: bool,
    ) -> Option<crate::eval::Theta> {
        let of_blur = match sampling {
            FitSampling::Auto => blurred,
            FitSampling::Point => !blurred,
            FitSampling::Integrated => false,
        };
        (of_blur && self.sampling == Sampling::Point && self.made_of(g)).then_some(self.theta)
    }

    /// This model moved to the position of `f`, where `f` differs from the parameters it was
    /// made of in its position alone (bit for bit): then exactly [`NeighbourModel::new`] of `f`
    /// (θ's position is the centre itself, which neither the pixel blur nor the choice of
    /// sampling reads).
    fn moved_to(&self, f: &DotFit) -> Option<NeighbourModel> {
        let (a, b) = (self.params.to_array(), f.params.to_array());
        let same = a[2..]
            .iter()
            .zip(&b[2..])
            .all(|(x, y)| x.to_bits() == y.to_bits());
        if !(same && f.status.is_ok() && f.params.is_valid()) {
            return None;
        }
        let mut m = self.clone();
        let g = &f.params;
        m.theta[crate::eval::IX] = g.x0;
        m.theta[crate::eval::IY] = g.y0;
        (m.x0, m.y0, m.params) = (g.x0, g.y0, *g);
        Some(m)
    }

    /// Whether the model was made of exactly these parameters (bit for bit).
    fn made_of(&self, g: &Gaussian2D) -> bool {
        self.params.to_array().map(f64::to_bits) == g.to_array().map(f64::to_bits)
    }

    /// The pixels whose area meets the 5σ box, clipped to a `width × height` image.
    fn pixel_box(&self, width: usize, height: usize) -> Option<PixelBox> {
        let lo = |c: f64, r: f64| (c - r - 0.5).ceil().max(0.0);
        let hi = |c: f64, r: f64, n: usize| (c + r + 0.5).floor().min(n as f64 - 1.0);
        let (x_lo, x_hi) = (lo(self.x0, self.rx), hi(self.x0, self.rx, width));
        let (y_lo, y_hi) = (lo(self.y0, self.ry), hi(self.y0, self.ry, height));
        // (NaN fails every comparison)
        (x_lo <= x_hi && y_lo <= y_hi).then_some(PixelBox {
            x_lo: x_lo as usize,
            x_hi: x_hi as usize,
            y_lo: y_lo as usize,
            y_hi: y_hi as usize,
        })
    }

    /// Renders the unit-amplitude factor over the pixel box `b` into `out` (row-major);
    /// returns its width and height.
    fn render(
        &self,
        b: PixelBox,
        out: &mut Vec<f64>,
        v: &mut Vec<f64>,
        q: &mut Vec<f64>,
    ) -> (usize, usize) {
        let (bw, bh) = (b.x_hi - b.x_lo + 1, b.y_hi - b.y_lo + 1);
        if out.len() < bw * bh {
            out.resize(bw * bh, 0.0);
        }
        let m = bw.max(bh);
        if v.len() < m {
            v.resize(m, 0.0);
            q.resize(m, 0.0);
        }
        crate::eval::factor_grid(
            &self.theta,
            self.sampling,
            b.x_lo as f64 - self.theta[crate::eval::IX],
            b.y_lo as f64 - self.theta[crate::eval::IY],
            bw,
            bh,
            out,
            v,
            q,
        );
        (bw, bh)
    }

    /// Zeroes the rendering in `ws.tmp` outside the pixel box, so that a window sees exactly
    /// the neighbour a [`Canvas`] holds.
    fn clip_to_box(&self, ws: &mut crate::eval::Workspace) {
        let Some(b) = self.pixel_box(usize::MAX, usize::MAX) else {
            let n = ws.len();
            ws.tmp[..n].fill(0.0);
            return;
        };
        // the window's columns (rows) inside the box: `a..z` (`a == z`: none)
        let span = |w0: i64, n: usize, lo: usize, hi: usize| {
            let n = n as i128;
            let a = (lo as i128 - i128::from(w0)).clamp(0, n);
            let z = (hi as i128 - i128::from(w0) + 1).clamp(a, n);
            (a as usize, z as usize)
        };
        let (w, h) = (ws.w, ws.h);
        let (i0, i1) = span(ws.wx, w, b.x_lo, b.x_hi);
        let (j0, j1) = span(ws.wy, h, b.y_lo, b.y_hi);
        for (j, row) in ws.tmp[..w * h].chunks_exact_mut(w.max(1)).enumerate() {
            if (j0..j1).contains(&j) {
                row[..i0].fill(0.0);
                row[i1..].fill(0.0);
            } else {
                row.fill(0.0);
            }
        }
    }

    /// The share of the dot's squared profile `∫G²` that falls on the pixel area of `w` (the
    /// product of the two marginal shares: exact for ρ = 0; `G²` has σ/√2 per axis).
    fn share_in(&self, w: Window) -> f64 {
        let axis = |c: f64, r: f64, lo: i64, n: usize| {
            let s = r / REACH_SIGMAS;
            let (a, b) = (lo as f64 - 0.5 - c, (lo + n as i64) as f64 - 0.5 - c);
            (0.5 * (erf_fast(b / s) - erf_fast(a / s))).clamp(0.0, 1.0)
        };
        axis(self.x0, self.rx, w.x, w.width) * axis(self.y0, self.ry, w.y, w.height)
    }

    /// Whether the dot's 5σ ellipse-bounding box touches the window's pixel area.
    fn reaches(&self, w: Window) -> bool {
        self.x0 + self.rx >= w.x as f64 - 0.5
            && self.x0 - self.rx <= (w.x + w.width as i64) as f64 - 0.5
            && self.y0 + self.ry >= w.y as f64 - 0.5
            && self.y0 - self.ry <= (w.y + w.height as i64) as f64 - 0.5
    }
}

/// From here on [`erf_fast`] is ±1 exactly in `f64` (its erfc below half an ulp of 1): returned
/// without the series (about half of a screening share's arguments lie beyond).
const ERF_ONE: f64 = 6.0;

/// erf(x) to 1.2e-7 absolute (Numerical Recipes' `erfcc`, Chebyshev fit of erfc): a screening
/// share needs no more, at a third of the cost of `libm::erf`.
fn erf_fast(x: f64) -> f64 {
    if x.abs() >= ERF_ONE {
        // (t·exp(p) < 2.2e-17 in the series: 1 − erfc rounds to 1 exactly)
        return x.signum();
    }
    erf_series(x)
}

/// The series of [`erf_fast`], for every `x`.
fn erf_series(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let p = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let erfc = t * p.exp();
    if x >= 0.0 { 1.0 - erfc } else { erfc - 1.0 }
}

fn fit_seed(
    f: &mut Fitter,
    img: &Image,
    mask: Option<&Mask>,
    s: &Seed,
    hint: Option<&Gaussian2D>,
    noise: &NoiseModel,
) -> DotFit {
    if s.flags.contains(DotFlags::MISSING) {
        let mut fit = DotFit {
            index: s.index,
            params: Gaussian2D {
                x0: f64::NAN,
                y0: f64::NAN,
                amplitude: f64::NAN,
                sigma_x: f64::NAN,
                sigma_y: f64::NAN,
                rho: f64::NAN,
                background: f64::NAN,
            },
            crlb_x: f64::NAN,
            crlb_y: f64::NAN,
            rms: f64::NAN,
            iterations: 0,
            status: FitStatus::NotFitted,
            flags: s.flags,
        };
        fit.flags |= DotFlags::FIT_FAILED;
        return fit;
    }
    let mut fit = f.fit_window(img, mask, s.window, s.centre, hint, noise);
    fit.index = s.index;
    fit.flags |= s.flags;
    fit
}

/// Whether seed `s` holds no dot: flagged `MISSING` by the detector, and not found by its fit
/// (`fit`, the seed's current record) either.
fn absent(s: &Seed, fit: &DotFit) -> bool {
    s.flags.contains(DotFlags::MISSING) && !fit.status.is_ok()
}

/// Two seeds closer than 1.5 px are the same dot found twice: never subtract one from the other.
fn same_seed(a: &Seed, b: &Seed) -> bool {
    let (dx, dy) = (a.centre[0] - b.centre[0], a.centre[1] - b.centre[1]);
    dx * dx + dy * dy < 1.5 * 1.5
}

/// The pairs of seeds closer than 1.5 px to each other ([`same_seed`]: one dot found twice,
/// never subtracted from the other's window), both ways round, sorted: what a window's
/// subtraction from a [`Canvas`] adds back, fixed by the seeds (rare: most seeds have none).
struct Twins(Vec<(u32, u32)>);

impl Twins {
    /// The pairs of `seeds`; `parallel`: blocks of seeds on rayon's pool (never from inside a
    /// parallel region that may wait for the result, see [`Neighbourhood::find_twins`]).
    fn of(seeds: &[Seed], parallel: bool) -> Twins {
        let finite = |s: &Seed| s.centre.iter().all(|v| v.is_finite());
        let index = NeighbourIndex::of_points(
            seeds
                .iter()
                .map(|s| finite(s).then_some((s.centre[0], s.centre[1], 1.5))),
        );
        // the pairs of one seed, appended to `pairs`
        let pairs_of = |(mut near, mut pairs): (Vec<usize>, Vec<(u32, u32)>),
                        (i, s): (usize, &Seed)| {
            if finite(s) {
                // (a one-pixel window at the centre: the index looks 1.5 px beyond it)
                let [x, y] = s.centre.map(floor_i64);
                let win = Window::new(x, y, 1, 1);
                index.near_unsorted(win, &mut near);
                pairs.extend(
                    near.iter()
                        .filter(|&&j| j != i && same_seed(s, &seeds[j]))
                        .map(|&j| (i as u32, j as u32)),
                );
            }
            (near, pairs)
        };
        let mut pairs: Vec<(u32, u32)> = if parallel {
            // (blocks of seeds in parallel, each into one list, joined)
            seeds
                .par_iter()
                .enumerate()
                .with_min_len(256)
                .fold(|| (Vec::new(), Vec::new()), pairs_of)
                .map(|(_, pairs)| pairs)
                .reduce(Vec::new, |mut a, b| {
                    a.extend(b);
                    a
                })
        } else {
            seeds
                .iter()
                .enumerate()
                .fold((Vec::new(), Vec::new()), pairs_of)
                .1
        };
        pairs.sort_unstable();
        Twins(pairs)
    }

    /// The pairs `(i, j)` of seed `i`.
    fn with(&self, i: usize) -> &[(u32, u32)] {
        let i = i as u32;
        let lo = self.0.partition_point(|p| p.0 < i);
        let hi = lo + self.0[lo..].partition_point(|p| p.0 == i);
        &self.0[lo..hi]
    }
}

/// `x.floor() as i64` (saturating; NaN gives 0), without the call to `floor` that the
/// baseline x86-64 target makes of it (no SSE4.1 rounding instruction): the neighbour index
/// keys ~10⁶ points per real frame.
#[inline]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// A point's bucket coordinates and reach ([`NeighbourIndex::of_keys`]).
type Keyed = ((i64, i64), f64);

/// Fitted dots bucketed on a coarse grid, for finding the neighbours of a window.
struct NeighbourIndex {
    reach: f64,
    /// Grid origin (cell coordinates of bucket 0) and size.
    cx0: i64,
    cy0: i64,
    nx: usize,
    ny: usize,
    /// Bucket `k` holds `items[start[k]..start[k + 1]]` (ascending dot indices).
    start: Vec<u32>,
    items: Vec<u32>,
}

impl NeighbourIndex {
    /// The side of a bucket (px).
    const CELL: f64 = 16.0;

    /// The bucket coordinates of a point.
    fn key_of(x: f64, y: f64) -> (i64, i64) {
        (floor_i64(x / Self::CELL), floor_i64(y / Self::CELL))
    }

    /// The index of the models (their buckets found in parallel: the index is rebuilt after
    /// every pass that moves a dot to another bucket).
    fn new(models: &[Option<NeighbourModel>]) -> NeighbourIndex {
        let keyed: Vec<Option<Keyed>> = models
            .par_iter()
            .with_min_len(1024)
            .map(|m| {
                m.as_ref()
                    .map(|m| (Self::key_of(m.x0, m.y0), m.rx.max(m.ry)))
            })
            .collect();
        NeighbourIndex::of_keys(&keyed)
    }

    /// The index of points `(x, y, reach)` (`None`: no point, its number kept).
    fn of_points(points: impl Iterator<Item = Option<(f64, f64, f64)>>) -> NeighbourIndex {
        let keyed: Vec<Option<Keyed>> = points
            .map(|p| p.map(|(x, y, r)| (Self::key_of(x, y), r)))
            .collect();
        NeighbourIndex::of_keys(&keyed)
    }

    /// The index of points given by their buckets and reaches.
    fn of_keys(keyed: &[Option<Keyed>]) -> NeighbourIndex {
        let mut reach: f64 = 0.0;
        let (mut lo, mut hi) = ((i64::MAX, i64::MAX), (i64::MIN, i64::MIN));
        for &((kx, ky), r) in keyed.iter().flatten() {
            reach = reach.max(r);
            lo = (lo.0.min(kx), lo.1.min(ky));
            hi = (hi.0.max(kx), hi.1.max(ky));
        }
        if lo.0 > hi.0 {
            return NeighbourIndex {
                reach,
                cx0: 0,
                cy0: 0,
                nx: 0,
                ny: 0,
                start: vec![0],
                items: Vec::new(),
            };
        }
        let (nx, ny) = ((hi.0 - lo.0 + 1) as usize, (hi.1 - lo.1 + 1) as usize);
        let bucket = |(kx, ky): (i64, i64)| (ky - lo.1) as usize * nx + (kx - lo.0) as usize;
        // counting sort into buckets (indices stay ascending within a bucket)
        let mut start = vec![0u32; nx * ny + 1];
        for &(k, _) in keyed.iter().flatten() {
            start[bucket(k) + 1] += 1;
        }
        for k in 0..nx * ny {
            start[k + 1] += start[k];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; start[nx * ny] as usize];
        for (i, p) in keyed.iter().enumerate() {
            if let Some((k, _)) = p {
                let b = bucket(*k);
                items[fill[b] as usize] = i as u32;
                fill[b] += 1;
            }
        }
        NeighbourIndex {
            reach,
            cx0: lo.0,
            cy0: lo.1,
            nx,
            ny,
            start,
            items,
        }
    }

    /// The bucket coordinates of a model's centre.
    fn key(&self, m: &NeighbourModel) -> (i64, i64) {
        Self::key_of(m.x0, m.y0)
    }

    /// Writes into `out` the indices of the fitted dots whose centre is within the largest
    /// reach of the window, in bucket order (deterministic, not ascending).
    fn near_unsorted(&self, w: Window, out: &mut Vec<usize>) {
        out.clear();
        if self.nx == 0 {
            return;
        }
        let cells = |lo: f64, hi: f64, c0: i64, n: usize| {
            let a = (floor_i64(lo / Self::CELL) - c0).max(0);
            let b = (floor_i64(hi / Self::CELL) - c0).min(n as i64 - 1);
            (a, b)
        };
        let (x0, x1) = cells(
            w.x as f64 - 0.5 - self.reach,
            (w.x + w.width as i64) as f64 + self.reach,
            self.cx0,
            self.nx,
        );
        let (y0, y1) = cells(
            w.y as f64 - 0.5 - self.reach,
            (w.y + w.height as i64) as f64 + self.reach,
            self.cy0,
            self.ny,
        );
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                let k = cy as usize * self.nx + cx as usize;
                let items = &self.items[self.start[k] as usize..self.start[k + 1] as usize];
                out.extend(items.iter().map(|&i| i as usize));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::erf_fast;

    /// `floor_i64` is `floor() as i64` everywhere: integers, halves, both signs, the ends of
    /// the `i64` range, ±∞ and NaN.
    #[test]
    fn floor_to_integer_as_the_library_does() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.5,
            -2.5,
            1e-300,
            -1e-300,
            1e15 + 0.5,
        ];
        xs.extend([
            -1e15 - 0.5,
            9.3e18,
            -9.3e18,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ]);
        xs.extend([
            f64::NAN,
            i64::MAX as f64,
            i64::MIN as f64,
            4503599627370495.5,
        ]);
        xs.extend((-4000..4000).map(|k| k as f64 * 0.37 - 3.0));
        for x in xs {
            assert_eq!(super::floor_i64(x), x.floor() as i64, "{x}");
        }
    }

    /// A converged fit of `g` (the neighbour-model tests).
    fn converged(g: bostrack_core::Gaussian2D) -> bostrack_core::DotFit {
        bostrack_core::DotFit {
            index: bostrack_core::GridIndex::new(3, 4),
            params: g,
            crlb_x: 0.01,
            crlb_y: 0.01,
            rms: 1.0,
            iterations: 5,
            status: bostrack_core::FitStatus::Converged,
            flags: bostrack_core::DotFlags::NONE,
        }
    }

    /// The neighbour-model tests' dot of shape `sx`, `sy`, `rho`.
    fn test_dot(sx: f64, sy: f64, rho: f64) -> bostrack_core::Gaussian2D {
        bostrack_core::Gaussian2D {
            x0: 10.25,
            y0: 7.5,
            amplitude: 800.0,
            sigma_x: sx,
            sigma_y: sy,
            rho,
            background: 90.0,
        }
    }

    /// The canvas is the sum of every model rendered over its own pixel box: dots of several
    /// sizes (boxes from 5 to 61 rows, taller than a band), some at the image's edges, on an
    /// image whose height is no multiple of a band, drawn into a new buffer and into a used one,
    /// on one thread and on three.
    #[test]
    fn a_canvas_is_the_sum_of_its_models() {
        use super::{Canvas, FitSampling, NeighbourModel};
        use bostrack_core::Gaussian2D;
        let (w, h) = (90usize, 157usize);
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let models: Vec<Option<NeighbourModel>> = (0..120)
            .map(|k| {
                if k % 17 == 5 {
                    return None;
                }
                let sigma = [0.4, 1.3, 2.2, 6.0][k % 4];
                let g = Gaussian2D {
                    x0: -3.0 + (w as f64 + 6.0) * next(),
                    y0: -3.0 + (h as f64 + 6.0) * next(),
                    amplitude: 100.0 + 900.0 * next(),
                    sigma_x: sigma * (0.8 + 0.4 * next()),
                    sigma_y: sigma * (0.8 + 0.4 * next()),
                    rho: 0.6 * (next() - 0.5),
                    background: 50.0,
                };
                NeighbourModel::new(&converged(g), FitSampling::Auto)
            })
            .collect();
        let mut want = vec![0.0f64; w * h];
        let (mut out, mut v, mut q) = (Vec::new(), Vec::new(), Vec::new());
        let mut tallest = 0;
        for m in models.iter().flatten() {
            let Some(b) = m.pixel_box(w, h) else { continue };
            tallest = tallest.max(b.y_hi - b.y_lo + 1);
            let (bw, bh) = m.render(b, &mut out, &mut v, &mut q);
            for jj in 0..bh {
                for ii in 0..bw {
                    want[(b.y_lo + jj) * w + b.x_lo + ii] +=
                        m.theta[crate::eval::IA] * out[jj * bw + ii];
                }
            }
        }
        assert!(tallest > super::BAND, "{tallest}");
        let scale = want.iter().fold(0.0f64, |a, &b| a.max(b.abs()));
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            for used in [Vec::new(), vec![7.5; 3 * w * h]] {
                let c = pool.install(|| Canvas::render(&models, w, h, used));
                assert_eq!(c.values.len(), w * h);
                for (k, (a, b)) in c.values.iter().zip(&want).enumerate() {
                    assert!((a - b).abs() <= 1e-12 * scale, "{threads} {k}: {a} {b}");
                }
            }
        }
    }

    /// A model moved to a fit that differs in its position alone is that fit's model, bit for
    /// bit, for every sampling and on both sides of the point model's threshold; any other
    /// change is not a move.
    #[test]
    fn a_moved_model_is_the_model_of_the_moved_fit() {
        use super::{FitSampling, NeighbourModel};
        use bostrack_core::{DotFit, FitStatus, Gaussian2D};
        let fit = converged;
        let bits = |m: &NeighbourModel| {
            let mut v: Vec<u64> = m.theta.iter().map(|t| t.to_bits()).collect();
            v.extend([m.x0, m.y0, m.rx, m.ry].map(f64::to_bits));
            v.extend(m.params.to_array().map(f64::to_bits));
            (v, m.sampling)
        };
        let mut checked = 0;
        for sampling in [
            FitSampling::Auto,
            FitSampling::Point,
            FitSampling::Integrated,
        ] {
            for (sx, sy, rho) in [(1.3, 1.1, 0.4), (0.35, 0.3, -0.2), (0.6, 0.9, 0.0)] {
                let g = test_dot(sx, sy, rho);
                let m = NeighbourModel::new(&fit(g), sampling).unwrap();
                for (dx, dy) in [(0.0, 0.0), (0.37, -1.2), (-41.9, 13.03)] {
                    let moved = Gaussian2D {
                        x0: g.x0 + dx,
                        y0: g.y0 + dy,
                        ..g
                    };
                    let want = NeighbourModel::new(&fit(moved), sampling).unwrap();
                    let got = m.moved_to(&fit(moved)).unwrap();
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "{sampling:?} {sx} {sy} {rho} {dx} {dy}"
                    );
                    checked += 1;
                }
                let wider = Gaussian2D {
                    sigma_x: sx * (1.0 + 1e-15),
                    ..g
                };
                assert!(m.moved_to(&fit(wider)).is_none());
                let failed = DotFit {
                    status: FitStatus::NotFitted,
                    ..fit(g)
                };
                assert!(m.moved_to(&failed).is_none());
            }
        }
        assert_eq!(checked, 27);
    }

    /// A neighbour model's `map_rep` is `coupling::rep` of the parameters it was made of, bit
    /// for bit, wherever it answers; it answers for every point model whose θ is that
    /// representation (blurred from `auto`, plain from `point`), and for no other parameters.
    #[test]
    fn a_models_map_rep_is_the_maps_rep() {
        use super::{FitSampling, NeighbourModel};
        use bostrack_core::Gaussian2D;
        let fit = converged;
        let mut answered = 0;
        for sampling in [
            FitSampling::Auto,
            FitSampling::Point,
            FitSampling::Integrated,
        ] {
            for (sx, sy, rho) in [(1.3, 1.1, 0.4), (0.35, 0.3, -0.2), (1.61, 1.38, -0.93)] {
                let g = test_dot(sx, sy, rho);
                let m = NeighbourModel::new(&fit(g), sampling).unwrap();
                for blurred in [true, false] {
                    let want = crate::coupling::rep(&g, blurred).map(f64::to_bits);
                    if let Some(t) = m.map_rep(&g, sampling, blurred) {
                        assert_eq!(t.map(f64::to_bits), want, "{sampling:?} {sx} {blurred}");
                        answered += 1;
                    }
                    // (the point model of its own sampling answers; wider parameters never)
                    let own = match sampling {
                        FitSampling::Auto => blurred && m.sampling == super::Sampling::Point,
                        FitSampling::Point => !blurred,
                        FitSampling::Integrated => false,
                    };
                    assert_eq!(
                        m.map_rep(&g, sampling, blurred).is_some(),
                        own,
                        "{sampling:?} {sx}"
                    );
                    let wider = Gaussian2D {
                        sigma_x: sx * (1.0 + 1e-15),
                        ..g
                    };
                    assert!(m.map_rep(&wider, sampling, blurred).is_none());
                }
            }
        }
        // auto: the one point model (the narrow dot, and the one narrow across its ρ of
        // −0.93, are integrated); point: all three
        assert_eq!(answered, 4);
    }

    /// `clip_to_box` keeps exactly the pixels of the window inside the model's pixel box (the
    /// rule of every pixel), for boxes inside, across and outside windows anywhere.
    #[test]
    fn clipping_keeps_the_pixels_inside_the_box() {
        use super::{NeighbourModel, Sampling};
        let mut ws = crate::eval::Workspace::default();
        let mut checked = 0;
        for (x0, y0, rx, ry) in [
            (5.3, 6.7, 4.1, 2.2),
            (0.2, -1.0, 3.0, 3.0),
            (40.0, 3.0, 2.0, 2.0),
        ] {
            let m = NeighbourModel {
                theta: [0.0; 7],
                sampling: Sampling::Point,
                x0,
                y0,
                rx,
                ry,
                params: bostrack_core::Gaussian2D::circular(x0, y0, 1.0, rx / 5.0, 0.0),
            };
            let b = m.pixel_box(usize::MAX, usize::MAX);
            for (wx, wy, w, h) in [(0, 0, 13, 11), (-4, -3, 9, 9), (6, 5, 7, 3), (30, 0, 20, 9)] {
                ws.resize(wx, wy, w, h);
                ws.tmp[..w * h].fill(1.0);
                m.clip_to_box(&mut ws);
                for j in 0..h {
                    for i in 0..w {
                        let (px, py) = (wx + i as i64, wy + j as i64);
                        let inside = b.is_some_and(|b| {
                            px >= b.x_lo as i64
                                && px <= b.x_hi as i64
                                && py >= b.y_lo as i64
                                && py <= b.y_hi as i64
                        });
                        assert_eq!(ws.tmp[j * w + i], if inside { 1.0 } else { 0.0 });
                        checked += usize::from(inside);
                    }
                }
            }
        }
        assert!(checked > 50, "{checked} pixels inside");
    }

    #[test]
    fn erf_fast_is_within_its_stated_error() {
        let mut worst = 0.0f64;
        for k in -8000..=8000 {
            let x = k as f64 * 1e-3;
            worst = worst.max((erf_fast(x) - libm::erf(x)).abs());
        }
        assert!(worst < 1.2e-7, "largest error {worst:e}");
        assert_eq!(erf_fast(-0.7), -erf_fast(0.7));
    }

    /// Beyond `ERF_ONE` the series itself gives ±1 exactly: the shortcut changes no share.
    #[test]
    fn erf_fast_is_one_exactly_where_it_skips_the_series() {
        let series = super::erf_series;
        for k in 0..=40_000 {
            let x = super::ERF_ONE + k as f64 * 1e-3;
            assert_eq!(series(x), 1.0, "{x}");
            assert_eq!(series(-x), -1.0, "{x}");
            assert_eq!(erf_fast(x), series(x));
            assert_eq!(erf_fast(-x), series(-x));
        }
        // and just below it the series is still used (not yet 1)
        assert!(erf_fast(5.0) < 1.0);
        assert_eq!(erf_fast(f64::INFINITY), 1.0);
    }

    /// The held ρ is the median where it differs from 0 by more than two standard errors, 0
    /// where it does not.
    #[test]
    fn held_rho_is_zero_only_where_the_fits_show_no_correlation() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let normal = Normal::new(0.0, 0.2).expect("a normal distribution");
        // ρ estimates of sd 0.2 (narrow dots): a median of 400 has a standard error of 0.0125
        let mut draw = |centre: f64| -> Vec<f64> {
            (0..400).map(|_| centre + normal.sample(&mut rng)).collect()
        };
        assert_eq!(super::held_rho(&mut draw(0.005)), 0.0);
        let r = super::held_rho(&mut draw(0.3));
        assert!((r - 0.3).abs() < 0.05, "{r}");
        let r = super::held_rho(&mut draw(-0.08));
        assert!((r + 0.08).abs() < 0.05, "{r}");
    }
}

#[cfg(test)]
mod link_tests {
    use super::{FitSampling, LinkRows, Links, Neighbourhood};
    use bostrack_core::{DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex, Seed, Window};

    /// Every operation on the flat rows against a `Vec` per row (pseudo-random pushes past
    /// the rows' room, entries set, removals, replacements).
    #[test]
    fn link_rows_behave_as_a_vec_per_row() {
        let n = 40;
        let mut model: Vec<Vec<(u32, f64)>> = (0..n)
            .map(|i| (0..(i % 5) as u32).map(|k| (k, k as f64 + 0.5)).collect())
            .collect();
        let blocks: Vec<super::RowBlock> = model
            .chunks(16)
            .map(|c| {
                let lens = c.iter().map(|r| r.len() as u32).collect();
                (c.concat(), lens)
            })
            .collect();
        let mut rows = LinkRows::from_blocks(&blocks, n);
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as usize
        };
        for step in 0..4000 {
            let i = next() % n;
            match next() % 4 {
                0 => {
                    let e = ((next() % 12) as u32, step as f64);
                    rows.push(i, e);
                    model[i].push(e);
                }
                1 => {
                    let e = ((next() % 12) as u32, step as f64);
                    rows.set(i, e);
                    match model[i].iter_mut().find(|x| x.0 == e.0) {
                        Some(x) => *x = e,
                        None => model[i].push(e),
                    }
                }
                2 => {
                    let j = (next() % 12) as u32;
                    rows.remove(i, j);
                    model[i].retain(|e| e.0 != j);
                }
                _ => {
                    let r: Vec<(u32, f64)> = (0..next() % 9)
                        .map(|k| (k as u32, -(step as f64)))
                        .collect();
                    rows.replace(i, &r);
                    model[i] = r;
                }
            }
            assert_eq!(rows.row(i), &model[i][..], "step {step}");
        }
        for (i, m) in model.iter().enumerate() {
            assert_eq!(rows.row(i), &m[..]);
        }
    }

    fn lattice(n: i32, shift: impl Fn(i32, i32) -> [f64; 2]) -> (Vec<Seed>, Vec<DotFit>) {
        let mut seeds = Vec::new();
        let mut fits = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let (x, y) = (10.0 + 7.0 * i as f64, 10.0 + 7.0 * j as f64);
                let d = shift(i, j);
                let index = GridIndex { i, j };
                seeds.push(Seed {
                    index,
                    predicted: [x, y],
                    centre: [x + d[0], y + d[1]],
                    window: Window::new(x as i64 - 4, y as i64 - 4, 9, 9),
                    flags: DotFlags::NONE,
                });
                fits.push(DotFit {
                    index,
                    params: Gaussian2D::circular(x + d[0], y + d[1], 100.0, 1.6, 10.0),
                    crlb_x: 0.01,
                    crlb_y: 0.01,
                    rms: 1.0,
                    iterations: 3,
                    status: FitStatus::Converged,
                    flags: DotFlags::NONE,
                });
            }
        }
        (seeds, fits)
    }

    fn sorted(r: &[(u32, f64)]) -> Vec<(u32, u64)> {
        let mut v: Vec<(u32, u64)> = r.iter().map(|&(j, s)| (j, s.to_bits())).collect();
        v.sort();
        v
    }

    /// Links carried from another image's iteration equal the links made anew from the current
    /// models where every model either stayed (its shares are the same) or moved by more than
    /// the relink distance (its shares are recomputed), where a dot is gone and where seed
    /// windows moved.
    #[test]
    fn carried_links_are_the_links_of_the_current_models() {
        let (seeds0, fits0) = lattice(12, |_, _| [0.0, 0.0]);
        let hood0 = Neighbourhood::new(&fits0, &seeds0, FitSampling::Auto);
        let memory = Links::new(&seeds0, &hood0).memory(&seeds0);
        assert!(memory.fits(&seeds0));
        // a flow region (dots 0.4 px off), one dot gone, two windows moved by a pixel
        let (mut seeds, mut fits) = lattice(12, |i, j| {
            if (4..8).contains(&i) && (3..9).contains(&j) {
                [0.4, -0.3]
            } else {
                [0.0, 0.0]
            }
        });
        fits[30].status = FitStatus::NotFitted;
        for k in [50, 51] {
            let w = seeds[k].window;
            seeds[k].window = Window::new(w.x + 1, w.y, w.width, w.height);
        }
        let hood = Neighbourhood::new(&fits, &seeds, FitSampling::Auto);
        let mut near = Vec::new();
        let carried = Links::carried(&memory, &seeds, &hood, &mut near);
        let fresh = Links::new(&seeds, &hood);
        let mut moved_rows = 0;
        for i in 0..seeds.len() {
            assert_eq!(sorted(carried.row(i)), sorted(fresh.row(i)), "row {i}");
            if sorted(memory.rows.row(i)) != sorted(fresh.row(i)) {
                moved_rows += 1;
            }
        }
        // (the test sees rows that did change)
        assert!(moved_rows > 40, "{moved_rows}");
        assert!(!(0..seeds.len()).any(|i| carried.row(i).iter().any(|e| e.0 == 30)));
    }
}
