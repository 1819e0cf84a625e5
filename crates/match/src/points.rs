//! A spatial index over the finite points of a slice, answering in the slice's own indices,
//! and the small robust statistics the matcher and the validation share.
//!
//! The index is kiddo's immutable kd-tree; ties in distance go to the lower source index, so
//! results never depend on the order of a search.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;

/// Spatial index over the points of `source` that are kept and finite. Queries return indices
/// into `source`; a set with no such point answers nothing.
pub(crate) struct PointSet {
    kind: Kind,
}

enum Kind {
    Empty,
    Tree {
        tree: ImmutableKdTree<f64, 2>,
        /// Tree item (position in the compacted point list) → source index.
        back: Vec<u32>,
    },
}

impl PointSet {
    /// Index over `source[i]` for every `i` with `keep(i)` and a finite point.
    pub(crate) fn new(source: &[[f64; 2]], keep: impl Fn(usize) -> bool) -> Self {
        if source.len() > u32::MAX as usize {
            // ids are u32: no image holds 4e9 dots; such a set simply answers nothing
            return PointSet { kind: Kind::Empty };
        }
        let mut pts = Vec::with_capacity(source.len());
        let mut ids = Vec::with_capacity(source.len());
        for (i, p) in source.iter().enumerate() {
            if keep(i) && p[0].is_finite() && p[1].is_finite() {
                pts.push(*p);
                ids.push(i as u32);
            }
        }
        if pts.is_empty() {
            return PointSet { kind: Kind::Empty };
        }
        // built serially (what kiddo does below 262,144 points anyway): the validation builds
        // its index lazily inside a parallel loop, where a parallel build could steal, while it
        // waits, a dot of that loop that waits for the same index (a deadlock); fails only when
        // the item count overflows u32, excluded above
        match ImmutableKdTree::<f64, 2>::builder()
            .with_serial_construction()
            .build_from_slice(&pts)
        {
            Ok(tree) => PointSet {
                kind: Kind::Tree { tree, back: ids },
            },
            Err(_) => PointSet { kind: Kind::Empty },
        }
    }

    /// Nearest point to `p`: (source index, squared distance); the lowest source index among
    /// equally near points.
    #[inline]
    pub(crate) fn nearest(&self, p: &[f64; 2]) -> Option<(usize, f64)> {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return None;
        }
        match &self.kind {
            Kind::Empty => None,
            Kind::Tree { tree, back } => {
                let two = NonZeroUsize::new(2).expect("2 > 0");
                let nn = tree
                    .query(p)
                    .nearest_n::<SquaredEuclidean<f64>>(two)
                    .execute();
                let first = nn.first()?;
                let d2 = first.distance;
                let mut best = back[first.item as usize];
                // a tie with the second nearest: every point at that distance, lowest index
                if d2.is_finite() && nn.get(1).is_some_and(|r| r.distance <= d2) {
                    tree.query(p)
                        .within::<SquaredEuclidean<f64>>(d2)
                        .unsorted()
                        .visit(|r| {
                            if r.distance <= d2 {
                                best = best.min(back[r.item as usize]);
                            }
                        });
                }
                Some((best as usize, d2))
            }
        }
    }

    /// The `k` nearest points to `p` other than source index `exclude` (all of them when there
    /// are fewer; ties in distance go to the lower source index), written to `out` as
    /// `(squared distance, source index)` in no particular order (`out` is cleared first).
    pub(crate) fn nearest_n(
        &self,
        p: &[f64; 2],
        k: usize,
        exclude: Option<usize>,
        out: &mut Vec<(f64, u32)>,
    ) {
        out.clear();
        if k == 0 || !(p[0].is_finite() && p[1].is_finite()) {
            return;
        }
        let ex = exclude.map_or(u32::MAX, |e| u32::try_from(e).unwrap_or(u32::MAX));
        match &self.kind {
            Kind::Empty => {}
            Kind::Tree { tree, back } => {
                // the k + 2 nearest (sorted by distance) hold the k nearest others; only when
                // the k-th and the next other point tie is every point within that distance
                // collected and sorted by (distance, index), so ties go to the lower index
                let Some(want) = NonZeroUsize::new(k.saturating_add(2)) else {
                    return;
                };
                let found = tree
                    .query(p)
                    .nearest_n::<SquaredEuclidean<f64>>(want)
                    .execute();
                let others: Vec<(f64, u32)> = found
                    .iter()
                    .map(|r| (r.distance, back[r.item as usize]))
                    .filter(|r| r.1 != ex)
                    .collect();
                let tie = others.len() > k && others[k].0 <= others[k - 1].0;
                if !tie {
                    out.extend(others.iter().take(k));
                    return;
                }
                let limit = others[k - 1].0;
                tree.query(p)
                    .within::<SquaredEuclidean<f64>>(limit)
                    .unsorted()
                    .visit(|r| {
                        let id = back[r.item as usize];
                        if id != ex && r.distance <= limit {
                            out.push((r.distance, id));
                        }
                    });
                if out.len() > k {
                    select_smallest(out, k);
                    out.truncate(k);
                }
            }
        }
    }
}

