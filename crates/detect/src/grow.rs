//! Index assignment by region growing: from one confirmed dot, each neighbouring lattice site is
//! predicted from the dots already found around it (a weighted local affine fit over the 5x5
//! index neighbourhood, so lens distortion never accumulates) and accepted when the dot map has
//! a peak there of at least 30 % of the neighbours' median contrast.

use crate::filter::{DotMap, Peak};
use crate::linalg::median;
use bostrack_core::GridIndex;
use rayon::prelude::*;
use std::collections::VecDeque;

/// A dense 2-D array over a range of grid indices.
#[derive(Clone, Debug)]
pub(crate) struct IndexGrid<T> {
    i0: i32,
    j0: i32,
    ni: usize,
    nj: usize,
    data: Vec<T>,
}

impl<T: Clone> IndexGrid<T> {
    /// Covers `imin..=imax` x `jmin..=jmax`.
    pub(crate) fn new(imin: i32, imax: i32, jmin: i32, jmax: i32, fill: T) -> Self {
        let ni = (imax - imin + 1).max(1) as usize;
        let nj = (jmax - jmin + 1).max(1) as usize;
        IndexGrid {
            i0: imin,
            j0: jmin,
            ni,
            nj,
            data: vec![fill; ni * nj],
        }
    }
    #[inline]
    fn slot(&self, i: i32, j: i32) -> Option<usize> {
        let (di, dj) = (i - self.i0, j - self.j0);
        (di >= 0 && dj >= 0 && (di as usize) < self.ni && (dj as usize) < self.nj)
            .then(|| dj as usize * self.ni + di as usize)
    }
    /// Every cell in grid order (`j`, then `i`) as `(i, j, value)`.
    pub(crate) fn iter(&self) -> impl Iterator<Item = (i32, i32, &T)> {
        self.data.iter().enumerate().map(|(k, v)| {
            (
                self.i0 + (k % self.ni) as i32,
                self.j0 + (k / self.ni) as i32,
                v,
            )
        })
    }
    /// Row slices of the `(2r+1)²` neighbourhood of `(i, j)` clipped to the grid: calls
    /// `f(di, dj, value)` for each cell, `(di, dj)` relative to `(i, j)`.
    #[inline]
    pub(crate) fn visit(&self, i: i32, j: i32, r: i32, mut f: impl FnMut(i32, i32, &T)) {
        let (ilo, ihi) = (
            (i - r).max(self.i0),
            (i + r).min(self.i0 + self.ni as i32 - 1),
        );
        let (jlo, jhi) = (
            (j - r).max(self.j0),
            (j + r).min(self.j0 + self.nj as i32 - 1),
        );
        if ilo > ihi {
            return;
        }
        for jj in jlo..=jhi {
            let base = (jj - self.j0) as usize * self.ni;
            let row = &self.data[base + (ilo - self.i0) as usize..=base + (ihi - self.i0) as usize];
            for (k, v) in row.iter().enumerate() {
                f(ilo + k as i32 - i, jj - j, v);
            }
        }
    }
    /// Mutable [`IndexGrid::visit`].
    #[inline]
    pub(crate) fn visit_mut(
        &mut self,
        i: i32,
        j: i32,
        r: i32,
        mut f: impl FnMut(i32, i32, &mut T),
    ) {
        let (ilo, ihi) = (
            (i - r).max(self.i0),
            (i + r).min(self.i0 + self.ni as i32 - 1),
        );
        let (jlo, jhi) = (
            (j - r).max(self.j0),
            (j + r).min(self.j0 + self.nj as i32 - 1),
        );
        if ilo > ihi {
            return;
        }
        for jj in jlo..=jhi {
            let base = (jj - self.j0) as usize * self.ni;
            let row =
                &mut self.data[base + (ilo - self.i0) as usize..=base + (ihi - self.i0) as usize];
            for (k, v) in row.iter_mut().enumerate() {
                f(ilo + k as i32 - i, jj - j, v);
            }
        }
    }
    #[inline]
    pub(crate) fn get(&self, i: i32, j: i32) -> Option<&T> {
        self.slot(i, j).map(|k| &self.data[k])
    }
    #[inline]
    pub(crate) fn get_mut(&mut self, i: i32, j: i32) -> Option<&mut T> {
        self.slot(i, j).map(|k| &mut self.data[k])
    }
}

/// The 8-neighbourhood of every item of a list placed on an [`IndexGrid`] of slots (item index
/// or `usize::MAX`): for each item, the items at the 3x3 index neighbours without itself, in
/// grid order (`j`, then `i`). Computed once, it replaces repeated grid look-ups.
pub(crate) struct Ring1 {
    nb: Vec<[u32; 8]>,
    len: Vec<u8>,
}

