//! From lattice sites with their dot-map peaks to seeds: found / faint / missing, rough centre,
//! fit window and flags.

use crate::filter::{Peak, dist2};
use crate::grow::{IndexGrid, Ring1};
use crate::linalg::{gauss_samples, hypot_exceeds, median, round_i64, window_centred};
use crate::{DetectConfig, LatticeKind};
use bostrack_core::{DotFlags, GridIndex, Image, Mask, Seed, Window};
use rayon::prelude::*;

/// Fewest sites (or seeds) per parallel task: below it, splitting costs more than it saves.
pub(crate) const PAR_MIN: usize = 256;

/// One lattice site before classification.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Site {
    pub index: GridIndex,
    /// Where the site is expected (grid map, or reference + predictor when tracking).
    pub predicted: [f64; 2],
    /// The dot-map peak chosen for the site, if any.
    pub peak: Option<Peak>,
    /// Extra signal-to-noise demanded when the decision rests on `peak` (a position found by a
    /// search, whose noise is biased upwards) rather than on `predicted`.
    pub peak_extra: f64,
    /// When tracking: the reference seed's centre and its (unclipped) fit window. The site's
    /// window is then that window moved by the whole pixels of the dot's displacement from the
    /// reference centre, instead of the window centred on its own centre.
    pub window_from: Option<([f64; 2], Window)>,
    /// When tracking a still dot: the template measure already taken at this point (the
    /// reference centre), in place of the one at the peak.
    pub measured: Option<([f64; 2], Measure)>,
}

/// A classified site.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Classified {
    pub seed: Seed,
    /// Template amplitude of the dot at its centre (counts); 0 when MISSING.
    pub contrast: f64,
}

/// Everything classification needs besides the sites.
#[derive(Debug)]
pub(crate) struct Ctx<'a> {
    pub img: &'a Image,
    pub sign: f64,
    pub mask: Option<&'a Mask>,
    /// Whether the image has non-finite samples (NAN_PIXELS is looked for only then).
    pub nonfinite: bool,
    pub spacing: f64,
    pub sigma: f64,
    /// Local lattice directions (for the MERGED test).
    pub a: [f64; 2],
    pub b: [f64; 2],
    pub cfg: &'a DetectConfig,
    /// Robust standard deviation of the template statistic ([`Template::eval`]) where there is
    /// no dot.
    pub noise: f64,
}

/// Rough shape of one dot, from its centroid window (compared only with the neighbours').
#[derive(Clone, Copy, Debug, Default)]
struct Shape {
    /// Template amplitude at the centre (counts, see [`Template::eval`]).
    amplitude: f64,
    /// Size `sqrt(M / (2π A))` from the summed weight M above that level (px).
    size: f64,
    /// Axis ratio of the intensity-weighted second moments (>= 1).
    elongation: f64,
    /// Weighted second central moments `[xx, yy, xy]`, for the direction of the major axis
    /// (computed only where the MERGED test needs it).
    mom: [f64; 3],
}

/// Mean of the finite samples (times `sign`) on the border of the pixel rectangle
/// `[x0, x1] x [y0, y1]`; NaN if there is none. `nonfinite`: whether the image may hold
/// non-finite samples (otherwise no sample is tested; the sum runs in the same order).
fn ring_mean(
    img: &Image,
    sign: f64,
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
    nonfinite: bool,
) -> f64 {
    if !nonfinite {
        let mut s = 0.0;
        for &v in &img.row(y0)[x0..=x1] {
            s += v;
        }
        let mut n = x1 - x0 + 1;
        if y1 > y0 {
            for &v in &img.row(y1)[x0..=x1] {
                s += v;
            }
            n += x1 - x0 + 1;
        }
        for y in y0 + 1..y1 {
            let row = &img.row(y)[x0..=x1];
            s += row[0];
            n += 1;
            if x1 > x0 {
                s += row[x1 - x0];
                n += 1;
            }
        }
        return sign * s / n as f64;
    }
    let (mut s, mut n) = (0.0, 0usize);
    let mut add = |v: f64| {
        if v.is_finite() {
            s += v;
            n += 1;
        }
    };
    for &v in &img.row(y0)[x0..=x1] {
        add(v);
    }
    if y1 > y0 {
        for &v in &img.row(y1)[x0..=x1] {
            add(v);
        }
    }
    for y in y0 + 1..y1 {
        let row = img.row(y);
        add(row[x0]);
        if x1 > x0 {
            add(row[x1]);
        }
    }
    if n == 0 {
        f64::NAN
    } else {
        sign * s / n as f64
    }
}

/// Scratch buffers of [`Template::measure`] (the separable weights of one window), reused
/// from one site to the next.
pub(crate) struct Scratch {
    gx: [f64; 64],
    gy: [f64; 64],
    wx: [f64; 64],
    wy: [f64; 64],
    wxd: [f64; 64],
    wxdd: [f64; 64],
}

impl Scratch {
    pub(crate) fn new() -> Self {
        Scratch {
            gx: [0.0; 64],
            gy: [0.0; 64],
            wx: [0.0; 64],
            wy: [0.0; 64],
            wxd: [0.0; 64],
            wxdd: [0.0; 64],
        }
    }
}

/// The per-row sums of [`Template::measure`] over finite samples, for `L` rows at once (one
/// lane per row, so that the sums of two rows share vector instructions): `r = Σ v g` (when
/// `TEMPLATE`), and with `wv = max(sign·v - tc, 0)`: `Σ wv w`, `Σ wv w dx`, `Σ wv w dx²` and
/// `max wv`, each accumulated left to right from 0, exactly as a row-by-row loop would.
#[inline(always)]
fn row_sums<const TEMPLATE: bool, const L: usize>(
    rows: [&[f64]; L],
    gx: &[f64],
    wx: &[f64],
    wxd: &[f64],
    wxdd: &[f64],
    sign: f64,
    tc: f64,
) -> RowSums<L> {
    let n = rows[0].len();
    let rows = rows.map(|r| &r[..n]);
    let (gx, wx, wxd, wxdd) = (&gx[..n], &wx[..n], &wxd[..n], &wxdd[..n]);
    let (mut r, mut r0, mut rx, mut rxx, mut peak) = (
        [0.0f64; L],
        [0.0f64; L],
        [0.0f64; L],
        [0.0f64; L],
        [0.0f64; L],
    );
    for k in 0..n {
        let (g, a, b, c) = (gx[k], wx[k], wxd[k], wxdd[k]);
        for l in 0..L {
            let v = rows[l][k];
            if TEMPLATE {
                r[l] += v * g;
            }
            // Finite samples: `max` without the NaN cases (a zero's sign cannot change a sum
            // that starts at +0).
            let d = sign * v - tc;
            let wv = if d > 0.0 { d } else { 0.0 };
            peak[l] = if wv > peak[l] { wv } else { peak[l] };
            r0[l] += wv * a;
            rx[l] += wv * b;
            rxx[l] += wv * c;
        }
    }
    RowSums {
        r,
        r0,
        rx,
        rxx,
        peak,
    }
}

