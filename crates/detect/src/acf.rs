//! The lattice basis and the dot size from the autocorrelation of one image crop.
//!
//! A dot lattice's autocorrelation has a peak at every lattice vector, whatever the rotation,
//! the missing dots or the brightness; its central lobe is the dots' own autocorrelation, a
//! Gaussian of variance `2(σ² + 1/12)` for pixel-integrated dots of sigma σ. The crop is
//! detrended (quadratic surface: vignetting), masked-out and non-finite pixels get weight 0,
//! and the correlation is normalised by that of the weights (the mean over the overlapping valid
//! pairs at each lag), computed with one zero-padded FFT pair.

use crate::fft::Fft;
use crate::linalg::solve_spd;
use bostrack_core::{Image, Mask};
use rayon::prelude::*;

/// What the autocorrelation says about the lattice.
#[derive(Clone, Copy, Debug)]
pub(crate) struct AcfEstimate {
    /// Reduced basis (the two shortest non-collinear lattice vectors), px.
    pub v1: [f64; 2],
    pub v2: [f64; 2],
    /// Dot sigma, px (rough).
    pub sigma: f64,
}

fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}
fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}
fn norm(a: [f64; 2]) -> f64 {
    a[0].hypot(a[1])
}

/// Lagrange-Gauss reduction: the basis of the same lattice with the shortest vectors.
pub(crate) fn reduce(mut u: [f64; 2], mut v: [f64; 2]) -> ([f64; 2], [f64; 2]) {
    for _ in 0..32 {
        if dot(u, u) > dot(v, v) {
            std::mem::swap(&mut u, &mut v);
        }
        let m = (dot(u, v) / dot(u, u)).round();
        if m == 0.0 {
            break;
        }
        v = [v[0] - m * u[0], v[1] - m * u[1]];
    }
    if dot(u, u) > dot(v, v) {
        std::mem::swap(&mut u, &mut v);
    }
    (u, v)
}

