//! Starting point of the fit and the two cheap estimators (IWC, TPG), all from the pixels
//! loaded in a [`Workspace`].

use crate::eval::{IA, IB, IT, IU, IV, IX, IY, Theta, Workspace};
use bostrack_core::FitStatus;
use bostrack_model::Sampling;

/// Fraction of the peak (above background) below which pixels do not count in the moments.
pub(crate) const THRESHOLD: f64 = 0.1;
/// The region grown from the peak only steps to pixels at most this fraction of the peak above
/// the current one, so it stops at the saddle towards a touching neighbour.
pub(crate) const RISE: f64 = 0.1;

/// Factor that turns the second moments of `(I - f·I_peak)⁺` into the covariance of the
/// untruncated Gaussian. For a 2-D Gaussian, with `s = r²/(2σ²)` (Mahalanobis) the weight is
/// `e^{-s} - f` on `s < L = ln(1/f)` and the area element is ∝ ds, so the weighted mean of `s`
/// is `[1 - f(1 + L) - f L²/2] / [1 - f - f L]` and the weighted covariance is that times Σ.
pub(crate) fn moment_correction(f: f64) -> f64 {
    let l = -f.ln();
    let num = 1.0 - f * (1.0 + l) - 0.5 * f * l * l;
    let den = 1.0 - f - f * l;
    den / num
}

/// Background guess: median of the usable pixels of the window's outer ring; if fewer than 4
/// of them are usable, the lower quartile of all usable pixels. NaN if no pixel is usable.
pub(crate) fn background(ws: &mut Workspace) -> f64 {
    let (w, h) = (ws.w, ws.h);
    ws.sort_buf.clear();
    if w > 0 && h > 0 {
        // the ring's pixels: the first and the last row, the first and the last column of the
        // rows between (the median does not depend on their order)
        let mut push = |k: usize| {
            if ws.keep[k] > 0.0 {
                ws.sort_buf.push(ws.data[k]);
            }
        };
        for i in 0..w {
            push(i);
        }
        for j in 1..h.saturating_sub(1) {
            push(j * w);
            if w > 1 {
                push(j * w + w - 1);
            }
        }
        if h > 1 {
            for i in 0..w {
                push((h - 1) * w + i);
            }
        }
    }
    let frac = if ws.sort_buf.len() >= 4 {
        0.5
    } else {
        ws.sort_buf.clear();
        for k in 0..w * h {
            if ws.keep[k] > 0.0 {
                ws.sort_buf.push(ws.data[k]);
            }
        }
        0.25
    };
    if ws.sort_buf.is_empty() {
        return f64::NAN;
    }
    let k = ((ws.sort_buf.len() - 1) as f64 * frac).round() as usize;
    let (_, v, _) = ws.sort_buf.select_nth_unstable_by(k, f64::total_cmp);
    *v
}

/// Brightest usable pixel within `max(2.5, 0.375·min(w, h))` px of `start` (window index).
pub(crate) fn peak_pixel(ws: &Workspace, start: [f64; 2]) -> Option<usize> {
    let (w, h) = (ws.w, ws.h);
    let r = (0.375 * w.min(h) as f64).max(2.5);
    // the rows and columns of the disc's bounding box (in window indices, clipped), scanned in
    // the same order as the whole window: the same first brightest pixel (issue 17: the whole
    // window's scan was a fifth of the moments' start)
    let span = |first: i64, c: f64, n: usize| {
        // (a hair wider than the disc: the disc's own test decides at its edge)
        let lo = (c - r - first as f64 - 1e-6).ceil().max(0.0);
        let hi = (c + r - first as f64 + 1e-6).floor().min(n as f64 - 1.0);
        if hi.is_nan() || lo.is_nan() || lo > hi {
            0..0
        } else {
            lo as usize..hi as usize + 1
        }
    };
    let mut best: Option<(usize, f64)> = None;
    let cols = span(ws.wx, start[0], w);
    for j in span(ws.wy, start[1], h) {
        let dy = (ws.wy + j as i64) as f64 - start[1];
        for i in cols.clone() {
            let dx = (ws.wx + i as i64) as f64 - start[0];
            let k = j * w + i;
            if ws.keep[k] > 0.0
                && dx * dx + dy * dy <= r * r
                && best.is_none_or(|(_, v)| ws.data[k] > v)
            {
                best = Some((k, ws.data[k]));
            }
        }
    }
    best.map(|(k, _)| k)
}

