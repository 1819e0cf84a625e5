//! Validation of displacement vectors: a magnitude threshold and the normalised median test for
//! scattered data (Westerweel & Scarano 2005).

use crate::error::MatchError;
use crate::points::{PointSet, median};
use bostrack_core::DotFlags;
use rayon::prelude::*;

/// The normalised median test of Westerweel & Scarano (2005, "Universal outlier detection for
/// PIV data", Exp. Fluids 39:1096-1100), for scattered vectors. For vector `d_0` and its
/// neighbours `d_1 … d_k`, per component:
///
/// `r = |d_0 - median(d_i)| / (median(|d_i - median(d_i)|) + ε)`
///
/// and the vector is an outlier when `r > threshold` in either component. The neighbours are
/// the `neighbours` nearest vector positions (spatial index; ties in distance go to the lower
/// index), the vector itself left out.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MedianTest {
    /// Number of nearest neighbours, default 8 (the 3x3 neighbourhood of the original test).
    pub neighbours: usize,
    /// Threshold on the normalised residual, default 2 (Westerweel & Scarano 2005).
    pub threshold: f64,
    /// ε (px): the displacement noise level, which keeps the test from rejecting vectors in
    /// regions where the neighbours agree better than the noise. Default 0.1 px (the
    /// original value for PIV); set it near the displacement noise of the data.
    pub epsilon: f64,
}

impl Default for MedianTest {
    fn default() -> Self {
        MedianTest {
            neighbours: 8,
            threshold: 2.0,
            epsilon: 0.1,
        }
    }
}

/// Settings of [`validate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValidationConfig {
    /// Vectors with `|d| > max_displacement` (px) are outliers; `None`: no threshold. Default
    /// `None`.
    pub max_displacement: Option<f64>,
    /// The normalised median test; `None`: not run. Default on with [`MedianTest::default`].
    pub median_test: Option<MedianTest>,
    /// Replace outliers by the median of their neighbours ([`Validation::replaced`]). Default
    /// off: outliers are only flagged.
    pub replace: bool,
}

impl Default for ValidationConfig {
    fn default() -> Self {
        ValidationConfig {
            max_displacement: None,
            median_test: Some(MedianTest::default()),
            replace: false,
        }
    }
}

/// Outcome of the validation for one vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Verdict {
    /// Passed every test that was run.
    Valid,
    /// `|d|` above the threshold.
    TooLarge,
    /// Rejected by the normalised median test.
    MedianTest,
    /// Not tested: the vector or its position is not finite, or the median test was asked
    /// for but fewer than 3 neighbours were available (and no threshold rejected it).
    NotTested,
}

/// Per-vector result of [`validate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VectorCheck {
    pub verdict: Verdict,
    /// Normalised residual `[r_x, r_y]` of the median test; `None` where it was not run.
    pub residual: Option<[f64; 2]>,
    /// Component-wise median of the neighbours' vectors; `None` where it was not computed.
    pub neighbour_median: Option<[f64; 2]>,
}

impl VectorCheck {
    /// Whether the vector was rejected (threshold or median test).
    pub fn is_outlier(&self) -> bool {
        matches!(self.verdict, Verdict::TooLarge | Verdict::MedianTest)
    }
    /// [`DotFlags::OUTLIER`] for a rejected vector, none otherwise.
    pub fn flags(&self) -> DotFlags {
        if self.is_outlier() {
            DotFlags::OUTLIER
        } else {
            DotFlags::NONE
        }
    }
}

/// Result of [`validate`], in the order of the input.
#[derive(Clone, Debug, PartialEq)]
pub struct Validation {
    pub checks: Vec<VectorCheck>,
    /// With [`ValidationConfig::replace`]: the vectors with every outlier replaced by the
    /// component-wise median of its neighbours (outliers with fewer than 3 valid neighbours
    /// are kept as they were; they stay flagged).
    pub replaced: Option<Vec<[f64; 2]>>,
}

impl Validation {
    /// Number of rejected vectors.
    pub fn outliers(&self) -> usize {
        self.checks.iter().filter(|c| c.is_outlier()).count()
    }
}

/// Extra neighbours a [`NeighbourLists`] keeps per position beyond those the median test
/// uses, for the vectors that the test leaves out (not finite, above the threshold).
const SPARE: usize = 4;

/// Every position's nearest other positions, found once for validating many sets of vectors
/// at the same positions (the reference positions of a campaign's frames) with
/// [`validate_at`]: each frame's median test then takes its neighbours from the lists
/// instead of a spatial index, with the same result (where a list cannot decide, its dot is
/// searched as without them).
#[derive(Clone, Debug)]
pub struct NeighbourLists {
    positions: Vec<[f64; 2]>,
    /// Per position, the ids of its nearest others by (distance, id), and the distance
    /// (squared) below which every other position is in the list (infinite: all are).
    start: Vec<usize>,
    ids: Vec<(f64, u32)>,
    complete_below: Vec<f64>,
}