/// [`row_sums`] of two rows of a window of the fixed width `N`: the loop over the columns is
/// unrolled, so that the sums of the two rows stay in vector registers (same operations in the
/// same order).
#[inline(always)]
fn row_sums_fixed<const TEMPLATE: bool, const N: usize>(
    rows: [&[f64]; 2],
    gx: &[f64],
    wx: &[f64],
    wxd: &[f64],
    wxdd: &[f64],
    sign: f64,
    tc: f64,
) -> RowSums<2> {
    let ra: &[f64; N] = rows[0][..N].try_into().unwrap();
    let rb: &[f64; N] = rows[1][..N].try_into().unwrap();
    let gx: &[f64; N] = gx[..N].try_into().unwrap();
    let wx: &[f64; N] = wx[..N].try_into().unwrap();
    let wxd: &[f64; N] = wxd[..N].try_into().unwrap();
    let wxdd: &[f64; N] = wxdd[..N].try_into().unwrap();
    let (mut r, mut r0, mut rx, mut rxx, mut peak) = (
        [0.0f64; 2],
        [0.0f64; 2],
        [0.0f64; 2],
        [0.0f64; 2],
        [0.0f64; 2],
    );
    for k in 0..N {
        let v = [ra[k], rb[k]];
        for l in 0..2 {
            if TEMPLATE {
                r[l] += v[l] * gx[k];
            }
            let d = sign * v[l] - tc;
            let wv = if d > 0.0 { d } else { 0.0 };
            peak[l] = if wv > peak[l] { wv } else { peak[l] };
            r0[l] += wv * wx[k];
            rx[l] += wv * wxd[k];
            rxx[l] += wv * wxdd[k];
        }
    }
    RowSums {
        r,
        r0,
        rx,
        rxx,
        peak,
    }
}

/// What [`row_sums`] returns, one lane per row.
struct RowSums<const L: usize> {
    r: [f64; L],
    r0: [f64; L],
    rx: [f64; L],
    rxx: [f64; L],
    peak: [f64; L],
}

/// The centroid of a dot (see [`Template::measure`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Blob {
    pub centre: [f64; 2],
    /// Weighted second central moments `[xx, yy, xy]` (px², with the Gaussian weight).
    pub mom: [f64; 3],
    /// Highest sample above the window-border level (counts).
    pub peak: f64,
    /// Sum of the weights (counts · px²).
    pub mass: f64,
}

/// What [`Template::measure`] returns: the template test at the start point and the centroid.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Measure {
    /// Template statistic `T` and amplitude `A` at the start point (see [`Template::eval`]).
    pub t: f64,
    pub a: f64,
    pub blob: Option<Blob>,
}

/// The matched-filter test of a dot at a sub-pixel point (see [`Template::eval`]).
#[derive(Clone, Debug)]
pub(crate) struct Template {
    /// Template sigma: the dot's sigma widened by the pixel, `sqrt(σ² + 1/12)`.
    sigma_t: f64,
    /// `-1/(2σt²)` and `exp(2 · that)`: the Gaussian sample recurrence of the template.
    inv2: f64,
    q: f64,
    /// Centroid weight sigma `σw = max(σt, 0.8)`, its `-1/(2σw²)` and `exp(2 · that)`.
    sw: f64,
    inv2w: f64,
    qw: f64,
    /// Window half-width: `ceil(2.5 σt)`, at least 1, at most round(spacing/2).
    half: usize,
    /// Where the local level is taken: `None` = the window's border (dots that fit in their
    /// cell); otherwise the offsets of the surrounding cell centres (overlapping dots, whose
    /// window border lies on the dot and its neighbours).
    cells: Option<Vec<[f64; 2]>>,
    /// Whether the image may hold non-finite samples (slower loop that skips them).
    nonfinite: bool,
}

impl Template {
    pub(crate) fn new(
        sigma: f64,
        spacing: f64,
        a: [f64; 2],
        b: [f64; 2],
        kind: LatticeKind,
        nonfinite: bool,
    ) -> Self {
        let sigma_t = (sigma * sigma + 1.0 / 12.0).sqrt();
        let want = (2.5 * sigma_t).ceil();
        let cell = (0.5 * spacing).round();
        let half = (want.min(cell) as usize).max(1);
        let cells = (want > cell).then(|| {
            let c = |p: f64, q: f64, d: f64| [(p * a[0] + q * b[0]) / d, (p * a[1] + q * b[1]) / d];
            match kind {
                LatticeKind::Square => vec![
                    c(1.0, 1.0, 2.0),
                    c(1.0, -1.0, 2.0),
                    c(-1.0, 1.0, 2.0),
                    c(-1.0, -1.0, 2.0),
                ],
                LatticeKind::Hexagonal => vec![
                    c(1.0, 1.0, 3.0),
                    c(-1.0, 2.0, 3.0),
                    c(-2.0, 1.0, 3.0),
                    c(-1.0, -1.0, 3.0),
                    c(1.0, -2.0, 3.0),
                    c(2.0, -1.0, 3.0),
                ],
            }
        });
        let inv2 = -0.5 / (sigma_t * sigma_t);
        let sw = sigma_t.max(0.8);
        let inv2w = -0.5 / (sw * sw);
        Template {
            sigma_t,
            inv2,
            q: (2.0 * inv2).exp(),
            sw,
            inv2w,
            qw: (2.0 * inv2w).exp(),
            half,
            cells,
            nonfinite,
        }
    }

