//! The pixel noise model (read + shot noise) estimated from a single image or from a no-flow
//! stack, never from fit residuals (which also hold the model mismatch).

use crate::FitError;
use crate::error::check_mask;
use bostrack_core::{Image, Mask, NoiseModel, SampleFormat};
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
    /// Standard errors of `model.read_variance` (counts²) and `model.gain` from the line fit:
    /// the weighted least-squares covariance scaled by the reduced χ² of the used bins when it
    /// exceeds 1 (so a curve that is not a straight line widens them). They are statistical
    /// only: a single image cannot tell static pixel-to-pixel variations from noise (see
    /// [`estimate_noise`]).
    pub read_variance_se: f64,
    pub gain_se: f64,
    /// Whether the line was resolved: `false` when it fell to zero or below at the darkest bin
    /// (the read variance is then the darkest used bin's variance, at its mean as the offset:
    /// the documented fall-back). A curve that
    /// does not grow with the mean gives gain 0 and the weighted mean variance (resolved).
    pub resolved: bool,
}

/// Number of intensity bins (equal pixel counts).
const N_BINS: usize = 32;

/// The 1-D 4th-difference kernel `h = [1, -4, 6, -4, 1] / √70` (unit noise gain) is applied with
/// its integer weights: the 2-D filter `h ⊗ h` is then `HP_NORM = 70` times too large. The
/// matching mean uses the integer weights `[1, 16, 36, 16, 1]` (70 times `h²`), whose sum is
/// `HP2_SUM = 70`: the local mean is the weighted sum divided by `HP2_SUM²`.
const HP_NORM: f64 = 70.0;
const HP2_SUM: f64 = 70.0;

/// Noise model of a single image, with no flow-free stack needed.
///
/// Method: a high-pass residual `r = (h ⊗ h) * I` with the 4th-difference kernel
/// `h = [1, -4, 6, -4, 1]/√70` (unit gain for white noise; it passes almost nothing of a
/// Gaussian dot of σ ≳ 1.3 px, whose spectrum is ~e^{-k²σ²/2}, while white noise is strongest at
/// the highest frequencies). For noise whose variance varies in space, `var(r)` is the
/// `h²`-weighted mean of the pixel variances, and because the model is linear in the mean,
/// `var(r) = read + gain·(m - offset)` with `m = (h² ⊗ h²) * I / Σh²`: each pixel is binned by
/// that matching local mean. Per bin (32 bins of equal counts: the pixels ranked by local mean,
/// ties in pixel order, and cut into 32 consecutive runs of ranks) the variance is
/// `(1.4826 · median|r|)²` (robust against the few pixels where dot structure leaks through),
/// then a weighted straight line `variance = α + β·mean` is fitted with 3σ rejection of outlier
/// bins. The model has `gain = β` (≥ 0), `offset` = mean of the darkest bin and
/// `read_variance` = the line at that offset. Pixels whose 5×5 support is not entirely usable
/// (masked, non-finite, saturated) are not used.
///
/// Checked on synthetic images with known read + shot noise (within 10 %, test
/// `estimate_noise_recovers_synthetic_noise`). It over-states the noise where dots are much
/// smaller than σ ≈ 1.3 px (their structure passes the filter): use [`noise_from_stack`] then.
/// Samples at the floor of unsigned data (0) are clipped and not used either.
///
/// A single image cannot tell noise from static pixel-to-pixel variations (fixed-pattern noise,
/// the print's texture), which are white too: the model is an upper bound of the temporal noise
/// (on the real sample's stack frames about twice the stack's variance; crates/fit/README.md).
/// [`estimate_noise_detailed`] gives the line's standard errors, and whether it was resolved
/// (where it falls to zero or below at the darkest bin, the read variance is the darkest used
/// bin's own, at its mean as the offset).
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
    // pairs (B, |A|) of integer-weighted sums, m = B / 70² and r = A / 70: the median of |r| is
    // the median of |A| divided by 70 exactly (division by a positive constant is monotone), and
    // ranking by B ranks by the exact local mean (ties are exact ties, none made by rounding)
    let src = SingleImage::new(img, mask);
    let bins = bin_medians(&src)?
        .into_iter()
        .map(|b| {
            let med = b.value / HP_NORM;
            NoiseBin {
                mean: b.mean / (HP2_SUM * HP2_SUM),
                variance: (1.482_602_218_505_602 * med).powi(2),
                count: b.count,
                used: true,
            }
        })
        .collect();
    fit_line(bins)
}

/// Noise model from K ≥ 2 images of the same scene without flow: per-pixel temporal mean and
/// unbiased variance (after removing each frame's mean offset from the stack mean, so global
/// brightness drift is not counted as pixel noise), binned by mean (32 bins of equal counts,
/// ranked by mean with ties in pixel order, as in [`estimate_noise`]),
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
    let src = stack_pairs(stack, mask)?;
    let kf = stack.len() as f64;
    let nu = kf - 1.0;
    let chi2_median = (1.0 - 2.0 / (9.0 * nu)).powi(3); // median of χ²_ν / ν
    let bins = bin_medians(&src)?
        .into_iter()
        .map(|b| NoiseBin {
            mean: b.mean,
            variance: b.value / chi2_median,
            count: b.count,
            used: true,
        })
        .collect();
    fit_line(bins)
}

/// The `(mean, variance)` pairs of [`noise_from_stack`], one part per band of `BAND` rows (the
/// images have the same size, at least 2, and the mask matches).
fn stack_pairs(stack: &[Image], mask: Option<&Mask>) -> Result<StoredParts, FitError> {
    let (w, h) = (stack[0].width(), stack[0].height());
    let keep = mask.map(Mask::as_slice);
    // per frame the limit below which a finite sample is not saturated
    let lim: Vec<f64> = stack.iter().map(usable_below).collect();
    let floor: Vec<f64> = stack.iter().map(usable_above).collect();
    let n_bands = h.div_ceil(BAND);
    let band_pixels = |band: usize| band * BAND * w..((band + 1) * BAND).min(h) * w;
    // Both passes go pixel by pixel (4 at a time, all frames for each: the frames are read as
    // parallel streams, and the 4 pixels vectorise), bands in parallel.
    //
    // Pass 1, per band: the pixels usable in every frame (and kept by the mask), and each
    // frame's sum over them (4 partial sums, by pixel index mod 4). Σ 0·v is NaN once a
    // sample is NaN or ±∞; max (v - lim) < 0 when none is saturated (for finite v, v - lim < 0
    // exactly when v < lim); the sums add the usable samples and +0 for the others (their bits
    // masked).
    let bands: Vec<(Vec<bool>, usize, Vec<[f64; 4]>)> = (0..n_bands)
        .into_par_iter()
        .map(|band| {
            let px = band_pixels(band);
            let data: Vec<&[f64]> = stack.iter().map(|img| &img.data()[px.clone()]).collect();
            let kept = keep.map(|m| &m[px.clone()]);
            let mut ok = vec![false; px.len()];
            let mut acc = vec![[0.0; 4]; stack.len()];
            let mut k = 0;
            while k < px.len() {
                let l = (px.len() - k).min(4);
                let (mut nonfinite, mut over, mut under) =
                    ([0.0; 4], [f64::NEG_INFINITY; 4], [f64::INFINITY; 4]);
                for ((d, &lim), &floor) in data.iter().zip(&lim).zip(&floor) {
                    let v = four(d, k);
                    for i in 0..4 {
                        nonfinite[i] += v[i] * 0.0;
                        let e = v[i] - lim;
                        over[i] = if e > over[i] { e } else { over[i] };
                        let f = v[i] - floor;
                        under[i] = if f < under[i] { f } else { under[i] };
                    }
                }
                let mut sel = [0u64; 4];
                for i in 0..l {
                    let o = (nonfinite[i] == 0.0)
                        & (over[i] < 0.0)
                        & (under[i] > 0.0)
                        & kept.is_none_or(|m| m[k + i]);
                    ok[k + i] = o;
                    sel[i] = if o { u64::MAX } else { 0 };
                }
                for (d, a) in data.iter().zip(acc.iter_mut()) {
                    let v = four(d, k);
                    for i in 0..4 {
                        a[i] += f64::from_bits(v[i].to_bits() & sel[i]);
                    }
                }
                k += l;
            }
            let used = ok.iter().filter(|&&o| o).count();
            (ok, used, acc)
        })
        .collect();
    let n_used: usize = bands.iter().map(|b| b.1).sum();
    if n_used == 0 {
        return Err(FitError::Noise(
            "no pixel is usable in every frame of the stack".into(),
        ));
    }
    // the frame means (band sums in band order: the same for any thread count, and exact for
    // integer samples), each frame's offset from their mean
    let frame_means: Vec<f64> = (0..stack.len())
        .map(|i| {
            let sum: f64 = bands
                .iter()
                .map(|b| {
                    let a = &b.2[i];
                    (a[0] + a[1]) + (a[2] + a[3])
                })
                .sum();
            sum / n_used as f64
        })
        .collect();
    let grand = frame_means.iter().sum::<f64>() / stack.len() as f64;
    let shift: Vec<f64> = frame_means.iter().map(|fm| fm - grand).collect();
    let kf = stack.len() as f64;
    // Pass 2: per usable pixel the temporal mean and variance (sums in frame order), in pixel
    // order
    let parts: Vec<Stored> = bands
        .par_iter()
        .enumerate()
        .map(|(band, (ok, used, _))| {
            let px = band_pixels(band);
            let data: Vec<&[f64]> = stack.iter().map(|img| &img.data()[px.clone()]).collect();
            let mut part = Stored {
                means: Vec::with_capacity(*used),
                values: Vec::with_capacity(*used),
                ranges: Ranges::EMPTY,
            };
            let mut k = 0;
            while k < px.len() {
                let l = (px.len() - k).min(4);
                let (mut s, mut s2) = ([0.0; 4], [0.0; 4]);
                for (d, c) in data.iter().zip(&shift) {
                    let v = four(d, k);
                    for i in 0..4 {
                        let v = v[i] - c;
                        s[i] += v;
                        s2[i] += v * v;
                    }
                }
                for i in 0..l {
                    if ok[k + i] {
                        let mean = s[i] / kf;
                        let var = ((s2[i] - s[i] * mean) / (kf - 1.0)).max(0.0);
                        part.ranges.add(mean, var);
                        part.means.push(mean);
                        part.values.push(var);
                    }
                }
                k += l;
            }
            part
        })
        .collect();
    Ok(StoredParts::new(parts))
}

