//! The pixel noise model (read + shot noise) estimated from a single image or from a no-flow
//! stack, never from fit residuals (which also hold the model mismatch).

use crate::FitError;
use bostrack_core::{Image, Mask, NoiseModel};
use rayon::prelude::*;

/// One intensity bin of a noise estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseBin {
    /// Mean intensity of the bin's pixels (counts).
    pub mean: f64,
    /// Robust noise variance of the bin (counts²).
    pub variance: f64,
    /// Pixels in the bin.
    pub count: usize,
    /// Whether the line fit kept the bin (false: rejected as an outlier).
    pub used: bool,
}

/// A noise model with the binned variance-versus-mean curve it was fitted to.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseFit {
    pub model: NoiseModel,
    pub bins: Vec<NoiseBin>,
}

/// Number of intensity bins (equal pixel counts).
const N_BINS: usize = 32;

/// 1-D 4th-difference kernel [1, -4, 6, -4, 1] / sqrt(70) (unit noise gain).
const HP: [f64; 5] = [1.0, -4.0, 6.0, -4.0, 1.0];
const HP_NORM: f64 = 70.0;

/// Noise model of a single image, with no flow-free stack needed.
///
/// Method: a high-pass residual `r = (h ⊗ h) * I` with the 4th-difference kernel
/// `h = [1, -4, 6, -4, 1]/√70` (unit gain for white noise; it passes almost nothing of a
/// Gaussian dot of σ ≳ 1.3 px, whose spectrum is ~e^{-k²σ²/2}, while white noise is strongest at
/// the highest frequencies). For noise whose variance varies in space, `var(r)` is the
/// `h²`-weighted mean of the pixel variances, and because the model is linear in the mean,
/// `var(r) = read + gain·(m - offset)` with `m = (h² ⊗ h²) * I / Σh²`: each pixel is binned by
/// that matching local mean. Per bin (32 bins of equal counts) the variance is
/// `(1.4826 · median|r|)²` (robust against the few pixels where dot structure leaks through),
/// then a weighted straight line `variance = α + β·mean` is fitted with 3σ rejection of outlier
/// bins. The model has `gain = β` (≥ 0), `offset` = mean of the darkest bin and
/// `read_variance` = the line at that offset. Pixels whose 5×5 support is not entirely usable
/// (masked, non-finite, saturated) are not used.
///
/// Checked on synthetic images with known read + shot noise (within 10 %, test
/// `estimate_noise_recovers_synthetic_noise`). It over-states the noise where dots are much
/// smaller than σ ≈ 1.3 px (their structure passes the filter): use [`noise_from_stack`] then.
pub fn estimate_noise(img: &Image, mask: Option<&Mask>) -> Result<NoiseModel, FitError> {
    estimate_noise_detailed(img, mask).map(|f| f.model)
}

/// [`estimate_noise`] with the binned curve.
pub fn estimate_noise_detailed(img: &Image, mask: Option<&Mask>) -> Result<NoiseFit, FitError> {
    check_mask(img, mask)?;
    let (w, h) = (img.width(), img.height());
    if w < 5 || h < 5 {
        return Err(FitError::Noise(format!(
            "image of {w}x{h} pixels is smaller than the 5x5 filter"
        )));
    }
    let usable: Vec<bool> = (0..w * h)
        .into_par_iter()
        .map(|k| {
            let v = img.data()[k];
            v.is_finite() && !img.is_saturated(v) && mask.is_none_or(|m| m.as_slice()[k])
        })
        .collect();
    // separable passes: rows then columns, for the high-pass (h) and the weights (h²); rows in
    // parallel, the residuals collected in row order (the same for any thread count)
    let hp2: [f64; 5] = HP.map(|c| c * c);
    let hp2_sum: f64 = hp2.iter().sum();
    let mut row_hp = vec![0.0; w * h];
    let mut row_lp = vec![0.0; w * h];
    let mut row_ok = vec![false; w * h];
    row_hp
        .par_chunks_mut(w)
        .zip(row_lp.par_chunks_mut(w))
        .zip(row_ok.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, ((hp, lp), okr))| {
            let data = &img.data()[y * w..(y + 1) * w];
            let use_row = &usable[y * w..(y + 1) * w];
            for x in 2..w - 2 {
                let (mut a, mut b, mut ok) = (0.0, 0.0, true);
                for t in 0..5 {
                    let xx = x + t - 2;
                    ok &= use_row[xx];
                    let v = data[xx];
                    a += HP[t] * v;
                    b += hp2[t] * v;
                }
                hp[x] = a;
                lp[x] = b;
                okr[x] = ok;
            }
        });
    // residual and matching mean per pixel (NaN where not usable), rows in parallel, then the
    // usable ones in pixel order
    let mut per_pixel = vec![(f64::NAN, f64::NAN); w * h];
    per_pixel
        .par_chunks_mut(w)
        .enumerate()
        .filter(|(y, _)| (2..h - 2).contains(y))
        .for_each(|(y, out)| {
            for (x, o) in out.iter_mut().enumerate().take(w - 2).skip(2) {
                let k = y * w + x;
                let (mut a, mut b, mut ok) = (0.0, 0.0, true);
                for t in 0..5 {
                    let kk = k + (t * w) - 2 * w;
                    ok &= row_ok[kk];
                    a += HP[t] * row_hp[kk];
                    b += hp2[t] * row_lp[kk];
                }
                if ok {
                    *o = (b / (hp2_sum * hp2_sum), a / HP_NORM);
                }
            }
        });
    let mut pairs: Vec<(f64, f64)> = per_pixel.into_iter().filter(|p| !p.0.is_nan()).collect();
    let bins = bin_robust(&mut pairs, |rs| {
        let med = median_abs(rs);
        (1.482_602_218_505_602 * med).powi(2)
    })?;
    fit_line(bins)
}