    /// The local level for the test at `p`: the window border's mean `ring`, or for overlapping
    /// dots the mean of 3x3 pixel blocks at the surrounding cell centres.
    fn level(&self, img: &Image, sign: f64, p: [f64; 2], ring: f64) -> f64 {
        let Some(offsets) = &self.cells else {
            return ring;
        };
        let (w, h) = (img.width() as i64, img.height() as i64);
        let (mut s, mut n) = (0.0, 0usize);
        for o in offsets {
            let (cx, cy) = (round_i64(p[0] + o[0]), round_i64(p[1] + o[1]));
            let (x0, x1) = ((cx - 1).max(0), (cx + 1).min(w - 1));
            let (y0, y1) = ((cy - 1).max(0), (cy + 1).min(h - 1));
            if x0 > x1 || y0 > y1 {
                continue;
            }
            let (x0, x1) = (x0 as usize, x1 as usize);
            if !self.nonfinite && x1 == x0 + 2 && y1 == y0 + 2 {
                // The whole 3x3 block inside the image (the usual case), unrolled.
                for y in y0 as usize..=y1 as usize {
                    let row: &[f64; 3] = img.row(y)[x0..x0 + 3].try_into().unwrap();
                    s += row[0];
                    s += row[1];
                    s += row[2];
                }
                n += 9;
                continue;
            }
            for y in y0 as usize..=y1 as usize {
                let row = &img.row(y)[x0..=x1];
                if self.nonfinite {
                    for &v in row {
                        if v.is_finite() {
                            s += v;
                            n += 1;
                        }
                    }
                } else {
                    for &v in row {
                        s += v;
                    }
                    n += row.len();
                }
            }
        }
        if n == 0 {
            f64::NAN
        } else {
            sign * s / n as f64
        }
    }