/// Moments of the background-subtracted pixels above `THRESHOLD × peak` that are reached from
/// the peak pixel by 8-connected steps that never rise by more than `RISE × peak` (so a touching
/// neighbour's pixels are not included; the rule is suspended next to unusable pixels, e.g. a
/// saturated core).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Moments {
    pub background: f64,
    pub x: f64,
    pub y: f64,
    /// Covariance of the dot (corrected for the threshold and, for integrated sampling, for
    /// the pixel's own variance 1/12), clamped to a valid shape.
    pub sxx: f64,
    pub syy: f64,
    pub rho: f64,
    pub amplitude: f64,
}

pub(crate) fn moments(ws: &mut Workspace, start: [f64; 2], sampling: Sampling) -> Option<Moments> {
    let bg = background(ws);
    if !bg.is_finite() {
        return None;
    }
    let pk = peak_pixel(ws, start)?;
    let peak = ws.data[pk] - bg;
    if peak.is_nan() || peak <= 0.0 {
        return None;
    }
    let thr = THRESHOLD * peak;
    let (w, h) = (ws.w, ws.h);
    ws.mark.iter_mut().for_each(|m| *m = false);
    ws.stack.clear();
    ws.stack.push(pk as u32);
    ws.mark[pk] = true;
    let (pi, pj) = ((pk % w) as f64, (pk / w) as f64);
    let (mut s0, mut sx, mut sy, mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    while let Some(k) = ws.stack.pop() {
        let k = k as usize;
        let (i, j) = (k % w, k / w);
        let wt = ws.data[k] - bg - thr;
        let (dx, dy) = (i as f64 - pi, j as f64 - pj);
        s0 += wt;
        sx += wt * dx;
        sy += wt * dy;
        sxx += wt * dx * dx;
        sxy += wt * dx * dy;
        syy += wt * dy * dy;
        // walk downhill only (a rise of more than RISE × peak is another dot's flank)
        // next to an unusable pixel (a clipped core) the rise rule is suspended, so that the
        // region can go round a saturated core
        let near_hole = (i > 0 && ws.keep[k - 1] == 0.0)
            || (i + 1 < w && ws.keep[k + 1] == 0.0)
            || (j > 0 && ws.keep[k - w] == 0.0)
            || (j + 1 < h && ws.keep[k + w] == 0.0);
        let ceiling = if near_hole {
            f64::INFINITY
        } else {
            ws.data[k] + RISE * peak
        };
        // 8-connected, so that a diagonal ridge (strong rho) is followed; rows then columns
        // from the top left (the order fixes the summation order, hence the rounding)
        let mut visit = |kk: usize| {
            if !ws.mark[kk] && ws.keep[kk] > 0.0 && ws.data[kk] - bg > thr && ws.data[kk] <= ceiling
            {
                ws.mark[kk] = true;
                ws.stack.push(kk as u32);
            }
        };
        if i > 0 && i + 1 < w && j > 0 && j + 1 < h {
            let up = k - w;
            let down = k + w;
            for kk in [up - 1, up, up + 1, k - 1, k + 1, down - 1, down, down + 1] {
                visit(kk);
            }
        } else {
            for dj in -1i64..=1 {
                for di in -1i64..=1 {
                    let (ii, jj) = (i as i64 + di, j as i64 + dj);
                    if (di == 0 && dj == 0) || ii < 0 || jj < 0 || ii >= w as i64 || jj >= h as i64
                    {
                        continue;
                    }
                    visit(jj as usize * w + ii as usize);
                }
            }
        }
    }
    if s0.is_nan() || s0 <= 0.0 {
        return None;
    }
    let (mx, my) = (sx / s0, sy / s0);
    let corr = moment_correction(THRESHOLD);
    let pix = if sampling == Sampling::Integrated {
        1.0 / 12.0
    } else {
        0.0
    };
    let max_var = (w.max(h) as f64).powi(2);
    let min_var = SIGMA_FLOOR * SIGMA_FLOOR;
    let vxx = (corr * (sxx / s0 - mx * mx) - pix).clamp(min_var, max_var);
    let vyy = (corr * (syy / s0 - my * my) - pix).clamp(min_var, max_var);
    let cxy = corr * (sxy / s0 - mx * my);
    let rho = (cxy / (vxx * vyy).sqrt()).clamp(-0.9, 0.9);
    let rho = if rho.is_finite() { rho } else { 0.0 };
    let x = ws.wx as f64 + pi + mx;
    let y = ws.wy as f64 + pj + my;
    // amplitude: the peak pixel divided by the model's factor there
    let (ex, ey) = (ws.wx as f64 + pi - x, ws.wy as f64 + pj - y);
    let (sxs, sys) = (vxx.sqrt(), vyy.sqrt());
    let (u, v) = (ex / sxs, ey / sys);
    let q = (u * u - 2.0 * rho * u * v + v * v) / (1.0 - rho * rho);
    let amplitude = (peak / (-0.5 * q).exp()).clamp(peak, 4.0 * peak);
    Some(Moments {
        background: bg,
        x,
        y,
        sxx: vxx,
        syy: vyy,
        rho,
        amplitude,
    })
}

/// The centre and the two σ of a narrow dot's axis-aligned start θ (the model of pass 1 for
/// dots narrower than half a pixel, whose ρ is held at 0) from the 3 × 3 block round the
/// brightest pixel near it: each axis from the block's three column (row) sums by the
/// pixel-integrated profile ([`narrow_axis`]), σ not below the moments' floor of 0.25 px. A
/// start from the window moments puts a dot that lies within one pixel on that pixel's centre
/// with the floor's σ, and its first Gauss-Newton steps overshoot (issue 17: at σ 0.3 px four
/// rejected trials before the first accepted one were common). `false` (θ unchanged) where
/// the block is not whole in the window or a profile has no solution.
pub(crate) fn narrow_start(ws: &Workspace, theta: &mut Theta) -> bool {
    let bg = theta[IB];
    let Some(pk) = peak_pixel(ws, [theta[IX], theta[IY]]) else {
        return false;
    };
    let Some(block) = block_of(ws, pk, bg) else {
        return false;
    };
    let cols = std::array::from_fn(|i| block[i] + block[3 + i] + block[6 + i]);
    let rows = std::array::from_fn(|j| block[3 * j..3 * j + 3].iter().sum());
    let (Some((dx, sx)), Some((dy, sy))) = (narrow_axis(cols), narrow_axis(rows)) else {
        return false;
    };
    let (i, j) = (pk % ws.w, pk / ws.w);
    theta[IX] = ws.wx as f64 + i as f64 + dx;
    theta[IY] = ws.wy as f64 + j as f64 + dy;
    theta[IU] = sx.max(SIGMA_FLOOR).ln();
    theta[IV] = sy.max(SIGMA_FLOOR).ln();
    true
}

/// The moments' smallest σ (px).
const SIGMA_FLOOR: f64 = 0.25;

/// The smallest share of the middle pixel a side pixel of [`narrow_axis`] is taken to hold.
const SIDE_MIN: f64 = 1e-3;

/// The background-subtracted values of the 3 × 3 block round the peak pixel `pk`, row by
/// row; `None` unless the whole block is in the window and usable.
fn block_of(ws: &Workspace, pk: usize, bg: f64) -> Option<[f64; 9]> {
    let (w, h) = (ws.w, ws.h);
    let (i, j) = (pk % w, pk / w);
    if i == 0 || j == 0 || i + 1 >= w || j + 1 >= h {
        return None;
    }
    let mut block = [0.0; 9];
    for (k, v) in block.iter_mut().enumerate() {
        let at = (j + k / 3 - 1) * w + i + k % 3 - 1;
        if ws.keep[at] <= 0.0 {
            return None;
        }
        *v = ws.data[at] - bg;
    }
    Some(block)
}

/// The centre offset `d` (from the middle pixel) and σ of a pixel-integrated Gaussian profile whose three pixels hold `c` (in proportion): each
/// `F_k = Φ((k + ½ − d)/σ) − Φ((k − ½ − d)/σ)`, solved for the two ratios `c₋₁/c₀`, `c₁/c₀` by
/// Newton's method in `(d, ln σ)` (a side below [`SIDE_MIN`] of the middle taken at that).
/// `None` where the middle pixel holds less than half the largest side, or no solution with
/// `|d| ≤ ½`, `0.1 < σ < 1` is found.
pub(crate) fn narrow_axis(c: [f64; 3]) -> Option<(f64, f64)> {
    if !(c[1] > 0.0 && 2.0 * c[1] >= c[0].max(c[2])) {
        return None;
    }
    // (a side at or below the noise of zero: a small share, not none)
    let side = |v: f64| v.max(SIDE_MIN * c[1]) / c[1];
    let (lm, lp) = (side(c[0]).ln(), side(c[2]).ln());
    // (the three-point Gaussian's offset as the first guess)
    let mut d = (0.5 * (lm - lp) / (lm + lp)).clamp(-0.45, 0.45);
    let mut u = 0.35f64.ln();
    let (u_lo, u_hi) = (0.1f64.ln(), 0.0);
    let cdf = |z: f64| 0.5 * libm::erfc(-z * std::f64::consts::FRAC_1_SQRT_2);
    let pdf = |z: f64| {
        (-0.5 * z * z).exp()
            * 0.5
            * std::f64::consts::FRAC_2_SQRT_PI
            * std::f64::consts::FRAC_1_SQRT_2
    };
    for _ in 0..12 {
        let s = u.exp();
        // edges −3/2, −1/2, 1/2, 3/2 in σ units, their Φ and φ
        let z: [f64; 4] = std::array::from_fn(|e| (e as f64 - 1.5 - d) / s);
        let (p, q): ([f64; 4], [f64; 4]) = (z.map(cdf), z.map(pdf));
        let f: [f64; 3] = std::array::from_fn(|k| p[k + 1] - p[k]);
        if f.iter().any(|v| v.is_nan() || *v <= 0.0) {
            return None;
        }
        // ∂F_k/∂d and ∂F_k/∂(ln σ)
        let fd: [f64; 3] = std::array::from_fn(|k| -(q[k + 1] - q[k]) / s);
        let fu: [f64; 3] = std::array::from_fn(|k| -(q[k + 1] * z[k + 1] - q[k] * z[k]));
        let r = [(f[0] / f[1]).ln() - lm, (f[2] / f[1]).ln() - lp];
        let jac = |k: usize, g: &[f64; 3]| g[k] / f[k] - g[1] / f[1];
        let (a, b) = (jac(0, &fd), jac(0, &fu));
        let (cc, dd) = (jac(2, &fd), jac(2, &fu));
        let det = a * dd - b * cc;
        if det.is_nan() || det.abs() <= 1e-12 {
            return None;
        }
        let (sd, su) = ((dd * r[0] - b * r[1]) / det, (a * r[1] - cc * r[0]) / det);
        // (steps of at most a quarter pixel and a factor 1.5 in σ; the centre may end on the
        // middle pixel's edge, where the peak pixel is not the column's largest)
        let (d1, u1) = (
            (d - sd.clamp(-0.25, 0.25)).clamp(-0.5, 0.5),
            (u - su.clamp(-0.4, 0.4)).clamp(u_lo, u_hi),
        );
        let small = (d1 - d).abs() < 1e-4 && (u1 - u).abs() < 1e-4;
        (d, u) = (d1, u1);
        if small {
            return (u > u_lo && u < u_hi).then_some((d, u.exp()));
        }
    }
    None
}

impl Moments {
    pub fn theta(&self) -> Theta {
        let mut t = [0.0; 7];
        t[IX] = self.x;
        t[IY] = self.y;
        t[IA] = self.amplitude;
        t[IU] = 0.5 * self.sxx.ln();
        t[IV] = 0.5 * self.syy.ln();
        t[IT] = self.rho.atanh();
        t[IB] = self.background;
        t
    }
}

/// Result of the three-point Gaussian estimator: θ (with t = 0; ρ is reported as NaN).
pub(crate) fn three_point(ws: &mut Workspace, start: [f64; 2]) -> Result<Theta, FitStatus> {
    let bg = background(ws);
    if !bg.is_finite() {
        return Err(FitStatus::TooFewPixels);
    }
    let pk = peak_pixel(ws, start).ok_or(FitStatus::TooFewPixels)?;
    let (w, h) = (ws.w, ws.h);
    let (i, j) = (pk % w, pk / w);
    if i == 0 || j == 0 || i + 1 == w || j + 1 == h {
        return Err(FitStatus::TooFewPixels);
    }
    let idx = [pk - 1, pk + 1, pk - w, pk + w];
    if idx.iter().any(|&k| ws.keep[k] <= 0.0) {
        return Err(FitStatus::TooFewPixels);
    }
    let lv = |k: usize| (ws.data[k] - bg).ln();
    let (l0, lxm, lxp, lym, lyp) = (lv(pk), lv(pk - 1), lv(pk + 1), lv(pk - w), lv(pk + w));
    let cx = lxm - 2.0 * l0 + lxp;
    let cy = lym - 2.0 * l0 + lyp;
    if !(cx < 0.0 && cy < 0.0 && [l0, lxm, lxp, lym, lyp].iter().all(|v| v.is_finite())) {
        return Err(FitStatus::Singular);
    }
    let dx = (lxm - lxp) / (2.0 * cx);
    let dy = (lym - lyp) / (2.0 * cy);
    let (vx, vy) = (-1.0 / cx, -1.0 / cy);
    let ln_a = l0 + 0.5 * dx * dx / vx + 0.5 * dy * dy / vy;
    let mut t = [0.0; 7];
    t[IX] = ws.wx as f64 + i as f64 + dx;
    t[IY] = ws.wy as f64 + j as f64 + dy;
    t[IA] = ln_a.exp();
    t[IU] = 0.5 * vx.ln();
    t[IV] = 0.5 * vy.ln();
    t[IT] = 0.0;
    t[IB] = bg;
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ring's median and the brightest pixel near the start are those of the whole
    /// window's scans they replace (every window shape from 1 × 1, masked pixels, starts
    /// inside, on the edge of and outside the window).
    #[test]
    fn ring_and_peak_scans_equal_the_whole_window_scans() {
        use rand::{RngExt, SeedableRng, rngs::StdRng};
        let mut rng = StdRng::seed_from_u64(5);
        for (w, h) in [(1, 1), (1, 4), (5, 1), (2, 2), (3, 7), (9, 9), (15, 13)] {
            for _ in 0..50 {
                let mut ws = Workspace::default();
                ws.resize(7, -3, w, h);
                for k in 0..w * h {
                    // ties on purpose: values from a few levels
                    ws.data[k] = rng.random_range(0..6) as f64;
                    ws.keep[k] = if rng.random::<f64>() < 0.2 { 0.0 } else { 1.0 };
                }
                let mut ring = vec![];
                for j in 0..h {
                    for i in 0..w {
                        if (j == 0 || j + 1 == h || i == 0 || i + 1 == w)
                            && ws.keep[j * w + i] > 0.0
                        {
                            ring.push(ws.data[j * w + i]);
                        }
                    }
                }
                let bg = background(&mut ws);
                if ring.len() >= 4 {
                    ring.sort_by(f64::total_cmp);
                    let k = ((ring.len() - 1) as f64 * 0.5).round() as usize;
                    assert_eq!(bg, ring[k], "{w}x{h}");
                }
                let start = [
                    7.0 + rng.random_range(-4.0..w as f64 + 4.0),
                    -3.0 + rng.random_range(-4.0..h as f64 + 4.0),
                ];
                let r = (0.375 * w.min(h) as f64).max(2.5);
                let mut best: Option<(usize, f64)> = None;
                for j in 0..h {
                    let dy = (ws.wy + j as i64) as f64 - start[1];
                    for i in 0..w {
                        let dx = (ws.wx + i as i64) as f64 - start[0];
                        let k = j * w + i;
                        if ws.keep[k] > 0.0
                            && dx * dx + dy * dy <= r * r
                            && best.is_none_or(|(_, v)| ws.data[k] > v)
                        {
                            best = Some((k, ws.data[k]));
                        }
                    }
                }
                assert_eq!(
                    peak_pixel(&ws, start),
                    best.map(|(k, _)| k),
                    "{w}x{h} {start:?}"
                );
            }
            // a start exactly a radius away along a row
            let mut ws = Workspace::default();
            ws.resize(0, 0, w, h);
            ws.data
                .iter_mut()
                .enumerate()
                .for_each(|(k, v)| *v = k as f64);
            ws.keep.fill(1.0);
            let r = (0.375 * w.min(h) as f64).max(2.5);
            let start = [w as f64 - 1.0 + r, 0.0];
            assert_eq!(peak_pixel(&ws, start), Some(w - 1), "{w}x{h} edge");
        }
    }

    /// The correction factor agrees with a direct numerical integration over a fine grid.
    #[test]
    fn moment_correction_matches_numerical_integral() {
        let f = THRESHOLD;
        let (mut s0, mut s2) = (0.0, 0.0);
        let step = 0.01;
        let n = 800;
        for j in -n..=n {
            for i in -n..=n {
                let (x, y) = (i as f64 * step, j as f64 * step);
                let e = (-0.5 * (x * x + y * y)).exp();
                if e > f {
                    s0 += e - f;
                    s2 += (e - f) * x * x;
                }
            }
        }
        let measured = s2 / s0; // variance of the weighted distribution, true variance 1
        assert!(
            (measured * moment_correction(f) - 1.0).abs() < 2e-3,
            "{}",
            measured * moment_correction(f)
        );
    }

    /// The three pixels of a pixel-integrated profile give back its centre and σ (exactly: the
    /// model is theirs), including a centre on the middle pixel's edge; a side lost in the
    /// noise (here: negative) still gives a start near the truth.
    #[test]
    fn narrow_axis_recovers_a_pixel_integrated_profile() {
        let cdf = |z: f64| 0.5 * libm::erfc(-z * std::f64::consts::FRAC_1_SQRT_2);
        let pixels = |d: f64, s: f64| -> [f64; 3] {
            std::array::from_fn(|k| {
                let e = k as f64 - 1.0;
                800.0 * (cdf((e + 0.5 - d) / s) - cdf((e - 0.5 - d) / s))
            })
        };
        for s in [0.2, 0.3, 0.45, 0.6] {
            for d in [-0.5, -0.37, 0.0, 0.12, 0.31] {
                let c = pixels(d, s);
                let (dd, ss) = narrow_axis(c).unwrap_or_else(|| panic!("{s} {d}: {c:?}"));
                if c[0].min(c[2]) >= SIDE_MIN * c[1] {
                    assert!(
                        (dd - d).abs() < 1e-6 && (ss - s).abs() < 1e-6,
                        "{s} {d}: {dd} {ss}"
                    );
                } else {
                    // (a side below SIDE_MIN of the middle, taken at that)
                    assert!((dd - d).abs() < 0.1 && ss < 0.35, "{s} {d}: {dd} {ss}");
                }
            }
        }
        let mut c = pixels(0.2, 0.3);
        c[0] = -12.0;
        let (d, s) = narrow_axis(c).expect("a start");
        assert!((d - 0.2).abs() < 0.1 && (s - 0.3).abs() < 0.1, "{d} {s}");
        // no profile: the middle pixel well below a side
        assert!(narrow_axis([500.0, 100.0, 10.0]).is_none());
    }

    /// A σ 0.3 px dot off the pixel centre: the thresholded moments put it on the peak pixel's
    /// centre with the variance floor; the narrow start is within a hundredth of a pixel.
    #[test]
    fn the_narrow_start_finds_a_narrow_dots_centre() {
        let win = bostrack_core::Window::new(10, 20, 7, 7);
        for (dx, dy) in [(0.3, -0.2), (-0.45, 0.1), (0.0, 0.0)] {
            let g = bostrack_core::Gaussian2D {
                x0: 13.0 + dx,
                y0: 23.0 + dy,
                amplitude: 1000.0,
                sigma_x: 0.3,
                sigma_y: 0.35,
                rho: 0.0,
                background: 50.0,
            };
            let mut ws = Workspace::default();
            ws.resize(win.x, win.y, win.width, win.height);
            ws.data
                .copy_from_slice(&bostrack_model::render(&g, win, Sampling::Integrated));
            ws.keep.fill(1.0);
            ws.n_used = ws.len();
            let mut t = moments(&mut ws, [13.0, 23.0], Sampling::Integrated)
                .expect("moments")
                .theta();
            assert!(narrow_start(&ws, &mut t));
            assert!(
                (t[IX] - g.x0).abs() < 0.01 && (t[IY] - g.y0).abs() < 0.01,
                "{dx} {dy}: {t:?}"
            );
            assert!((t[IU].exp() - 0.3).abs() < 0.02 && (t[IV].exp() - 0.35).abs() < 0.02);
        }
    }
}
