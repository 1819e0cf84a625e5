//! Rendering: background, dots over small windows, noise, quantisation.

use crate::config::{MaskConfig, SceneConfig};
use crate::rng::row_rng;
use crate::{SynthError, TruthDot};
use bostrack_core::{DotFlags, Gaussian2D, Image, ImageMeta, Mask, Window};
use bostrack_model::Sampling;
use rand_distr::{Distribution, Poisson, StandardNormal};
use rayon::prelude::*;

/// Rows per rendering strip. Fixed (not derived from the thread count), so the order in which
/// contributions are summed into a pixel, and hence every bit of the result, does not depend on
/// the number of threads.
const STRIP_ROWS: usize = 16;

/// The illumination factor `L(x, y)` of [`crate::BackgroundConfig`].
#[derive(Clone, Debug)]
pub(crate) struct Illumination<'a> {
    cfg: &'a SceneConfig,
    centre: [f64; 2],
    inv_r2_corner: f64,
}

impl<'a> Illumination<'a> {
    pub(crate) fn new(cfg: &'a SceneConfig) -> Self {
        let (w, h) = (cfg.width as f64, cfg.height as f64);
        let centre = cfg
            .background
            .vignetting_centre
            .unwrap_or([(w - 1.0) / 2.0, (h - 1.0) / 2.0]);
        // Farthest pixel-area corner from the centre.
        let r2 = [
            [-0.5, -0.5],
            [w - 0.5, -0.5],
            [-0.5, h - 0.5],
            [w - 0.5, h - 0.5],
        ]
        .iter()
        .map(|c| (c[0] - centre[0]).powi(2) + (c[1] - centre[1]).powi(2))
        .fold(0.0, f64::max);
        Illumination {
            cfg,
            centre,
            inv_r2_corner: if r2 > 0.0 { 1.0 / r2 } else { 0.0 },
        }
    }

    /// `L(x, y)`.
    pub(crate) fn at(&self, x: f64, y: f64) -> f64 {
        let b = &self.cfg.background;
        let mut l = 1.0;
        if b.vignetting > 0.0 {
            let r2 = (x - self.centre[0]).powi(2) + (y - self.centre[1]).powi(2);
            l *= (1.0 - b.vignetting * r2 * self.inv_r2_corner).max(0.0);
        }
        for r in &b.dark {
            let s = smooth_box(x, r.x, r.edge) * smooth_box(y, r.y, r.edge);
            l *= 1.0 - (1.0 - r.factor) * s;
        }
        l
    }
}

/// `½(tanh((t - lo)/edge) - tanh((t - hi)/edge))`, a sharp box for `edge = 0`, 1 for no interval.
fn smooth_box(t: f64, iv: Option<[f64; 2]>, edge: f64) -> f64 {
    let Some([lo, hi]) = iv else { return 1.0 };
    if edge <= 0.0 {
        return if t >= lo && t <= hi { 1.0 } else { 0.0 };
    }
    let step = |a: f64| {
        if a.is_infinite() {
            a.signum()
        } else {
            a.tanh()
        }
    };
    0.5 * (step((t - lo) / edge) - step((t - hi) / edge))
}

/// The mask of the scene, if it has one.
pub fn scene_mask(cfg: &SceneConfig) -> Option<Mask> {
    let m = cfg.mask.as_ref()?;
    let ill = Illumination::new(cfg);
    Some(Mask::from_fn(cfg.width, cfg.height, |x, y| {
        let (xf, yf) = (x as f64, y as f64);
        match m {
            MaskConfig::Rect { x: xi, y: yi } => {
                xf >= xi[0] && xf <= xi[1] && yf >= yi[0] && yf <= yi[1]
            }
            MaskConfig::Circle { centre, radius } => {
                (xf - centre[0]).hypot(yf - centre[1]) <= *radius
            }
            MaskConfig::Illumination { min } => ill.at(xf, yf) >= *min,
        }
    }))
}