/// The 4 samples from `k` (0 past the end: the callers use only the first `len - k`).
fn four(d: &[f64], k: usize) -> [f64; 4] {
    match d.get(k..k + 4) {
        Some(v) => [v[0], v[1], v[2], v[3]],
        None => std::array::from_fn(|i| d.get(k + i).copied().unwrap_or(0.0)),
    }
}

/// The limit below which a finite sample is not saturated (∞ without a saturation level).
fn usable_below(img: &Image) -> f64 {
    img.meta.saturation.unwrap_or(f64::INFINITY)
}

/// The limit above which a sample is not clipped at the floor: 0 for unsigned integer samples
/// (a camera whose dark level is subtracted clips at 0: such samples carry no noise, and the
/// real sample's dark band, about 10 % of its pixels at 0, made the single-image read noise 0),
/// -∞ for float samples.
fn usable_above(img: &Image) -> f64 {
    match img.meta.sample_format {
        SampleFormat::Unsigned => 0.0,
        SampleFormat::Float => f64::NEG_INFINITY,
    }
}

/// Rows per part (work item) of the per-pixel passes. Fixed, so that the order of the pairs and
/// every partial sum are the same for any number of threads.
const BAND: usize = 32;

/// Bounds of the means and of the values of a pair source. They only set the resolution of the
/// histograms of [`bin_ranked`]: pairs outside are clamped into the end buckets, which stays
/// exact, so bounds that hold up to rounding, or a guess, are enough.
#[derive(Clone, Copy, Debug)]
struct Ranges {
    mean_lo: f64,
    mean_hi: f64,
    /// The largest value.
    value_hi: f64,
}

impl Ranges {
    const EMPTY: Ranges = Ranges {
        mean_lo: f64::INFINITY,
        mean_hi: f64::NEG_INFINITY,
        value_hi: f64::NEG_INFINITY,
    };
    fn add(&mut self, mean: f64, value: f64) {
        self.mean_lo = self.mean_lo.min(mean);
        self.mean_hi = self.mean_hi.max(mean);
        self.value_hi = self.value_hi.max(value);
    }
    fn merge(self, o: Ranges) -> Ranges {
        Ranges {
            mean_lo: self.mean_lo.min(o.mean_lo),
            mean_hi: self.mean_hi.max(o.mean_hi),
            value_hi: self.value_hi.max(o.value_hi),
        }
    }
}

/// `(mean, value)` pairs in consecutive parts, which [`bin_ranked`] visits several times (in
/// parallel over the parts). Their order, part after part, is the pairs' position.
trait PairSource: Sync {
    /// Per-worker buffers of [`PairSource::visit`].
    type Scratch: Default + Send;
    fn parts(&self) -> usize;
    fn ranges(&self) -> Ranges;
    /// Calls `f(means, values)` on consecutive runs of the pairs of `part`, in order (the two
    /// slices of equal length). The values are only computed when `values` (else unspecified).
    fn visit(
        &self,
        part: usize,
        values: bool,
        scratch: &mut Self::Scratch,
        f: impl FnMut(&[f64], &[f64]),
    );
}

/// One part of pairs held in memory.
struct Stored {
    means: Vec<f64>,
    values: Vec<f64>,
    ranges: Ranges,
}

/// Pairs held in memory (those of [`noise_from_stack`], whose recomputation would read every
/// frame again).
struct StoredParts {
    parts: Vec<Stored>,
    ranges: Ranges,
}

impl StoredParts {
    fn new(parts: Vec<Stored>) -> StoredParts {
        let ranges = parts.iter().fold(Ranges::EMPTY, |a, p| a.merge(p.ranges));
        StoredParts { parts, ranges }
    }
}

impl PairSource for StoredParts {
    type Scratch = ();
    fn parts(&self) -> usize {
        self.parts.len()
    }
    fn ranges(&self) -> Ranges {
        self.ranges
    }
    fn visit(&self, part: usize, _: bool, _: &mut (), mut f: impl FnMut(&[f64], &[f64])) {
        let p = &self.parts[part];
        f(&p.means, &p.values);
    }
}

/// The pairs `(B, |A|)` of [`estimate_noise`], recomputed from the image on every visit (so that
/// the ~10⁶ pairs of a megapixel image are never held in memory): `A = (h ⊗ h) * I` and
/// `B = (g ⊗ g) * I` with the integer weights `h = [1, -4, 6, -4, 1]` and
/// `g = [1, 16, 36, 16, 1]`, at every pixel whose 5×5 support is usable, in pixel order, parts
/// of `BAND` output rows. The image is at least 5×5.
struct SingleImage<'a> {
    data: &'a [f64],
    w: usize,
    h: usize,
    /// The runs `[x0, x1)` of used output pixels (whose 5×5 support is usable) of output row `y`
    /// (in `2..h-2`): `used[used_at[y - 2]..used_at[y - 1]]`.
    used: Vec<(usize, usize)>,
    used_at: Vec<usize>,
    ranges: Ranges,
}

/// Filtered rows of one part and the filtered output row (reused across parts).
#[derive(Default)]
struct RowPass {
    hp: Vec<f64>,
    lp: Vec<f64>,
    mean: Vec<f64>,
    abs_a: Vec<f64>,
}

/// The runs `[x0, x1)` of unusable samples of a row, and the lowest and highest usable sample.
type RowScan = (Vec<(usize, usize)>, f64, f64);

