//! A kd-tree over the finite points of a slice, answering in the slice's own indices, and the
//! small robust statistics the matcher and the validation share.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;

/// kd-tree (kiddo 6) over the points of `source` whose coordinates are finite. Queries return
/// indices into `source`; a set with no finite point answers nothing.
pub(crate) struct PointSet {
    tree: Option<ImmutableKdTree<f64, 2>>,
    /// Tree item (position in the compacted point list) → index into the source slice.
    back: Vec<usize>,
}

impl PointSet {
    /// Tree over `source[i]` for every `i` with `keep(i)` and a finite point.
    pub(crate) fn new(source: &[[f64; 2]], keep: impl Fn(usize) -> bool) -> Self {
        let mut pts = Vec::with_capacity(source.len());
        let mut back = Vec::with_capacity(source.len());
        for (i, p) in source.iter().enumerate() {
            if keep(i) && p[0].is_finite() && p[1].is_finite() {
                pts.push(*p);
                back.push(i);
            }
        }
        // `new_from_slice` fails only when the item count overflows u32 (4e9 points), which
        // no image holds; such a set then simply answers nothing.
        let tree = if pts.is_empty() {
            None
        } else {
            ImmutableKdTree::<f64, 2>::new_from_slice(&pts).ok()
        };
        PointSet { tree, back }
    }

    /// Nearest point to `p`: (source index, squared distance).
    #[inline]
    pub(crate) fn nearest(&self, p: &[f64; 2]) -> Option<(usize, f64)> {
        let tree = self.tree.as_ref()?;
        if !(p[0].is_finite() && p[1].is_finite()) {
            return None;
        }
        let nn = tree
            .query(p)
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        Some((self.back[nn.item as usize], nn.distance))
    }

    /// Up to `k` nearest points to `p`, nearest first, as source indices, appended to `out`
    /// (cleared first).
    pub(crate) fn nearest_n(&self, p: &[f64; 2], k: usize, out: &mut Vec<usize>) {
        out.clear();
        let (Some(tree), Some(k)) = (self.tree.as_ref(), NonZeroUsize::new(k)) else {
            return;
        };
        if !(p[0].is_finite() && p[1].is_finite()) {
            return;
        }
        let found = tree
            .query(p)
            .nearest_n::<SquaredEuclidean<f64>>(k)
            .execute();
        out.extend(found.iter().map(|r| self.back[r.item as usize]));
    }
}

/// Median of `v` (reordered in place); NaN for an empty slice. For an even count, the mean of
/// the two middle values.
pub(crate) fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    let (_, &mut hi, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        hi
    } else {
        let lo = v[..n / 2].iter().copied().fold(f64::NEG_INFINITY, f64::max);
        0.5 * (lo + hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_odd_even_empty() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(&mut []).is_nan());
    }

    #[test]
    fn point_set_skips_non_finite_and_maps_back() {
        let src = [[0.0, 0.0], [f64::NAN, 1.0], [5.0, 5.0], [1.0, 0.0]];
        let s = PointSet::new(&src, |i| i != 3);
        assert_eq!(s.nearest(&[4.0, 4.0]), Some((2, 2.0)));
        let mut out = Vec::new();
        s.nearest_n(&[0.9, 0.0], 5, &mut out);
        assert_eq!(out, vec![0, 2]);
        // many identical points (e.g. a degenerate input) and huge coordinates do not panic
        let same = vec![[3.0, 4.0]; 5000];
        let s = PointSet::new(&same, |_| true);
        assert_eq!(s.nearest(&[0.0, 0.0]).map(|(_, d)| d), Some(25.0));
        s.nearest_n(&[3.0, 4.0], 9, &mut out);
        assert_eq!(out.len(), 9);
        let huge = [[1e300, -1e300], [0.0, 0.0]];
        assert_eq!(
            PointSet::new(&huge, |_| true)
                .nearest(&[1.0, 1.0])
                .map(|(i, _)| i),
            Some(1)
        );
        let empty = PointSet::new(&[], |_| true);
        assert_eq!(empty.nearest(&[0.0, 0.0]), None);
    }
}