/// The window a dot is drawn over, `round(x0) ± ceil(k σx + 1)` (likewise in y), clipped to a
/// `w × h` image; `None` if it misses the image. Computed in f64 before any integer conversion,
/// so dots far away (or absurdly wide) cannot overflow the window arithmetic.
pub(crate) fn render_window(g: &Gaussian2D, k: f64, w: usize, h: usize) -> Option<Window> {
    let hx = (k * g.sigma_x + 1.0).ceil();
    let hy = (k * g.sigma_y + 1.0).ceil();
    let (cx, cy) = (g.x0.round(), g.y0.round());
    let x0 = (cx - hx).max(0.0);
    let y0 = (cy - hy).max(0.0);
    let x1 = (cx + hx).min(w as f64 - 1.0);
    let y1 = (cy + hy).min(h as f64 - 1.0);
    if !(x0 <= x1 && y0 <= y1) {
        return None;
    }
    Some(Window::new(
        x0 as i64,
        y0 as i64,
        (x1 - x0) as usize + 1,
        (y1 - y0) as usize + 1,
    ))
}

/// Columns `[xa, xb]` of the pixels of row `y` whose unit square meets the ellipse
/// `Q ≤ k²` of the dot, `Q = q/(1-ρ²)` (docs/CONVENTIONS.md); `None` if the row misses it.
///
/// In units `u = (x-x0)/σx`, `v = (y-y0)/σy` the ellipse is `(u - ρv)² ≤ (1-ρ²)(k² - v²)`, so at
/// height `v` it spans `ρv ± s(v)`, `s(v) = sqrt((1-ρ²)(k² - v²))`. Over the pixel's interval
/// `v ∈ [a, b]` the right end `ρv + s(v)` is concave with its maximum at `v = kρ`, the left end
/// convex with its minimum at `v = -kρ`: clamping those to `[a, b]` gives the exact extent.
/// The light outside the ellipse is `exp(-k²/2)` of the volume (1.5e-8 at k = 6).
fn ellipse_row(g: &Gaussian2D, y: i64, k: f64) -> Option<(i64, i64)> {
    let a = ((y as f64 - 0.5 - g.y0) / g.sigma_y).max(-k);
    let b = ((y as f64 + 0.5 - g.y0) / g.sigma_y).min(k);
    if a > b {
        return None;
    }
    let r = g.rho;
    let c = 1.0 - r * r;
    let s = |v: f64| (c * (k * k - v * v)).max(0.0).sqrt();
    let v_hi = (k * r).clamp(a, b);
    let v_lo = (-k * r).clamp(a, b);
    let x_hi = g.x0 + g.sigma_x * (r * v_hi + s(v_hi));
    let x_lo = g.x0 + g.sigma_x * (r * v_lo - s(v_lo));
    Some(((x_lo - 0.5).ceil() as i64, (x_hi + 0.5).floor() as i64))
}

/// The noise-free image: background `level · L(x, y)` plus every dot not flagged MISSING, each
/// drawn with [`bostrack_model::add_dot`] over its window (see [`crate::RenderConfig`]).
/// Float samples (`ImageMeta::synthetic(64)`), no quantisation.
pub fn render_mean(cfg: &SceneConfig, dots: &[TruthDot]) -> Result<Image, SynthError> {
    cfg.validate()?;
    for d in dots {
        if !d.params.is_valid() {
            return Err(SynthError::InvalidDot {
                i: d.index.i,
                j: d.index.j,
            });
        }
    }
    let (w, h) = (cfg.width, cfg.height);
    let ill = Illumination::new(cfg);
    let level = cfg.background.level;
    let mut data = vec![0.0; w * h];
    data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, v) in row.iter_mut().enumerate() {
            *v = level * ill.at(x as f64, y as f64);
        }
    });

    // Clipped window of each drawn dot, bucketed by strip in truth order.
    let n_strips = h.div_ceil(STRIP_ROWS);
    let mut buckets: Vec<Vec<(usize, Window)>> = vec![Vec::new(); n_strips];
    for (k, d) in dots.iter().enumerate() {
        if d.flags.contains(DotFlags::MISSING) {
            continue;
        }
        let Some(win) = render_window(&d.params, cfg.render.window_sigmas, w, h) else {
            continue;
        };
        let (y0, y1) = (win.y as usize, win.y as usize + win.height);
        for s in y0 / STRIP_ROWS..=(y1 - 1) / STRIP_ROWS {
            buckets[s].push((k, win));
        }
    }
    let sampling = cfg.render.sampling;
    data.par_chunks_mut(STRIP_ROWS * w)
        .zip(buckets.par_iter())
        .enumerate()
        .for_each(|(s, (strip, bucket))| {
            let r0 = (s * STRIP_ROWS) as i64;
            let r1 = r0 + (strip.len() / w) as i64;
            let mut buf = Vec::new();
            for &(k, win) in bucket {
                let g = &dots[k].params;
                let ya = win.y.max(r0);
                let yb = (win.y + win.height as i64).min(r1);
                if g.rho == 0.0 && sampling == Sampling::Integrated {
                    // Separable in the model (erf differences per column and per row): the
                    // whole rectangle costs little.
                    let sub = Window::new(win.x, ya, win.width, (yb - ya) as usize);
                    buf.clear();
                    buf.resize(sub.len(), 0.0);
                    bostrack_model::add_dot(g, sub, sampling, &mut buf);
                    for (r, src) in buf.chunks_exact(sub.width).enumerate() {
                        let off = ((ya - r0) as usize + r) * w + sub.x as usize;
                        for (d, s) in strip[off..off + sub.width].iter_mut().zip(src) {
                            *d += s;
                        }
                    }
                    continue;
                }
                // Per-pixel path: only the pixels that reach the k-sigma ellipse.
                for y in ya..yb {
                    let Some((xa, xb)) = ellipse_row(g, y, cfg.render.window_sigmas) else {
                        continue;
                    };
                    let xa = xa.max(win.x);
                    let xb = xb.min(win.x + win.width as i64 - 1);
                    if xb < xa {
                        continue;
                    }
                    let sub = Window::new(xa, y, (xb - xa + 1) as usize, 1);
                    buf.clear();
                    buf.resize(sub.len(), 0.0);
                    bostrack_model::add_dot(g, sub, sampling, &mut buf);
                    let off = (y - r0) as usize * w + xa as usize;
                    for (d, s) in strip[off..off + sub.width].iter_mut().zip(&buf) {
                        *d += s;
                    }
                }
            }
        });
    Ok(Image::new(w, h, data, ImageMeta::synthetic(64)).expect("size checked by validate"))
}