/// The nearest point within a fixed radius: the points of `source` that are kept and finite,
/// in square cells a little wider than the radius, so that a query reads the 3 × 3 cells around
/// its own (a few points on a dot lattice) instead of walking a tree and collecting its answer
/// in a fresh list (~2,800 instructions per query of [`PointSet::nearest`] on a real frame's
/// 12,236 dots). Same answers as [`PointSet::nearest`] kept where its distance is within the
/// radius: squared distances computed as kiddo does (`dx² + dy²`), ties to the lowest source
/// index. Points spread over far more cells than there are points (a stray far point) fall
/// back to the tree.
pub(crate) struct RadiusSet {
    radius: f64,
    r2: f64,
    kind: RadiusKind,
}

enum RadiusKind {
    Cells {
        /// Cell width (px), the origin's coordinates and the grid's size in cells.
        cell: f64,
        origin: [f64; 2],
        nx: usize,
        ny: usize,
        /// Points of cell `c`: `points[start[c]..start[c + 1]]`, (x, y, source index), in
        /// source order.
        start: Vec<u32>,
        points: Vec<(f64, f64, u32)>,
    },
    Tree(PointSet),
}

impl RadiusSet {
    /// The set of `source[i]` with `keep(i)` and a finite point, for queries within `radius`.
    pub(crate) fn new(source: &[[f64; 2]], keep: impl Fn(usize) -> bool, radius: f64) -> Self {
        let r2 = radius * radius;
        let kept: Vec<u32> = (0..source.len().min(u32::MAX as usize))
            .filter(|&i| keep(i) && source[i][0].is_finite() && source[i][1].is_finite())
            .map(|i| i as u32)
            .collect();
        let tree = |keep: &dyn Fn(usize) -> bool| RadiusSet {
            radius,
            r2,
            kind: RadiusKind::Tree(PointSet::new(source, keep)),
        };
        if !(radius.is_finite() && radius > 0.0) || kept.is_empty() {
            return tree(&keep);
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for &i in &kept {
            for a in 0..2 {
                lo[a] = lo[a].min(source[i as usize][a]);
                hi[a] = hi[a].max(source[i as usize][a]);
            }
        }
        // (a cell wider than the radius by far more than the rounding of a cell's coordinate,
        // a few ulp of the largest coordinate: a point within the radius of a query lies in
        // one of the 3 × 3 cells around the query's)
        let largest = lo.iter().chain(&hi).fold(0.0f64, |m, v| m.max(v.abs()));
        let cell = radius * (1.0 + 1e-6) + 1e-12 * largest;
        let span = |a: usize| ((hi[a] - lo[a]) / cell).floor() + 1.0;
        let (sx, sy) = (span(0), span(1));
        // (finite points: the spans are numbers, +∞ for a span beyond f64)
        if sx * sy > 16.0 * kept.len() as f64 + 65_536.0 {
            return tree(&keep);
        }
        let (nx, ny) = (sx as usize, sy as usize);
        let at = |p: &[f64; 2]| {
            let cx = (((p[0] - lo[0]) / cell).floor() as usize).min(nx - 1);
            let cy = (((p[1] - lo[1]) / cell).floor() as usize).min(ny - 1);
            cy * nx + cx
        };
        let cells: Vec<usize> = kept.iter().map(|&i| at(&source[i as usize])).collect();
        let mut start = vec![0u32; nx * ny + 1];
        for &c in &cells {
            start[c + 1] += 1;
        }
        for c in 0..nx * ny {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut points = vec![(0.0, 0.0, 0u32); kept.len()];
        for (&i, &c) in kept.iter().zip(&cells) {
            let p = source[i as usize];
            points[fill[c] as usize] = (p[0], p[1], i);
            fill[c] += 1;
        }
        RadiusSet {
            radius,
            r2,
            kind: RadiusKind::Cells {
                cell,
                origin: lo,
                nx,
                ny,
                start,
                points,
            },
        }
    }

    /// The radius the set answers within.
    pub(crate) fn radius(&self) -> f64 {
        self.radius
    }

    /// The nearest point to `p` within the radius: (source index, squared distance); the
    /// lowest source index among equally near points; `None` where none is that near.
    #[inline]
    pub(crate) fn nearest(&self, p: &[f64; 2]) -> Option<(usize, f64)> {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return None;
        }
        match &self.kind {
            RadiusKind::Tree(set) => set.nearest(p).filter(|&(_, d2)| d2 <= self.r2),
            RadiusKind::Cells {
                cell,
                origin,
                nx,
                ny,
                start,
                points,
            } => {
                // the query's cell (possibly outside the grid) and the cells around it
                let range = |v: f64, o: f64, n: usize| {
                    let c = ((v - o) / cell).floor();
                    let a = (c - 1.0).max(0.0);
                    let b = (c + 1.0).min(n as f64 - 1.0);
                    (a <= b).then_some((a as usize, b as usize))
                };
                let (x0, x1) = range(p[0], origin[0], *nx)?;
                let (y0, y1) = range(p[1], origin[1], *ny)?;
                let mut best: Option<(u32, f64)> = None;
                for cy in y0..=y1 {
                    let row = cy * nx;
                    let (a, b) = (start[row + x0] as usize, start[row + x1 + 1] as usize);
                    for &(x, y, i) in &points[a..b] {
                        let (dx, dy) = (x - p[0], y - p[1]);
                        let d2 = dx * dx + dy * dy;
                        if d2 <= self.r2
                            && best.is_none_or(|(bi, bd)| d2 < bd || (d2 == bd && i < bi))
                        {
                            best = Some((i, d2));
                        }
                    }
                }
                best.map(|(i, d2)| (i as usize, d2))
            }
        }
    }
}

/// Reorder `v` so that its first `k` entries are the `k` smallest in (squared distance, index)
/// order (the keys are distinct: indices are). Quickselect, insertion sort for short spans.
fn select_smallest(v: &mut [(f64, u32)], k: usize) {
    #[inline(always)]
    fn lt(a: (f64, u32), b: (f64, u32)) -> bool {
        a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
    }
    let (mut lo, mut hi) = (0, v.len());
    while hi - lo > 12 {
        // median of three as pivot, moved to the end
        let mid = lo + (hi - lo) / 2;
        let (a, b, c) = (v[lo], v[mid], v[hi - 1]);
        let m = if lt(a, b) == lt(b, c) {
            mid
        } else if lt(a, b) == lt(a, c) {
            hi - 1
        } else {
            lo
        };
        v.swap(m, hi - 1);
        let pivot = v[hi - 1];
        let mut store = lo;
        for t in lo..hi - 1 {
            if lt(v[t], pivot) {
                v.swap(t, store);
                store += 1;
            }
        }
        v.swap(store, hi - 1);
        // v[lo..store] < pivot = v[store] < v[store + 1..hi]
        match store.cmp(&k) {
            std::cmp::Ordering::Equal => return,
            std::cmp::Ordering::Greater => hi = store,
            std::cmp::Ordering::Less => lo = store + 1,
        }
    }
    for a in lo + 1..hi {
        let x = v[a];
        let mut b = a;
        while b > lo && lt(x, v[b - 1]) {
            v[b] = v[b - 1];
            b -= 1;
        }
        v[b] = x;
    }
}

/// Order of neighbours: squared distance, then source index.
#[cfg(test)]
fn by_distance_then_index(a: &(f64, u32), b: &(f64, u32)) -> std::cmp::Ordering {
    a.0.total_cmp(&b.0).then(a.1.cmp(&b.1))
}

/// The workspace's median (finite values only; NaN when none): [`bostrack_core::median`].
pub(crate) use bostrack_core::median;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn point_set_skips_non_finite_and_maps_back() {
        let src = [[0.0, 0.0], [f64::NAN, 1.0], [5.0, 5.0], [1.0, 0.0]];
        let s = PointSet::new(&src, |i| i != 3);
        assert_eq!(s.nearest(&[4.0, 4.0]), Some((2, 2.0)));
        let mut out = Vec::new();
        s.nearest_n(&[0.9, 0.0], 5, None, &mut out);
        out.sort_by(by_distance_then_index);
        assert_eq!(out, vec![(0.81, 0), (4.1 * 4.1 + 25.0, 2)]);
        s.nearest_n(&[0.9, 0.0], 5, Some(0), &mut out);
        assert_eq!(out.len(), 1);
        // many identical points (e.g. a degenerate input) and huge coordinates do not panic
        let same = vec![[3.0, 4.0]; 5000];
        let s = PointSet::new(&same, |_| true);
        assert_eq!(s.nearest(&[0.0, 0.0]), Some((0, 25.0)));
        s.nearest_n(&[3.0, 4.0], 9, Some(0), &mut out);
        out.sort_by(by_distance_then_index);
        assert_eq!(
            out.iter().map(|o| o.1).collect::<Vec<_>>(),
            (1..10).collect::<Vec<_>>()
        );
        let huge = [[1e300, -1e300], [0.0, 0.0]];
        assert_eq!(
            PointSet::new(&huge, |_| true)
                .nearest(&[1.0, 1.0])
                .map(|(i, _)| i),
            Some(1)
        );
        let extreme = [[f64::MAX, -f64::MAX], [-f64::MAX, f64::MAX], [0.0, 0.0]];
        assert_eq!(
            PointSet::new(&extreme, |_| true)
                .nearest(&[1.0, 1.0])
                .map(|(i, _)| i),
            Some(2)
        );
        let empty = PointSet::new(&[], |_| true);
        assert_eq!(empty.nearest(&[0.0, 0.0]), None);
        assert_eq!(
            PointSet::new(&src, |_| true).nearest(&[f64::NAN, 0.0]),
            None
        );
    }