impl NeighbourLists {
    /// The lists of `positions` for the median test with `neighbours` neighbours (see
    /// [`MedianTest::neighbours`]); positions that are not finite have none.
    pub fn new(positions: &[[f64; 2]], neighbours: usize) -> NeighbourLists {
        let keep = neighbours.saturating_add(SPARE);
        let set = PointSet::new(positions, |_| true);
        // in blocks of positions, each block's lists in one buffer (a buffer per position
        // would leave as many small holes in the heap)
        const BLOCK: usize = 512;
        // per block: its lists one after the other, their lengths, their `complete_below`
        type Block = (Vec<(f64, u32)>, Vec<usize>, Vec<f64>);
        let blocks: Vec<Block> = (0..positions.len())
            .step_by(BLOCK)
            .collect::<Vec<usize>>()
            .into_par_iter()
            .map(|lo| {
                let hi = (lo + BLOCK).min(positions.len());
                let mut ids = Vec::with_capacity((hi - lo) * keep);
                let mut lens = Vec::with_capacity(hi - lo);
                let mut below = Vec::with_capacity(hi - lo);
                let mut nb = Vec::with_capacity(keep + 4);
                for (i, p) in positions.iter().enumerate().take(hi).skip(lo) {
                    set.nearest_n(p, keep, Some(i), &mut nb);
                    nb.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                    // fewer than asked: every finite other position is in the list
                    below.push(if nb.len() < keep {
                        f64::INFINITY
                    } else {
                        nb.last().map_or(f64::INFINITY, |l| l.0)
                    });
                    lens.push(nb.len());
                    ids.extend_from_slice(&nb);
                }
                (ids, lens, below)
            })
            .collect();
        let mut start = Vec::with_capacity(positions.len() + 1);
        let mut ids = Vec::with_capacity(blocks.iter().map(|b| b.0.len()).sum());
        let mut complete_below = Vec::with_capacity(positions.len());
        start.push(0);
        for (b_ids, lens, below) in blocks {
            for len in lens {
                start.push(start[start.len() - 1] + len);
            }
            ids.extend(b_ids);
            complete_below.extend(below);
        }
        NeighbourLists {
            positions: positions.to_vec(),
            start,
            ids,
            complete_below,
        }
    }

    /// Into `out`, the `k` nearest positions to list position `i` among those of a
    /// validation's (`slot`: the validation's index of each list position, `u32::MAX` where it
    /// has none) that are `eligible` (by the validation's index), itself left out, by distance
    /// and index, if its list decides them: every position closer than the last one taken is in
    /// the list. (A list is the first of all positions by (distance, index), so the first `k`
    /// eligible in it are always those where the validation's indices keep the lists' order;
    /// the check is kept as a guard.)
    fn nearest(
        &self,
        i: usize,
        k: usize,
        slot: &[u32],
        eligible: &[bool],
        out: &mut Vec<(f64, u32)>,
    ) -> bool {
        out.clear();
        let list = &self.ids[self.start[i]..self.start[i + 1]];
        for &(d, q) in list {
            let q = slot[q as usize];
            if q != u32::MAX && eligible[q as usize] {
                out.push((d, q));
                if out.len() == k {
                    return d < self.complete_below[i];
                }
            }
        }
        // fewer than k: decided only where the list holds every other position
        self.complete_below[i] == f64::INFINITY
    }
}

/// A validation's vectors at positions of [`NeighbourLists`]: each vector's list position,
/// and the vector at each list position.
struct AtLists<'a> {
    lists: &'a NeighbourLists,
    at: &'a [usize],
    slot: Vec<u32>,
}

/// Validate displacement vectors `displacements[i]` located at `positions[i]` (px; use the
/// reference positions). First the threshold, then the median test, whose neighbourhoods
/// leave out vectors that are not finite or failed the threshold.
///
/// Errors for slices of different lengths or a bad configuration.
pub fn validate(
    positions: &[[f64; 2]],
    displacements: &[[f64; 2]],
    cfg: &ValidationConfig,
) -> Result<Validation, MatchError> {
    validate_inner(None, positions, displacements, cfg)
}

/// [`validate`] for vectors at positions of `lists`: `displacements[k]` at list position
/// `at[k]` (each vector's reference dot, e.g. a frame's matched pairs in reference order). The
/// median test takes its neighbours from the lists (where `at` increases, as the lists' ties
/// go to the lower index), with the same result as [`validate`] at those positions. Errors
/// also for an `at` beyond the lists.
pub fn validate_at(
    lists: &NeighbourLists,
    at: &[usize],
    displacements: &[[f64; 2]],
    cfg: &ValidationConfig,
) -> Result<Validation, MatchError> {
    let n = lists.positions.len();
    if let Some(&bad) = at.iter().find(|&&i| i >= n) {
        return Err(MatchError::Config(format!(
            "a vector at list position {bad} of {n}"
        )));
    }
    let positions: Vec<[f64; 2]> = at.iter().map(|&i| lists.positions[i]).collect();
    let increasing = at.windows(2).all(|w| w[0] < w[1]) && at.len() < u32::MAX as usize;
    let mapped = increasing.then(|| {
        let mut slot = vec![u32::MAX; n];
        for (k, &i) in at.iter().enumerate() {
            slot[i] = k as u32;
        }
        AtLists { lists, at, slot }
    });
    validate_inner(mapped, &positions, displacements, cfg)
}

