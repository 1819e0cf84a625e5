//! The dot size from the image, once the dots are located: a least-squares fit of the lattice
//! of Gaussian dots to patches around well-surrounded dots.
//!
//! The autocorrelation's central lobe gives the size well when the dots are separated, but for
//! dots that overlap heavily (diameter near the spacing) the pattern is close to a sinusoid and
//! the lobe shape hardly depends on the size. In the image, with the dot positions known, the
//! fit is well posed: around a dot, the image is modelled as
//! `v(x) = b + A Σ_n exp(-|x - p_n|² / (2 σe²))` over the dot and its 8 index neighbours
//! (positions `p_n` from the grid map), `σe² = σ² + 1/12` (pixel integration), with `b` and
//! `A` per patch (linear least squares) and `σ` common: the σ of smallest total residual over a
//! search grid, refined by a parabola.

use crate::linalg::{gauss_samples, median};
use bostrack_core::{Image, Window};
use rayon::prelude::*;

/// One patch: the centre dot and its neighbours' positions (the centre first).
pub(crate) struct Patch {
    pub dots: Vec<[f64; 2]>,
}

/// Residual sum of squares of the best `b + A m` fit on one patch for one σ, or `None` when the
/// patch leaves the image or the fit is degenerate.
fn patch_rss(img: &Image, sign: f64, patch: &Patch, half: usize, sigma: f64) -> Option<f64> {
    let (w, h) = (img.width(), img.height());
    let c = patch.dots[0];
    let win = Window::centred(c[0], c[1], half);
    if win.clip(w, h) != Some(win) {
        return None;
    }
    let (x0, y0) = (win.x as usize, win.y as usize);
    let n = win.width;
    let inv2 = -0.5 / (sigma * sigma + 1.0 / 12.0);
    // Separable Gaussians of each dot over the window's columns and rows.
    let mut gx = vec![0.0; patch.dots.len() * n];
    let mut gy = vec![0.0; patch.dots.len() * n];
    let q = (2.0 * inv2).exp();
    for (d, p) in patch.dots.iter().enumerate() {
        gauss_samples(&mut gx[d * n..(d + 1) * n], x0 as f64 - p[0], inv2, q);
        gauss_samples(&mut gy[d * n..(d + 1) * n], y0 as f64 - p[1], inv2, q);
    }
    let (mut sm, mut smm, mut sv, mut smv, mut svv, mut cnt) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for ky in 0..n {
        let row = &img.row(y0 + ky)[x0..x0 + n];
        for (kx, &raw) in row.iter().enumerate() {
            if !raw.is_finite() {
                continue;
            }
            let v = sign * raw;
            let m: f64 = (0..patch.dots.len())
                .map(|d| gx[d * n + kx] * gy[d * n + ky])
                .sum();
            sm += m;
            smm += m * m;
            sv += v;
            smv += m * v;
            svv += v * v;
            cnt += 1.0;
        }
    }
    let det = cnt * smm - sm * sm;
    if det.is_nan() || det <= 1e-12 * cnt * smm.max(1e-300) {
        return None;
    }
    let a = (cnt * smv - sm * sv) / det;
    let b = (sv - a * sm) / cnt;
    if a.is_nan() || a <= 0.0 {
        return None;
    }
    Some(
        (svv - 2.0 * a * smv - 2.0 * b * sv + a * a * smm + 2.0 * a * b * sm + b * b * cnt)
            .max(0.0),
    )
}

/// The dot sigma (px) that best fits the patches, searched between 0.3 px and 0.35 spacing;
/// `None` with fewer than 5 usable patches.
pub(crate) fn fit_sigma(img: &Image, sign: f64, patches: &[Patch], spacing: f64) -> Option<f64> {
    let half = ((0.5 * spacing).round() as usize).max(1);
    let (lo, hi) = (0.3f64, (0.35 * spacing).max(0.31));
    let k = 16;
    let sig = |t: f64| lo * (hi / lo).powf(t / (k - 1) as f64);
    // Patches usable at every σ of the grid (the same set for every σ).
    let usable: Vec<&Patch> = patches
        .iter()
        .filter(|p| patch_rss(img, sign, p, half, sig(0.0)).is_some())
        .collect();
    if usable.len() < 5 {
        return None;
    }
    // Each patch's residual is normalised by its median over the grid, so that bright patches
    // do not dominate.
    // Each patch on its own (in parallel; the same table whatever the threads).
    let table: Vec<f64> = usable
        .par_iter()
        .flat_map_iter(|p| {
            (0..k)
                .map(move |s| patch_rss(img, sign, p, half, sig(s as f64)).unwrap_or(f64::INFINITY))
        })
        .collect();
    let mut cost = vec![0.0; k];
    let mut used = 0;
    for pi in 0..usable.len() {
        let row = &table[pi * k..(pi + 1) * k];
        if row.iter().any(|r| !r.is_finite()) {
            continue;
        }
        let mut tmp = row.to_vec();
        let m = median(&mut tmp);
        if m.is_nan() || m <= 0.0 {
            continue;
        }
        for s in 0..k {
            cost[s] += row[s] / m;
        }
        used += 1;
    }
    if used < 5 {
        return None;
    }
    let (best, _) = cost.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    let mut t = best as f64;
    if best > 0 && best + 1 < k {
        let (a, b, c) = (cost[best - 1], cost[best], cost[best + 1]);
        let den = a - 2.0 * b + c;
        if den > 0.0 {
            t += (0.5 * (a - c) / den).clamp(-0.5, 0.5);
        }
    }
    Some(sig(t))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_the_sigma_of_overlapping_dots() {
        // Square lattice, spacing 5 px, sigma 1.1 px (diameter 0.88 spacing): dots overlap.
        let (s, sigma) = (5.0, 1.1);
        let img = Image::from_fn(60, 60, |x, y| {
            let mut v = 50.0;
            for j in -2..14 {
                for i in -2..14 {
                    let (cx, cy) = (2.3 + s * i as f64, 1.7 + s * j as f64);
                    let r2 = (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2);
                    v += 800.0 * (-r2 / (2.0 * (sigma * sigma + 1.0 / 12.0))).exp();
                }
            }
            v
        });
        let mut patches = Vec::new();
        for j in 2..10 {
            for i in 2..10 {
                let mut dots = vec![[2.3 + s * i as f64, 1.7 + s * j as f64]];
                for dj in -1..=1 {
                    for di in -1..=1 {
                        if (di, dj) != (0, 0) {
                            dots.push([2.3 + s * (i + di) as f64, 1.7 + s * (j + dj) as f64]);
                        }
                    }
                }
                patches.push(Patch { dots });
            }
        }
        let got = fit_sigma(&img, 1.0, &patches, s).unwrap();
        assert!((got - sigma).abs() < 0.02, "{got}");
    }
}