/// Per image row: the runs `[x0, x1)` of unusable samples (masked, or not `floor < v < lim`), and
/// the range of the usable ones. Chunks of 16 samples that do not change the state (all usable,
/// or all masked) are passed over whole.
fn unusable_runs(row: &[f64], keep: Option<&[bool]>, floor: f64, lim: f64) -> RowScan {
    const C: usize = 16;
    let w = row.len();
    let value_ok = |v: f64| (v > floor) & (v < lim);
    let mut runs = Vec::new();
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut x, mut bad_from) = (0, None);
    while x < w {
        if x + C <= w {
            let c = &row[x..x + C];
            let skip = match bad_from {
                None => {
                    // all usable: also their range (lanes of 4, no NaN among them)
                    let ok = c.iter().fold(true, |a, &v| a & value_ok(v))
                        && keep.is_none_or(|k| k[x..x + C].iter().fold(true, |a, &k| a & k));
                    if ok {
                        let (mut l, mut h) = ([f64::INFINITY; 4], [f64::NEG_INFINITY; 4]);
                        for q in c.chunks_exact(4) {
                            for i in 0..4 {
                                l[i] = if q[i] < l[i] { q[i] } else { l[i] };
                                h[i] = if q[i] > h[i] { q[i] } else { h[i] };
                            }
                        }
                        lo = lo.min(l[0].min(l[1]).min(l[2].min(l[3])));
                        hi = hi.max(h[0].max(h[1]).max(h[2].max(h[3])));
                    }
                    ok
                }
                Some(_) => keep.is_some_and(|k| !k[x..x + C].iter().fold(false, |a, &k| a | k)),
            };
            if skip {
                x += C;
                continue;
            }
        }
        let v = row[x];
        let ok = value_ok(v) & keep.is_none_or(|k| k[x]);
        if ok {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        match (ok, bad_from) {
            (false, None) => bad_from = Some(x),
            (true, Some(a)) => {
                runs.push((a, x));
                bad_from = None;
            }
            _ => {}
        }
        x += 1;
    }
    if let Some(a) = bad_from {
        runs.push((a, w));
    }
    (runs, lo, hi)
}

impl<'a> SingleImage<'a> {
    fn new(img: &'a Image, mask: Option<&'a Mask>) -> Self {
        let (w, h) = (img.width(), img.height());
        let data = img.data();
        let keep = mask.map(Mask::as_slice);
        let (floor, lim) = (usable_above(img), usable_below(img));
        let rows: Vec<RowScan> = (0..h)
            .into_par_iter()
            .map(|y| {
                unusable_runs(
                    &data[y * w..][..w],
                    keep.map(|m| &m[y * w..][..w]),
                    floor,
                    lim,
                )
            })
            .collect();
        // an unusable sample at x blocks the outputs x-2..=x+2 of rows y-2..=y+2
        let used_rows: Vec<Vec<(usize, usize)>> = (2..h - 2)
            .into_par_iter()
            .map(|y| {
                let mut blocked: Vec<(usize, usize)> = rows[y - 2..=y + 2]
                    .iter()
                    .flat_map(|r| r.0.iter().map(|&(a, b)| (a.saturating_sub(2), b + 2)))
                    .collect();
                blocked.sort_unstable();
                let mut used = Vec::new();
                let mut x = 2;
                for &(a, b) in blocked.iter().chain(&[(w - 2, w - 2)]) {
                    let end = a.min(w - 2);
                    if end > x {
                        used.push((x, end));
                    }
                    x = x.max(b);
                    if x >= w - 2 {
                        break;
                    }
                }
                used
            })
            .collect();
        let mut used = Vec::new();
        let mut used_at = Vec::with_capacity(h - 3);
        for u in used_rows {
            used_at.push(used.len());
            used.extend(u);
        }
        used_at.push(used.len());
        // B is a sum of usable samples with positive weights summing to 70², so within their
        // range times 70² (up to rounding); |A| ≤ (Σ|h_i|)² · max|v| = 256 · max|v|
        let (lo, hi) = rows
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |a, r| {
                (a.0.min(r.1), a.1.max(r.2))
            });
        let norm = HP2_SUM * HP2_SUM;
        SingleImage {
            data,
            w,
            h,
            used,
            used_at,
            ranges: Ranges {
                mean_lo: lo * norm,
                mean_hi: hi * norm,
                value_hi: 256.0 * lo.abs().max(hi.abs()),
            },
        }
    }

    /// The runs of used output pixels of output row `y`.
    fn used_in(&self, y: usize) -> &[(usize, usize)] {
        &self.used[self.used_at[y - 2]..self.used_at[y - 1]]
    }
}

impl PairSource for SingleImage<'_> {
    type Scratch = RowPass;
    fn parts(&self) -> usize {
        (self.h - 4).div_ceil(BAND)
    }
    fn ranges(&self) -> Ranges {
        self.ranges
    }
    /// Separable passes, rows then columns, over the columns between the part's first and last
    /// used pixel, without branches (so that they vectorise); the used pixels are then handed
    /// over run by run. The part filters its own rows plus 2 halo rows on each side. Integer
    /// weights: exact for integer samples.
    fn visit(
        &self,
        part: usize,
        values: bool,
        rp: &mut RowPass,
        mut f: impl FnMut(&[f64], &[f64]),
    ) {
        let (w, h) = (self.w, self.h);
        // output rows y0..y1 need the filtered rows r0..r1
        let y0 = 2 + part * BAND;
        let y1 = (y0 + BAND).min(h - 2);
        let (r0, r1) = (y0 - 2, y1 + 2);
        // the output columns x0..x1 that hold used pixels (index j = x - x0)
        let (x0, x1) = (y0..y1)
            .flat_map(|y| self.used_in(y))
            .fold((w, 0), |a, &(s, e)| (a.0.min(s), a.1.max(e)));
        if x1 <= x0 {
            return;
        }
        let n = x1 - x0;
        let len = (r1 - r0) * n;
        rp.hp.resize(len, 0.0);
        rp.lp.resize(len, 0.0);
        rp.mean.resize(n, 0.0);
        rp.abs_a.resize(n, 0.0);
        for (i, y) in (r0..r1).enumerate() {
            // five shifted slices of equal length: samples x-2..=x+2 of the outputs x0..x1
            let r = &self.data[y * w + x0 - 2..][..n + 4];
            let (v0, v1, v2, v3, v4) = (
                &r[..n],
                &r[1..][..n],
                &r[2..][..n],
                &r[3..][..n],
                &r[4..][..n],
            );
            let lp = &mut rp.lp[i * n..][..n];
            if values {
                let hp = &mut rp.hp[i * n..][..n];
                for j in 0..n {
                    let (s04, s13) = (v0[j] + v4[j], v1[j] + v3[j]);
                    lp[j] = s04 + 16.0 * s13 + 36.0 * v2[j];
                    hp[j] = s04 - 4.0 * s13 + 6.0 * v2[j];
                }
            } else {
                for j in 0..n {
                    lp[j] = (v0[j] + v4[j]) + 16.0 * (v1[j] + v3[j]) + 36.0 * v2[j];
                }
            }
        }
        for y in y0..y1 {
            let used = self.used_in(y);
            if used.is_empty() {
                continue;
            }
            // output row y needs the filtered rows y-2..=y+2, the part's rows i..i+5
            let i = y - y0;
            let [l0, l1, l2, l3, l4] = five_rows(&rp.lp, i, n);
            let mean = &mut rp.mean[..n];
            for j in 0..n {
                mean[j] = (l0[j] + l4[j]) + 16.0 * (l1[j] + l3[j]) + 36.0 * l2[j];
            }
            if values {
                let [h0, h1, h2, h3, h4] = five_rows(&rp.hp, i, n);
                let abs_a = &mut rp.abs_a[..n];
                for j in 0..n {
                    abs_a[j] = ((h0[j] + h4[j]) - 4.0 * (h1[j] + h3[j]) + 6.0 * h2[j]).abs();
                }
            }
            for &(s, e) in used {
                f(&rp.mean[s - x0..e - x0], &rp.abs_a[s - x0..e - x0]);
            }
        }
    }
}

/// Rows `i..i+5` of `n` values each.
fn five_rows(buf: &[f64], i: usize, n: usize) -> [&[f64]; 5] {
    std::array::from_fn(|t| &buf[(i + t) * n..][..n])
}

