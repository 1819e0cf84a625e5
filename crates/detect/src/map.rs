//! The smooth grid → image mapping: a polynomial in the grid index fitted robustly by least
//! squares to the detected dots (affine part = the lattice, higher terms = lens distortion and
//! target non-planarity).

use crate::linalg::{median, solve_spd};
use bostrack_core::{GridIndex, Lattice};
use serde::{Deserialize, Serialize};

/// Polynomial map from grid index `(i, j)` to image position `(x, y)` (px):
/// `x = Σ cx_pq u^p v^q`, `y = Σ cy_pq u^p v^q` over `p + q <= degree`, with the normalised
/// index `u = (i - centre_i)/scale`, `v = (j - centre_j)/scale`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridMap {
    degree: u8,
    centre: [f64; 2],
    scale: f64,
    cx: Vec<f64>,
    cy: Vec<f64>,
}

/// Monomials `u^p v^q` ordered by total degree, then by decreasing power of u.
fn monomials(degree: u8, u: f64, v: f64, out: &mut [f64]) {
    match degree {
        1 => out[..3].copy_from_slice(&[1.0, u, v]),
        2 => out[..6].copy_from_slice(&[1.0, u, v, u * u, u * v, v * v]),
        3 => {
            let (uu, uv, vv) = (u * u, u * v, v * v);
            out[..10].copy_from_slice(&[1.0, u, v, uu, uv, vv, uu * u, uu * v, u * vv, vv * v]);
        }
        _ => {
            let d = degree as usize;
            let (mut pu, mut pv) = ([1.0; 5], [1.0; 5]);
            for k in 1..=d {
                pu[k] = pu[k - 1] * u;
                pv[k] = pv[k - 1] * v;
            }
            let mut k = 0;
            for t in 0..=d {
                for p in (0..=t).rev() {
                    out[k] = pu[p] * pv[t - p];
                    k += 1;
                }
            }
        }
    }
}

fn n_terms(degree: u8) -> usize {
    (degree as usize + 1) * (degree as usize + 2) / 2
}

impl GridMap {
    /// The affine map of a lattice (`degree` 1).
    pub fn from_lattice(l: &Lattice) -> Self {
        GridMap {
            degree: 1,
            centre: [0.0, 0.0],
            scale: 1.0,
            cx: vec![l.origin[0], l.a[0], l.b[0]],
            cy: vec![l.origin[1], l.a[1], l.b[1]],
        }
    }

    /// Total degree of the polynomial (1 = affine).
    pub fn degree(&self) -> u8 {
        self.degree
    }

    /// Image position (px) of the (possibly fractional) grid index `(i, j)`.
    pub fn predict(&self, i: f64, j: f64) -> [f64; 2] {
        let mut t = [0.0; 15];
        let n = n_terms(self.degree);
        monomials(
            self.degree,
            (i - self.centre[0]) / self.scale,
            (j - self.centre[1]) / self.scale,
            &mut t,
        );
        let x = t[..n].iter().zip(&self.cx).map(|(a, b)| a * b).sum();
        let y = t[..n].iter().zip(&self.cy).map(|(a, b)| a * b).sum();
        [x, y]
    }

    /// Position of a grid site.
    pub fn position(&self, idx: GridIndex) -> [f64; 2] {
        self.predict(idx.i as f64, idx.j as f64)
    }

    /// The local lattice at `(i, j)`: origin = the predicted position, `a` = ∂p/∂i, `b` = ∂p/∂j
    /// (central differences of the polynomial, exact for degree <= 2).
    pub fn local_lattice(&self, i: f64, j: f64) -> Lattice {
        let h = 0.5;
        let (pi, mi) = (self.predict(i + h, j), self.predict(i - h, j));
        let (pj, mj) = (self.predict(i, j + h), self.predict(i, j - h));
        Lattice {
            origin: self.predict(i, j),
            a: [(pi[0] - mi[0]) / (2.0 * h), (pi[1] - mi[1]) / (2.0 * h)],
            b: [(pj[0] - mj[0]) / (2.0 * h), (pj[1] - mj[1]) / (2.0 * h)],
        }
    }

