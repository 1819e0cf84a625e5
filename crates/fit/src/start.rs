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
    for j in 0..h {
        for i in 0..w {
            if (j == 0 || j + 1 == h || i == 0 || i + 1 == w) && ws.keep[j * w + i] > 0.0 {
                ws.sort_buf.push(ws.data[j * w + i]);
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
    let min_var = 0.25f64.powi(2);
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
}