/// Noise model from K ≥ 2 images of the same scene without flow: per-pixel temporal mean and
/// unbiased variance (after removing each frame's mean offset from the stack mean, so global
/// brightness drift is not counted as pixel noise), binned by mean (32 bins of equal counts),
/// per-bin variance = median of the pixel variances divided by the median of χ²_{K-1}/(K-1)
/// (Wilson-Hilferty), then the same robust line fit as [`estimate_noise`]. Pixels masked,
/// non-finite or saturated in any frame are not used.
pub fn noise_from_stack(stack: &[Image], mask: Option<&Mask>) -> Result<NoiseModel, FitError> {
    noise_from_stack_detailed(stack, mask).map(|f| f.model)
}

/// [`noise_from_stack`] with the binned curve.
pub fn noise_from_stack_detailed(
    stack: &[Image],
    mask: Option<&Mask>,
) -> Result<NoiseFit, FitError> {
    if stack.len() < 2 {
        return Err(FitError::StackTooShort(stack.len()));
    }
    let first = &stack[0];
    let (w, h) = (first.width(), first.height());
    for (index, img) in stack.iter().enumerate() {
        if img.width() != w || img.height() != h {
            return Err(FitError::StackSize {
                index,
                width: img.width(),
                height: img.height(),
                first_w: w,
                first_h: h,
            });
        }
    }
    check_mask(first, mask)?;
    let usable: Vec<bool> = (0..w * h)
        .into_par_iter()
        .map(|k| {
            mask.is_none_or(|m| m.as_slice()[k])
                && stack.iter().all(|img| {
                    let v = img.data()[k];
                    v.is_finite() && !img.is_saturated(v)
                })
        })
        .collect();
    let n_used = usable.iter().filter(|&&u| u).count();
    if n_used == 0 {
        return Err(FitError::Noise(
            "no pixel is usable in every frame of the stack".into(),
        ));
    }
    let frame_means: Vec<f64> = stack
        .par_iter()
        .map(|img| {
            img.data()
                .iter()
                .zip(&usable)
                .filter(|(_, u)| **u)
                .map(|(v, _)| v)
                .sum::<f64>()
                / n_used as f64
        })
        .collect();
    let grand = frame_means.iter().sum::<f64>() / stack.len() as f64;
    let kf = stack.len() as f64;
    // per-pixel temporal mean and variance (NaN where not usable), rows in parallel, then the
    // usable ones in pixel order
    let mut per_pixel = vec![(f64::NAN, f64::NAN); w * h];
    per_pixel
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, out)| {
            for (x, o) in out.iter_mut().enumerate() {
                let k = y * w + x;
                if !usable[k] {
                    continue;
                }
                let mut s = 0.0;
                let mut s2 = 0.0;
                for (img, fm) in stack.iter().zip(&frame_means) {
                    let v = img.data()[k] - (fm - grand);
                    s += v;
                    s2 += v * v;
                }
                let mean = s / kf;
                let var = ((s2 - s * mean) / (kf - 1.0)).max(0.0);
                *o = (mean, var);
            }
        });
    let mut pairs: Vec<(f64, f64)> = per_pixel.into_iter().filter(|p| !p.0.is_nan()).collect();
    let nu = kf - 1.0;
    let chi2_median = (1.0 - 2.0 / (9.0 * nu)).powi(3); // median of χ²_ν / ν
    let bins = bin_robust(&mut pairs, |vs| median(vs) / chi2_median)?;
    fit_line(bins)
}

