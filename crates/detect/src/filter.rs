//! The dot map: a band-pass filtered (and, for large dots, binned) copy of the image in which
//! every dot is a single positive peak whose height measures the dot's contrast.
//!
//! `D = G_σf * J − Box_L * J`, with `J = sign · I` binned by `k x k` blocks, `G_σf` a Gaussian
//! close to the dot's own size (a matched filter, Lindeberg-style blob detection) and `Box_L` the
//! mean over a square of about one lattice period (which removes the background, vignetting
//! included, and the lattice's mean level). A dot's peak in `D` is its contrast above the local
//! mean; a missing dot leaves `D <= 0` plus noise.

use bostrack_core::Image;

/// A single-channel f32 raster, row-major.
#[derive(Clone, Debug)]
pub(crate) struct Plane {
    pub w: usize,
    pub h: usize,
    pub data: Vec<f32>,
}

impl Plane {
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

/// Horizontal convolution with edge replication.
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

/// Vertical convolution with edge replication.
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

/// Subtracts from `out` the mean of `src` over the `(2·half+1)²` box around each pixel (over
/// the part of the box inside the image).
fn subtract_box_mean(src: &Plane, half: usize, out: &mut Plane) {
    let (w, h) = (src.w, src.h);
    let mut col = vec![0.0f64; w];
    let mut prefix = vec![0.0f64; w + 1];
    for yy in 0..=half.min(h - 1) {
        for (c, v) in col.iter_mut().zip(&src.data[yy * w..(yy + 1) * w]) {
            *c += *v as f64;
        }
    }
    let side = 2 * half + 1;
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
        let o = &mut out.data[y * w..(y + 1) * w];
        let edge = |x: usize| {
            let x0 = x.saturating_sub(half);
            let x1 = (x + half + 1).min(w);
            ((prefix[x1] - prefix[x0]) / ((x1 - x0) as f64 * rows)) as f32
        };
        if w > side {
            let inv = 1.0 / (side as f64 * rows);
            for x in 0..half {
                o[x] -= edge(x);
            }
            for x in half..w - half {
                o[x] -= ((prefix[x + half + 1] - prefix[x - half]) * inv) as f32;
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
}

/// `sign · I` binned by `k x k` blocks (mean), non-finite samples replaced by `fill`.
fn binned(img: &Image, sign: f64, fill: f64, nonfinite: bool, k: usize) -> Plane {
    let (wb, hb) = (img.width() / k, img.height() / k);
    let mut out = Plane::zeros(wb, hb);
    let scale = sign / (k * k) as f64;
    for yb in 0..hb {
        let o = &mut out.data[yb * wb..(yb + 1) * wb];
        for dy in 0..k {
            let row = img.row(yb * k + dy);
            if k == 1 && !nonfinite {
                for (ov, &v) in o.iter_mut().zip(row) {
                    *ov = (scale * v) as f32;
                }
            } else if k == 1 {
                for (ov, &v) in o.iter_mut().zip(row) {
                    *ov = (scale * if v.is_finite() { v } else { fill }) as f32;
                }
            } else {
                for (xb, ov) in o.iter_mut().enumerate() {
                    let s: f64 = row[xb * k..xb * k + k]
                        .iter()
                        .map(|&v| if v.is_finite() { v } else { fill })
                        .sum();
                    *ov += (scale * s) as f32;
                }
            }
        }
    }
    out
}

impl DotMap {
    /// Build the dot map of `img` (see the module documentation). `fill` replaces non-finite
    /// samples (`nonfinite` says whether there are any).
    pub(crate) fn build(
        img: &Image,
        sign: f64,
        fill: f64,
        nonfinite: bool,
        p: &FilterParams,
    ) -> Self {
        let j = binned(img, sign, fill, nonfinite, p.k);
        let kern = gaussian_kernel(p.sigma_f);
        let mut d = conv_cols(&conv_rows(&j, &kern), &kern);
        subtract_box_mean(&j, p.box_half, &mut d);
        DotMap { d, k: p.k }
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
        let (w, h) = (self.d.w, self.d.h);
        let d = &self.d.data;
        let v = d[y * w + x];
        if x > 0 && y > 0 && x + 1 < w && y + 1 < h {
            let up = &d[(y - 1) * w + x - 1..(y - 1) * w + x + 2];
            let mid = &d[y * w + x - 1..y * w + x + 2];
            let dn = &d[(y + 1) * w + x - 1..(y + 1) * w + x + 2];
            return up[0] < v
                && up[1] < v
                && up[2] < v
                && mid[0] < v
                && mid[2] <= v
                && dn[0] <= v
                && dn[1] <= v
                && dn[2] <= v;
        }
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
        let x0 = ((cx - r).ceil() as i64).max(0);
        let x1 = ((cx + r).floor() as i64).min(w - 1);
        let y0 = ((cy - r).ceil() as i64).max(0);
        let y1 = ((cy + r).floor() as i64).min(h - 1);
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
        let x0 = (cx - hc).ceil().max(0.0) as usize;
        let x1 = ((cx + hc).floor() as i64).min(self.d.w as i64 - 1);
        if x1 < x0 as i64 {
            (1, 0)
        } else {
            (x0, x1 as usize)
        }
    }

    /// Appends to `out` every 8-neighbour local maximum of D within `radius` (full-resolution
    /// px) of `c`, with a parabolic sub-pixel position.
    pub(crate) fn local_maxima(&self, c: [f64; 2], radius: f64, out: &mut Vec<Peak>) {
        let Some((cx, cy, r, [_, _, y0, y1])) = self.disc(c, radius) else {
            return;
        };
        for y in y0..=y1 {
            let (x0, x1) = self.chord(cx, cy, r, y);
            for x in x0..=x1 {
                if self.is_local_max(x, y) {
                    out.push(self.peak_at(x, y));
                }
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
        let vmax = buf.iter().map(|p| p.v).fold(f64::NEG_INFINITY, f64::max);
        buf.iter()
            .copied()
            .filter(|p| p.v >= 0.5 * vmax)
            .min_by(|a, b| dist2(a.pos(), c).total_cmp(&dist2(b.pos(), c)))
    }
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
