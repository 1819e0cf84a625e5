//! The dot map: a band-pass filtered (and, for large dots, binned) copy of the image in which
//! every dot is a single positive peak whose height measures the dot's contrast.
//!
//! `D = G_σf * J − Box_L * J`, with `J = sign · I` binned by `k x k` blocks, `G_σf` a Gaussian
//! close to the dot's own size (a matched filter, Lindeberg-style blob detection) and `Box_L` the
//! mean over a square of about one lattice period (which removes the background, vignetting
//! included, and the lattice's mean level). A dot's peak in `D` is its contrast above the local
//! mean; a missing dot leaves `D <= 0` plus noise.

use bostrack_core::Image;
use rayon::prelude::*;

/// A single-channel f32 raster, row-major.
#[derive(Clone, Debug)]
pub(crate) struct Plane {
    pub w: usize,
    pub h: usize,
    pub data: Vec<f32>,
}

impl Plane {
    #[cfg(test)]
    fn zeros(w: usize, h: usize) -> Self {
        Plane {
            w,
            h,
            data: vec![0.0; w * h],
        }
    }
    #[inline]
    pub(crate) fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.w + x]
    }
}

/// How the dot map is built from the spacing and dot size (both in full-resolution px).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct FilterParams {
    /// Binning factor k (1 = full resolution).
    pub k: usize,
    /// Gaussian smoothing sigma in binned px.
    pub sigma_f: f64,
    /// Half-size of the background box in binned px (box side 2·half + 1 ≈ one period).
    pub box_half: usize,
}

impl FilterParams {
    /// Binning `k = floor(σ / 1.5)` limited so that the binned spacing stays ≥ 5 px; the
    /// smoothing is 0.8 × the binned dot sigma (pixel and binning box included), clamped to
    /// [0.6, 1.6] binned px; the background box spans about one period.
    pub(crate) fn new(spacing: f64, sigma: f64) -> Self {
        let k =
            ((sigma / 1.5).floor() as usize).clamp(1, ((spacing / 5.0).floor() as usize).max(1));
        let kf = k as f64;
        let sigma_b = ((sigma * sigma + kf * kf / 12.0) / (kf * kf)).sqrt();
        let sigma_f = (0.8 * sigma_b).clamp(0.6, 1.6);
        let box_half = ((0.5 * spacing / kf).round() as usize).max(1);
        FilterParams {
            k,
            sigma_f,
            box_half,
        }
    }
}

/// Band-pass response of an image (see the module documentation).
#[derive(Clone, Debug)]
pub(crate) struct DotMap {
    pub d: Plane,
    pub k: usize,
    /// Whether each pixel of `d` is a local maximum (see [`DotMap::is_local_max`]).
    lmax: Vec<bool>,
}

/// A local maximum of the dot map, in full-resolution image coordinates (sub-pixel).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Peak {
    pub x: f64,
    pub y: f64,
    /// Filtered contrast at the maximum (counts).
    pub v: f64,
}

impl Peak {
    pub(crate) fn pos(&self) -> [f64; 2] {
        [self.x, self.y]
    }
}