    /// The template test at `p0` ([`Template::eval`]) and, sharing its pass over the window, a
    /// Gaussian-weighted centroid started at `p0`: weights `max(v - t, 0) · exp(-r²/(2σw²))`,
    /// `σw = max(σt, 0.8)` (not narrower, which would lock tiny dots to pixel centres) and `t`
    /// the mean of the first window's border; each step moves the centre by `k` times the
    /// weighted mean offset, `k = 1 + σ²/σw²` (at most 1.6), which undoes the pull of the weight
    /// towards the current centre (for a Gaussian dot the weighted mean moves only
    /// `σw²/(σ² + σw²)` of the way) and keeps the iteration contracting whatever the true size;
    /// two steps. Unbiased for a symmetric dot; the Gaussian weight keeps the neighbours' light
    /// and far noise out. `sigma` is the dot's sigma.
    pub(crate) fn measure(
        &self,
        img: &Image,
        sign: f64,
        p0: [f64; 2],
        sigma: f64,
        sc: &mut Scratch,
    ) -> Option<Measure> {
        let (w, h) = (img.width(), img.height());
        if !(p0[0].is_finite() && p0[1].is_finite()) {
            return None;
        }
        let (inv2, q, sw, inv2w, qw) = (self.inv2, self.q, self.sw, self.inv2w, self.qw);
        let same = sw == self.sigma_t;
        let gain = (1.0 + sigma * sigma / (sw * sw)).min(1.6);
        let Scratch {
            gx,
            gy,
            wx,
            wy,
            wxd,
            wxdd,
        } = sc;
        let mut c = p0;
        let (mut tstat, mut amp, mut tc) = (f64::NAN, f64::NAN, f64::NAN);
        let mut blob = None;
        for step in 0..2 {
            let Some(win) = window_centred(c[0], c[1], self.half).clip(w, h) else {
                break;
            };
            let (x0, y0) = (win.x as usize, win.y as usize);
            let (nx, ny) = (win.width.min(64), win.height.min(64));
            let (x1, y1) = (x0 + nx - 1, y0 + ny - 1);
            let mut b = f64::NAN;
            if step == 0 {
                tc = ring_mean(img, sign, x0, x1, y0, y1, self.nonfinite);
                b = self.level(img, sign, p0, tc);
                if !(tc.is_finite() && b.is_finite()) {
                    return None;
                }
                // The template is evaluated at the start point only.
                gauss_samples(&mut gx[..nx], x0 as f64 - c[0], inv2, q);
                gauss_samples(&mut gy[..ny], y0 as f64 - c[1], inv2, q);
            }
            if same && step == 0 {
                wx[..nx].copy_from_slice(&gx[..nx]);
                wy[..ny].copy_from_slice(&gy[..ny]);
            } else {
                gauss_samples(&mut wx[..nx], x0 as f64 - c[0], inv2w, qw);
                gauss_samples(&mut wy[..ny], y0 as f64 - c[1], inv2w, qw);
            }
            for k in 0..nx {
                let dx = (x0 + k) as f64 - c[0];
                wxd[k] = wx[k] * dx;
                wxdd[k] = wx[k] * dx * dx;
            }
            let gsum: f64 = gx[..nx].iter().sum();
            let gxx: f64 = gx[..nx].iter().map(|g| g * g).sum();
            let (mut sg, mut sgg) = (0.0, 0.0);
            let (mut s0, mut sx, mut sy, mut sxx, mut syy, mut sxy) =
                (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
            let mut peak: f64 = 0.0;
            // Adds one row's sums to the window's, rows in order.
            let mut fold = |ky: usize, r: f64, rs: f64, rr: f64, t: [f64; 3]| {
                let (g_y, w_y) = (gy[ky], wy[ky]);
                let dy = (y0 + ky) as f64 - c[1];
                let [r0, rx, rxx] = t;
                if step == 0 {
                    sg += g_y * (sign * r - b * rs);
                    sgg += g_y * g_y * rr;
                }
                s0 += w_y * r0;
                sx += w_y * rx;
                sxx += w_y * rxx;
                sy += w_y * r0 * dy;
                syy += w_y * r0 * dy * dy;
                sxy += w_y * rx * dy;
            };
            if self.nonfinite {
                for ky in 0..ny {
                    let row = &img.row(y0 + ky)[x0..=x1];
                    // r = Σ v g over the finite samples, rs = Σ g and rr = Σ g² over the same.
                    let (mut r, mut rs, mut rr) = (0.0, 0.0, 0.0);
                    let (mut r0, mut rx, mut rxx) = (0.0, 0.0, 0.0);
                    for k in 0..nx {
                        let v = row[k];
                        if v.is_finite() {
                            r += v * gx[k];
                            rs += gx[k];
                            rr += gx[k] * gx[k];
                        }
                        // NaN.max(0) is 0: non-finite samples weigh nothing.
                        let wv = (sign * v - tc).max(0.0);
                        peak = peak.max(wv);
                        r0 += wv * wx[k];
                        rx += wv * wxd[k];
                        rxx += wv * wxdd[k];
                    }
                    fold(ky, r, rs, rr, [r0, rx, rxx]);
                }
            } else {
                let (gx, wx, wxd, wxdd) = (&gx[..nx], &wx[..nx], &wxd[..nx], &wxdd[..nx]);
                let row = |ky: usize| &img.row(y0 + ky)[x0..=x1];
                let mut ky = 0;
                while ky < ny {
                    if ky + 1 < ny {
                        let rows = [row(ky), row(ky + 1)];
                        // Common window widths unrolled (dots of diameter about 3 to 10 px).
                        macro_rules! sums {
                            ($t:literal, $($n:literal),*) => {
                                match nx {
                                    $($n => row_sums_fixed::<$t, $n>(
                                        rows, gx, wx, wxd, wxdd, sign, tc
                                    ),)*
                                    _ => row_sums::<$t, 2>(rows, gx, wx, wxd, wxdd, sign, tc),
                                }
                            };
                        }
                        let t = if step == 0 {
                            sums!(true, 5, 7, 9, 11, 13)
                        } else {
                            sums!(false, 5, 7, 9, 11, 13)
                        };
                        for d in 0..2 {
                            peak = if t.peak[d] > peak { t.peak[d] } else { peak };
                            fold(ky + d, t.r[d], gsum, gxx, [t.r0[d], t.rx[d], t.rxx[d]]);
                        }
                        ky += 2;
                    } else {
                        let t = if step == 0 {
                            row_sums::<true, 1>([row(ky)], gx, wx, wxd, wxdd, sign, tc)
                        } else {
                            row_sums::<false, 1>([row(ky)], gx, wx, wxd, wxdd, sign, tc)
                        };
                        peak = if t.peak[0] > peak { t.peak[0] } else { peak };
                        fold(ky, t.r[0], gsum, gxx, [t.r0[0], t.rx[0], t.rxx[0]]);
                        ky += 1;
                    }
                }
            }
            if step == 0 {
                if sgg <= 0.0 {
                    return None;
                }
                tstat = sg / sgg.sqrt();
                amp = sg / sgg;
            }
            if s0.is_nan() || s0 <= 0.0 {
                break;
            }
            let (mx, my) = (sx / s0, sy / s0);
            let mom = [sxx / s0 - mx * mx, syy / s0 - my * my, sxy / s0 - mx * my];
            c = [c[0] + gain * mx, c[1] + gain * my];
            blob = Some(Blob {
                centre: c,
                mom,
                peak,
                mass: s0,
            });
        }
        Some(Measure {
            t: tstat,
            a: amp,
            blob,
        })
    }

    /// Matched-filter test of a dot at the sub-pixel point `p`: with the Gaussian template
    /// `g = exp(-|x - p|²/(2σt²))` over the `(2·half+1)²` window and `b` the local level,
    /// returns `T = Σ(v - b) g / ‖g‖` (counts; its noise is about the pixel noise, so `T / σ_T`
    /// is the signal-to-noise ratio of the best linear detector of a dot of that shape at that
    /// place) and the least-squares amplitude `A = Σ(v - b) g / Σg²`. The level is the mean of
    /// the window's border, or, for overlapping dots, the mean of 3x3 pixel blocks at the
    /// surrounding cell centres (the darkest points of the pattern). Non-finite samples are
    /// left out. `None` when the window leaves the image or has no finite sample.
    pub(crate) fn eval(&self, img: &Image, sign: f64, p: [f64; 2]) -> Option<(f64, f64)> {
        let (w, h) = (img.width(), img.height());
        if !(p[0].is_finite() && p[1].is_finite()) {
            return None;
        }
        let win = window_centred(p[0], p[1], self.half).clip(w, h)?;
        let (x0, y0) = (win.x as usize, win.y as usize);
        let (x1, y1) = (x0 + win.width - 1, y0 + win.height - 1);
        let b = self.level(
            img,
            sign,
            p,
            ring_mean(img, sign, x0, x1, y0, y1, self.nonfinite),
        );
        if !b.is_finite() {
            return None;
        }
        let (inv2, q) = (self.inv2, self.q);
        let nx = win.width.min(64);
        let ny = win.height.min(64);
        let mut gx = [0.0f64; 64];
        let mut gy = [0.0f64; 64];
        gauss_samples(&mut gx[..nx], x0 as f64 - p[0], inv2, q);
        gauss_samples(&mut gy[..ny], y0 as f64 - p[1], inv2, q);
        let gsum: f64 = gx[..nx].iter().sum();
        let (mut sg, mut sgg) = (0.0, 0.0);
        let gxx: f64 = gx[..nx].iter().map(|g| g * g).sum();
        for (ky, &g_y) in gy[..ny].iter().enumerate() {
            let row = &img.row(y0 + ky)[x0..x0 + nx];
            let (mut r, mut rr) = (0.0, gxx);
            if self.nonfinite {
                rr = 0.0;
                for (&v, &g) in row.iter().zip(&gx[..nx]) {
                    if v.is_finite() {
                        r += v * g;
                        rr += g * g;
                    }
                }
            } else {
                for (&v, &g) in row.iter().zip(&gx[..nx]) {
                    r += v * g;
                }
            }
            // Σ (sign·v - b) g over the finite samples of the row.
            let rs: f64 = if self.nonfinite {
                row.iter()
                    .zip(&gx[..nx])
                    .filter(|(v, _)| v.is_finite())
                    .map(|(_, g)| g)
                    .sum()
            } else {
                gsum
            };
            sg += g_y * (sign * r - b * rs);
            sgg += g_y * g_y * rr;
        }
        (sgg > 0.0).then(|| (sg / sgg.sqrt(), sg / sgg))
    }
}

/// The fit window: `cfg.window_half_width` or `max(2, min(round(spacing/2), ceil(1.5·d)))`.
pub(crate) fn window_half(cfg: &DetectConfig, spacing: f64, sigma: f64) -> usize {
    cfg.window_half_width.unwrap_or_else(|| {
        let cell = (0.5 * spacing).round() as usize;
        let dot = (6.0 * sigma).ceil() as usize;
        cell.min(dot).max(2)
    })
}

/// Robust standard deviation of a statistic (`stat`: the dot map or the template test) at the
/// interstitial points of the lattice: the
/// centre of each unit cell (square: mean of the 4 corners; hexagonal: centroid of the
/// triangle (i,j), (i+1,j), (i,j+1)), where no dot contributes. Uses the MAD of differences
/// between neighbouring cells (`/√2`), which cancels the smooth background level. `pos` gives
/// the position of a site if known; only points on kept pixels count.
pub(crate) fn interstitial_noise(
    stat: impl Fn([f64; 2]) -> Option<f64> + Sync,
    (w, h): (usize, usize),
    mask: Option<&Mask>,
    kind: LatticeKind,
    sites: &[GridIndex],
    pos: impl Fn(GridIndex) -> Option<[f64; 2]>,
) -> Option<f64> {
    if sites.is_empty() {
        return None;
    }
    let (imin, imax) = sites.iter().fold((i32::MAX, i32::MIN), |(lo, hi), s| {
        (lo.min(s.i), hi.max(s.i))
    });
    let (jmin, jmax) = sites.iter().fold((i32::MAX, i32::MIN), |(lo, hi), s| {
        (lo.min(s.j), hi.max(s.j))
    });
    let mut cell = IndexGrid::new(imin, imax, jmin, jmax, f64::NAN);
    // About 2000 cells (whole rows, spread over the lattice) are plenty for a robust spread.
    let row_step = (sites.len() / 2000).max(1) as i32;
    let sites: Vec<GridIndex> = sites
        .iter()
        .copied()
        .filter(|s| (s.j - jmin) % row_step == 0)
        .collect();
    // The cell centres on kept pixels, then the statistic at each (in parallel), in order.
    let mut centres: Vec<(GridIndex, [f64; 2])> = Vec::with_capacity(sites.len());
    for s in &sites {
        let corners: &[(i32, i32)] = match kind {
            LatticeKind::Square => &[(0, 0), (1, 0), (0, 1), (1, 1)],
            LatticeKind::Hexagonal => &[(0, 0), (1, 0), (0, 1)],
        };
        let mut acc = [0.0, 0.0];
        let mut ok = true;
        for &(di, dj) in corners {
            match pos(GridIndex::new(s.i + di, s.j + dj)) {
                Some(p) => {
                    acc[0] += p[0];
                    acc[1] += p[1];
                }
                None => {
                    ok = false;
                    break;
                }
            }
        }
        if !ok {
            continue;
        }
        let c = [acc[0] / corners.len() as f64, acc[1] / corners.len() as f64];
        let (px, py) = (c[0].round(), c[1].round());
        if px < 0.0 || py < 0.0 || px >= w as f64 || py >= h as f64 {
            continue;
        }
        if mask.is_some_and(|m| !m.keeps(px as usize, py as usize)) {
            continue;
        }
        centres.push((*s, c));
    }
    let values: Vec<Option<f64>> = centres
        .par_iter()
        .with_min_len(64)
        .map(|&(_, c)| stat(c))
        .collect();
    for (&(s, _), t) in centres.iter().zip(values) {
        if let Some(v) = cell.get_mut(s.i, s.j)
            && let Some(t) = t
        {
            *v = t;
        }
    }
    let mut diffs = Vec::new();
    for s in &sites {
        let (Some(&v), Some(&u)) = (cell.get(s.i, s.j), cell.get(s.i + 1, s.j)) else {
            continue;
        };
        if v.is_finite() && u.is_finite() {
            diffs.push((v - u).abs());
        }
    }
    if diffs.len() < 10 {
        return None;
    }
    Some(1.4826 * median(&mut diffs) / std::f64::consts::SQRT_2)
}

/// The index neighbourhoods of a list of sites: the slot grid (site number per grid index, or
/// `usize::MAX`) and the 8-neighbourhoods.
pub(crate) struct Neighbourhoods {
    pub slot: IndexGrid<usize>,
    pub ring: Ring1,
}

impl Neighbourhoods {
    pub(crate) fn new(index: impl Fn(usize) -> GridIndex + Sync, n: usize) -> Self {
        let (mut imin, mut imax, mut jmin, mut jmax) = (i32::MAX, i32::MIN, i32::MAX, i32::MIN);
        for k in 0..n {
            let g = index(k);
            (imin, imax) = (imin.min(g.i), imax.max(g.i));
            (jmin, jmax) = (jmin.min(g.j), jmax.max(g.j));
        }
        let mut slot = IndexGrid::new(imin, imax, jmin, jmax, usize::MAX);
        for k in 0..n {
            let g = index(k);
            if let Some(v) = slot.get_mut(g.i, g.j) {
                *v = k;
            }
        }
        let ring = Ring1::new(&slot, &index, n);
        Neighbourhoods { slot, ring }
    }
}

/// Classify every site (see the crate documentation for the rules). `nbhd`: the sites'
/// neighbourhoods when the caller has them already (for the same sites in the same order).
pub(crate) fn classify(
    ctx: &Ctx,
    sites: &[Site],
    nbhd: Option<&Neighbourhoods>,
) -> Vec<Classified> {
    let n = sites.len();
    if n == 0 {
        return Vec::new();
    }
    let (w, h) = (ctx.img.width(), ctx.img.height());
    let cfg = ctx.cfg;
    let s = ctx.spacing;
    let own;
    let nbhd = match nbhd {
        Some(x) => x,
        None => {
            own = Neighbourhoods::new(|k| sites[k].index, n);
            &own
        }
    };
    let (slot, ring) = (&nbhd.slot, &nbhd.ring);
    let neighbours = |k: usize, r: i32, out: &mut Vec<usize>| {
        out.clear();
        let idx = sites[k].index;
        slot.visit(idx.i, idx.j, r, |di, dj, &q| {
            if (di, dj) != (0, 0) && q != usize::MAX {
                out.push(q);
            }
        });
    };

    // 1. Significant dots (template test at the prediction, or at the searched peak with a
    //    stricter threshold) and the local amplitude scale. Each site on its own, in parallel
    //    (results in site order: the same whatever the threads).
    let tpl = Template::new(ctx.sigma, s, ctx.a, ctx.b, cfg.lattice, ctx.nonfinite);
    let noise = ctx.noise.max(1e-12);
    let tested: Vec<(f64, f64, [f64; 2], Option<Blob>)> = sites
        .par_iter()
        .with_min_len(PAR_MIN)
        .map_init(Scratch::new, |scratch, st| {
            let (mut snr, mut val, mut pos, mut blob) =
                (f64::NEG_INFINITY, 0.0, st.predicted, None);
            // The test and the centroid start at the searched peak when there is one (or were
            // taken at the still dot's reference centre).
            let p0 = match st.measured {
                Some((at, _)) => at,
                None => st.peak.map_or(st.predicted, |p| p.pos()),
            };
            let searched = st.peak.is_some() && dist2(p0, st.predicted) > 0.25;
            let measure = match st.measured {
                Some((_, m)) => Some(m),
                None => tpl.measure(ctx.img, ctx.sign, p0, ctx.sigma, scratch),
            };
            if let Some(m) = measure {
                snr = m.t / noise - if searched { st.peak_extra } else { 0.0 };
                val = m.a;
                pos = p0;
                blob = m.blob;
            }
            // A weak result at a searched peak: the prediction itself may be better.
            if searched
                && snr < cfg.min_snr + 1.0
                && let Some((t, a)) = tpl.eval(ctx.img, ctx.sign, st.predicted)
                && t / noise > snr
            {
                snr = t / noise;
                val = a;
                pos = st.predicted;
            }
            (snr, val, pos, blob)
        })
        .collect();
    let snr: Vec<f64> = tested.iter().map(|t| t.0).collect();
    let vals: Vec<f64> = tested.iter().map(|t| t.1).collect();
    let cand: Vec<bool> = (0..n)
        .map(|k| snr[k] >= cfg.min_snr && vals[k] > 0.0)
        .collect();
    let mut all: Vec<f64> = (0..n).filter(|&k| cand[k]).map(|k| vals[k]).collect();
    let global = median(&mut all);
    let mut found: Vec<bool> = (0..n)
        .into_par_iter()
        .with_min_len(PAR_MIN)
        .map_init(
            || (Vec::with_capacity(24), Vec::with_capacity(24)),
            |(nb, tmp), k| {
                if !cand[k] {
                    return false;
                }
                let mut local_v = global;
                for r in 1..=2 {
                    tmp.clear();
                    if r == 1 {
                        tmp.extend(ring.of(k).filter(|&q| cand[q]).map(|q| vals[q]));
                    } else {
                        neighbours(k, r, nb);
                        tmp.extend(nb.iter().filter(|&&q| cand[q]).map(|&q| vals[q]));
                    }
                    if tmp.len() >= 3 {
                        local_v = median(tmp);
                        break;
                    }
                }
                local_v.is_nan() || local_v <= 0.0 || vals[k] >= cfg.missing_ratio * local_v
            },
        )
        .collect();

    // 2. Centres and shapes of the found dots.
    let measured: Vec<([f64; 2], Shape)> = (0..n)
        .into_par_iter()
        .with_min_len(PAR_MIN)
        .map(|k| {
            if !found[k] {
                return (sites[k].predicted, Shape::default());
            }
            let p = sites[k].peak.map_or(sites[k].predicted, |p| p.pos());
            let blob = tested[k].3;
            let (c, mom) = blob.map_or((p, [0.0; 3]), |b| (b.centre, b.mom));
            // A centroid that wandered off its start (a brighter neighbour) is not trusted.
            let centre = if dist2(c, p) <= (0.3 * s).powi(2) {
                c
            } else {
                p
            };
            let size = blob.map_or(0.0, |b| {
                (b.mass / (2.0 * std::f64::consts::PI * b.peak.max(1e-300))).sqrt()
            });
            // The amplitude at the centre; the decision's value serves when within 0.3 px of
            // it.
            let amp = if dist2(centre, tested[k].2) <= 0.09 {
                vals[k]
            } else {
                tpl.eval(ctx.img, ctx.sign, centre).map_or(0.0, |t| t.1)
            };
            let tr = mom[0] + mom[1];
            let disc = ((mom[0] - mom[1]).powi(2) + 4.0 * mom[2] * mom[2]).sqrt();
            let (l1, l2) = (0.5 * (tr + disc), 0.5 * (tr - disc));
            let elongation = if l2 > 1e-9 { (l1 / l2).sqrt() } else { 1.0 };
            let shape = Shape {
                amplitude: amp,
                size,
                elongation,
                mom,
            };
            (centre, shape)
        })
        .collect();
    let (mut centre, shape): (Vec<[f64; 2]>, Vec<Shape>) = measured.into_iter().unzip();

    // 3. Duplicates: two neighbouring sites on the same dot keep the better-predicted one
    //    (in site order).
    for k in 0..n {
        if !found[k] {
            continue;
        }
        for q in ring.of(k) {
            if found[q] && found[k] && dist2(centre[k], centre[q]) < (0.4 * s).powi(2) {
                let dk = dist2(centre[k], sites[k].predicted);
                let dq = dist2(centre[q], sites[q].predicted);
                let lose = if dk > dq { k } else { q };
                found[lose] = false;
                centre[lose] = sites[lose].predicted;
            }
        }
    }

    // 4. Flags relative to the neighbours. The shape tests run only where the dot is clearly
    //    above the noise and its shape differs from the image-wide median by over 20 %.
    let strong = |k: usize| found[k] && snr[k] >= 8.0;
    let mut gs: Vec<f64> = (0..n)
        .filter(|&k| strong(k))
        .map(|k| shape[k].size)
        .collect();
    let mut ge: Vec<f64> = (0..n)
        .filter(|&k| strong(k))
        .map(|k| shape[k].elongation)
        .collect();
    let (gsize, gelong) = (median(&mut gs), median(&mut ge));
    let half_w = window_half(cfg, s, ctx.sigma);
    (0..n)
        .into_par_iter()
        .with_min_len(PAR_MIN)
        .map_init(
            || {
                let v = || Vec::with_capacity(24);
                (v(), v(), v(), v(), v())
            },
            |(ta, ts, te, tox, toy), k| {
                let mut flags = DotFlags::NONE;
                let c = centre[k];
                if !found[k] {
                    flags.insert(DotFlags::MISSING);
                } else {
                    ta.clear();
                    ts.clear();
                    te.clear();
                    tox.clear();
                    toy.clear();
                    let sh = shape[k];
                    let own_off = [c[0] - sites[k].predicted[0], c[1] - sites[k].predicted[1]];
                    let check_off = hypot_exceeds(own_off[0], own_off[1], 0.1 * s);
                    let check_shape = strong(k)
                        && ((sh.size / gsize - 1.0).abs() > 0.2
                            || sh.elongation > 1.2 * gelong
                            || gsize.is_nan()
                            || gsize <= 0.0);
                    for q in ring.of(k).filter(|&q| found[q]) {
                        ta.push(shape[q].amplitude);
                        if check_shape && strong(q) {
                            ts.push(shape[q].size);
                            te.push(shape[q].elongation);
                        }
                        if check_off {
                            tox.push(centre[q][0] - sites[q].predicted[0]);
                            toy.push(centre[q][1] - sites[q].predicted[1]);
                        }
                    }
                    if ta.len() >= 3 {
                        let am = median(ta);
                        if sh.amplitude < cfg.faint_ratio * am {
                            flags.insert(DotFlags::FAINT);
                        } else if sh.amplitude > 2.5 * am {
                            flags.insert(DotFlags::DEFECT);
                        }
                        if check_off {
                            let off = [own_off[0] - median(tox), own_off[1] - median(toy)];
                            if hypot_exceeds(off[0], off[1], 0.25 * s) {
                                flags.insert(DotFlags::DEFECT);
                            }
                        }
                    }
                    if check_shape && ts.len() >= 3 {
                        let sm = median(ts);
                        let em = median(te);
                        let elongated = sh.elongation > (1.4 * em).max(1.5);
                        let along_lattice = [ctx.a, ctx.b].iter().any(|d| {
                            // Direction of the major axis (radians).
                            let angle = 0.5 * (2.0 * sh.mom[2]).atan2(sh.mom[0] - sh.mom[1]);
                            let da = (angle - d[1].atan2(d[0])).rem_euclid(std::f64::consts::PI);
                            da.min(std::f64::consts::PI - da) < 20f64.to_radians()
                        });
                        if elongated && along_lattice && sh.size > 1.3 * sm {
                            flags.insert(DotFlags::MERGED);
                        } else if elongated || sh.size > 1.5 * sm || sh.size < 0.67 * sm {
                            flags.insert(DotFlags::DEFECT);
                        }
                    }
                }
                // a tracked dot keeps its reference window, moved by the whole pixels of its
                // displacement: where it moved by less than half a pixel its fit sees the
                // reference fit's pixels (a window of its own rounded centre would differ for
                // the dots whose centre lies near a pixel's edge, ~10 % of a no-flow image, and
                // cost the fit stage the reference's remembered matrices there)
                let win = match sites[k].window_from {
                    Some((r, rw)) => Window::new(
                        rw.x + (c[0] - r[0]).round() as i64,
                        rw.y + (c[1] - r[1]).round() as i64,
                        rw.width,
                        rw.height,
                    ),
                    None => Window::centred(c[0], c[1], half_w),
                };
                let clipped = win.clip(w, h).unwrap_or(Window::new(
                    win.x.clamp(0, w as i64 - 1),
                    win.y.clamp(0, h as i64 - 1),
                    1,
                    1,
                ));
                if clipped != win {
                    flags.insert(DotFlags::BORDER);
                }
                let (x0, y0) = (clipped.x as usize, clipped.y as usize);
                let (x1, y1) = (x0 + clipped.width, y0 + clipped.height);
                if ctx.nonfinite
                    && (y0..y1).any(|y| ctx.img.row(y)[x0..x1].iter().any(|v| !v.is_finite()))
                {
                    flags.insert(DotFlags::NAN_PIXELS);
                }
                if let Some(m) = ctx.mask
                    // (a count of the kept pixels per row: a sum vectorises, a search with an
                    // early exit does not)
                    && (y0..y1).any(|y| {
                        m.as_slice()[y * w + x0..y * w + x1]
                            .iter()
                            .map(|&k| usize::from(k))
                            .sum::<usize>()
                            != x1 - x0
                    })
                {
                    flags.insert(DotFlags::MASKED);
                }
                let seed = Seed {
                    index: sites[k].index,
                    predicted: sites[k].predicted,
                    centre: c,
                    window: clipped,
                    flags,
                };
                Classified {
                    seed,
                    contrast: if found[k] { shape[k].amplitude } else { 0.0 },
                }
            },
        )
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    // The straightforward implementation the optimised [`Template::measure`] must reproduce
    // bit for bit (row-pair sums, unrolled widths, fast paths for finite images).

    fn ring_reference(img: &Image, sign: f64, x0: usize, x1: usize, y0: usize, y1: usize) -> f64 {
        let (mut s, mut n) = (0.0, 0usize);
        let mut add = |v: f64| {
            if v.is_finite() {
                s += v;
                n += 1;
            }
        };
        for &v in &img.row(y0)[x0..=x1] {
            add(v);
        }
        if y1 > y0 {
            for &v in &img.row(y1)[x0..=x1] {
                add(v);
            }
        }
        for y in y0 + 1..y1 {
            let row = img.row(y);
            add(row[x0]);
            if x1 > x0 {
                add(row[x1]);
            }
        }
        if n == 0 {
            f64::NAN
        } else {
            sign * s / n as f64
        }
    }

    fn level_reference(tpl: &Template, img: &Image, sign: f64, p: [f64; 2], ring: f64) -> f64 {
        let Some(offsets) = &tpl.cells else {
            return ring;
        };
        let (w, h) = (img.width() as i64, img.height() as i64);
        let (mut s, mut n) = (0.0, 0usize);
        for o in offsets {
            let (cx, cy) = (round_i64(p[0] + o[0]), round_i64(p[1] + o[1]));
            let (x0, x1) = ((cx - 1).max(0), (cx + 1).min(w - 1));
            let (y0, y1) = ((cy - 1).max(0), (cy + 1).min(h - 1));
            if x0 > x1 || y0 > y1 {
                continue;
            }
            for y in y0..=y1 {
                for &v in &img.row(y as usize)[x0 as usize..=x1 as usize] {
                    if !tpl.nonfinite || v.is_finite() {
                        s += v;
                        n += 1;
                    }
                }
            }
        }
        if n == 0 {
            f64::NAN
        } else {
            sign * s / n as f64
        }
    }

    fn measure_reference(
        tpl: &Template,
        img: &Image,
        sign: f64,
        p0: [f64; 2],
        sigma: f64,
    ) -> Option<Measure> {
        let (w, h) = (img.width(), img.height());
        if !(p0[0].is_finite() && p0[1].is_finite()) {
            return None;
        }
        let inv2 = -0.5 / (tpl.sigma_t * tpl.sigma_t);
        let q = (2.0 * inv2).exp();
        let sw = tpl.sigma_t.max(0.8);
        let inv2w = -0.5 / (sw * sw);
        let qw = (2.0 * inv2w).exp();
        let same = sw == tpl.sigma_t;
        let gain = (1.0 + sigma * sigma / (sw * sw)).min(1.6);
        let (mut gx, mut gy) = ([0.0f64; 64], [0.0f64; 64]);
        let (mut wx, mut wy, mut wxd, mut wxdd) =
            ([0.0f64; 64], [0.0f64; 64], [0.0f64; 64], [0.0f64; 64]);
        let mut c = p0;
        let (mut tstat, mut amp, mut tc) = (f64::NAN, f64::NAN, f64::NAN);
        let mut blob = None;
        for step in 0..2 {
            let Some(win) = window_centred(c[0], c[1], tpl.half).clip(w, h) else {
                break;
            };
            let (x0, y0) = (win.x as usize, win.y as usize);
            let (nx, ny) = (win.width.min(64), win.height.min(64));
            let (x1, y1) = (x0 + nx - 1, y0 + ny - 1);
            let mut b = f64::NAN;
            if step == 0 {
                tc = ring_reference(img, sign, x0, x1, y0, y1);
                b = level_reference(tpl, img, sign, p0, tc);
                if !(tc.is_finite() && b.is_finite()) {
                    return None;
                }
            }
            gauss_samples(&mut gx[..nx], x0 as f64 - c[0], inv2, q);
            gauss_samples(&mut gy[..ny], y0 as f64 - c[1], inv2, q);
            if same {
                wx[..nx].copy_from_slice(&gx[..nx]);
                wy[..ny].copy_from_slice(&gy[..ny]);
            } else {
                gauss_samples(&mut wx[..nx], x0 as f64 - c[0], inv2w, qw);
                gauss_samples(&mut wy[..ny], y0 as f64 - c[1], inv2w, qw);
            }
            for k in 0..nx {
                let dx = (x0 + k) as f64 - c[0];
                wxd[k] = wx[k] * dx;
                wxdd[k] = wx[k] * dx * dx;
            }
            let gsum: f64 = gx[..nx].iter().sum();
            let gxx: f64 = gx[..nx].iter().map(|g| g * g).sum();
            let (mut sg, mut sgg) = (0.0, 0.0);
            let (mut s0, mut sx, mut sy, mut sxx, mut syy, mut sxy) =
                (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
            let mut peak: f64 = 0.0;
            for (ky, (&g_y, &w_y)) in gy[..ny].iter().zip(&wy[..ny]).enumerate() {
                let row = &img.row(y0 + ky)[x0..=x1];
                let dy = (y0 + ky) as f64 - c[1];
                // r = Σ v g over the finite samples, rs = Σ g and rr = Σ g² over the same.
                let (mut r, mut rs, mut rr) = (0.0, gsum, gxx);
                let (mut r0, mut rx, mut rxx) = (0.0, 0.0, 0.0);
                if tpl.nonfinite {
                    (rs, rr) = (0.0, 0.0);
                    for k in 0..nx {
                        let v = row[k];
                        if v.is_finite() {
                            r += v * gx[k];
                            rs += gx[k];
                            rr += gx[k] * gx[k];
                        }
                        // NaN.max(0) is 0: non-finite samples weigh nothing.
                        let wv = (sign * v - tc).max(0.0);
                        peak = peak.max(wv);
                        r0 += wv * wx[k];
                        rx += wv * wxd[k];
                        rxx += wv * wxdd[k];
                    }
                } else {
                    for k in 0..nx {
                        let v = row[k];
                        r += v * gx[k];
                        let wv = (sign * v - tc).max(0.0);
                        peak = peak.max(wv);
                        r0 += wv * wx[k];
                        rx += wv * wxd[k];
                        rxx += wv * wxdd[k];
                    }
                }
                sg += g_y * (sign * r - b * rs);
                sgg += g_y * g_y * rr;
                s0 += w_y * r0;
                sx += w_y * rx;
                sxx += w_y * rxx;
                sy += w_y * r0 * dy;
                syy += w_y * r0 * dy * dy;
                sxy += w_y * rx * dy;
            }
            if step == 0 {
                if sgg <= 0.0 {
                    return None;
                }
                tstat = sg / sgg.sqrt();
                amp = sg / sgg;
            }
            if s0.is_nan() || s0 <= 0.0 {
                break;
            }
            let (mx, my) = (sx / s0, sy / s0);
            let mom = [sxx / s0 - mx * mx, syy / s0 - my * my, sxy / s0 - mx * my];
            c = [c[0] + gain * mx, c[1] + gain * my];
            blob = Some(Blob {
                centre: c,
                mom,
                peak,
                mass: s0,
            });
        }
        Some(Measure {
            t: tstat,
            a: amp,
            blob,
        })
    }

    fn bits(m: &Option<Measure>) -> Vec<u64> {
        match m {
            None => vec![],
            Some(m) => {
                let mut v = vec![m.t.to_bits(), m.a.to_bits()];
                if let Some(b) = m.blob {
                    v.extend(b.centre.iter().chain(&b.mom).map(|x| x.to_bits()));
                    v.extend([b.peak.to_bits(), b.mass.to_bits()]);
                }
                v
            }
        }
    }

    #[test]
    fn measure_equals_the_plain_implementation_bit_for_bit() {
        // Float-valued dots on a slope, one image with non-finite samples; windows of every
        // width from 3 to 17 px and beyond (the unrolled widths and the general loop), both
        // level modes (window border, cell centres), clipped windows at the edges.
        for bad in [false, true] {
            let img = Image::from_fn(70, 61, |x, y| {
                let (fx, fy) = (x as f64, y as f64);
                let d = (fx * 0.71).sin() * (fy * 0.69).cos();
                let v =
                    120.0 + 1.5 * fx - 0.7 * fy + 900.0 * d * d + ((x * 31 + y * 17) % 13) as f64;
                if bad && (x * 7 + y * 3) % 41 == 0 {
                    f64::NAN
                } else {
                    v
                }
            });
            let mut sc = Scratch::new();
            for sigma in [0.3, 0.6, 1.0, 1.6, 2.2, 3.0, 3.6] {
                for spacing in [4.0, 8.0, 30.0] {
                    let tpl = Template::new(
                        sigma,
                        spacing,
                        [spacing, 0.3],
                        [-0.3, spacing],
                        LatticeKind::Square,
                        bad,
                    );
                    for (k, p) in [
                        [35.3, 30.6],
                        [12.49, 40.5],
                        [0.2, 3.7],
                        [69.4, 60.1],
                        [50.0, 1.0],
                        [-3.0, 20.0],
                    ]
                    .iter()
                    .enumerate()
                    {
                        for sign in [1.0, -1.0] {
                            let want = measure_reference(&tpl, &img, sign, *p, sigma);
                            let got = tpl.measure(&img, sign, *p, sigma, &mut sc);
                            assert_eq!(
                                bits(&got),
                                bits(&want),
                                "sigma {sigma} spacing {spacing} point {k} sign {sign} bad {bad}"
                            );
                        }
                    }
                }
            }
        }
    }
}