/// Equal-width buckets of the means, which locate the bin edges (2¹⁶ counts of 4 bytes: the
/// histogram stays in the L2 cache).
const N_BUCKETS: usize = 1 << 16;
/// `bucket_bin` tag of a bucket that holds a bin edge (plus the index of that bucket among them).
const SPLIT: u8 = 128;
/// Value buckets per bin: 64 per octave (the top 6 mantissa bits) over the 32 octaves below the
/// largest value; smaller values share the first bucket, negative ones too.
const V_SHIFT: u32 = 46;
const N_VBUCKETS: usize = 32 << 6;
/// Pairs per batch of the binning passes (bucket indices computed a batch at a time).
const BATCH: usize = 256;

/// A zeroed array on the heap (its fixed length lets the indexing below go unchecked).
fn zeroed<T: Copy + Default, const N: usize>() -> Box<[T; N]> {
    vec![T::default(); N]
        .into_boxed_slice()
        .try_into()
        .unwrap_or_else(|_| unreachable!("the vector has N elements"))
}

/// One bin of [`bin_ranked`].
#[derive(Clone, Copy, Debug, PartialEq)]
struct RankedBin {
    count: usize,
    /// Mean of the bin's means.
    mean: f64,
    /// The bin's value of the requested rank.
    value: f64,
}

/// Per bin the median of the values: the value of rank `count / 2` (the upper median).
fn bin_medians(src: &impl PairSource) -> Result<Vec<RankedBin>, FitError> {
    bin_ranked(src, |count| count / 2)
}

/// The mean buckets: a monotone non-decreasing function of the mean for every mean but NaN
/// (rejected): a subtraction, a product with a number ≥ 0, clamping, and rounding to an integer
/// (the low mantissa bits of `x + 2⁵²` for `x` in `[0, 2¹⁶)`).
#[derive(Clone, Copy)]
struct MeanBuckets {
    lo: f64,
    scale: f64,
}

impl MeanBuckets {
    fn new(r: &Ranges) -> Self {
        let scale = N_BUCKETS as f64 / (r.mean_hi - r.mean_lo);
        // a degenerate range (one value, or not finite) puts every pair in bucket 0, which is
        // then sorted: slower, still exact
        if scale.is_finite() && scale > 0.0 {
            MeanBuckets {
                lo: r.mean_lo,
                scale,
            }
        } else {
            MeanBuckets {
                lo: 0.0,
                scale: 0.0,
            }
        }
    }
    /// The buckets of `means` into `out`; whether a mean is NaN.
    fn fill(&self, means: &[f64], out: &mut [u32]) -> bool {
        let top = (N_BUCKETS - 1) as f64;
        let mut nan = false;
        for (o, &m) in out.iter_mut().zip(means) {
            let x = (m - self.lo) * self.scale;
            let x = if x > 0.0 { x } else { 0.0 };
            let x = if x < top { x } else { top };
            *o = (x + 4_503_599_627_370_496.0).to_bits() as u32;
            nan |= m.is_nan();
        }
        nan
    }
}

/// The value buckets: monotone non-decreasing in `f64::total_cmp` order: the negative values
/// (sign bit set) in bucket 0, then the non-negative ones by their top 18 bits (exponent and 6
/// mantissa bits, in value order), clamped so that the largest value `value_hi` is in the last
/// bucket. Computed on the high 32 bits (32-bit integer operations vectorise).
#[derive(Clone, Copy)]
struct ValueBuckets {
    base: i32,
}

impl ValueBuckets {
    fn new(r: &Ranges) -> Self {
        let hi = if r.value_hi >= 0.0 { r.value_hi } else { 0.0 };
        ValueBuckets {
            base: ((hi.to_bits() >> 32) as i32 >> (V_SHIFT - 32)) - (N_VBUCKETS as i32 - 1),
        }
    }
    fn of(&self, v: f64) -> u32 {
        let h = (v.to_bits() >> 32) as i32;
        // (h >> 31) is all ones for a negative value: bucket 0
        let q = ((h >> (V_SHIFT - 32)) - self.base) & !(h >> 31);
        q.clamp(0, N_VBUCKETS as i32 - 1) as u32
    }
    fn fill(&self, values: &[f64], out: &mut [u32]) {
        for (o, &v) in out.iter_mut().zip(values) {
            *o = self.of(v);
        }
    }
}

/// Per bucket tag, the window of value buckets `lo ..= lo + width` (wrapping: an empty window
/// has `lo = u32::MAX`, width 0).
struct Windows {
    lo: [u32; 256],
    width: [u32; 256],
}

impl Windows {
    fn holds(&self, tag: usize, q: u32) -> bool {
        q.wrapping_sub(self.lo[tag & 255]) <= self.width[tag & 255]
    }
}

/// Per part and bin the sum of the means (4 partial sums, taking the pairs in turn), and the
/// pairs of the split buckets set aside: (mean, position, value, split index).
struct PartSums {
    part: usize,
    sums: [f64; 4 * N_BINS],
    aside: Vec<(f64, usize, f64, u8)>,
}

/// A batch of pairs of the second visit of [`bin_ranked`], with their mean and value buckets.
struct Batch<'a> {
    means: &'a [f64],
    values: &'a [f64],
    mbuckets: &'a [u32; BATCH],
    vbuckets: &'a [u32; BATCH],
    /// Position of the first pair.
    first: usize,
}

impl Batch<'_> {
    /// Adds the batch to the sums, the value histogram (`N_VBUCKETS` per bin) and the
    /// candidates (`cand[n_cand..]` has room for the batch); returns the new number of
    /// candidates. (A function of its own, so that the compiler knows that its arguments do
    /// not alias.)
    fn assign(
        &self,
        bucket_bin: &[u8; N_BUCKETS],
        win: &Windows,
        ps: &mut PartSums,
        vhist: &mut [u32; N_BINS * N_VBUCKETS],
        cand: &mut [(u8, u32, f64)],
        mut n_cand: usize,
    ) -> usize {
        let pairs = self
            .mbuckets
            .iter()
            .zip(self.vbuckets)
            .zip(self.means.iter().zip(self.values));
        for (k, ((&mk, &vk), (&m, &v))) in pairs.enumerate() {
            let t = bucket_bin[mk as usize & (N_BUCKETS - 1)];
            if t < SPLIT {
                let b = (t & 31) as usize;
                // 4 partial sums taking the pairs in turn: no chain of additions
                ps.sums[4 * b + (k & 3)] += m;
                vhist[b * N_VBUCKETS + (vk as usize & (N_VBUCKETS - 1))] += 1;
                // written always, kept when in the window (no branch to miss)
                cand[n_cand] = (t, vk, v);
                n_cand += usize::from(win.holds(b, vk));
            } else {
                ps.aside.push((m, self.first + k, v, t - SPLIT));
            }
        }
        n_cand
    }
}

/// Every `PILOT`-th part (from the first) also gives its values in the first visit of
/// [`bin_ranked`]: a sample (~1/8 of the pairs, spread over the image) to guess where each bin's
/// value of the requested rank lies.
const PILOT: usize = 8;
/// Half-width of the guessed window, in standard deviations of the sample rank.
const PILOT_Z: f64 = 4.0;