/// Noise and quantisation of a noise-free image `mean` (see [`crate::NoiseConfig`] and
/// [`SceneConfig::bits`]). Row `y` draws from its own RNG seeded by `(seed, y)`, so the result
/// depends on `seed` only, not on the number of threads.
pub fn add_noise(cfg: &SceneConfig, mean: &Image, seed: u64) -> Result<Image, SynthError> {
    cfg.validate()?;
    if mean.width() != cfg.width || mean.height() != cfg.height {
        return Err(crate::config::invalid(
            "width/height",
            format!(
                "the image is {}x{}, the scene {}x{}",
                mean.width(),
                mean.height(),
                cfg.width,
                cfg.height
            ),
        ));
    }
    let w = cfg.width;
    let n = &cfg.noise;
    let sat = cfg.saturation();
    let mut data = mean.data().to_vec();
    data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let mut rng = row_rng(seed, y);
        for v in row.iter_mut() {
            let mu = *v;
            let mut out = mu;
            if n.gain > 0.0 {
                let lambda = (mu - n.offset).max(0.0) / n.gain;
                let count = poisson(lambda, &mut rng);
                out = mu.min(n.offset) + n.gain * count;
            }
            if n.read_noise > 0.0 {
                let z: f64 = StandardNormal.sample(&mut rng);
                out += n.read_noise * z;
            }
            if let Some(s) = sat {
                out = out.round().clamp(0.0, s);
            }
            *v = out;
        }
    });
    Ok(
        Image::new(cfg.width, cfg.height, data, ImageMeta::synthetic(cfg.bits))
            .expect("same size as mean"),
    )
}

/// A Poisson draw (normal approximation above λ = 1e12, where the two agree to ~1e-6 relative
/// in every moment that matters here).
fn poisson(lambda: f64, rng: &mut impl rand::Rng) -> f64 {
    if lambda.is_nan() || lambda <= 0.0 {
        return 0.0;
    }
    if lambda > 1e12 {
        let z: f64 = StandardNormal.sample(rng);
        return (lambda + lambda.sqrt() * z).round().max(0.0);
    }
    match Poisson::new(lambda) {
        Ok(p) => p.sample(rng),
        Err(_) => lambda.round(),
    }
}

/// A noisy image of `dots`: [`render_mean`] then [`add_noise`] with noise seed `seed`.
pub fn render(cfg: &SceneConfig, dots: &[TruthDot], seed: u64) -> Result<Image, SynthError> {
    let mean = render_mean(cfg, dots)?;
    add_noise(cfg, &mean, seed)
}
