//! Lookup by grid index.

use crate::GridIndex;
use std::collections::HashMap;

/// The record number of each grid index (the first record wins for a duplicated index): a
/// dense table over the box of the indices when that box is compact (a detected lattice patch:
/// at most ~4 slots per record), a hash map otherwise. Used by matching (reference records by
/// index) and the fits (the seeds around a lattice site).
///
/// ```
/// use bostrack_core::{GridIndex, GridTable};
/// let idx = [GridIndex::new(0, 0), GridIndex::new(1, 0), GridIndex::new(0, 1)];
/// let t = GridTable::new(idx.iter().copied());
/// assert_eq!(t.get(GridIndex::new(0, 1)), Some(2));
/// assert_eq!(t.get(GridIndex::new(1, 1)), None);
/// ```
#[derive(Clone, Debug)]
pub struct GridTable(Repr);

#[derive(Clone, Debug)]
enum Repr {
    Dense {
        i0: i64,
        j0: i64,
        ni: i64,
        nj: i64,
        slot: Vec<u32>,
    },
    Map(HashMap<GridIndex, usize>),
}

impl GridTable {
    /// The table of `indices` (record `k`: the `k`-th index).
    pub fn new(indices: impl Iterator<Item = GridIndex> + Clone) -> Self {
        let n = indices.clone().count();
        let (mut i0, mut i1, mut j0, mut j1) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
        for g in indices.clone() {
            i0 = i0.min(g.i as i64);
            i1 = i1.max(g.i as i64);
            j0 = j0.min(g.j as i64);
            j1 = j1.max(g.j as i64);
        }
        let (ni, nj) = (i1 - i0 + 1, j1 - j0 + 1);
        // i32 ranges: ni, nj <= 2^32, the product fits an i64 only after the size check
        if n > 0 && n < u32::MAX as usize && ni <= (4 * n as i64 + 64) / nj.max(1) {
            let mut slot = vec![u32::MAX; (ni * nj) as usize];
            for (k, g) in indices.enumerate() {
                let s = &mut slot[((g.j as i64 - j0) * ni + (g.i as i64 - i0)) as usize];
                if *s == u32::MAX {
                    *s = k as u32;
                }
            }
            return GridTable(Repr::Dense {
                i0,
                j0,
                ni,
                nj,
                slot,
            });
        }
        let mut map = HashMap::with_capacity(n);
        for (k, g) in indices.enumerate() {
            map.entry(g).or_insert(k);
        }
        GridTable(Repr::Map(map))
    }

    /// The slots of the 8 indices around `g` when they all lie inside a dense table (the
    /// common case, answered without checks per neighbour); `u32::MAX`: no record.
    #[inline]
    pub fn ring1(&self, g: GridIndex) -> Option<[u32; 8]> {
        let Repr::Dense {
            i0,
            j0,
            ni,
            nj,
            slot,
        } = &self.0
        else {
            return None;
        };
        let (x, y) = (g.i as i64 - i0, g.j as i64 - j0);
        if x < 1 || y < 1 || x + 1 >= *ni || y + 1 >= *nj {
            return None;
        }
        let c = (y * ni + x) as usize;
        let w = *ni as usize;
        let (up, down) = (&slot[c - w - 1..c - w + 2], &slot[c + w - 1..c + w + 2]);
        Some([
            up[0],
            up[1],
            up[2],
            slot[c - 1],
            slot[c + 1],
            down[0],
            down[1],
            down[2],
        ])
    }

    /// Call `f` with the record of every index at Chebyshev distance `w` from `g` (those
    /// present).
    #[inline]
    pub fn ring(&self, g: GridIndex, w: i64, mut f: impl FnMut(usize)) {
        let (a, b) = (g.i as i64, g.j as i64);
        let mut at = |da: i64, db: i64| {
            if let (Ok(x), Ok(y)) = (i32::try_from(a + da), i32::try_from(b + db))
                && let Some(s) = self.get(GridIndex::new(x, y))
            {
                f(s);
            }
        };
        for da in -w..=w {
            at(da, -w);
            at(da, w);
        }
        for db in 1 - w..w {
            at(-w, db);
            at(w, db);
        }
    }

    /// The record at `g`, if any.
    #[inline]
    pub fn get(&self, g: GridIndex) -> Option<usize> {
        match &self.0 {
            Repr::Dense {
                i0,
                j0,
                ni,
                nj,
                slot,
            } => {
                let (a, b) = (g.i as i64 - i0, g.j as i64 - j0);
                if a < 0 || b < 0 || a >= *ni || b >= *nj {
                    return None;
                }
                let s = slot[(b * ni + a) as usize];
                (s != u32::MAX).then_some(s as usize)
            }
            Repr::Map(m) => m.get(&g).copied(),
        }
    }
}
