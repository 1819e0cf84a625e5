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
        let mut dup: Vec<[f64; 2]> = (0..300).map(|k| [(k % 7) as f64, (k % 5) as f64]).collect();
        dup.push([f64::NAN, 1.0]);
        sets.push(("duplicates", dup));
        let mut out = Vec::new();
        for (name, src) in &sets {
            let keep = |i: usize| i % 11 != 4;
            let s = PointSet::new(src, keep);
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