fn gaussian_kernel(sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as i64;
    let w: Vec<f64> = (-r..=r)
        .map(|t| (-(t * t) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = w.iter().sum();
    w.iter().map(|v| (v / s) as f32).collect()
}

/// Columns per strip of the filter loops: their partial sums stay in eight SSE registers.
const STRIP: usize = 32;

/// `out[x] = Σ_t k[t] · src[offs[t] + x]`, the taps added in order from 0.0 in f32 (the same
/// rounding as a tap-by-tap accumulation over a whole row), with the partial sums of a strip
/// of columns kept in registers. The horizontal pass reads one padded row at offsets
/// `0, 1, 2, …`; the vertical pass reads the rows of the taps (edges replicated by the caller).
#[inline(always)]
fn correlate(src: &[f32], offs: &[usize], k: &[f32], out: &mut [f32]) {
    let n = out.len();
    let mut x = 0;
    while x + STRIP <= n {
        let mut acc = [0.0f32; STRIP];
        for (&off, &kt) in offs.iter().zip(k) {
            let s: &[f32; STRIP] = src[off + x..off + x + STRIP].try_into().unwrap();
            for l in 0..STRIP {
                acc[l] += kt * s[l];
            }
        }
        out[x..x + STRIP].copy_from_slice(&acc);
        x += STRIP;
    }
    for (x, o) in out.iter_mut().enumerate().skip(x) {
        let mut acc = 0.0f32;
        for (&off, &kt) in offs.iter().zip(k) {
            acc += kt * src[off + x];
        }
        *o = acc;
    }
}

/// Subtracts from row `y` of the output the mean of J over the clipped `(2·half + 1)²` box
/// around each pixel, from the prefix sums `prefix` (length `w + 1`) of that row's column sums.
#[inline(always)]
fn subtract_box_row(prefix: &[f64], h: usize, half: usize, y: usize, o: &mut [f32]) {
    let w = o.len();
    let side = 2 * half + 1;
    let nrows = ((y + half).min(h - 1) - y.saturating_sub(half) + 1) as f64;
    let edge = |x: usize| {
        let x0 = x.saturating_sub(half);
        let x1 = (x + half + 1).min(w);
        ((prefix[x1] - prefix[x0]) / ((x1 - x0) as f64 * nrows)) as f32
    };
    if w > side {
        let inv = 1.0 / (side as f64 * nrows);
        for x in 0..half {
            o[x] -= edge(x);
        }
        let m = w - 2 * half;
        let (hi, lo) = (&prefix[side..side + m], &prefix[..m]);
        for ((ov, a), b) in o[half..half + m].iter_mut().zip(hi).zip(lo) {
            *ov -= ((a - b) * inv) as f32;
        }
        for x in w - half..w {
            o[x] -= edge(x);
        }
    } else {
        for (x, ov) in o.iter_mut().enumerate() {
            *ov -= edge(x);
        }
    }
}

/// Row `yb` of `sign · I` binned by `k x k` blocks (mean), non-finite samples replaced by
/// `fill`, into `out` (length `width / k`).
#[inline(always)]
fn binned_row(
    img: &Image,
    sign: f64,
    fill: f64,
    nonfinite: bool,
    k: usize,
    yb: usize,
    out: &mut [f32],
) {
    let scale = sign / (k * k) as f64;
    if k == 1 {
        let row = img.row(yb);
        if nonfinite {
            for (ov, &v) in out.iter_mut().zip(row) {
                *ov = (scale * if v.is_finite() { v } else { fill }) as f32;
            }
        } else {
            for (ov, &v) in out.iter_mut().zip(row) {
                *ov = (scale * v) as f32;
            }
        }
        return;
    }
    out.fill(0.0);
    for dy in 0..k {
        let row = img.row(yb * k + dy);
        for (xb, ov) in out.iter_mut().enumerate() {
            let s: f64 = row[xb * k..xb * k + k]
                .iter()
                .map(|&v| if v.is_finite() { v } else { fill })
                .sum();
            *ov += (scale * s) as f32;
        }
    }
}

/// Whether `(x, y)` is a local maximum of `d` over its 8 neighbours, for any pixel (edges
/// included): strictly greater than the neighbours before it in raster order, not smaller than
/// those after (a plateau gives one maximum).
fn local_max_generic(d: &[f32], w: usize, h: usize, x: usize, y: usize) -> bool {
    let v = d[y * w + x];
    for ny in y.saturating_sub(1)..=(y + 1).min(h - 1) {
        for nx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
            if nx == x && ny == y {
                continue;
            }
            let nv = d[ny * w + nx];
            let before = ny < y || (ny == y && nx < x);
            if nv > v || (before && nv == v) {
                return false;
            }
        }
    }
    true
}

/// Local-maximum flags of row `y` of `d` ([`local_max_generic`]); the interior pixels by a
/// branch-free pass over the three rows.
#[inline(always)]
fn row_maxima(d: &[f32], w: usize, h: usize, y: usize, out: &mut [bool]) {
    if y == 0 || y + 1 >= h || w < 3 {
        for (x, o) in out.iter_mut().enumerate() {
            *o = local_max_generic(d, w, h, x, y);
        }
        return;
    }
    let up = &d[(y - 1) * w..y * w];
    let mid = &d[y * w..(y + 1) * w];
    let dn = &d[(y + 1) * w..(y + 2) * w];
    let m = w - 2;
    let (ul, uc, ur) = (&up[..m], &up[1..m + 1], &up[2..m + 2]);
    let (ml, mc, mr) = (&mid[..m], &mid[1..m + 1], &mid[2..m + 2]);
    let (dl, dc, dr) = (&dn[..m], &dn[1..m + 1], &dn[2..m + 2]);
    let o = &mut out[1..m + 1];
    for x in 0..m {
        let v = mc[x];
        o[x] = (ul[x] < v)
            & (uc[x] < v)
            & (ur[x] < v)
            & (ml[x] < v)
            & (mr[x] <= v)
            & (dl[x] <= v)
            & (dc[x] <= v)
            & (dr[x] <= v);
    }
    out[0] = local_max_generic(d, w, h, 0, y);
    out[w - 1] = local_max_generic(d, w, h, w - 1, y);
}

/// `ceil` without a library call (the baseline x86-64 target has no rounding instruction);
/// exact, up to the sign of a zero result.
#[inline]
fn ceil_fast(t: f64) -> f64 {
    if t.abs() < 4.0e15 {
        let i = t as i64 as f64; // truncated, exact
        if i < t { i + 1.0 } else { i }
    } else {
        t.ceil() // large, infinite or NaN
    }
}

/// `floor` without a library call; exact, up to the sign of a zero result.
#[inline]
fn floor_fast(t: f64) -> f64 {
    if t.abs() < 4.0e15 {
        let i = t as i64 as f64; // truncated, exact
        if i > t { i - 1.0 } else { i }
    } else {
        t.floor() // large, infinite or NaN
    }
}

/// The source of the dot map: `sign · I` binned by `k x k` blocks (see [`binned_row`]).
struct Binned<'a> {
    img: &'a Image,
    sign: f64,
    fill: f64,
    nonfinite: bool,
    k: usize,
}