fn check_mask(img: &Image, mask: Option<&Mask>) -> Result<(), FitError> {
    match mask {
        Some(m) if !m.matches(img) => Err(FitError::MaskSize {
            mask_w: m.width(),
            mask_h: m.height(),
            img_w: img.width(),
            img_h: img.height(),
        }),
        _ => Ok(()),
    }
}

/// Sorts `(mean, value)` pairs by mean, cuts them into `N_BINS` bins of equal counts and
/// applies `stat` to each bin's values.
fn bin_robust(
    pairs: &mut [(f64, f64)],
    stat: impl Fn(&mut [f64]) -> f64,
) -> Result<Vec<NoiseBin>, FitError> {
    if pairs.len() < 20 * N_BINS {
        return Err(FitError::Noise(format!(
            "only {} usable pixels, need at least {}",
            pairs.len(),
            20 * N_BINS
        )));
    }
    // rayon's parallel pattern-defeating quicksort: deterministic (its pivots do not depend on
    // the thread count), so the order of tied means, and the bins, depend only on the input
    // order, which is the pixel order (test `noise_estimates_do_not_depend_on_threads`)
    pairs.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    let n = pairs.len();
    let mut vals = Vec::with_capacity(n / N_BINS + 1);
    let mut bins = Vec::with_capacity(N_BINS);
    for b in 0..N_BINS {
        let (lo, hi) = (b * n / N_BINS, (b + 1) * n / N_BINS);
        let part = &pairs[lo..hi];
        vals.clear();
        vals.extend(part.iter().map(|p| p.1));
        let mean = part.iter().map(|p| p.0).sum::<f64>() / part.len() as f64;
        bins.push(NoiseBin {
            mean,
            variance: stat(&mut vals),
            count: part.len(),
            used: true,
        });
    }
    Ok(bins)
}

fn median(v: &mut [f64]) -> f64 {
    let k = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(k, f64::total_cmp);
    *m
}

fn median_abs(v: &mut [f64]) -> f64 {
    for x in v.iter_mut() {
        *x = x.abs();
    }
    median(v)
}

/// Weighted straight line through the bins' variances (weights count / variance², the
/// inverse variance of a variance estimate), refitted without bins more than 3 standard
/// errors off (up to 5 rounds), then turned into a [`NoiseModel`].
fn fit_line(mut bins: Vec<NoiseBin>) -> Result<NoiseFit, FitError> {
    // relative standard error of a robust variance estimate from n values (MAD efficiency 37 %)
    let rel = |b: &NoiseBin| 2.33 / (b.count as f64).sqrt();
    let mut line = (0.0, 0.0);
    for _ in 0..5 {
        let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for b in bins.iter().filter(|b| b.used) {
            let wgt = 1.0 / (rel(b) * b.variance.max(1e-12)).powi(2);
            sw += wgt;
            sx += wgt * b.mean;
            sy += wgt * b.variance;
            sxx += wgt * b.mean * b.mean;
            sxy += wgt * b.mean * b.variance;
        }
        let det = sw * sxx - sx * sx;
        line = if det > 1e-12 * sw * sxx {
            let beta = (sw * sxy - sx * sy) / det;
            ((sy - beta * sx) / sw, beta)
        } else {
            (sy / sw, 0.0)
        };
        let mut changed = false;
        for b in bins.iter_mut() {
            let pred = line.0 + line.1 * b.mean;
            let z = (b.variance - pred) / (rel(b) * pred.abs().max(1e-12));
            // a bin is rejected only while enough bins remain
            let keep = z.abs() <= 3.0;
            if keep != b.used {
                b.used = keep;
                changed = true;
            }
        }
        if bins.iter().filter(|b| b.used).count() < 4 {
            bins.iter_mut().for_each(|b| b.used = true);
            break;
        }
        if !changed {
            break;
        }
    }
    let offset = bins.iter().map(|b| b.mean).fold(f64::INFINITY, f64::min);
    let (alpha, beta) = line;
    let model = if beta > 0.0 {
        NoiseModel {
            read_variance: (alpha + beta * offset).max(1e-12),
            gain: beta,
            offset,
        }
    } else {
        // no growth with the signal: the weighted mean variance
        let (mut sw, mut s) = (0.0, 0.0);
        for b in bins.iter().filter(|b| b.used) {
            let wgt = b.count as f64;
            sw += wgt;
            s += wgt * b.variance;
        }
        NoiseModel {
            read_variance: (s / sw).max(1e-12),
            gain: 0.0,
            offset: 0.0,
        }
    };
    if !(model.read_variance.is_finite() && model.gain.is_finite()) {
        return Err(FitError::Noise(
            "the variance-versus-mean line is not finite".into(),
        ));
    }
    Ok(NoiseFit { model, bins })
}