fn validate_inner(
    lists: Option<AtLists>,
    positions: &[[f64; 2]],
    displacements: &[[f64; 2]],
    cfg: &ValidationConfig,
) -> Result<Validation, MatchError> {
    if positions.len() != displacements.len() {
        return Err(MatchError::Length {
            positions: positions.len(),
            vectors: displacements.len(),
        });
    }
    if let Some(t) = cfg.max_displacement
        && (t.is_nan() || t < 0.0)
    {
        return Err(MatchError::Config(format!(
            "max_displacement must be >= 0 px, got {t}"
        )));
    }
    if let Some(m) = cfg.median_test {
        if m.neighbours < 3 {
            return Err(MatchError::Config(format!(
                "the median test needs at least 3 neighbours, got {}",
                m.neighbours
            )));
        }
        if !(m.threshold > 0.0 && m.threshold.is_finite()) {
            return Err(MatchError::Config(format!(
                "median-test threshold must be positive, got {}",
                m.threshold
            )));
        }
        if !(m.epsilon >= 0.0 && m.epsilon.is_finite()) {
            return Err(MatchError::Config(format!(
                "median-test epsilon must be >= 0 px, got {}",
                m.epsilon
            )));
        }
    }

    let n = positions.len();
    let finite = |i: usize| {
        positions[i].iter().all(|v| v.is_finite()) && displacements[i].iter().all(|v| v.is_finite())
    };
    let mut checks = vec![
        VectorCheck {
            verdict: Verdict::NotTested,
            residual: None,
            neighbour_median: None,
        };
        n
    ];
    for (i, c) in checks.iter_mut().enumerate() {
        if !finite(i) {
            continue;
        }
        c.verdict = match cfg.max_displacement {
            Some(t) if displacements[i][0].hypot(displacements[i][1]) > t => Verdict::TooLarge,
            Some(_) => Verdict::Valid,
            None if cfg.median_test.is_none() => Verdict::Valid,
            None => Verdict::NotTested,
        };
    }

    if cfg.median_test.is_some() || cfg.replace {
        let k = cfg
            .median_test
            .map_or(MedianTest::default().neighbours, |m| m.neighbours);
        let eligible: Vec<bool> = (0..n)
            .map(|i| finite(i) && checks[i].verdict != Verdict::TooLarge)
            .collect();
        // (the spatial index of the eligible positions: without lists, or for a dot its list
        // cannot decide)
        let tree = std::sync::OnceLock::new();
        let set = || tree.get_or_init(|| PointSet::new(positions, |i| eligible[i]));
        // every dot's test is independent: rayon over dots, scratch buffers per worker
        checks.par_iter_mut().enumerate().for_each_init(
            || {
                (
                    Vec::with_capacity(k),
                    [Vec::with_capacity(k), Vec::with_capacity(k)],
                    [Vec::with_capacity(k), Vec::with_capacity(k)],
                )
            },
            |(nb, [bx, by], [ax, ay]), (i, c)| {
                if !finite(i) {
                    return;
                }
                if !lists
                    .as_ref()
                    .is_some_and(|l| l.lists.nearest(l.at[i], k, &l.slot, &eligible, nb))
                {
                    set().nearest_n(&positions[i], k, Some(i), nb);
                }
                if nb.len() < 3 {
                    return; // keeps the threshold's verdict (Valid, TooLarge or NotTested)
                }
                bx.clear();
                by.clear();
                for &(_, q) in nb.iter() {
                    bx.push(displacements[q as usize][0]);
                    by.push(displacements[q as usize][1]);
                }
                let mx = median(bx);
                let my = median(by);
                c.neighbour_median = Some([mx, my]);
                let Some(m) = cfg.median_test else { return };
                if c.verdict == Verdict::TooLarge {
                    return;
                }
                // (the median reordered bx and by; the deviations' median does not mind)
                ax.clear();
                ay.clear();
                ax.extend(bx.iter().map(|v| (v - mx).abs()));
                ay.extend(by.iter().map(|v| (v - my).abs()));
                let rx = (displacements[i][0] - mx).abs() / (median(ax) + m.epsilon);
                let ry = (displacements[i][1] - my).abs() / (median(ay) + m.epsilon);
                c.residual = Some([rx, ry]);
                // with epsilon = 0 and identical neighbours, r = 0/0 = NaN for an identical
                // vector (kept) and inf for a differing one (rejected)
                c.verdict = if rx > m.threshold || ry > m.threshold {
                    Verdict::MedianTest
                } else {
                    Verdict::Valid
                };
            },
        );
    }

    let replaced = cfg.replace.then(|| {
        displacements
            .iter()
            .zip(&checks)
            .map(|(d, c)| match c.neighbour_median {
                Some(m) if c.is_outlier() => m,
                _ => *d,
            })
            .collect()
    });
    Ok(Validation { checks, replaced })
}