impl Binned<'_> {
    #[inline(always)]
    fn row(&self, y: usize, out: &mut [f32]) {
        binned_row(
            self.img,
            self.sign,
            self.fill,
            self.nonfinite,
            self.k,
            y,
            out,
        );
    }
}

/// Rows `y0..` of the dot map (as many as `out` holds, `w` samples each) in one streaming pass:
/// each binned row `J`, its horizontal Gaussian pass `H` and the column sums of the background
/// box live in small ring buffers; an output row is the vertical Gaussian pass over the `H`
/// rows minus the box mean. The column sums are first brought to row `y0` by the very sequence
/// of additions and subtractions a pass from the top would make, so a band's rows are bit for
/// bit those of the whole-image pass.
///
/// Run through `pulp`'s dispatch ([`bostrack_core::simd_arch`]): the same scalar code, which
/// the compiler vectorises for the widest instruction set the CPU has (AVX2: 8 columns of f32
/// per instruction where the baseline has 4); the same operations in the same order on every
/// path, so the same bits (test `the_dispatched_band_is_the_portable_one`).
fn dot_map_band(arch: pulp::Arch, band: &Band, y0: usize, out: &mut [f32]) {
    bostrack_core::dispatch(arch, || band.rows(y0, out))
}

/// What the bands of a dot map share.
struct Band<'a> {
    src: &'a Binned<'a>,
    w: usize,
    h: usize,
    kern: &'a [f32],
    half: usize,
}

impl Band<'_> {
    /// [`dot_map_band`]'s work (inlined into the dispatched call, so that it is vectorised
    /// with it).
    #[inline(always)]
    fn rows(&self, y0: usize, out: &mut [f32]) {
        let Band {
            src,
            w,
            h,
            kern,
            half,
        } = *self;
        let y_end = y0 + out.len() / w;
        let r = kern.len() / 2;
        // Ring of J and H rows: J is needed from row y - half - 1 to y + 1 + max(half, r), H from
        // y - r to the same.
        let ahead = half.max(r);
        let cap = half + r + ahead + 3;
        let mut jring = vec![0.0f32; cap * w];
        let mut hring = vec![0.0f32; cap * w];
        let mut pad = vec![0.0f32; w + 2 * r];
        let taps: Vec<usize> = (0..kern.len()).collect();
        let first = y0.saturating_sub(half + 1).min(y0.saturating_sub(r));
        let mut made = first; // J and H rows computed so far (from `first`)
        // (a loop, not a closure: inlined into the dispatched body, it is vectorised with it)
        macro_rules! make_rows {
            ($upto:expr) => {
                while made <= ($upto).min(h - 1) {
                    let s = (made % cap) * w;
                    let jr = &mut jring[s..s + w];
                    src.row(made, jr);
                    pad[..r].fill(jr[0]);
                    pad[r..r + w].copy_from_slice(jr);
                    pad[r + w..].fill(jr[w - 1]);
                    correlate(&pad, &taps, kern, &mut hring[s..s + w]);
                    made += 1;
                }
            };
        }
        let row_of = |t: usize| -> std::ops::Range<usize> {
            let s = (t % cap) * w;
            s..s + w
        };
        let zeros = vec![0.0f32; w];
        // Column sums of J over rows 0..=half, then the updates of rows 1..y0 (row yy gains row
        // yy + half and loses row yy - half - 1; a zero row where there is none: adding +0 to a
        // sum that started at +0 changes nothing).
        let mut col = vec![0.0f64; w];
        {
            let (mut ja, mut js) = (vec![0.0f32; w], vec![0.0f32; w]);
            for yy in 0..=half.min(h - 1) {
                src.row(yy, &mut ja);
                for (c, v) in col.iter_mut().zip(&ja) {
                    *c += *v as f64;
                }
            }
            for yy in 1..y0 {
                let add = if yy + half < h {
                    src.row(yy + half, &mut ja);
                    &ja[..]
                } else {
                    &zeros[..]
                };
                let sub = if yy > half {
                    src.row(yy - half - 1, &mut js);
                    &js[..]
                } else {
                    &zeros[..]
                };
                for ((c, a), s) in col.iter_mut().zip(add).zip(sub) {
                    *c = *c + *a as f64 - *s as f64;
                }
            }
        }
        let mut col2 = vec![0.0f64; w];
        let (mut pa, mut pb) = (vec![0.0f64; w + 1], vec![0.0f64; w + 1]);
        let mut offs = vec![0usize; kern.len()];
        // Rows in pairs, so that the two rows' prefix sums (each a chain of dependent additions)
        // run side by side.
        let mut y = y0;
        while y < y_end {
            let pair = y + 1 < y_end;
            let last = if pair { y + 1 } else { y };
            make_rows!(last + ahead);
            // Vertical Gaussian pass (edge rows replicated).
            for yy in y..=last {
                for (t, off) in offs.iter_mut().enumerate() {
                    *off = row_of((yy + t).saturating_sub(r).min(h - 1)).start;
                }
                let o = &mut out[(yy - y0) * w..(yy - y0 + 1) * w];
                correlate(&hring, &offs, kern, o);
            }
            // Box mean of J over the clipped (2·half + 1)² box: the column sums' update, then a
            // prefix sum along the row.
            let updates = |yy: usize| -> (&[f32], &[f32]) {
                if yy == 0 {
                    return (&zeros, &zeros);
                }
                let add = if yy + half < h {
                    &jring[row_of(yy + half)]
                } else {
                    &zeros[..]
                };
                let sub = if yy > half {
                    &jring[row_of(yy - half - 1)]
                } else {
                    &zeros[..]
                };
                (add, sub)
            };
            let (a_add, a_sub) = updates(y);
            for ((c, a), s) in col.iter_mut().zip(a_add).zip(a_sub) {
                *c = *c + *a as f64 - *s as f64;
            }
            if pair {
                let (b_add, b_sub) = updates(y + 1);
                for (((c2, c), a), s) in col2.iter_mut().zip(&col).zip(b_add).zip(b_sub) {
                    *c2 = *c + *a as f64 - *s as f64;
                }
                let (mut acc_a, mut acc_b) = (0.0, 0.0);
                for x in 0..w {
                    acc_a += col[x];
                    acc_b += col2[x];
                    pa[x + 1] = acc_a;
                    pb[x + 1] = acc_b;
                }
                std::mem::swap(&mut col, &mut col2);
            } else {
                let mut acc_a = 0.0;
                for x in 0..w {
                    acc_a += col[x];
                    pa[x + 1] = acc_a;
                }
            }
            let o = &mut out[(y - y0) * w..(last - y0 + 1) * w];
            let (oa, ob) = o.split_at_mut(w);
            subtract_box_row(&pa, h, half, y, oa);
            if pair {
                subtract_box_row(&pb, h, half, y + 1, ob);
            }
            y = last + 1;
        }
    }
}