    /// The site whose predicted position is nearest to `p` (Newton inversion of the map from
    /// the local lattice, then a check of the 3x3 neighbourhood).
    pub fn nearest_site(&self, p: [f64; 2]) -> Option<GridIndex> {
        let mut f = [self.centre[0], self.centre[1]];
        for _ in 0..20 {
            let l = self.local_lattice(f[0], f[1]);
            // Offset of p from the local lattice's origin (the site f), in index units.
            let step = l.fractional(p)?;
            f = [f[0] + step[0], f[1] + step[1]];
            if step[0].abs() + step[1].abs() < 1e-6 {
                break;
            }
        }
        if !(f[0].is_finite() && f[1].is_finite()) || f[0].abs() > 1e9 || f[1].abs() > 1e9 {
            return None;
        }
        let (ci, cj) = (f[0].round() as i32, f[1].round() as i32);
        let mut best = None;
        let mut bd = f64::INFINITY;
        for dj in -1..=1 {
            for di in -1..=1 {
                let q = self.predict((ci + di) as f64, (cj + dj) as f64);
                let d = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2);
                if d < bd {
                    bd = d;
                    best = Some(GridIndex::new(ci + di, cj + dj));
                }
            }
        }
        best
    }

    /// Re-index: the site called `(di, dj)` becomes `(0, 0)`.
    pub(crate) fn shift(&mut self, di: i32, dj: i32) {
        self.centre[0] -= di as f64;
        self.centre[1] -= dj as f64;
    }

    /// Least-squares fit of `degree` to `(i, j, x, y)` points. `None` if the system is singular.
    fn fit_once(
        points: &[(f64, f64, [f64; 2])],
        use_pt: &[bool],
        degree: u8,
        centre: [f64; 2],
        scale: f64,
    ) -> Option<Self> {
        let n = n_terms(degree);
        let mut ata = vec![0.0; n * n];
        let mut bx = vec![0.0; n];
        let mut by = vec![0.0; n];
        let mut t = [0.0; 15];
        // At most about 4000 points enter a fit (a regular subsample): plenty for 15 terms.
        let stride = points.len().div_ceil(4000).max(1);
        for (pt, _) in points
            .iter()
            .zip(use_pt)
            .step_by(stride)
            .filter(|(_, u)| **u)
        {
            monomials(
                degree,
                (pt.0 - centre[0]) / scale,
                (pt.1 - centre[1]) / scale,
                &mut t,
            );
            for r in 0..n {
                bx[r] += t[r] * pt.2[0];
                by[r] += t[r] * pt.2[1];
                for c in 0..=r {
                    ata[r * n + c] += t[r] * t[c];
                }
            }
        }
        for r in 0..n {
            for c in r + 1..n {
                ata[r * n + c] = ata[c * n + r];
            }
        }
        let mut a2 = ata.clone();
        if !solve_spd(&mut ata, &mut bx, n) || !solve_spd(&mut a2, &mut by, n) {
            return None;
        }
        Some(GridMap {
            degree,
            centre,
            scale,
            cx: bx,
            cy: by,
        })
    }

    /// Robust fit in two stages, the affine map and then the highest degree up to `max_degree`
    /// whose terms are all supported (at least 6 inliers per coefficient and an index extent of
    /// `2·degree + 1` in both directions): at each stage a least-squares fit, then points farther
    /// than `max(4 · 1.4826 · MAD, floor)` from it are left out and the fit repeated (twice per
    /// stage; a point left out may come back). Returns the map, the inlier mask and the rms
    /// residual of the inliers.
    pub(crate) fn fit_robust(
        points: &[(f64, f64, [f64; 2])],
        max_degree: u8,
        floor: f64,
    ) -> Option<(Self, Vec<bool>, f64)> {
        if points.len() < 3 {
            return None;
        }
        // The fit works on a regular subsample of at most about 2500 points (plenty for 15
        // terms); the final inlier mask and rms cover every point.
        let all = points;
        let stride = all.len().div_ceil(2500).max(1);
        let sub: Vec<(f64, f64, [f64; 2])> = all.iter().step_by(stride).copied().collect();
        let points = &sub[..];
        let mut inl = vec![true; points.len()];
        let mut res = vec![0.0; points.len()];
        let mut best: Option<Self> = None;
        let mut thr_last = f64::INFINITY;
        for stage in 0..2 {
            let (mut imin, mut imax, mut jmin, mut jmax) = (
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            );
            let mut count = 0;
            for (p, _) in points.iter().zip(&inl).filter(|(_, u)| **u) {
                imin = imin.min(p.0);
                imax = imax.max(p.0);
                jmin = jmin.min(p.1);
                jmax = jmax.max(p.1);
                count += 1;
            }
            let extent = (imax - imin).min(jmax - jmin);
            let mut degree = if stage == 0 { 1 } else { max_degree.max(1) };
            while degree > 1 && (count < 6 * n_terms(degree) || extent < (2 * degree + 1) as f64) {
                degree -= 1;
            }
            if stage == 1 && degree == 1 {
                break;
            }
            let centre = [0.5 * (imin + imax), 0.5 * (jmin + jmax)];
            let scale = (0.5 * (imax - imin).max(jmax - jmin)).max(1.0);
            let mut map = match Self::fit_once(points, &inl, degree, centre, scale) {
                Some(m) => m,
                None => break,
            };
            for _ in 0..2 {
                for (r, p) in res.iter_mut().zip(points) {
                    let q = map.predict(p.0, p.1);
                    *r = ((q[0] - p.2[0]).powi(2) + (q[1] - p.2[1]).powi(2)).sqrt();
                }
                let mut tmp: Vec<f64> = res
                    .iter()
                    .zip(&inl)
                    .filter(|(_, u)| **u)
                    .map(|(r, _)| *r)
                    .collect();
                let thr = (4.0 * 1.4826 * median(&mut tmp)).max(floor);
                thr_last = thr;
                let next: Vec<bool> = res.iter().map(|r| *r <= thr).collect();
                if next.iter().filter(|u| **u).count() < n_terms(degree) + 2 {
                    break;
                }
                inl = next;
                match Self::fit_once(points, &inl, degree, centre, scale) {
                    Some(m) => map = m,
                    None => break,
                }
            }
            best = Some(map);
        }
        let map = best?;
        let (mut ss, mut nn) = (0.0, 0usize);
        let mut inl = Vec::with_capacity(all.len());
        for p in all {
            let q = map.predict(p.0, p.1);
            let r2 = (q[0] - p.2[0]).powi(2) + (q[1] - p.2[1]).powi(2);
            let ok = r2 <= thr_last * thr_last;
            if ok {
                ss += r2;
                nn += 1;
            }
            inl.push(ok);
        }
        let rms = (ss / nn.max(1) as f64).sqrt();
        Some((map, inl, rms))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_cubic_map_despite_outliers() {
        let truth = |i: f64, j: f64| {
            [
                100.0 + 8.0 * i + 0.5 * j + 0.002 * i * i * i - 0.01 * i * j,
                50.0 - 0.3 * i + 8.2 * j + 0.004 * j * j,
            ]
        };
        let mut pts = Vec::new();
        for j in -10..=10 {
            for i in -12..=12 {
                let (fi, fj) = (i as f64, j as f64);
                let mut p = truth(fi, fj);
                if (i * 7 + j * 3) % 37 == 0 {
                    p[0] += 3.0; // outlier
                }
                pts.push((fi, fj, p));
            }
        }
        let (map, inl, rms) = GridMap::fit_robust(&pts, 3, 0.05).unwrap();
        assert_eq!(map.degree(), 3);
        assert!(rms < 1e-6, "rms {rms}");
        assert_eq!(
            inl.iter().filter(|u| !**u).count(),
            pts.iter()
                .filter(|p| p.2[0] - truth(p.0, p.1)[0] > 1.0)
                .count()
        );
        let q = map.predict(3.5, -2.0);
        let t = truth(3.5, -2.0);
        assert!((q[0] - t[0]).abs() < 1e-6 && (q[1] - t[1]).abs() < 1e-6);
        let mut shifted = map.clone();
        shifted.shift(2, -1);
        let s = shifted.predict(1.5, -1.0);
        assert!((s[0] - t[0]).abs() < 1e-9 && (s[1] - t[1]).abs() < 1e-9);
        let p = map.predict(4.0, -2.0);
        assert_eq!(
            map.nearest_site([p[0] + 1.5, p[1] - 1.5]),
            Some(GridIndex::new(4, -2))
        );
        assert_eq!(
            map.nearest_site(map.predict(-7.0, 5.0)),
            Some(GridIndex::new(-7, 5))
        );
    }
}
