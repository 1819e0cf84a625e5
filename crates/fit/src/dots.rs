//! Fitting every dot of an image, in parallel, with the neighbours' tails subtracted.

use crate::FitError;
use crate::config::{AUTO_SIGMA, Estimator, FitConfig, FitSampling, Neighbours};
use crate::error::check_mask;
use crate::eval::{IA, conditional_sigma, pixel_blur, theta_from_gaussian};
use crate::fit::Fitter;
use bostrack_core::{
    DotFit, DotFlags, FitStatus, Gaussian2D, Image, Mask, NoiseModel, Seed, Window,
};
use bostrack_model::Sampling;
use rayon::prelude::*;

/// Sigmas beyond which a neighbour's dot is taken as zero (exp(-12.5) ≈ 4e-6 of its peak).
const REACH_SIGMAS: f64 = 5.0;

/// Fits every seed's window (rayon over dots; the output is in the order of `seeds`).
///
/// Seeds flagged `MISSING` are not fitted (status `NotFitted`); every record carries its
/// seed's flags and grid index. With [`Neighbours::Subtract`] (the default, least-squares
/// estimator only) each dot is fitted again: the next fit sees its window minus the fitted
/// dots (without background) of its neighbours, each over the pixels of its 5σ box (rendered
/// once per pass into an image-sized canvas, from which a window takes its values and adds its
/// own dot back), and starts from the previous fit; this is repeated `cfg.neighbour_passes`
/// times (block Jacobi). Seeds closer than 1.5 px are taken as the same dot found twice and
/// not subtracted from each other. The result does not depend on the number of threads.
pub fn fit_dots(
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
) -> Result<Vec<DotFit>, FitError> {
    cfg.validate()?;
    check_mask(img, mask)?;
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
    // one canvas allocation for all passes
    let mut canvas_buf = Vec::new();
    for pass in 0..cfg.neighbour_passes {
        let last = pass + 1 == cfg.neighbour_passes;
        let kind = SubtractPass {
            first: pass == 0,
            last,
            warm: false,
        };
        prev = subtract_pass(
            img,
            mask,
            seeds,
            cfg,
            noise,
            &prev,
            kind,
            None,
            &mut canvas_buf,
        );
    }
    Ok(prev)
}

/// Fits every seed's window once, starting from `prior` (one record per seed: fits of the same
/// dots in a similar image, e.g. the reference's fits moved by the camera's common shift, for
/// the images of a no-flow stack). The neighbours are modelled by the prior, noise included:
/// positions differ from [`fit_dots`]' by up to ~0.4 of the bound on an 8 px lattice at peak
/// SNR 100 (test `refit_with_tails_equals_refit_without_and_both_find_the_dots`); for a stack
/// that model is the same in every image, so the scatter (u_ref) is not affected.
///
/// With [`Neighbours::Subtract`] (least-squares estimator) each window first has the `prior`
/// dots of its neighbours subtracted: one block-Jacobi pass from `prior` instead of
/// [`fit_dots`]' moment estimates and `neighbour_passes` passes. Otherwise each window is
/// fitted from its prior's shape. A prior that is not a usable fit makes its dot start from
/// the seed (and, as a neighbour, not be subtracted).
///
/// `tails`: the neighbours' tails rendered once ([`NeighbourTails`], from the unmoved prior);
/// used for every window that is the one they were rendered for, instead of rendering the
/// `prior` neighbours again (the caller decides that `prior` moved little enough: see
/// [`NeighbourTails`]).
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
        return Ok(subtract_pass(
            img,
            mask,
            seeds,
            cfg,
            noise,
            prior,
            SubtractPass {
                first: true,
                last: true,
                warm: true,
            },
            tails,
            &mut Vec::new(),
        ));
    }
    Ok(seeds
        .par_iter()
        .zip(prior)
        .map_init(
            || Fitter::new(cfg),
            |f, (s, p)| {
                let hint = p.status.is_ok().then_some(&p.params);
                fit_seed(f, img, mask, s, hint, noise)
            },
        )
        .collect())
}