impl DotMap {
    /// Build the dot map of `img` (see the module documentation). `fill` replaces non-finite
    /// samples (`nonfinite` says whether there are any).
    ///
    /// The rows are computed in bands, in parallel on the current rayon pool (one band per
    /// thread; see [`dot_map_band`]), then the local-maximum flags row by row. The arithmetic
    /// (order of every f32 and f64 operation) is that of three whole-image passes, horizontal
    /// Gaussian, vertical Gaussian, box mean over `J` (running f64 column sums and a per-row f64
    /// prefix sum), whatever the number of bands: the result does not depend on the threads.
    pub(crate) fn build(
        img: &Image,
        sign: f64,
        fill: f64,
        nonfinite: bool,
        p: &FilterParams,
    ) -> Self {
        // Bands of at least 64 rows; later bands replay the column sums above them (about
        // 3 operations per pixel above), so that a few bands cost little.
        let h = img.height() / p.k;
        let bands = rayon::current_num_threads().min(h / 64).clamp(1, 8);
        Self::build_in_bands(img, sign, fill, nonfinite, p, bands)
    }

    /// [`DotMap::build`] with a given number of bands (the result does not depend on it).
    fn build_in_bands(
        img: &Image,
        sign: f64,
        fill: f64,
        nonfinite: bool,
        p: &FilterParams,
        bands: usize,
    ) -> Self {
        let k = p.k;
        let (w, h) = (img.width() / k, img.height() / k);
        let kern = gaussian_kernel(p.sigma_f);
        let src = Binned {
            img,
            sign,
            fill,
            nonfinite,
            k,
        };
        let band = h.div_ceil(bands.clamp(1, h));
        let arch = bostrack_core::simd_arch();
        let job = Band {
            src: &src,
            w,
            h,
            kern: &kern,
            half: p.box_half,
        };
        // (both planes zeroed in parallel: a 1-MP image's serial fill was ~0.5 % of a frame,
        // all of it on one thread)
        let mut data = Vec::with_capacity(w * h);
        data.par_extend(rayon::iter::repeat_n(0.0f32, w * h));
        data.par_chunks_mut(band * w)
            .enumerate()
            .for_each(|(b, out)| dot_map_band(arch, &job, b * band, out));
        let mut lmax = Vec::with_capacity(w * h);
        lmax.par_extend(rayon::iter::repeat_n(false, w * h));
        lmax.par_chunks_mut(w)
            .enumerate()
            .with_min_len(32)
            .for_each(|(y, o)| {
                bostrack_core::dispatch(bostrack_core::simd_arch(), || {
                    row_maxima(&data, w, h, y, o)
                })
            });
        DotMap {
            d: Plane { w, h, data },
            k,
            lmax,
        }
    }

    /// Full-resolution coordinate of binned coordinate `t`.
    #[inline]
    fn to_full(&self, t: f64) -> f64 {
        let k = self.k as f64;
        k * t + 0.5 * (k - 1.0)
    }

    /// Binned coordinate of full-resolution coordinate `t`.
    #[inline]
    fn to_binned(&self, t: f64) -> f64 {
        let k = self.k as f64;
        (t - 0.5 * (k - 1.0)) / k
    }

    /// D at the map pixel nearest to a full-resolution point (clamped to the map). Not
    /// interpolated: interpolation would average the noise down.
    pub(crate) fn sample(&self, p: [f64; 2]) -> f64 {
        let (w, h) = (self.d.w, self.d.h);
        let x = self.to_binned(p[0]).round().clamp(0.0, (w - 1) as f64) as usize;
        let y = self.to_binned(p[1]).round().clamp(0.0, (h - 1) as f64) as usize;
        self.d.at(x, y) as f64
    }