/// Cuts the `(mean, value)` pairs of `src` into `N_BINS` bins of equal counts by mean, and
/// gives per bin its count, the mean of its means and its value of rank `rank(count)` (in
/// `0..count`, values ordered by `f64::total_cmp`).
///
/// Definition: the pairs are ranked by the total order key `(mean, position)`: means compared
/// with `f64::total_cmp`, ties (common: the means are low-pass sums of integer data) broken by
/// the position in the source, which is the pixel order. Bin `b` holds the pairs of ranks
/// `b·n/N_BINS .. (b+1)·n/N_BINS`. So the bins, and the value of a given rank in each, are a
/// function of the input alone, whatever the algorithm or the number of threads. The sum of a
/// bin's means is taken in a fixed order (per part, 4 partial sums taking the pairs in turn,
/// combined in part order, then the pairs of the split buckets in rank order), also the same
/// for any number of threads; it differs from the sum in rank order only by rounding.
///
/// Algorithm (two visits of the source, rarely three; no sort of the ~10⁶ pairs; little memory):
/// 1. a histogram of the means in `N_BUCKETS` equal-width buckets over the source's range,
///    clamped at the ends. The bucket index is monotone in the mean, so each bucket holds
///    consecutive ranks, and the cumulative counts give each bucket its bin, or show that a bin
///    edge falls inside it (at most `N_BINS - 1` split buckets); the pairs per part give the
///    positions. The pilot parts (every `PILOT`-th) also record their value buckets
///    (`N_VBUCKETS` buckets, monotone in `f64::total_cmp` order), which give per bin a window of
///    value buckets that very likely holds the requested rank (± `PILOT_Z` standard deviations
///    of the sample rank);
/// 2. per bin the sum of the means, the exact histogram of the value buckets, and the values in
///    the window (the candidates); the pairs of the split buckets are set aside and sorted by
///    `(mean, position)`, which gives their ranks and bins. The value histogram tells which
///    bucket holds the requested rank and its rank in there: when the window holds that bucket
///    (checked, not assumed), the value is found by selection among its candidates;
/// 3. only for the bins whose window missed: a third visit collects the values of that bucket.
///
/// The parts are visited in parallel; the histograms hold integer counts and the per-part sums
/// are combined in part order, so nothing depends on the thread count. Checked against a stable
/// full sort in the unit tests (the third visit too).
fn bin_ranked<S: PairSource>(
    src: &S,
    rank: impl Fn(usize) -> usize,
) -> Result<Vec<RankedBin>, FitError> {
    bin_ranked_with(src, rank, PILOT_Z)
}