/// Estimate the lattice from the `n x n` crop (n a power of two) centred as near `centre` as
/// the image allows. `Err` says why no clear lattice was seen.
pub(crate) fn estimate(
    img: &Image,
    sign: f64,
    mask: Option<&Mask>,
    centre: [f64; 2],
    n: usize,
) -> Result<AcfEstimate, String> {
    let (w, h) = (img.width(), img.height());
    let x0 = ((centre[0] - n as f64 / 2.0).round() as i64).clamp(0, (w - n) as i64) as usize;
    let y0 = ((centre[1] - n as f64 / 2.0).round() as i64).clamp(0, (h - n) as i64) as usize;

    // Crop, validity weights, quadratic detrend over the valid pixels.
    let mut f = vec![0.0f64; n * n];
    let mut m = vec![0.0f64; n * n];
    let mut ata = [0.0f64; 36];
    let mut atb = [0.0f64; 6];
    let half = n as f64 / 2.0;
    let terms = |x: usize, y: usize| {
        let (u, v) = ((x as f64 - half) / half, (y as f64 - half) / half);
        [1.0, u, v, u * u, u * v, v * v]
    };
    let mut nvalid = 0usize;
    for y in 0..n {
        for x in 0..n {
            let v = img.get(x0 + x, y0 + y);
            let keep = v.is_finite() && mask.is_none_or(|mk| mk.keeps(x0 + x, y0 + y));
            if keep {
                let v = sign * v;
                f[y * n + x] = v;
                m[y * n + x] = 1.0;
                nvalid += 1;
                let t = terms(x, y);
                for r in 0..6 {
                    atb[r] += t[r] * v;
                    for c in 0..=r {
                        ata[r * 6 + c] += t[r] * t[c];
                    }
                }
            }
        }
    }
    if nvalid < n * n / 8 {
        return Err(format!(
            "only {nvalid} valid pixels in the {n}x{n} analysis crop"
        ));
    }
    for r in 0..6 {
        for c in r + 1..6 {
            ata[r * 6 + c] = ata[c * 6 + r];
        }
    }
    let trend = if solve_spd(&mut ata, &mut atb, 6) {
        atb
    } else {
        [0.0; 6]
    };
    let mut var = 0.0;
    for y in 0..n {
        for x in 0..n {
            if m[y * n + x] > 0.0 {
                let t = terms(x, y);
                let tr: f64 = t.iter().zip(&trend).map(|(a, b)| a * b).sum();
                f[y * n + x] -= tr;
                var += f[y * n + x].powi(2);
            }
        }
    }
    if var.is_nan() || var <= 0.0 {
        return Err("the analysis crop has no contrast".into());
    }

    // Zero-padded correlation of f and m in one complex FFT pair.
    let p = 2 * n;
    let mut re = vec![0.0f64; p * p];
    let mut im = vec![0.0f64; p * p];
    for y in 0..n {
        re[y * p..y * p + n].copy_from_slice(&f[y * n..(y + 1) * n]);
        im[y * p..y * p + n].copy_from_slice(&m[y * n..(y + 1) * n]);
    }
    let fft = Fft::new(p);
    fft.run_2d(&mut re, &mut im, false);
    let mut pr = vec![0.0f64; p * p];
    let mut pi = vec![0.0f64; p * p];
    for ky in 0..p {
        for kx in 0..p {
            let k = ky * p + kx;
            let q = ((p - ky) % p) * p + (p - kx) % p;
            // Z = F + iM with F, M the spectra of the real inputs f and m.
            let (fr, fi) = (0.5 * (re[k] + re[q]), 0.5 * (im[k] - im[q]));
            let (mr, mi) = (0.5 * (im[k] + im[q]), -0.5 * (re[k] - re[q]));
            pr[k] = fr * fr + fi * fi;
            pi[k] = mr * mr + mi * mi;
        }
    }
    fft.run_2d(&mut pr, &mut pi, true);

    // Normalised correlation A(τ) for |τx|, |τy| <= L.
    let l = n / 2;
    let side = 2 * l + 1;
    let m0 = pi[0];
    let mut a = vec![f64::NAN; side * side];
    for dy in -(l as i64)..=l as i64 {
        for dx in -(l as i64)..=l as i64 {
            let k = (dy.rem_euclid(p as i64) as usize) * p + dx.rem_euclid(p as i64) as usize;
            if pi[k] >= 0.3 * m0 {
                a[(dy + l as i64) as usize * side + (dx + l as i64) as usize] = pr[k] / pi[k];
            }
        }
    }
    let at = |dx: i64, dy: i64| -> f64 {
        if dx.abs() > l as i64 || dy.abs() > l as i64 {
            return f64::NAN;
        }
        a[(dy + l as i64) as usize * side + (dx + l as i64) as usize]
    };

    // Ring means (lag 0 carries the noise variance and is left out of everything below).
    let mut ring = vec![0.0f64; l + 2];
    let mut cnt = vec![0usize; l + 2];
    for dy in -(l as i64)..=l as i64 {
        for dx in -(l as i64)..=l as i64 {
            let r = ((dx * dx + dy * dy) as f64).sqrt().round() as usize;
            let v = at(dx, dy);
            if r <= l && v.is_finite() {
                ring[r] += v;
                cnt[r] += 1;
            }
        }
    }
    for r in 0..=l {
        ring[r] = if cnt[r] > 0 {
            ring[r] / cnt[r] as f64
        } else {
            f64::NAN
        };
    }
    let mut rc = 1;
    while rc + 1 < l && ring[rc].is_finite() && ring[rc + 1].is_finite() && ring[rc + 1] < ring[rc]
    {
        rc += 1;
    }
    let floor = ring[rc];

    // Smoothed correlation for the peak search (binomial 3x3, ignoring missing lags).
    let smooth = |dx: i64, dy: i64| -> f64 {
        let (mut s, mut wsum) = (0.0, 0.0);
        for (oy, wy) in [(-1i64, 1.0), (0, 2.0), (1, 1.0)] {
            for (ox, wx) in [(-1i64, 1.0), (0, 2.0), (1, 1.0)] {
                let v = at(dx + ox, dy + oy);
                if v.is_finite() && (dx + ox, dy + oy) != (0, 0) {
                    s += wx * wy * v;
                    wsum += wx * wy;
                }
            }
        }
        if wsum > 0.0 { s / wsum } else { f64::NAN }
    };
    let lm = l as i64 - 1;
    let rmin = (rc as f64).max(2.0);
    let mut cands: Vec<([i64; 2], f64)> = Vec::new();
    for dy in 0..=lm {
        for dx in -lm..=lm {
            if dy == 0 && dx <= 0 {
                continue;
            }
            let r = ((dx * dx + dy * dy) as f64).sqrt();
            if r < rmin || r > lm as f64 {
                continue;
            }
            let v = smooth(dx, dy);
            if v.is_nan() || v <= floor {
                continue;
            }
            let mut is_max = true;
            'n: for oy in -1..=1 {
                for ox in -1..=1 {
                    if (ox, oy) != (0, 0) {
                        let nv = smooth(dx + ox, dy + oy);
                        if nv > v || (nv == v && (oy < 0 || (oy == 0 && ox < 0))) {
                            is_max = false;
                            break 'n;
                        }
                    }
                }
            }
            if is_max {
                cands.push(([dx, dy], v));
            }
        }
    }
    let vmax = cands.iter().map(|c| c.1).fold(f64::NEG_INFINITY, f64::max);
    if cands.is_empty() {
        return Err(format!("no autocorrelation peak within {lm} px"));
    }
    let height = vmax - floor;
    cands.retain(|c| c.1 - floor >= 0.4 * height);
    let len = |t: [i64; 2]| ((t[0] * t[0] + t[1] * t[1]) as f64).sqrt();
    cands.sort_by(|p, q| len(p.0).total_cmp(&len(q.0)));
    let c1 = cands[0];
    let Some(c2) = cands[1..].iter().find(|c| {
        let (u, v) = (
            [c1.0[0] as f64, c1.0[1] as f64],
            [c.0[0] as f64, c.0[1] as f64],
        );
        cross(u, v).abs() >= 0.5 * norm(u) * norm(v)
    }) else {
        return Err("the autocorrelation shows no second lattice direction".into());
    };
    let refine = |t: [i64; 2]| -> [f64; 2] {
        let (x, y) = (t[0], t[1]);
        let c = smooth(x, y);
        let px = parabola(smooth(x - 1, y), c, smooth(x + 1, y));
        let py = parabola(smooth(x, y - 1), c, smooth(x, y + 1));
        [x as f64 + px, y as f64 + py]
    };
    let (v1, v2) = (refine(c1.0), refine(c2.0));

    // Confirmation: v1 + v2 or v1 - v2 must be a peak as well.
    let weakest = c1.1.min(c2.1);
    let mut confirmed = false;
    let mut checked = false;
    for s in [1.0, -1.0] {
        let t = [v1[0] + s * v2[0], v1[1] + s * v2[1]];
        if norm(t) > lm as f64 - 1.0 {
            continue;
        }
        checked = true;
        let (tx, ty) = (t[0].round() as i64, t[1].round() as i64);
        let mut best = f64::NEG_INFINITY;
        for oy in -1..=1 {
            for ox in -1..=1 {
                let v = smooth(tx + ox, ty + oy);
                if v.is_finite() {
                    best = best.max(v);
                }
            }
        }
        if best - floor >= 0.3 * (weakest - floor) {
            confirmed = true;
        }
    }
    if !checked {
        return Err(format!(
            "lattice vectors of {:.1} px are too long for the {n}x{n} crop",
            norm(v2)
        ));
    }
    if !confirmed {
        return Err("the autocorrelation peaks do not form a lattice".into());
    }
    let (v1, v2) = reduce(v1, v2);

    let sigma = lobe_sigma(&at, v1, v2);
    Ok(AcfEstimate { v1, v2, sigma })
}