    /// Whether binned pixel `(x, y)` is a local maximum over its 8 neighbours (plateaus give one
    /// maximum: a pixel must be strictly greater than the neighbours before it in raster order).
    #[inline]
    fn is_local_max(&self, x: usize, y: usize) -> bool {
        self.lmax[y * self.d.w + x]
    }

    /// The peak at binned pixel `(x, y)` with a parabolic sub-pixel position.
    fn peak_at(&self, x: usize, y: usize) -> Peak {
        let (w, h) = (self.d.w, self.d.h);
        let d = &self.d;
        let v = d.at(x, y);
        let sx = if x > 0 && x + 1 < w {
            parabola(d.at(x - 1, y), v, d.at(x + 1, y))
        } else {
            0.0
        };
        let sy = if y > 0 && y + 1 < h {
            parabola(d.at(x, y - 1), v, d.at(x, y + 1))
        } else {
            0.0
        };
        Peak {
            x: self.to_full(x as f64 + sx),
            y: self.to_full(y as f64 + sy),
            v: v as f64,
        }
    }

    /// The disc of `radius` (full-resolution px) around `c` in binned px: centre, radius and the
    /// clipped bounding box `[x0, x1, y0, y1]`.
    fn disc(&self, c: [f64; 2], radius: f64) -> Option<(f64, f64, f64, [usize; 4])> {
        let (w, h) = (self.d.w as i64, self.d.h as i64);
        let (cx, cy) = (self.to_binned(c[0]), self.to_binned(c[1]));
        let r = radius / self.k as f64;
        if !(cx.is_finite() && cy.is_finite() && r.is_finite()) {
            return None;
        }
        let x0 = (ceil_fast(cx - r) as i64).max(0);
        let x1 = (floor_fast(cx + r) as i64).min(w - 1);
        let y0 = (ceil_fast(cy - r) as i64).max(0);
        let y1 = (floor_fast(cy + r) as i64).min(h - 1);
        (x0 <= x1 && y0 <= y1).then_some((
            cx,
            cy,
            r,
            [x0 as usize, x1 as usize, y0 as usize, y1 as usize],
        ))
    }

    /// Column range `[x0, x1]` of row `y` inside the disc (empty when `x0 > x1`).
    #[inline]
    fn chord(&self, cx: f64, cy: f64, r: f64, y: usize) -> (usize, usize) {
        let dy = y as f64 - cy;
        let hc2 = r * r - dy * dy;
        if hc2 < 0.0 {
            return (1, 0);
        }
        let hc = hc2.sqrt();
        let x0 = ceil_fast(cx - hc).max(0.0) as usize;
        let x1 = (floor_fast(cx + hc) as i64).min(self.d.w as i64 - 1);
        if x1 < x0 as i64 {
            (1, 0)
        } else {
            (x0, x1 as usize)
        }
    }

    /// Calls `f(x, y)` for every binned pixel within `radius` (full-resolution px) of `c` that
    /// is an 8-neighbour local maximum of D, in raster order.
    #[inline]
    fn scan_maxima(&self, c: [f64; 2], radius: f64, mut f: impl FnMut(usize, usize)) {
        let Some((cx, cy, r, [_, _, y0, y1])) = self.disc(c, radius) else {
            return;
        };
        let w = self.d.w;
        for y in y0..=y1 {
            let (x0, x1) = self.chord(cx, cy, r, y);
            if x0 > x1 {
                continue;
            }
            for (k, &m) in self.lmax[y * w + x0..=y * w + x1].iter().enumerate() {
                if m {
                    f(x0 + k, y);
                }
            }
        }
    }

    /// Appends to `out` every 8-neighbour local maximum of D within `radius` (full-resolution
    /// px) of `c`, with a parabolic sub-pixel position.
    pub(crate) fn local_maxima(&self, c: [f64; 2], radius: f64, out: &mut Vec<Peak>) {
        self.scan_maxima(c, radius, |x, y| out.push(self.peak_at(x, y)));
    }

    /// [`DotMap::local_maxima`] with the binned pixel of each maximum, for
    /// [`DotMap::maxima_within`].
    pub(crate) fn local_maxima_px(&self, c: [f64; 2], radius: f64, out: &mut Vec<Maximum>) {
        self.scan_maxima(c, radius, |x, y| {
            out.push(Maximum {
                x: x as u32,
                y: y as u32,
                peak: self.peak_at(x, y),
            })
        });
    }

    /// Appends to `out`, in order, the maxima of `list` that [`DotMap::local_maxima`] of `c`
    /// and `radius` would return, provided `list` holds every maximum of a disc that contains
    /// that disc (e.g. [`DotMap::local_maxima_px`] of a larger disc around a nearby point):
    /// the same pixel test on fewer candidates.
    pub(crate) fn maxima_within(
        &self,
        list: &[Maximum],
        c: [f64; 2],
        radius: f64,
        out: &mut Vec<Peak>,
    ) {
        let Some((cx, cy, r, [_, _, y0, y1])) = self.disc(c, radius) else {
            return;
        };
        for m in list {
            let (x, y) = (m.x as usize, m.y as usize);
            if y < y0 || y > y1 {
                continue;
            }
            let (x0, x1) = self.chord(cx, cy, r, y);
            if x0 <= x && x <= x1 {
                out.push(m.peak);
            }
        }
    }