/// Which pass [`subtract_pass`] is: `first` (`prev` holds moment estimates: every dot is
/// fitted), `last` (the fits are final: full tolerance and the weights check), `warm` (`prev`
/// are least-squares fits of the same dots in an image of the same scene: the weights at the
/// start are right, no check).
#[derive(Clone, Copy)]
struct SubtractPass {
    first: bool,
    last: bool,
    warm: bool,
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
    kind: SubtractPass,
    tails: Option<&NeighbourTails>,
    canvas_buf: &mut Vec<f64>,
) -> Vec<DotFit> {
    let SubtractPass { first, last, warm } = kind;
    // every neighbour's rendering parameters once per pass, not once per window it reaches
    let hood = Neighbourhood::new(prev, seeds, cfg.sampling);
    // without rendered tails: every neighbour model once into one canvas
    let canvas = tails.is_none().then(|| {
        Canvas::render(
            &hood.models,
            img.width(),
            img.height(),
            std::mem::take(canvas_buf),
        )
    });
    let fits = seeds
        .par_iter()
        .enumerate()
        .map_init(
            || {
                let mut f = Fitter::new(cfg);
                f.intermediate = !last;
                f.warm = warm;
                (f, Vec::new())
            },
            |(f, near), (i, s)| {
                if s.flags.contains(DotFlags::MISSING) {
                    return prev[i];
                }
                let flags = f.load_image(img, mask, s.window);
                let own = &prev[i];
                let win = Window::new(f.ws.wx, f.ws.wy, f.ws.w, f.ws.h);
                let subtracted = match (tails.and_then(|t| t.for_window(i, win)), &canvas) {
                    (Some((sum, count)), _) => {
                        let ws = &mut f.ws;
                        for (k, v) in sum.iter().enumerate() {
                            ws.data[k] -= ws.keep[k] * v;
                        }
                        count
                    }
                    (None, Some(canvas)) => canvas.subtract_neighbours(&mut f.ws, i, &hood, near),
                    (None, None) => for_each_neighbour(&mut f.ws, i, &hood, near, |ws, amp| {
                        let n = ws.len();
                        for k in 0..n {
                            ws.data[k] -= ws.keep[k] * amp * ws.tmp[k];
                        }
                    }),
                };
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
        .collect();
    if let Some(c) = canvas {
        *canvas_buf = c.values;
    }
    fits
}

/// The fits of a pass as neighbour models (`None`: not a usable fit), bucketed for finding the
/// neighbours of a window.
struct Neighbourhood<'a> {
    seeds: &'a [Seed],
    models: Vec<Option<NeighbourModel>>,
    index: NeighbourIndex,
}

impl<'a> Neighbourhood<'a> {
    fn new(fits: &[DotFit], seeds: &'a [Seed], sampling: FitSampling) -> Neighbourhood<'a> {
        let models: Vec<Option<NeighbourModel>> = fits
            .par_iter()
            .map(|f| NeighbourModel::new(f, sampling))
            .collect();
        let index = NeighbourIndex::new(&models);
        Neighbourhood {
            seeds,
            models,
            index,
        }
    }

    /// Calls `f(j, model, same)` for every fitted dot `j ≠ i` whose 5σ reach touches `win`, in
    /// ascending `j`; `same`: seed `j` is closer than 1.5 px to seed `i` (the same dot found
    /// twice, never subtracted).
    fn touching(
        &self,
        i: usize,
        win: Window,
        near: &mut Vec<usize>,
        mut f: impl FnMut(usize, &NeighbourModel, bool),
    ) {
        self.index.near(win, near);
        for &j in near.iter() {
            let Some(m) = &self.models[j] else { continue };
            if j == i || !m.reaches(win) {
                continue;
            }
            f(j, m, same_seed(&self.seeds[i], &self.seeds[j]));
        }
    }
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

/// Rows per band of a [`Canvas`] (bands are rendered in parallel, each in dot order, so the
/// canvas does not depend on the number of threads).
const BAND: usize = 32;

/// Every neighbour model of a pass rendered once over its 5σ box into an image-sized canvas.
/// A window then has its neighbours subtracted by reading the canvas and adding back its own
/// dot (and a seed found twice), instead of rendering each of its ~8 neighbours over it: on the
/// real sample a 17 × 17 box per dot and pass instead of ~8 windows of 9 × 9.
struct Canvas {
    width: usize,
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
    /// Renders into `values` (any contents; resized to the image and zeroed band by band).
    fn render(
        models: &[Option<NeighbourModel>],
        width: usize,
        height: usize,
        mut values: Vec<f64>,
    ) -> Canvas {
        let boxes: Vec<Option<PixelBox>> = models
            .iter()
            .map(|m| m.as_ref().and_then(|m| m.pixel_box(width, height)))
            .collect();
        values.resize(width * height, 0.0);
        if width == 0 || height == 0 {
            return Canvas {
                width,
                values,
                boxes,
            };
        }
        let mut bands: Vec<Vec<u32>> = vec![Vec::new(); height.div_ceil(BAND)];
        for (j, b) in boxes.iter().enumerate() {
            if let Some(b) = b {
                for band in &mut bands[b.y_lo / BAND..=b.y_hi / BAND] {
                    band.push(j as u32);
                }
            }
        }
        values
            .par_chunks_mut(BAND * width)
            .zip(bands.par_iter())
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new(), Vec::new()),
                |(out, v, q), (band, (chunk, list))| {
                    chunk.fill(0.0);
                    let r0 = band * BAND;
                    let r1 = r0 + chunk.len() / width - 1;
                    for &j in list {
                        let (Some(m), Some(b)) = (&models[j as usize], boxes[j as usize]) else {
                            continue;
                        };
                        let part = PixelBox {
                            y_lo: b.y_lo.max(r0),
                            y_hi: b.y_hi.min(r1),
                            ..b
                        };
                        let (bw, bh) = m.render(part, out, v, q);
                        let amp = m.theta[IA];
                        for (jj, e) in out[..bw * bh].chunks_exact(bw).enumerate() {
                            let at = (part.y_lo - r0 + jj) * width + part.x_lo;
                            for (c, e) in chunk[at..at + bw].iter_mut().zip(e) {
                                *c += amp * e;
                            }
                        }
                    }
                },
            );
        Canvas {
            width,
            values,
            boxes,
        }
    }

    /// Subtracts from the loaded window of seed `i` every neighbour model as
    /// [`for_each_neighbour`] does (the canvas, minus the dot's own model and any seed closer
    /// than 1.5 px); returns how many neighbours touch the window.
    fn subtract_neighbours(
        &self,
        ws: &mut crate::eval::Workspace,
        i: usize,
        hood: &Neighbourhood,
        near: &mut Vec<usize>,
    ) -> u32 {
        let (w, h) = (ws.w, ws.h);
        if w == 0 || h == 0 {
            return 0;
        }
        let (wx, wy) = (ws.wx as usize, ws.wy as usize);
        for j in 0..h {
            let row = &self.values[(wy + j) * self.width + wx..][..w];
            let k0 = j * w;
            for ((d, kp), c) in ws.data[k0..k0 + w]
                .iter_mut()
                .zip(&ws.keep[k0..k0 + w])
                .zip(row)
            {
                *d -= kp * c;
            }
        }
        let win = Window::new(ws.wx, ws.wy, w, h);
        self.add_back(ws, i, &hood.models);
        let mut count = 0;
        hood.touching(i, win, near, |j, _, same| {
            if same {
                self.add_back(ws, j, &hood.models);
            } else {
                count += 1;
            }
        });
        count
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
        // (a prior of another length: no tails, every window is rendered by `refit_dots`)
        let same_length = prior.len() == seeds.len();
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
                    let count = for_each_neighbour(&mut f.ws, i, &hood, near, |ws, amp| {
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
        }
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

/// A fitted dot as it is subtracted from its neighbours' windows.
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
}

impl NeighbourModel {
    fn new(f: &DotFit, sampling: FitSampling) -> Option<NeighbourModel> {
        let g = &f.params;
        if !f.status.is_ok() || !g.is_valid() || g.amplitude.is_nan() || g.amplitude <= 0.0 {
            return None;
        }
        let th = theta_from_gaussian(g);
        let (theta, sampling) = match sampling {
            FitSampling::Auto if conditional_sigma(&th) >= AUTO_SIGMA => {
                (pixel_blur(&th), Sampling::Point)
            }
            s => (th, s.image_model()),
        };
        Some(NeighbourModel {
            theta,
            sampling,
            x0: g.x0,
            y0: g.y0,
            rx: REACH_SIGMAS * g.sigma_x,
            ry: REACH_SIGMAS * g.sigma_y,
        })
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
        let inside =
            |p: i64, lo: usize, hi: usize| p >= 0 && (p as usize) >= lo && (p as usize) <= hi;
        for j in 0..ws.h {
            let y_in = inside(ws.wy + j as i64, b.y_lo, b.y_hi);
            for i in 0..ws.w {
                if !(y_in && inside(ws.wx + i as i64, b.x_lo, b.x_hi)) {
                    ws.tmp[j * ws.w + i] = 0.0;
                }
            }
        }
    }

    /// Whether the dot's 5σ ellipse-bounding box touches the window's pixel area.
    fn reaches(&self, w: Window) -> bool {
        self.x0 + self.rx >= w.x as f64 - 0.5
            && self.x0 - self.rx <= (w.x + w.width as i64) as f64 - 0.5
            && self.y0 + self.ry >= w.y as f64 - 0.5
            && self.y0 - self.ry <= (w.y + w.height as i64) as f64 - 0.5
    }
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

/// Two seeds closer than 1.5 px are the same dot found twice: never subtract one from the other.
fn same_seed(a: &Seed, b: &Seed) -> bool {
    let (dx, dy) = (a.centre[0] - b.centre[0], a.centre[1] - b.centre[1]);
    dx * dx + dy * dy < 1.5 * 1.5
}

/// Fitted dots bucketed on a coarse grid, for finding the neighbours of a window.
struct NeighbourIndex {
    cell: f64,
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
    fn new(models: &[Option<NeighbourModel>]) -> NeighbourIndex {
        let cell = 16.0;
        let key = |m: &NeighbourModel| ((m.x0 / cell).floor() as i64, (m.y0 / cell).floor() as i64);
        let mut reach: f64 = 0.0;
        let (mut lo, mut hi) = ((i64::MAX, i64::MAX), (i64::MIN, i64::MIN));
        for m in models.iter().flatten() {
            reach = reach.max(m.rx.max(m.ry));
            let (kx, ky) = key(m);
            lo = (lo.0.min(kx), lo.1.min(ky));
            hi = (hi.0.max(kx), hi.1.max(ky));
        }
        if lo.0 > hi.0 {
            return NeighbourIndex {
                cell,
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
        let bucket = |m: &NeighbourModel| {
            let (kx, ky) = key(m);
            (ky - lo.1) as usize * nx + (kx - lo.0) as usize
        };
        // counting sort into buckets (dot indices stay ascending within a bucket)
        let mut start = vec![0u32; nx * ny + 1];
        for m in models.iter().flatten() {
            start[bucket(m) + 1] += 1;
        }
        for k in 0..nx * ny {
            start[k + 1] += start[k];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; start[nx * ny] as usize];
        for (i, m) in models.iter().enumerate() {
            if let Some(m) = m {
                let b = bucket(m);
                items[fill[b] as usize] = i as u32;
                fill[b] += 1;
            }
        }
        NeighbourIndex {
            cell,
            reach,
            cx0: lo.0,
            cy0: lo.1,
            nx,
            ny,
            start,
            items,
        }
    }

    /// Writes into `out` the indices of the fitted dots whose centre is within the largest
    /// reach of the window (ascending, so the subtraction order and hence the result are
    /// deterministic).
    fn near(&self, w: Window, out: &mut Vec<usize>) {
        out.clear();
        if self.nx == 0 {
            return;
        }
        let cells = |lo: f64, hi: f64, c0: i64, n: usize| {
            let a = ((lo / self.cell).floor() as i64 - c0).max(0);
            let b = ((hi / self.cell).floor() as i64 - c0).min(n as i64 - 1);
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
        out.sort_unstable();
    }
}