/// [`bin_ranked`] with the pilot window's half-width; a negative one gives empty windows, so
/// that every bin takes the third visit (for the tests).
fn bin_ranked_with<S: PairSource>(
    src: &S,
    rank: impl Fn(usize) -> usize,
    pilot_z: f64,
) -> Result<Vec<RankedBin>, FitError> {
    let ranges = src.ranges();
    let mb = MeanBuckets::new(&ranges);
    let vb = ValueBuckets::new(&ranges);

    // 1. histogram of the means, pairs per part, (mean bucket, value bucket) of the pilot parts
    struct Pass1<Sc> {
        hist: Box<[u32; N_BUCKETS]>,
        counts: Vec<(usize, usize)>,
        pilot: Vec<(u32, u32)>,
        nan: bool,
        scratch: Sc,
    }
    let pass1 = (0..src.parts())
        .into_par_iter()
        .fold(
            || Pass1 {
                hist: zeroed(),
                counts: Vec::new(),
                pilot: Vec::new(),
                nan: false,
                scratch: S::Scratch::default(),
            },
            |mut acc, part| {
                let Pass1 {
                    hist,
                    pilot,
                    nan,
                    scratch,
                    ..
                } = &mut acc;
                let mut count = 0;
                let is_pilot = part % PILOT == 0;
                let (mut mbuf, mut vbuf) = ([0u32; BATCH], [0u32; BATCH]);
                src.visit(part, is_pilot, scratch, |means, values| {
                    for (m, v) in means.chunks(BATCH).zip(values.chunks(BATCH)) {
                        *nan |= mb.fill(m, &mut mbuf);
                        for &k in &mbuf[..m.len()] {
                            hist[k as usize & (N_BUCKETS - 1)] += 1;
                        }
                        if is_pilot {
                            vb.fill(v, &mut vbuf);
                            pilot.extend(
                                mbuf.iter().copied().zip(vbuf.iter().copied()).take(m.len()),
                            );
                        }
                    }
                    count += means.len();
                });
                acc.counts.push((part, count));
                acc
            },
        )
        .reduce_with(|mut a, b| {
            a.hist
                .iter_mut()
                .zip(b.hist.iter())
                .for_each(|(x, y)| *x += y);
            a.counts.extend(b.counts);
            a.pilot.extend(b.pilot);
            a.nan |= b.nan;
            a
        });
    let Some(Pass1 {
        hist,
        mut counts,
        pilot,
        nan,
        ..
    }) = pass1
    else {
        return Err(FitError::Noise("no usable pixels".into()));
    };
    let n: usize = counts.iter().map(|c| c.1).sum();
    if n < 20 * N_BINS {
        return Err(FitError::Noise(format!(
            "only {n} usable pixels, need at least {}",
            20 * N_BINS
        )));
    }
    if nan {
        return Err(FitError::Noise(
            "a local mean is not a number (samples too large)".into(),
        ));
    }
    counts.sort_unstable();
    let offsets: Vec<usize> = counts
        .iter()
        .scan(0, |next, c| {
            let first = *next;
            *next += c.1;
            Some(first)
        })
        .collect();
    // first rank of each bin, then n
    let edges: [usize; N_BINS + 1] = std::array::from_fn(|b| b * n / N_BINS);
    let count_of = |b: usize| edges[b + 1] - edges[b];
    let bin_of_rank = |r: usize| edges.partition_point(|&e| e <= r) - 1;
    // the requested rank of each bin
    let ranks: [usize; N_BINS] = std::array::from_fn(|b| rank(count_of(b)).min(count_of(b) - 1));

    // per bucket its bin, or SPLIT + i when a bin edge falls strictly inside it, `split_first[i]`
    // being the rank of that bucket's first pair
    let mut bucket_bin: Box<[u8; N_BUCKETS]> = zeroed();
    let mut split_first: Vec<usize> = Vec::new();
    let mut first = 0;
    for (tag, &c) in bucket_bin.iter_mut().zip(hist.iter()) {
        if c == 0 {
            continue;
        }
        let end = first + c as usize;
        let b = bin_of_rank(first);
        *tag = if edges[b + 1] < end {
            split_first.push(first);
            SPLIT + (split_first.len() - 1) as u8
        } else {
            b as u8
        };
        first = end;
    }
    drop(hist);

    // the pilot's windows of value buckets, indexed by bucket tag: bucket q is in the window
    // when q - lo (wrapping) ≤ width (empty for the split tags: lo = u32::MAX, width 0)
    let (mut win_lo, mut win_w) = ([u32::MAX; 256], [0u32; 256]);
    let mut sample: Vec<Vec<u32>> = vec![Vec::new(); N_BINS];
    for &(m, v) in &pilot {
        let t = bucket_bin[m as usize & (N_BUCKETS - 1)];
        if t < SPLIT {
            sample[t as usize].push(v);
        }
    }
    drop(pilot);
    for (b, s) in sample.iter_mut().enumerate() {
        let (lo, hi) = if pilot_z < 0.0 {
            continue;
        } else if s.len() < 64 {
            (0, N_VBUCKETS as u32 - 1)
        } else {
            let p = ranks[b] as f64 / count_of(b) as f64;
            let len = s.len() as f64;
            let half = pilot_z * (len * p * (1.0 - p)).sqrt() + 2.0;
            let (r_lo, r_hi) = ((len * p - half).floor(), (len * p + half).ceil());
            let hi = if r_hi >= len - 1.0 {
                N_VBUCKETS as u32 - 1
            } else {
                *s.select_nth_unstable(r_hi as usize).1
            };
            let lo = if r_lo <= 0.0 {
                0
            } else {
                // (the smaller ranks are now left of r_hi)
                *s.select_nth_unstable(r_lo as usize).1
            };
            (lo, hi)
        };
        win_lo[b] = lo;
        win_w[b] = hi.saturating_sub(lo);
    }
    drop(sample);
    let win = Windows {
        lo: win_lo,
        width: win_w,
    };
    let in_window = |b: usize, q: u32| win.holds(b, q);

    // 2. per part and bin the sum of the means (4 partial sums), per bin the value histogram, and
    // the candidates (in the window); the pairs of split buckets set aside with their position
    struct Pass2<Sc> {
        vhist: Box<[u32; N_BINS * N_VBUCKETS]>,
        parts: Vec<PartSums>,
        /// The candidates, `candidates[..n_cand]` (the rest is room for a batch).
        candidates: Vec<(u8, u32, f64)>,
        n_cand: usize,
        scratch: Sc,
    }
    let pass2 = (0..src.parts())
        .into_par_iter()
        .fold(
            || Pass2 {
                vhist: zeroed(),
                parts: Vec::new(),
                candidates: Vec::new(),
                n_cand: 0,
                scratch: S::Scratch::default(),
            },
            |mut acc, part| {
                let mut ps = PartSums {
                    part,
                    sums: [0.0; 4 * N_BINS],
                    aside: Vec::new(),
                };
                let mut pos = offsets[part];
                let (vhist, cand) = (&mut acc.vhist, &mut acc.candidates);
                // (a local count: no chain through memory)
                let mut n_cand = acc.n_cand;
                let (mut mbuf, mut vbuf) = ([0u32; BATCH], [0u32; BATCH]);
                src.visit(part, true, &mut acc.scratch, |means, values| {
                    for (m, v) in means.chunks(BATCH).zip(values.chunks(BATCH)) {
                        mb.fill(m, &mut mbuf);
                        vb.fill(v, &mut vbuf);
                        if cand.len() < n_cand + BATCH {
                            cand.resize(2 * cand.len() + BATCH, (0, 0, 0.0));
                        }
                        let batch = Batch {
                            means: m,
                            values: v,
                            mbuckets: &mbuf,
                            vbuckets: &vbuf,
                            first: pos,
                        };
                        n_cand = batch.assign(&bucket_bin, &win, &mut ps, vhist, cand, n_cand);
                        pos += m.len();
                    }
                });
                acc.n_cand = n_cand;
                acc.parts.push(ps);
                acc
            },
        )
        .reduce_with(|mut a, mut b| {
            a.vhist
                .iter_mut()
                .zip(b.vhist.iter())
                .for_each(|(x, y)| *x += y);
            a.parts.extend(b.parts);
            a.candidates.truncate(a.n_cand);
            b.candidates.truncate(b.n_cand);
            a.candidates.extend(b.candidates);
            a.n_cand = a.candidates.len();
            a
        });
    let Some(Pass2 {
        mut vhist,
        parts: mut part_sums,
        mut candidates,
        n_cand,
        ..
    }) = pass2
    else {
        unreachable!("n > 0 pairs, so at least one part");
    };
    candidates.truncate(n_cand);
    part_sums.sort_unstable_by_key(|p| p.part);

    // the split buckets, sorted by (mean, position), give their pairs' ranks and bins
    let mut aside: Vec<Vec<(f64, usize, f64)>> = vec![Vec::new(); split_first.len()];
    for p in &part_sums {
        for &(m, k, v, s) in &p.aside {
            aside[s as usize].push((m, k, v));
        }
    }
    let mut aside_bins: Vec<(u8, f64)> = Vec::new();
    let mut extra_sums = [0.0; N_BINS];
    for (list, &first) in aside.iter_mut().zip(&split_first) {
        list.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for (i, &(m, _, v)) in list.iter().enumerate() {
            let b = bin_of_rank(first + i);
            let q = vb.of(v);
            extra_sums[b] += m;
            vhist[b * N_VBUCKETS + q as usize] += 1;
            aside_bins.push((b as u8, v));
            if in_window(b, q) {
                candidates.push((b as u8, q, v));
            }
        }
    }
    drop(aside);

    // per bin: the value bucket holding the requested rank, and the rank within it
    let mut want = [u32::MAX; 256];
    let mut rank_in = [0usize; N_BINS];
    for b in 0..N_BINS {
        let k = ranks[b];
        let mut below = 0;
        for (q, &c) in vhist[b * N_VBUCKETS..][..N_VBUCKETS].iter().enumerate() {
            if below + c as usize > k {
                want[b] = q as u32;
                rank_in[b] = k - below;
                break;
            }
            below += c as usize;
        }
    }
    drop(vhist);
    let mut values: Vec<Vec<f64>> = vec![Vec::new(); N_BINS];
    for &(t, q, v) in &candidates {
        if q == want[t as usize] {
            values[t as usize].push(v);
        }
    }
    drop(candidates);

    // 3. only for the bins whose window missed the bucket: its values from one more visit
    let missed: Vec<usize> = (0..N_BINS).filter(|&b| !in_window(b, want[b])).collect();
    if !missed.is_empty() {
        let mut want3 = [u32::MAX; 256];
        for &b in &missed {
            want3[b] = want[b];
            values[b].clear();
        }
        let found: Vec<Vec<(u8, f64)>> = (0..src.parts())
            .into_par_iter()
            .map_init(S::Scratch::default, |scratch, part| {
                let mut out = Vec::new();
                let (mut mbuf, mut vbuf) = ([0u32; BATCH], [0u32; BATCH]);
                src.visit(part, true, scratch, |means, values| {
                    for (m, v) in means.chunks(BATCH).zip(values.chunks(BATCH)) {
                        mb.fill(m, &mut mbuf);
                        vb.fill(v, &mut vbuf);
                        for ((&mk, &vk), &v) in mbuf.iter().zip(&vbuf).zip(v) {
                            let t = bucket_bin[mk as usize & (N_BUCKETS - 1)];
                            if vk == want3[t as usize] {
                                out.push((t, v));
                            }
                        }
                    }
                });
                out
            })
            .collect();
        for &(b, v) in found.iter().flatten() {
            values[b as usize].push(v);
        }
        for &(b, v) in &aside_bins {
            if vb.of(v) == want3[b as usize] {
                values[b as usize].push(v);
            }
        }
    }

    let mut bins = Vec::with_capacity(N_BINS);
    for (b, vals) in values.iter_mut().enumerate() {
        let count = count_of(b);
        let sum = part_sums
            .iter()
            .map(|p| {
                let s = &p.sums[4 * b..][..4];
                (s[0] + s[1]) + (s[2] + s[3])
            })
            .sum::<f64>()
            + extra_sums[b];
        let (_, &mut value, _) = vals.select_nth_unstable_by(rank_in[b], f64::total_cmp);
        bins.push(RankedBin {
            count,
            mean: sum / count as f64,
            value,
        });
    }
    Ok(bins)
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
    // the line's covariance: (XᵀWX)⁻¹ scaled by the reduced χ² of the used bins when above 1
    let used: Vec<&NoiseBin> = bins.iter().filter(|b| b.used).collect();
    let (mut sw, mut sx, mut sxx, mut chi2) = (0.0, 0.0, 0.0, 0.0);
    for b in &used {
        let wgt = 1.0 / (rel(b) * b.variance.max(1e-12)).powi(2);
        sw += wgt;
        sx += wgt * b.mean;
        sxx += wgt * b.mean * b.mean;
        chi2 += wgt * (b.variance - alpha - beta * b.mean).powi(2);
    }
    let scale = (chi2 / (used.len().saturating_sub(2).max(1)) as f64).max(1.0);
    let det = sw * sxx - sx * sx;
    let darkest = used
        .iter()
        .min_by(|a, b| a.mean.total_cmp(&b.mean))
        .copied()
        .unwrap_or(&bins[0]);
    let at_offset = alpha + beta * offset;
    let (model, read_variance_se, gain_se, resolved) = if beta > 0.0 && at_offset > 0.0 {
        let (var_a, var_b, cov) = (sxx / det * scale, sw / det * scale, -sx / det * scale);
        let var_r = var_a + offset * offset * var_b + 2.0 * offset * cov;
        let model = NoiseModel {
            read_variance: at_offset,
            gain: beta,
            offset,
        };
        (model, var_r.max(0.0).sqrt(), var_b.max(0.0).sqrt(), true)
    } else if beta > 0.0 {
        // the line falls to zero or below at the darkest bin: not resolved there; the
        // documented fall-back is the darkest used bin's own variance as the read variance, at
        // that bin's mean as the offset
        let model = NoiseModel {
            read_variance: darkest.variance.max(1e-12),
            gain: beta,
            offset: darkest.mean,
        };
        let se = rel(darkest) * darkest.variance;
        (model, se, (sw / det * scale).max(0.0).sqrt(), false)
    } else {
        // no growth with the signal: the weighted mean variance
        let (mut sw, mut s, mut s2) = (0.0, 0.0, 0.0);
        for b in &used {
            let wgt = b.count as f64;
            sw += wgt;
            s += wgt * b.variance;
            s2 += wgt * b.variance * b.variance;
        }
        let mean = s / sw;
        let spread = ((s2 / sw - mean * mean).max(0.0) / used.len().max(1) as f64).sqrt();
        let model = NoiseModel {
            read_variance: mean.max(1e-12),
            gain: 0.0,
            offset: 0.0,
        };
        (model, spread, 0.0, true)
    };
    if !(model.read_variance.is_finite() && model.gain.is_finite()) {
        return Err(FitError::Noise(
            "the variance-versus-mean line is not finite".into(),
        ));
    }
    Ok(NoiseFit {
        model,
        bins,
        read_variance_se,
        gain_se,
        resolved,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// splitmix64: a small deterministic generator for the test inputs.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        /// Uniform in [0, 1).
        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
        fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }
    }

    /// Pairs held in memory, cut into parts of the given sizes (in order).
    fn stored(pairs: &[(f64, f64)], sizes: &[usize]) -> StoredParts {
        assert_eq!(sizes.iter().sum::<usize>(), pairs.len());
        let mut parts = Vec::new();
        let mut at = 0;
        for &len in sizes {
            let mut part = Stored {
                means: Vec::new(),
                values: Vec::new(),
                ranges: Ranges::EMPTY,
            };
            for &(m, v) in &pairs[at..at + len] {
                part.ranges.add(m, v);
                part.means.push(m);
                part.values.push(v);
            }
            parts.push(part);
            at += len;
        }
        StoredParts::new(parts)
    }

    /// Random part sizes summing to n, some of them empty.
    fn random_sizes(n: usize, rng: &mut Rng) -> Vec<usize> {
        let mut sizes = Vec::new();
        let mut left = n;
        while left > 0 {
            let len = if rng.below(5) == 0 {
                0
            } else {
                (rng.below(n as u64 / 3 + 2) as usize).min(left)
            };
            sizes.push(len);
            left -= len;
        }
        sizes
    }

    /// The definition, by a stable full sort: per bin (count, mean of means, values in total
    /// order).
    fn reference(pairs: &[(f64, f64)]) -> Vec<(usize, f64, Vec<f64>)> {
        let mut sorted = pairs.to_vec();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let n = sorted.len();
        (0..N_BINS)
            .map(|b| {
                let bin = &sorted[b * n / N_BINS..(b + 1) * n / N_BINS];
                let mean = bin.iter().map(|p| p.0).sum::<f64>() / bin.len() as f64;
                let mut values: Vec<f64> = bin.iter().map(|p| p.1).collect();
                values.sort_by(f64::total_cmp);
                (bin.len(), mean, values)
            })
            .collect()
    }

    /// `bin_ranked` against the reference for the given ranks (fractions of the count, or
    /// every rank when `all`), with the normal pilot window and with one that always misses
    /// (so that the third visit runs).
    fn check_against_reference(pairs: &[(f64, f64)], sizes: &[usize], all: bool, what: &str) {
        let src = stored(pairs, sizes);
        let expect = reference(pairs);
        let most = expect.iter().map(|e| e.0).max().unwrap();
        let ranks: Vec<Box<dyn Fn(usize) -> usize + Sync>> = if all {
            (0..most)
                .map(|k| {
                    Box::new(move |c: usize| k.min(c - 1)) as Box<dyn Fn(usize) -> usize + Sync>
                })
                .collect()
        } else {
            vec![
                Box::new(|c: usize| c / 2),
                Box::new(|_| 0),
                Box::new(|c: usize| c - 1),
                Box::new(|c: usize| c / 4),
                Box::new(|c: usize| 3 * c / 4),
            ]
        };
        for (r, rank) in ranks.iter().enumerate() {
            for z in [PILOT_Z, -1.0] {
                let got = bin_ranked_with(&src, rank, z).unwrap();
                for (b, (g, e)) in got.iter().zip(&expect).enumerate() {
                    let k = rank(e.0);
                    assert_eq!(g.count, e.0, "{what}: count of bin {b}");
                    assert_eq!(
                        g.value.to_bits(),
                        e.2[k].to_bits(),
                        "{what}: bin {b}, rank {k} (rank fn {r}, window {z}): {} vs {}",
                        g.value,
                        e.2[k]
                    );
                    let tol = 1e-12 * e.1.abs().max(f64::MIN_POSITIVE);
                    assert!(
                        (g.mean - e.1).abs() <= tol,
                        "{what}: mean of bin {b}: {} vs {}",
                        g.mean,
                        e.1
                    );
                }
            }
        }
    }

    #[test]
    fn binning_matches_a_stable_sort_with_many_ties() {
        let mut rng = Rng(1);
        // integer means from a few levels and integer values: ties everywhere, also at the edges
        let pairs: Vec<(f64, f64)> = (0..5000)
            .map(|_| (rng.below(23) as f64, rng.below(40) as f64))
            .collect();
        let sizes = random_sizes(pairs.len(), &mut rng);
        check_against_reference(&pairs, &sizes, false, "ties");
        // every rank of every bin: the whole multiset of each bin's values
        let small: Vec<(f64, f64)> = pairs[..900].to_vec();
        check_against_reference(
            &small,
            &random_sizes(900, &mut rng),
            true,
            "ties, all ranks",
        );
    }

    #[test]
    fn binning_matches_a_stable_sort_on_random_input() {
        let mut rng = Rng(2);
        let pairs: Vec<(f64, f64)> = (0..30_000)
            .map(|_| {
                let m = 50.0 + 3000.0 * rng.unit().powi(3);
                (m, -(1.0 - rng.unit()).ln() * m.sqrt())
            })
            .collect();
        let sizes = random_sizes(pairs.len(), &mut rng);
        check_against_reference(&pairs, &sizes, false, "random");
        // a wide range: nearly all means in one histogram bucket (sorted there), signed
        // values with both zeros, negative means
        let mut wide: Vec<(f64, f64)> = (0..3000)
            .map(|i| {
                let v = match i % 7 {
                    0 => 0.0,
                    1 => -0.0,
                    _ => rng.unit() - 0.5,
                };
                (rng.unit() - 0.5, v)
            })
            .collect();
        wide[17].0 = 1e12;
        wide[2000].0 = -3e11;
        check_against_reference(&wide, &random_sizes(3000, &mut rng), false, "wide");
    }

    #[test]
    fn binning_edge_cases() {
        let mut rng = Rng(3);
        let min = 20 * N_BINS;
        // just above the minimum, and the minimum
        for n in [min + 1, min] {
            let pairs: Vec<(f64, f64)> = (0..n).map(|_| (rng.unit(), rng.unit())).collect();
            check_against_reference(&pairs, &[n], true, "minimum");
        }
        let few: Vec<(f64, f64)> = (0..min - 1).map(|_| (rng.unit(), rng.unit())).collect();
        assert!(matches!(
            bin_medians(&stored(&few, &[min - 1])),
            Err(FitError::Noise(_))
        ));
        assert!(matches!(
            bin_medians(&stored(&[], &[0, 0])),
            Err(FitError::Noise(_))
        ));
        // all means equal: the bins are runs of positions
        let equal: Vec<(f64, f64)> = (0..2000).map(|i| (7.0, i as f64)).collect();
        check_against_reference(&equal, &random_sizes(2000, &mut rng), false, "equal means");
        let bins = bin_medians(&stored(&equal, &[2000])).unwrap();
        for (b, bin) in bins.iter().enumerate() {
            let (lo, hi) = (b * 2000 / N_BINS, (b + 1) * 2000 / N_BINS);
            assert_eq!(bin.value, (lo + (hi - lo) / 2) as f64);
            assert_eq!(bin.mean, 7.0);
        }
        // two distinct means
        let two: Vec<(f64, f64)> = (0..1500)
            .map(|_| (if rng.below(3) == 0 { -1.0 } else { 4.5 }, rng.unit()))
            .collect();
        check_against_reference(&two, &random_sizes(1500, &mut rng), false, "two means");
        // a NaN mean is an error, not a wrong answer
        let mut nan = equal.clone();
        nan[5].0 = f64::NAN;
        assert!(bin_medians(&stored(&nan, &[2000])).is_err());
    }

    #[test]
    fn binning_does_not_depend_on_threads() {
        let mut rng = Rng(4);
        let pairs: Vec<(f64, f64)> = (0..40_000)
            .map(|_| ((rng.below(300) as f64).sqrt(), rng.below(1000) as f64 / 7.0))
            .collect();
        let sizes = random_sizes(pairs.len(), &mut rng);
        let src = stored(&pairs, &sizes);
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| bin_medians(&src).unwrap())
                .iter()
                .map(|b| (b.count, b.mean.to_bits(), b.value.to_bits()))
                .collect::<Vec<_>>()
        };
        let one = on(1);
        assert_eq!(one, on(2));
        assert_eq!(one, on(3));
    }

    #[test]
    fn an_unresolved_line_falls_back_to_the_darkest_bin() {
        // variance falling to 0 at the darkest bin (as a clipped dark band made it): the
        // line's value there is not used, the darkest bin's own variance is
        let bins: Vec<NoiseBin> = (0..8)
            .map(|k| NoiseBin {
                mean: 100.0 * k as f64,
                variance: if k == 0 { 40.0 } else { 100.0 * k as f64 },
                count: 10_000,
                used: true,
            })
            .collect();
        let f = fit_line(bins).unwrap();
        assert!(!f.resolved, "{f:?}");
        // the darkest bin is rejected as an outlier of the line; the darkest used one is (100,
        // 100), and the model passes through it with the line's slope
        assert_eq!((f.model.read_variance, f.model.offset), (100.0, 100.0));
        assert!((f.model.gain - 1.0).abs() < 1e-9, "{f:?}");
        // a straight line through positive values is resolved, with small errors
        let bins: Vec<NoiseBin> = (0..8)
            .map(|k| NoiseBin {
                mean: 100.0 * k as f64,
                variance: 50.0 + 0.5 * 100.0 * k as f64,
                count: 10_000,
                used: true,
            })
            .collect();
        let f = fit_line(bins).unwrap();
        assert!(f.resolved);
        assert!((f.model.read_variance - 50.0).abs() < 1e-6 && (f.model.gain - 0.5).abs() < 1e-9);
        assert!(
            f.read_variance_se > 0.0 && f.read_variance_se < 2.0,
            "{f:?}"
        );
    }

    /// An image with 12-bit integer samples, a mask with a hole, and unusable samples (NaN, ±∞,
    /// saturated, clipped at the floor 0).
    fn test_image(w: usize, h: usize, rng: &mut Rng) -> (Image, Mask) {
        let mut img = Image::from_fn(w, h, |_, _| 0.0);
        img.meta = bostrack_core::ImageMeta::synthetic(12);
        for v in img.data_mut() {
            *v = match rng.below(200) {
                0 => f64::NAN,
                1 => f64::INFINITY,
                2 => f64::NEG_INFINITY,
                3 => 4095.0,
                4 => 0.0,
                _ => 1.0 + rng.below(4094) as f64,
            };
        }
        let (cx, cy) = (w / 3, h / 2);
        let mask = Mask::from_fn(w, h, |x, y| {
            let hole = x.abs_diff(cx) < 3 && y.abs_diff(cy) < 4;
            let corner = y > h - 3 && x < w / 2;
            !(hole || corner)
        });
        (img, mask)
    }

    /// `(B, |A|)` at every pixel whose 5×5 support is usable, pixel by pixel.
    fn single_image_reference(img: &Image, mask: Option<&Mask>) -> Vec<(f64, f64)> {
        let (w, h) = (img.width(), img.height());
        let usable = |x: usize, y: usize| {
            let v = img.get(x, y);
            v.is_finite() && v > 0.0 && !img.is_saturated(v) && mask.is_none_or(|m| m.keeps(x, y))
        };
        let mut out = Vec::new();
        for y in 2..h - 2 {
            for x in 2..w - 2 {
                if !(0..5).all(|i| (0..5).all(|j| usable(x + j - 2, y + i - 2))) {
                    continue;
                }
                // the same grouping as the separable passes
                let row = |yy: usize, g: [f64; 3]| {
                    let v = |dx: usize| img.get(x + dx - 2, yy);
                    (v(0) + v(4)) * g[0] + g[1] * (v(1) + v(3)) + g[2] * v(2)
                };
                let col = |g: [f64; 3], r: &dyn Fn(usize) -> f64| {
                    (r(y - 2) + r(y + 2)) * g[0] + g[1] * (r(y - 1) + r(y + 1)) + g[2] * r(y)
                };
                let (gl, gh) = ([1.0, 16.0, 36.0], [1.0, -4.0, 6.0]);
                let b = col(gl, &|yy| row(yy, gl));
                let a = col(gh, &|yy| row(yy, gh));
                out.push((b, a.abs()));
            }
        }
        out
    }

    fn visit_all(src: &impl PairSource) -> Vec<(f64, f64)> {
        let mut out = Vec::new();
        let mut scratch = Default::default();
        for part in 0..src.parts() {
            src.visit(part, true, &mut scratch, |m, v| {
                out.extend(m.iter().copied().zip(v.iter().copied()));
            });
        }
        out
    }

    #[test]
    fn single_image_pairs_match_a_pixel_by_pixel_filter() {
        let mut rng = Rng(5);
        for (w, h) in [(37, 75), (5, 5), (80, 6), (9, 41)] {
            let (img, mask) = test_image(w, h, &mut rng);
            for m in [None, Some(&mask)] {
                let got = visit_all(&SingleImage::new(&img, m));
                let expect = single_image_reference(&img, m);
                assert_eq!(got.len(), expect.len(), "{w}x{h}");
                for (g, e) in got.iter().zip(&expect) {
                    assert_eq!(
                        (g.0.to_bits(), g.1.to_bits()),
                        (e.0.to_bits(), e.1.to_bits())
                    );
                }
                // the visit without values gives the same means
                let src = SingleImage::new(&img, m);
                let mut means = Vec::new();
                let mut scratch = Default::default();
                for part in 0..src.parts() {
                    src.visit(part, false, &mut scratch, |mm, _| {
                        means.extend_from_slice(mm)
                    });
                }
                assert!(
                    means
                        .iter()
                        .zip(&expect)
                        .all(|(a, e)| a.to_bits() == e.0.to_bits())
                );
                // and the ranges hold every pair
                let r = src.ranges();
                assert!(expect.iter().all(|p| r.mean_lo <= p.0 && p.0 <= r.mean_hi));
                assert!(expect.iter().all(|p| p.1 <= r.value_hi));
            }
        }
    }

    #[test]
    fn stack_pairs_match_a_pixel_by_pixel_computation() {
        let mut rng = Rng(6);
        let (w, h) = (23, 70);
        let stack: Vec<Image> = (0..4).map(|_| test_image(w, h, &mut rng).0).collect();
        let mask = test_image(w, h, &mut rng).1;
        for m in [None, Some(&mask)] {
            let src = stack_pairs(&stack, m).unwrap();
            let got = visit_all(&src);
            // the original computation: frame means over the pixels usable in every frame
            let usable = |k: usize| {
                m.is_none_or(|m| m.as_slice()[k])
                    && stack.iter().all(|img| {
                        let v = img.data()[k];
                        v.is_finite() && v > 0.0 && !img.is_saturated(v)
                    })
            };
            let used: Vec<usize> = (0..w * h).filter(|&k| usable(k)).collect();
            let fm: Vec<f64> = stack
                .iter()
                .map(|img| used.iter().map(|&k| img.data()[k]).sum::<f64>() / used.len() as f64)
                .collect();
            let grand = fm.iter().sum::<f64>() / fm.len() as f64;
            let kf = stack.len() as f64;
            assert_eq!(got.len(), used.len());
            for (g, &k) in got.iter().zip(&used) {
                let (mut s, mut s2) = (0.0, 0.0);
                for (img, f) in stack.iter().zip(&fm) {
                    let v = img.data()[k] - (f - grand);
                    s += v;
                    s2 += v * v;
                }
                let mean = s / kf;
                let var = ((s2 - s * mean) / (kf - 1.0)).max(0.0);
                // integer samples: the frame sums are exact in any order, so bit for bit
                assert_eq!(
                    (g.0.to_bits(), g.1.to_bits()),
                    (mean.to_bits(), var.to_bits())
                );
            }
        }
    }
}