    /// The strongest local maximum within `radius` of `c`. Fast path: the brightest pixel of the
    /// disc, when it is a local maximum, is the strongest one.
    pub(crate) fn strongest(&self, c: [f64; 2], radius: f64, buf: &mut Vec<Peak>) -> Option<Peak> {
        let (cx, cy, r, [_, _, y0, y1]) = self.disc(c, radius)?;
        let w = self.d.w;
        let mut best = (usize::MAX, 0usize, f32::NEG_INFINITY);
        for y in y0..=y1 {
            let (x0, x1) = self.chord(cx, cy, r, y);
            if x0 > x1 {
                continue;
            }
            let row = &self.d.data[y * w + x0..=y * w + x1];
            for (k, &v) in row.iter().enumerate() {
                if v > best.2 {
                    best = (x0 + k, y, v);
                }
            }
        }
        if best.0 == usize::MAX {
            return None;
        }
        if self.is_local_max(best.0, best.1) {
            return Some(self.peak_at(best.0, best.1));
        }
        buf.clear();
        self.local_maxima(c, radius, buf);
        buf.iter().copied().max_by(|a, b| a.v.total_cmp(&b.v))
    }

    /// Among the local maxima within `radius` of `c` that reach at least half the strongest,
    /// the one nearest to `c` (a dot's own peak rather than a neighbour's or a noise bump).
    pub(crate) fn nearest_strong(
        &self,
        c: [f64; 2],
        radius: f64,
        buf: &mut Vec<Peak>,
    ) -> Option<Peak> {
        buf.clear();
        self.local_maxima(c, radius, buf);
        nearest_strong_of(buf, c)
    }
}

/// Among `peaks` (in scan order), those at least half the strongest, the one nearest to `c`
/// (the first one on a tie): the choice of [`DotMap::nearest_strong`].
pub(crate) fn nearest_strong_of(peaks: &[Peak], c: [f64; 2]) -> Option<Peak> {
    let vmax = peaks.iter().map(|p| p.v).fold(f64::NEG_INFINITY, f64::max);
    peaks
        .iter()
        .copied()
        .filter(|p| p.v >= 0.5 * vmax)
        .min_by(|a, b| dist2(a.pos(), c).total_cmp(&dist2(b.pos(), c)))
}

/// A local maximum of the dot map with its binned pixel.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Maximum {
    pub x: u32,
    pub y: u32,
    pub peak: Peak,
}