impl Ring1 {
    pub(crate) fn new(
        slot: &IndexGrid<usize>,
        index: impl Fn(usize) -> GridIndex + Sync,
        n: usize,
    ) -> Self {
        // Each item on its own (in parallel), in order.
        let (nb, len): (Vec<[u32; 8]>, Vec<u8>) = (0..n)
            .into_par_iter()
            .with_min_len(256)
            .map(|k| {
                let idx = index(k);
                let (mut out, mut cnt) = ([0u32; 8], 0u8);
                slot.visit(idx.i, idx.j, 1, |di, dj, &q| {
                    if (di, dj) != (0, 0) && q != usize::MAX && (cnt as usize) < 8 {
                        out[cnt as usize] = q as u32;
                        cnt += 1;
                    }
                });
                (out, cnt)
            })
            .unzip();
        Ring1 { nb, len }
    }

    /// The neighbours of item `k`.
    #[inline]
    pub(crate) fn of(&self, k: usize) -> impl Iterator<Item = usize> + '_ {
        self.nb[k][..self.len[k] as usize]
            .iter()
            .map(|&q| q as usize)
    }
}

/// A site accepted by the growth: its index (relative to the start dot), peak position, contrast.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Grown {
    pub index: GridIndex,
    pub pos: [f64; 2],
    /// Filtered contrast of its peak.
    pub v: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum State {
    Unvisited,
    Queued,
    Found,
    Failed,
    Outside,
}

#[derive(Clone, Copy, Debug)]
struct Cell {
    state: State,
    pos: [f64; 2],
    v: f64,
    tries: u8,
}

fn add(p: [f64; 2], q: [f64; 2], s: f64) -> [f64; 2] {
    [p[0] + s * q[0], p[1] + s * q[1]]
}

/// Prediction of the site `(i, j)` from found sites of its index neighbourhood (`nb`: index
/// offsets, position, contrast):
/// weighted (1/index distance²) affine least squares `p = c0 + c1 di + c2 dj` evaluated at
/// the site, or, with fewer than three non-collinear neighbours, the nearest neighbour plus the
/// global basis. Also returns the neighbours' median contrast.
pub(crate) fn predict_from_neighbours(
    nb: &[(i32, i32, [f64; 2], f64)],
    a: [f64; 2],
    b: [f64; 2],
    vals: &mut Vec<f64>,
) -> Option<([f64; 2], f64)> {
    if nb.is_empty() {
        return None;
    }
    // Contrast scale: median of the 3x3 neighbours (of all when fewer than three).
    vals.clear();
    vals.extend(
        nb.iter()
            .filter(|n| n.0.abs() <= 1 && n.1.abs() <= 1)
            .map(|n| n.3),
    );
    if vals.len() < 3 {
        vals.clear();
        vals.extend(nb.iter().map(|n| n.3));
    }
    let m = median(vals);
    if nb.len() >= 3 {
        // Normal equations of the weighted affine fit.
        let mut s = [0.0f64; 6]; // w, w di, w dj, w di², w di dj, w dj²
        let mut bx = [0.0f64; 3];
        let mut by = [0.0f64; 3];
        for &(di, dj, p, _) in nb {
            let (di, dj) = (di as f64, dj as f64);
            let w = 1.0 / (di * di + dj * dj);
            s[0] += w;
            s[1] += w * di;
            s[2] += w * dj;
            s[3] += w * di * di;
            s[4] += w * di * dj;
            s[5] += w * dj * dj;
            for (k, t) in [1.0, di, dj].iter().enumerate() {
                bx[k] += w * t * p[0];
                by[k] += w * t * p[1];
            }
        }
        let mtx = [[s[0], s[1], s[2]], [s[1], s[3], s[4]], [s[2], s[4], s[5]]];
        let det = det3(&mtx);
        let scale = s[0] * s[3] * s[5];
        if det > 1e-6 * scale {
            let x = cramer_first(&mtx, &bx, det);
            let y = cramer_first(&mtx, &by, det);
            return Some(([x, y], m));
        }
    }
    let n = nb.iter().min_by_key(|n| n.0 * n.0 + n.1 * n.1)?;
    let p = add(add(n.2, a, -(n.0 as f64)), b, -(n.1 as f64));
    Some((p, m))
}