    /// Brute force: (d2, index) order over the kept finite points.
    fn brute(src: &[[f64; 2]], p: &[f64; 2], k: usize, ex: Option<usize>) -> Vec<(f64, u32)> {
        let mut all: Vec<(f64, u32)> = src
            .iter()
            .enumerate()
            .filter(|(i, q)| Some(*i) != ex && q[0].is_finite() && q[1].is_finite())
            .map(|(i, q)| {
                let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
                (dx * dx + dy * dy, i as u32)
            })
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        all.truncate(k);
        all
    }

    /// The index against brute force: jittered lattice (with exact ties), uniform random, one
    /// far stray point, two tight clusters far apart, points on a line, and many duplicates.
    /// Queries inside, on and far outside the points.
    #[test]
    fn index_agrees_with_brute_force() {
        // (also the nearest point within a radius, `RadiusSet`)
        let mut rng = StdRng::seed_from_u64(3);
        let lattice = |j: f64, rng: &mut StdRng| -> Vec<[f64; 2]> {
            (0..900)
                .map(|k| {
                    let jx = if j > 0.0 {
                        rng.random_range(-j..j)
                    } else {
                        0.0
                    };
                    let jy = if j > 0.0 {
                        rng.random_range(-j..j)
                    } else {
                        0.0
                    };
                    [8.0 * (k % 30) as f64 + jx, 8.0 * (k / 30) as f64 + jy]
                })
                .collect()
        };
        type Set = (&'static str, Vec<[f64; 2]>);
        let mut sets: Vec<Set> = vec![
            ("exact lattice", lattice(0.0, &mut rng)),
            ("jittered lattice", lattice(1.0, &mut rng)),
            (
                "uniform",
                (0..700)
                    .map(|_| [rng.random_range(0.0..300.0), rng.random_range(0.0..200.0)])
                    .collect(),
            ),
        ];
        let mut stray = lattice(0.5, &mut rng);
        stray.push([1e7, -3e6]);
        sets.push(("stray point", stray));
        let clusters: Vec<[f64; 2]> = (0..600)
            .map(|k| {
                let c = if k % 2 == 0 { 0.0 } else { 1e5 };
                [
                    c + rng.random_range(0.0..1.0),
                    c + rng.random_range(0.0..1.0),
                ]
            })
            .collect();
        sets.push(("two clusters", clusters));
        let line: Vec<[f64; 2]> = (0..400).map(|k| [3.0 * k as f64, 7.0]).collect();
        sets.push(("line", line));
        // (far from the origin: the cells' rounding)
        let far: Vec<[f64; 2]> = (0..400)
            .map(|k| {
                [
                    3e8 + 0.75 * (k % 20) as f64 + rng.random_range(0.0..0.5),
                    -7e8 + 0.75 * (k / 20) as f64,
                ]
            })
            .collect();
        sets.push(("far away", far));
        let mut dup: Vec<[f64; 2]> = (0..300).map(|k| [(k % 7) as f64, (k % 5) as f64]).collect();
        dup.push([f64::NAN, 1.0]);
        sets.push(("duplicates", dup));
        let mut out = Vec::new();
        for (name, src) in &sets {
            let keep = |i: usize| i % 11 != 4;
            let s = PointSet::new(src, keep);
            // (radii below, at and above the lattice's half spacing; the stray point and the
            // clusters' spread fall back to the tree)
            let within: Vec<(f64, RadiusSet)> = [0.5, 3.2, 4.0, 8.0, 25.0]
                .iter()
                .map(|&r| (r, RadiusSet::new(src, keep, r)))
                .collect();
            let cells = |w: &RadiusSet| matches!(w.kind, RadiusKind::Cells { .. });
            if !matches!(*name, "stray point" | "two clusters") {
                // (0.5 px cells over the lattice: more cells than the limit, the tree)
                assert!(within[1..].iter().all(|(_, w)| cells(w)), "{name}");
            } else {
                assert!(!cells(&within[1].1), "{name}");
            }
            let kept: Vec<[f64; 2]> = src
                .iter()
                .enumerate()
                .map(|(i, p)| if keep(i) { *p } else { [f64::NAN; 2] })
                .collect();
            let mut queries: Vec<[f64; 2]> = src.iter().step_by(7).copied().collect();
            for _ in 0..100 {
                let q = src[rng.random_range(0..src.len())];
                queries.push([q[0] + rng.random_range(-9.0..9.0), q[1] - 3.5]);
            }
            queries.extend([[-1e4, -1e4], [1e9, 5.0], [4.0, 4.0]]);
            for (qi, q) in queries.iter().enumerate() {
                if !(q[0].is_finite() && q[1].is_finite()) {
                    continue;
                }
                let b = brute(&kept, q, 1, None);
                assert_eq!(
                    s.nearest(q),
                    b.first().map(|&(d, i)| (i as usize, d)),
                    "{name} {q:?}"
                );
                for (r, w) in &within {
                    assert_eq!(
                        w.nearest(q),
                        b.first()
                            .filter(|&&(d, _)| d <= r * r)
                            .map(|&(d, i)| (i as usize, d)),
                        "{name} {q:?} within {r}"
                    );
                }
                for k in [1, 4, 9, 30] {
                    let ex = (qi % 3 == 0).then_some(qi * 7 % src.len());
                    s.nearest_n(q, k, ex, &mut out);
                    out.sort_by(by_distance_then_index);
                    assert_eq!(out, brute(&kept, q, k, ex), "{name} {q:?} k {k}");
                }
            }
        }
    }
}