/// Vertex offset of the parabola through (-1, a), (0, b), (1, c), clamped to ±0.5.
#[inline]
fn parabola(a: f32, b: f32, c: f32) -> f64 {
    let (a, b, c) = (a as f64, b as f64, c as f64);
    let den = a - 2.0 * b + c;
    if den < 0.0 {
        (0.5 * (a - c) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

#[inline]
pub(crate) fn dist2(p: [f64; 2], q: [f64; 2]) -> f64 {
    (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    // The plain three-pass dot map (horizontal Gaussian, vertical Gaussian, box mean, each over
    // the whole image) and the direct local-maximum test: the reference that the streaming
    // [`DotMap::build`] must reproduce bit for bit.

    fn conv_rows(src: &Plane, k: &[f32]) -> Plane {
        let (w, h) = (src.w, src.h);
        let r = k.len() / 2;
        let mut out = Plane::zeros(w, h);
        let mut pad = Vec::with_capacity(w + 2 * r);
        for y in 0..h {
            let row = &src.data[y * w..(y + 1) * w];
            pad.clear();
            pad.extend(std::iter::repeat_n(row[0], r));
            pad.extend_from_slice(row);
            pad.extend(std::iter::repeat_n(row[w - 1], r));
            let o = &mut out.data[y * w..(y + 1) * w];
            for (t, &kt) in k.iter().enumerate() {
                let s = &pad[t..t + w];
                for (ov, sv) in o.iter_mut().zip(s) {
                    *ov += kt * sv;
                }
            }
        }
        out
    }

    fn conv_cols(src: &Plane, k: &[f32]) -> Plane {
        let (w, h) = (src.w, src.h);
        let r = k.len() / 2;
        let mut out = Plane::zeros(w, h);
        for y in 0..h {
            let o = &mut out.data[y * w..(y + 1) * w];
            for (t, &kt) in k.iter().enumerate() {
                let yy = (y + t).saturating_sub(r).min(h - 1);
                let s = &src.data[yy * w..(yy + 1) * w];
                for (ov, sv) in o.iter_mut().zip(s) {
                    *ov += kt * sv;
                }
            }
        }
        out
    }

    fn subtract_box_mean(src: &Plane, half: usize, out: &mut Plane) {
        let (w, h) = (src.w, src.h);
        let mut col = vec![0.0f64; w];
        let mut prefix = vec![0.0f64; w + 1];
        for yy in 0..=half.min(h - 1) {
            for (c, v) in col.iter_mut().zip(&src.data[yy * w..(yy + 1) * w]) {
                *c += *v as f64;
            }
        }
        for y in 0..h {
            if y > 0 {
                let add = y + half;
                if add < h {
                    for (c, v) in col.iter_mut().zip(&src.data[add * w..(add + 1) * w]) {
                        *c += *v as f64;
                    }
                }
                if y > half {
                    let sub = y - half - 1;
                    for (c, v) in col.iter_mut().zip(&src.data[sub * w..(sub + 1) * w]) {
                        *c -= *v as f64;
                    }
                }
            }
            let rows = ((y + half).min(h - 1) - y.saturating_sub(half) + 1) as f64;
            let mut acc = 0.0;
            for x in 0..w {
                acc += col[x];
                prefix[x + 1] = acc;
            }
            for x in 0..w {
                let x0 = x.saturating_sub(half);
                let x1 = (x + half + 1).min(w);
                let m = if x >= half && x + half < w {
                    let inv = 1.0 / ((2 * half + 1) as f64 * rows);
                    ((prefix[x1] - prefix[x0]) * inv) as f32
                } else {
                    ((prefix[x1] - prefix[x0]) / ((x1 - x0) as f64 * rows)) as f32
                };
                out.data[y * w + x] -= m;
            }
        }
    }

    fn reference_map(
        img: &Image,
        sign: f64,
        fill: f64,
        nonfinite: bool,
        p: &FilterParams,
    ) -> Plane {
        let k = p.k;
        let (w, h) = (img.width() / k, img.height() / k);
        let mut j = Plane::zeros(w, h);
        for y in 0..h {
            binned_row(
                img,
                sign,
                fill,
                nonfinite,
                k,
                y,
                &mut j.data[y * w..(y + 1) * w],
            );
        }
        let kern = gaussian_kernel(p.sigma_f);
        let mut d = conv_cols(&conv_rows(&j, &kern), &kern);
        subtract_box_mean(&j, p.box_half, &mut d);
        d
    }

    fn reference_local_max(d: &Plane, x: usize, y: usize) -> bool {
        let (w, h) = (d.w, d.h);
        let v = d.at(x, y);
        if x > 0 && y > 0 && x + 1 < w && y + 1 < h {
            return d.at(x - 1, y - 1) < v
                && d.at(x, y - 1) < v
                && d.at(x + 1, y - 1) < v
                && d.at(x - 1, y) < v
                && d.at(x + 1, y) <= v
                && d.at(x - 1, y + 1) <= v
                && d.at(x, y + 1) <= v
                && d.at(x + 1, y + 1) <= v;
        }
        local_max_generic(&d.data, w, h, x, y)
    }

    #[test]
    fn streaming_build_equals_the_three_pass_filter_bit_for_bit() {
        // Float-valued dots on a sloping background with noise-like texture, plateaus (integer
        // steps) and, in one case, non-finite samples; several sizes, binnings and filters.
        for (w, h, k, sigma_f, box_half, bad) in [
            (61usize, 47usize, 1usize, 1.3, 4usize, false),
            (40, 33, 1, 0.6, 1, true),
            (70, 52, 2, 1.6, 3, true),
            (64, 64, 3, 1.0, 2, false),
            (9, 40, 1, 1.2, 6, false),
        ] {
            let img = Image::from_fn(w, h, |x, y| {
                let (fx, fy) = (x as f64, y as f64);
                let dots = (fx * 0.79).sin() * (fy * 0.81).cos();
                let tex = ((x * 7919 + y * 104729) % 97) as f64 * 0.37;
                let v = 200.0 + 3.0 * fx - 2.0 * fy + 500.0 * dots * dots + tex;
                if bad && (x * 13 + y * 7) % 89 == 0 {
                    f64::NAN
                } else if (x / 5 + y / 5) % 7 == 0 {
                    v.floor()
                } else {
                    v
                }
            });
            let p = FilterParams {
                k,
                sigma_f,
                box_half,
            };
            for (sign, bands) in [(1.0, 1), (-1.0, 1), (1.0, 2), (1.0, 3), (-1.0, 7)] {
                let m = DotMap::build_in_bands(&img, sign, 321.5, bad, &p, bands);
                let want = reference_map(&img, sign, 321.5, bad, &p);
                assert_eq!((m.d.w, m.d.h), (want.w, want.h));
                for (a, b) in m.d.data.iter().zip(&want.data) {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "{w}x{h} k {k} bands {bands}: {a} vs {b}"
                    );
                }
                for y in 0..want.h {
                    for x in 0..want.w {
                        assert_eq!(
                            m.is_local_max(x, y),
                            reference_local_max(&want, x, y),
                            "{w}x{h} k {k} at ({x}, {y})"
                        );
                    }
                }
            }
        }
    }

    /// The band on the dispatched instruction set (AVX2 where the CPU has it) and on the
    /// portable path give the same bits (the three-pass reference above checks the dispatched
    /// one).
    #[test]
    fn the_dispatched_band_is_the_portable_one() {
        for (w, h, k, bad) in [(97usize, 41usize, 1usize, false), (130, 40, 2, true)] {
            let img = Image::from_fn(w, h, |x, y| {
                let v = 150.0
                    + 300.0 * ((x as f64 * 0.9).sin() * (y as f64 * 0.7).cos()).powi(2)
                    + ((x * 7919 + y * 104729) % 61) as f64;
                if bad && (x + 3 * y) % 53 == 0 {
                    f64::INFINITY
                } else {
                    v
                }
            });
            let src = Binned {
                img: &img,
                sign: -1.0,
                fill: 222.0,
                nonfinite: bad,
                k,
            };
            let kern = gaussian_kernel(1.4);
            let (bw, bh) = (w / k, h / k);
            for y0 in [0, 5, bh / 2] {
                let rows = (bh - y0).min(9);
                let mut a = vec![0.0f32; rows * bw];
                let mut b = vec![0.0f32; rows * bw];
                let job = Band {
                    src: &src,
                    w: bw,
                    h: bh,
                    kern: &kern,
                    half: 3,
                };
                dot_map_band(bostrack_core::simd_arch(), &job, y0, &mut a);
                dot_map_band(pulp::Arch::Scalar, &job, y0, &mut b);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&a), bits(&b), "{w}x{h} k {k} from row {y0}");
            }
        }
    }

    #[test]
    fn maxima_within_a_larger_disc_are_those_of_a_scan() {
        // A noisy dot pattern (many maxima); discs of r2 inside discs of r1 around nearby
        // points, edges of the map included, binned and not.
        let img = Image::from_fn(48, 40, |x, y| {
            let (fx, fy) = (x as f64, y as f64);
            100.0
                + 400.0 * ((fx * 0.8).sin() * (fy * 0.77).cos()).powi(2)
                + ((x * 7919 + y * 104729) % 89) as f64
        });
        let mut state = 7u64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for k in [1usize, 2] {
            let p = FilterParams {
                k,
                sigma_f: 0.8,
                box_half: 3,
            };
            let m = DotMap::build(&img, 1.0, 0.0, false, &p);
            let (r1, r2) = (3.6, 2.4);
            for _ in 0..400 {
                let q = [uniform() * 52.0 - 2.0, uniform() * 44.0 - 2.0];
                let (a, d) = (uniform() * 6.3, uniform() * (r1 - r2 - 1e-6));
                let c = [q[0] + d * a.cos(), q[1] + d * a.sin()];
                let mut list = Vec::new();
                m.local_maxima_px(q, r1, &mut list);
                let (mut got, mut want) = (Vec::new(), Vec::new());
                m.maxima_within(&list, c, r2, &mut got);
                m.local_maxima(c, r2, &mut want);
                assert_eq!(got, want, "k {k} q {q:?} c {c:?}");
                assert_eq!(
                    nearest_strong_of(&got, c),
                    m.nearest_strong(c, r2, &mut want)
                );
            }
        }
    }

    #[test]
    fn fast_rounding_matches_the_library() {
        for t in [
            -3.5,
            -3.0,
            -2.7,
            -0.5,
            -0.0,
            0.0,
            0.2,
            1.0,
            1.5,
            2.9999,
            4.5e15,
            -7e15,
            1e300,
            f64::INFINITY,
        ] {
            assert_eq!(ceil_fast(t), t.ceil(), "{t}");
            assert_eq!(floor_fast(t), t.floor(), "{t}");
        }
        assert!(ceil_fast(f64::NAN).is_nan() && floor_fast(f64::NAN).is_nan());
    }

    #[test]
    fn box_mean_is_the_mean_over_the_clipped_box() {
        let src = Plane {
            w: 5,
            h: 4,
            data: (0..20).map(|v| v as f32).collect(),
        };
        let mut b = Plane::zeros(5, 4);
        subtract_box_mean(&src, 1, &mut b);
        b.data.iter_mut().for_each(|v| *v = -*v);
        // Interior pixel (2, 1): mean of rows 0..=2, cols 1..=3.
        let want: f32 = [1.0, 2.0, 3.0, 6.0, 7.0, 8.0, 11.0, 12.0, 13.0]
            .iter()
            .sum::<f32>()
            / 9.0;
        assert!((b.at(2, 1) - want).abs() < 1e-5);
        // Corner (0, 0): rows 0..=1, cols 0..=1.
        assert!((b.at(0, 0) - (0.0 + 1.0 + 5.0 + 6.0) / 4.0).abs() < 1e-5);
    }

    #[test]
    fn a_gaussian_dot_gives_one_peak_at_its_centre() {
        let img = Image::from_fn(40, 40, |x, y| {
            let (dx, dy) = (x as f64 - 20.3, y as f64 - 18.8);
            100.0 + 500.0 * (-(dx * dx + dy * dy) / (2.0 * 1.5 * 1.5)).exp()
        });
        for k in [1usize, 2] {
            let p = FilterParams {
                k,
                sigma_f: 1.0,
                box_half: 4,
            };
            let m = DotMap::build(&img, 1.0, 0.0, false, &p);
            let mut buf = Vec::new();
            m.local_maxima([20.0, 19.0], 6.0, &mut buf);
            assert_eq!(buf.len(), 1, "k = {k}: {buf:?}");
            assert!(
                (buf[0].x - 20.3).abs() < 0.3 * k as f64
                    && (buf[0].y - 18.8).abs() < 0.3 * k as f64,
                "{buf:?}"
            );
            assert!(buf[0].v > 0.0);
        }
    }
}