fn det3(m: &[[f64; 3]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// First unknown of `m x = r` by Cramer's rule.
fn cramer_first(m: &[[f64; 3]; 3], r: &[f64; 3], det: f64) -> f64 {
    let mut c = *m;
    for k in 0..3 {
        c[k][0] = r[k];
    }
    det3(&c) / det
}

/// Finds a start dot near `start`: a strong peak with at least three of its four neighbours at
/// `±a`, `±b` (within a quarter spacing) of comparable contrast (0.3x to 3x).
pub(crate) fn find_start(
    map: &DotMap,
    a: [f64; 2],
    b: [f64; 2],
    start: [f64; 2],
    w: usize,
    h: usize,
) -> Option<Peak> {
    let s = a[0].hypot(a[1]).min(b[0].hypot(b[1]));
    let mut buf = Vec::new();
    let mut nbuf = Vec::new();
    for radius in [2.5 * s, 6.0 * s, (w.max(h)) as f64] {
        buf.clear();
        map.local_maxima(start, radius, &mut buf);
        buf.retain(|p| p.v > 0.0);
        buf.sort_by(|p, q| q.v.total_cmp(&p.v));
        for p in buf.iter().take(60) {
            let ok = [(a, 1.0), (a, -1.0), (b, 1.0), (b, -1.0)]
                .iter()
                .filter(|(d, sg)| {
                    map.strongest(add(p.pos(), *d, *sg), 0.25 * s, &mut nbuf)
                        .is_some_and(|q| q.v >= 0.3 * p.v && q.v <= 3.0 * p.v)
                })
                .count();
            if ok >= 3 {
                return Some(*p);
            }
        }
    }
    None
}

/// Grows the lattice from the start dot `seed` (see the module documentation), accepting only
/// peaks of at least `min_v`. Indices are relative to the start dot, along `a` and `b`.
pub(crate) fn grow(
    map: &DotMap,
    a: [f64; 2],
    b: [f64; 2],
    seed: Peak,
    min_v: f64,
    w: usize,
    h: usize,
) -> Vec<Grown> {
    let s = a[0].hypot(a[1]).min(b[0].hypot(b[1]));
    // Index range: the image corners in lattice coordinates, with a margin for distortion.
    let det = a[0] * b[1] - a[1] * b[0];
    let (mut imin, mut imax, mut jmin, mut jmax) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for c in [
        [0.0, 0.0],
        [w as f64, 0.0],
        [0.0, h as f64],
        [w as f64, h as f64],
    ] {
        let (dx, dy) = (c[0] - seed.x, c[1] - seed.y);
        let fi = (dx * b[1] - dy * b[0]) / det;
        let fj = (a[0] * dy - a[1] * dx) / det;
        imin = imin.min(fi);
        imax = imax.max(fi);
        jmin = jmin.min(fj);
        jmax = jmax.max(fj);
    }
    let mi = 0.15 * (imax - imin) + 3.0;
    let mj = 0.15 * (jmax - jmin) + 3.0;
    let empty = Cell {
        state: State::Unvisited,
        pos: [0.0; 2],
        v: 0.0,
        tries: 0,
    };
    let mut grid = IndexGrid::new(
        (imin - mi).floor() as i32,
        (imax + mi).ceil() as i32,
        (jmin - mj).floor() as i32,
        (jmax + mj).ceil() as i32,
        empty,
    );
    let mut queue = VecDeque::new();
    let mut found = Vec::new();
    let mut nb = Vec::with_capacity(24);
    let mut vals = Vec::with_capacity(24);
    let mut buf = Vec::new();
    let (xmax, ymax) = (w as f64 - 0.5, h as f64 - 0.5);

    let mut accept =
        |grid: &mut IndexGrid<Cell>, queue: &mut VecDeque<(i32, i32)>, i: i32, j: i32, p: Peak| {
            if let Some(c) = grid.get_mut(i, j) {
                *c = Cell {
                    state: State::Found,
                    pos: p.pos(),
                    v: p.v,
                    tries: c.tries,
                };
            }
            found.push(Grown {
                index: GridIndex::new(i, j),
                pos: p.pos(),
                v: p.v,
            });
            grid.visit_mut(i, j, 2, |di, dj, c| match c.state {
                State::Unvisited => {
                    c.state = State::Queued;
                    queue.push_back((i + di, j + dj));
                }
                State::Failed if c.tries < 3 => {
                    c.state = State::Queued;
                    queue.push_back((i + di, j + dj));
                }
                _ => {}
            });
        };
    accept(&mut grid, &mut queue, 0, 0, seed);
    while let Some((i, j)) = queue.pop_front() {
        let Some(cell) = grid.get(i, j).copied() else {
            continue;
        };
        if cell.state != State::Queued {
            continue;
        }
        nb.clear();
        grid.visit(i, j, 2, |di, dj, c| {
            if c.state == State::Found {
                nb.push((di, dj, c.pos, c.v));
            }
        });
        let Some((pred, m)) = predict_from_neighbours(&nb, a, b, &mut vals) else {
            if let Some(c) = grid.get_mut(i, j) {
                c.state = State::Failed;
                c.tries += 1;
            }
            continue;
        };
        if pred[0] < -0.5 || pred[1] < -0.5 || pred[0] > xmax || pred[1] > ymax {
            if let Some(c) = grid.get_mut(i, j) {
                c.state = State::Outside;
            }
            continue;
        }
        match map.strongest(pred, 0.3 * s, &mut buf) {
            Some(p) if p.v > 0.0 && p.v >= min_v && p.v >= 0.3 * m => {
                accept(&mut grid, &mut queue, i, j, p)
            }
            _ => {
                if let Some(c) = grid.get_mut(i, j) {
                    c.state = State::Failed;
                    c.tries += 1;
                }
            }
        }
    }
    found
}
