//! Fitting every dot of an image, in parallel, with the neighbours' tails subtracted.

use crate::FitError;
use crate::config::{Estimator, FitConfig, Neighbours};
use crate::eval::{IA, theta_from_gaussian};
use crate::fit::Fitter;
use bostrack_core::{
    DotFit, DotFlags, FitStatus, Gaussian2D, Image, Mask, NoiseModel, Seed, Window,
};
use rayon::prelude::*;
use std::collections::HashMap;

/// Sigmas beyond which a neighbour's dot is taken as zero (exp(-12.5) ≈ 4e-6 of its peak).
const REACH_SIGMAS: f64 = 5.0;

/// Fits every seed's window (rayon over dots; the output is in the order of `seeds`).
///
/// Seeds flagged `MISSING` are not fitted (status `NotFitted`); every record carries its
/// seed's flags and grid index. With [`Neighbours::Subtract`] (the default, least-squares
/// estimator only) each dot is fitted again: the next fit sees its window minus the fitted
/// dots (without background) of every neighbour whose 5σ reach touches the window, and starts
/// from the previous fit; this is repeated `cfg.neighbour_passes` times (block Jacobi). Neighbours closer than `σ_i + σ_j` (or 1.5 px) are taken as the same
/// dot found twice and not subtracted.
pub fn fit_dots(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
) -> Result<Vec<DotFit>, FitError> {
    cfg.validate()?;
    if let Some(m) = mask.filter(|m| !m.matches(img)) {
        return Err(FitError::MaskSize {
            mask_w: m.width(),
            mask_h: m.height(),
            img_w: img.width(),
            img_h: img.height(),
        });
    }
    if cfg.neighbours == Neighbours::None
        || cfg.estimator != Estimator::Lsg
        || cfg.neighbour_passes == 0
    {
        return Ok(seeds
            .par_iter()
            .map_init(
                || Fitter::new(cfg),
                |f, s| fit_seed(f, img, mask, s, None, noise),
            )
            .collect());
    }
    // first neighbour models: the moment estimates (IWC record), which stop at the saddle
    // towards a touching neighbour, whereas a plain least-squares fit of a window holding two
    // touching dots can converge to one wide blob over both
    let iwc = FitConfig {
        estimator: Estimator::Iwc,
        bound: false,
        ..cfg.clone()
    };
    let mut prev: Vec<DotFit> = seeds
        .par_iter()
        .map_init(
            || Fitter::new(&iwc),
            |f, s| fit_seed(f, img, mask, s, None, noise),
        )
        .collect();
    for pass in 0..cfg.neighbour_passes {
        prev = subtract_pass(img, mask, seeds, cfg, noise, &prev, pass == 0);
    }
    Ok(prev)
}

/// One block-Jacobi pass: every dot refitted after subtracting its neighbours' fits of `prev`
/// (`first`: `prev` holds the moment estimates, so every dot is fitted even without neighbours).
fn subtract_pass(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
    prev: &[DotFit],
    first: bool,
) -> Vec<DotFit> {
    let index = NeighbourIndex::new(prev);
    seeds
        .par_iter()
        .enumerate()
        .map_init(
            || Fitter::new(cfg),
            |f, (i, s)| {
                if s.flags.contains(DotFlags::MISSING) {
                    return prev[i];
                }
                let flags = f.load_image(img, mask, s.window);
                let own = &prev[i];
                let win = Window::new(f.ws.wx, f.ws.wy, f.ws.w, f.ws.h);
                let mut subtracted = 0;
                for j in index.near(win) {
                    if j == i {
                        continue;
                    }
                    let nb = &prev[j].params;
                    if !reaches(nb, win) || same_seed(s, &seeds[j]) {
                        continue;
                    }
                    let th = theta_from_gaussian(nb);
                    crate::eval::dot_factor(&mut f.ws, &th, cfg.sampling);
                    let ws = &mut f.ws;
                    let n = ws.len();
                    for k in 0..n {
                        ws.data[k] -= ws.keep[k] * th[IA] * ws.tmp[k];
                    }
                    subtracted += 1;
                }
                if subtracted == 0 && !first {
                    return prev[i];
                }
                let (start, hint) = if own.status.is_ok() {
                    ([own.params.x0, own.params.y0], Some(own.params))
                } else {
                    (s.centre, None)
                };
                let mut fit = f.fit_loaded(flags, start, hint.as_ref(), noise);
                fit.index = s.index;
                fit.flags |= s.flags;
                fit
            },
        )
        .collect()
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

/// Whether the dot's 5σ ellipse-bounding box touches the window's pixel area.
fn reaches(g: &Gaussian2D, w: Window) -> bool {
    if !g.is_valid() || g.amplitude.is_nan() || g.amplitude <= 0.0 {
        return false;
    }
    let (rx, ry) = (REACH_SIGMAS * g.sigma_x, REACH_SIGMAS * g.sigma_y);
    g.x0 + rx >= w.x as f64 - 0.5
        && g.x0 - rx <= (w.x + w.width as i64) as f64 - 0.5
        && g.y0 + ry >= w.y as f64 - 0.5
        && g.y0 - ry <= (w.y + w.height as i64) as f64 - 0.5
}

/// Two seeds closer than 1.5 px are the same dot found twice: never subtract one from the other.
fn same_seed(a: &Seed, b: &Seed) -> bool {
    (a.centre[0] - b.centre[0]).hypot(a.centre[1] - b.centre[1]) < 1.5
}

/// Buckets of fitted dots on a coarse grid, for finding the neighbours of a window.
struct NeighbourIndex {
    cell: f64,
    reach: f64,
    buckets: HashMap<(i64, i64), Vec<usize>>,
}

impl NeighbourIndex {
    fn new(fits: &[DotFit]) -> NeighbourIndex {
        let mut reach: f64 = 0.0;
        let mut buckets: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
        let cell = 16.0;
        for (i, f) in fits.iter().enumerate() {
            let p = &f.params;
            if !f.status.is_ok() || !p.is_valid() {
                continue;
            }
            reach = reach.max(REACH_SIGMAS * p.sigma_x.max(p.sigma_y));
            let key = ((p.x0 / cell).floor() as i64, (p.y0 / cell).floor() as i64);
            buckets.entry(key).or_default().push(i);
        }
        NeighbourIndex {
            cell,
            reach,
            buckets,
        }
    }

    /// Indices of the fitted dots whose centre is within the largest reach of the window
    /// (ascending, so the subtraction order and hence the result are deterministic).
    fn near(&self, w: Window) -> Vec<usize> {
        let x0 = ((w.x as f64 - 0.5 - self.reach) / self.cell).floor() as i64;
        let x1 = (((w.x + w.width as i64) as f64 + self.reach) / self.cell).floor() as i64;
        let y0 = ((w.y as f64 - 0.5 - self.reach) / self.cell).floor() as i64;
        let y1 = (((w.y + w.height as i64) as f64 + self.reach) / self.cell).floor() as i64;
        let mut out = Vec::new();
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                if let Some(b) = self.buckets.get(&(cx, cy)) {
                    out.extend_from_slice(b);
                }
            }
        }
        out.sort_unstable();
        out
    }
}