/// Dot sigma from the autocorrelation near lag 0. Model: the lobes of the dot lattice,
/// `A(τ) = C Σ_L exp(-|τ - L|² / (2 s²)) + F` over L = 0 and the eight nearest lattice vectors,
/// with `s² = 2(σ² + 1/12)` (the autocorrelation of a pixel-integrated Gaussian dot), fitted by
/// least squares (C, F linear; σ by a search over 60 values from 0.3 px to 0.4 spacing, refined
/// by a parabola) to the lags `0 < |τ| <= spacing/2`. The neighbours' lobes make it right for
/// overlapping dots; lag 0 (noise variance) is left out.
fn lobe_sigma(at: &impl Fn(i64, i64) -> f64, v1: [f64; 2], v2: [f64; 2]) -> f64 {
    let spacing = norm(v1).min(norm(v2));
    let r = 0.5 * spacing;
    let ri = r.floor() as i64;
    let mut lags: Vec<([f64; 2], f64)> = Vec::new();
    for dy in -ri..=ri {
        for dx in -ri..=ri {
            let d2 = (dx * dx + dy * dy) as f64;
            if d2 == 0.0 || d2 > r * r {
                continue;
            }
            let v = at(dx, dy);
            if v.is_finite() {
                lags.push(([dx as f64, dy as f64], v));
            }
        }
    }
    let step = lags.len().div_ceil(200).max(1);
    let lags: Vec<([f64; 2], f64)> = lags.into_iter().step_by(step).collect();
    let lattice: Vec<[f64; 2]> = [
        (0.0, 0.0),
        (1.0, 0.0),
        (-1.0, 0.0),
        (0.0, 1.0),
        (0.0, -1.0),
        (1.0, 1.0),
        (-1.0, -1.0),
        (1.0, -1.0),
        (-1.0, 1.0),
    ]
    .iter()
    .map(|&(p, q)| [p * v1[0] + q * v2[0], p * v1[1] + q * v2[1]])
    .collect();
    let (lo, hi) = (0.3f64, (0.4 * spacing).max(0.31));
    let n = 60;
    let sig = |k: usize| lo * (hi / lo).powf(k as f64 / (n - 1) as f64);
    let cost = |sigma: f64| -> f64 {
        let s2 = 2.0 * (sigma * sigma + 1.0 / 12.0);
        let (mut sf, mut sff, mut sa, mut sfa, mut saa, mut m) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for (t, a) in &lags {
            let f: f64 = lattice
                .iter()
                .map(|l| (-((t[0] - l[0]).powi(2) + (t[1] - l[1]).powi(2)) / (2.0 * s2)).exp())
                .sum();
            sf += f;
            sff += f * f;
            sa += a;
            sfa += f * a;
            saa += a * a;
            m += 1.0;
        }
        let det = m * sff - sf * sf;
        if det.is_nan() || det <= 1e-12 {
            return f64::INFINITY;
        }
        let c = (m * sfa - sf * sa) / det;
        if c.is_nan() || c <= 0.0 {
            return f64::INFINITY;
        }
        let f0 = (sa - c * sf) / m;
        // Residual sum of squares of the linear fit.
        saa - 2.0 * c * sfa - 2.0 * f0 * sa + c * c * sff + 2.0 * c * f0 * sf + f0 * f0 * m
    };
    // Each σ on its own (in parallel; the same values whatever the threads).
    let costs: Vec<f64> = (0..n).into_par_iter().map(|k| cost(sig(k))).collect();
    let Some((kbest, _)) = costs
        .iter()
        .enumerate()
        .filter(|(_, c)| c.is_finite())
        .min_by(|a, b| a.1.total_cmp(b.1))
    else {
        return 0.25 * spacing;
    };
    let mut t = kbest as f64;
    if kbest > 0 && kbest + 1 < n && costs[kbest - 1].is_finite() && costs[kbest + 1].is_finite() {
        t += parabola(-costs[kbest - 1], -costs[kbest], -costs[kbest + 1]);
    }
    (lo * (hi / lo).powf(t / (n - 1) as f64)).clamp(0.3, 0.4 * spacing)
}

fn parabola(a: f64, b: f64, c: f64) -> f64 {
    let den = a - 2.0 * b + c;
    if den < 0.0 && a.is_finite() && c.is_finite() {
        (0.5 * (a - c) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reduction_finds_the_short_basis() {
        let (u, v) = reduce([8.0, 0.0], [24.0, 8.0]);
        assert_eq!(u, [8.0, 0.0]);
        assert_eq!(v, [0.0, 8.0]);
    }
}
