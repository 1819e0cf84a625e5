//! Matching fitted dots ([`DotFit`] records): by grid index first, nearest neighbours as
//! fall-back and as a check of the index pairs around the locally predicted displacement.

use crate::error::MatchError;
use crate::nearest::{NearestConfig, iterate, mutual_pass_sets};
use crate::points::{RadiusSet, median};
use bostrack_core::{DotFit, DotFlags, GridTable};
use rayon::prelude::*;

/// Fewest dots per rayon task of the per-dot loops (each dot's work is a few hundred
/// instructions: smaller tasks cost more to schedule than they save).
const PAR_MIN: usize = 512;

/// How [`match_dots`] pairs the records.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum MatchMode {
    /// The primary path when detection kept the reference grid indices in the gradient image
    /// (docs/CONVENTIONS.md): records with the same [`GridIndex`] are a pair, whatever their
    /// fit status (the first record wins for a duplicated index). Usable records (fit status
    /// ok, finite position) left without a partner are matched among themselves by mutual
    /// nearest neighbours around the displacement predicted from the trusted index pairs
    /// nearby.
    ///
    /// **Index-pair check.** Every index pair of usable records `(r_i, g_j)` is checked against
    /// the geometry, relative to a predictor (the issue's "local median displacement of
    /// matched neighbours"):
    ///
    /// 1. `d̂_i` = component-wise median of `g − r` over the usable index pairs among the
    ///    lattice neighbours of `i` (reference dots with grid index `(a ± 1, b ± 1)`, the pair
    ///    itself left out; widened to `± 2` and `± 3` until at least
    ///    `⌈predictor_neighbours / 2⌉` pairs are found; [`NearestConfig::initial_displacement`]
    ///    or zero where there is none). The neighbourhood comes from the reference indices, not
    ///    from the gradient indices under test.
    /// 2. Mutual nearest neighbours within [`NearestConfig::radius`] between the predicted
    ///    positions `r + d̂` of all usable reference dots and all usable gradient dots. The pair
    ///    is flagged [`DotFlags::GRID_MISMATCH`] when the mutual partner of `r_i` is another
    ///    gradient dot, or `g_j` is the mutual partner of another reference dot.
    /// 3. Flagged pairs are left out of the predictors and the check is run again, until the
    ///    flags no longer change (at most `1 + iterations` passes, [`Matches::passes`]).
    ///
    /// So a smooth displacement field is followed whatever its size (a bump of 0.6 spacing or
    /// a uniform shift of 0.7 spacing raises no flag), while an index pair that disagrees with
    /// its neighbours is flagged: isolated wrong pairs and wrongly indexed patches of up to
    /// about 3 x 3 dots completely, larger patches along their border (inside, the neighbours
    /// agree with the wrong pairs). An index error shared by a whole region cannot be told
    /// from a displacement one lattice step larger: see the crate documentation ("What the
    /// index check cannot see").
    #[default]
    GridIndex,
    /// Nearest neighbours only (mutual nearest neighbours with the local-median predictor,
    /// see [`crate::match_points`]) over the usable records; no index information is used. With `compare_indices`, a pair whose
    /// grid indices differ is flagged [`DotFlags::GRID_MISMATCH`].
    Nearest { compare_indices: bool },
}

/// Settings of [`match_dots`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MatchConfig {
    pub mode: MatchMode,
    pub nearest: NearestConfig,
}

impl MatchConfig {
    /// Grid-index mode with the nearest-neighbour settings of [`NearestConfig::for_spacing`].
    pub fn for_spacing(spacing: f64) -> Self {
        MatchConfig {
            mode: MatchMode::GridIndex,
            nearest: NearestConfig::for_spacing(spacing),
        }
    }
}

/// How a pair was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MatchedBy {
    /// Same grid index in both images.
    GridIndex,
    /// Mutual nearest neighbours (no index partner, or [`MatchMode::Nearest`]).
    Nearest,
}

/// One reference/gradient pair: indices into the slices given to [`match_dots`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pair {
    pub reference: usize,
    pub gradient: usize,
    pub by: MatchedBy,
    /// Match flags only ([`DotFlags::GRID_MISMATCH`]); the records keep their own flags.
    pub flags: DotFlags,
}

/// Result of [`match_dots`]: every input index appears exactly once, in `pairs` or in one of
/// the unmatched lists.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Matches {
    /// One-to-one pairs, sorted by reference index.
    pub pairs: Vec<Pair>,
    /// Reference records without a partner, ascending.
    pub unmatched_reference: Vec<usize>,
    /// Gradient records without a partner, ascending.
    pub unmatched_gradient: Vec<usize>,
    /// Passes of the nearest-neighbour matching (grid-index mode: of the index-pair check, 0
    /// when there was no usable index pair to check).
    pub passes: usize,
}

impl Matches {
    /// Number of pairs flagged [`DotFlags::GRID_MISMATCH`].
    pub fn grid_mismatches(&self) -> usize {
        self.pairs
            .iter()
            .filter(|p| p.flags.contains(DotFlags::GRID_MISMATCH))
            .count()
    }
}

/// Whether a record takes part in nearest-neighbour matching: fit usable and position finite.
fn usable(d: &DotFit) -> bool {
    d.status.is_ok() && d.params.x0.is_finite() && d.params.y0.is_finite()
}

fn position(d: &DotFit) -> [f64; 2] {
    [d.params.x0, d.params.y0]
}

/// Pair the dots of a gradient image with those of the reference image (see [`MatchMode`]).
///
/// Per-dot problems (failed fits, missing partners, index disagreements) are data in the
/// result; the only error is a bad configuration.
pub fn match_dots(
    reference: &[DotFit],
    gradient: &[DotFit],
    cfg: &MatchConfig,
) -> Result<Matches, MatchError> {
    cfg.nearest.check()?;
    let ref_pos: Vec<[f64; 2]> = reference.iter().map(position).collect();
    let grad_pos: Vec<[f64; 2]> = gradient.iter().map(position).collect();
    let use_ref: Vec<bool> = reference.iter().map(usable).collect();
    let use_grad: Vec<bool> = gradient.iter().map(usable).collect();
    let mut pairs = Vec::new();
    let passes;
    match cfg.mode {
        MatchMode::Nearest { compare_indices } => {
            let init = cfg.nearest.initial_displacement.unwrap_or([0.0, 0.0]);
            let (partner, n) =
                iterate(&ref_pos, &grad_pos, &use_ref, &use_grad, init, &cfg.nearest);
            passes = n;
            for (i, p) in partner.iter().enumerate() {
                if let Some(j) = *p {
                    let mut flags = DotFlags::NONE;
                    if compare_indices && reference[i].index != gradient[j].index {
                        flags.insert(DotFlags::GRID_MISMATCH);
                    }
                    pairs.push(Pair {
                        reference: i,
                        gradient: j,
                        by: MatchedBy::Nearest,
                        flags,
                    });
                }
            }
        }
        MatchMode::GridIndex => {
            passes = by_grid_index(
                reference, gradient, &ref_pos, &grad_pos, &use_ref, &use_grad, cfg, &mut pairs,
            );
        }
    }
    pairs.sort_by_key(|p| p.reference);
    let mut ref_taken = vec![false; reference.len()];
    let mut grad_taken = vec![false; gradient.len()];
    for p in &pairs {
        ref_taken[p.reference] = true;
        grad_taken[p.gradient] = true;
    }
    Ok(Matches {
        pairs,
        unmatched_reference: (0..reference.len()).filter(|&i| !ref_taken[i]).collect(),
        unmatched_gradient: (0..gradient.len()).filter(|&j| !grad_taken[j]).collect(),
        passes,
    })
}

/// Widest ring of lattice neighbours the index predictor looks at.
const MAX_RING: i64 = 3;

/// The predictor of the index-pair check. For reference dot `i` with grid index `(a, b)`: the
/// component-wise median displacement of the usable index pairs among its lattice neighbours
/// (reference dots with index `(a ± w, b ± w)`, the dot itself left out), ring by ring from
/// `w = 1` until at least `need` pairs are found or `w` = [`MAX_RING`]; pairs flagged by the
/// previous pass are skipped. The neighbourhoods come from the reference indices (detection
/// on the reference image), not from the gradient indices under test, and cost no search.
struct IndexPredictor<'a> {
    reference: &'a [DotFit],
    table: &'a GridTable,
    /// `g - r` of every usable index pair (`None` elsewhere).
    disp: Vec<Option<[f64; 2]>>,
    need: usize,
    fallback: [f64; 2],
}

impl<'a> IndexPredictor<'a> {
    fn new(
        reference: &'a [DotFit],
        table: &'a GridTable,
        ref_pos: &[[f64; 2]],
        grad_pos: &[[f64; 2]],
        paired: &[Option<usize>],
        predictor_neighbours: usize,
        fallback: [f64; 2],
    ) -> Self {
        let disp = (0..reference.len())
            .map(|i| {
                paired[i].map(|j| {
                    [
                        grad_pos[j][0] - ref_pos[i][0],
                        grad_pos[j][1] - ref_pos[i][1],
                    ]
                })
            })
            .collect();
        IndexPredictor {
            reference,
            table,
            disp,
            need: predictor_neighbours.div_ceil(2).max(1),
            fallback,
        }
    }

    /// Predicted displacement of reference dot `i`, skipping `excluded` pairs; `fallback`
    /// when no neighbour qualifies.
    fn predict(&self, i: usize, excluded: &[bool]) -> [f64; 2] {
        let g = self.reference[i].index;
        // fast path: the 8 lattice neighbours, enough of them usable
        if let Some(ring) = self.table.ring1(g) {
            let (mut xs, mut ys) = ([0.0; 8], [0.0; 8]);
            let mut n = 0;
            for m in ring {
                let m = m as usize;
                if m < self.disp.len()
                    && m != i
                    && !excluded[m]
                    && let Some(d) = self.disp[m]
                {
                    xs[n] = d[0];
                    ys[n] = d[1];
                    n += 1;
                }
            }
            if n >= self.need {
                return [median(&mut xs[..n]), median(&mut ys[..n])];
            }
        }
        let (mut xs, mut ys) = (Vec::with_capacity(48), Vec::with_capacity(48));
        for w in 1..=MAX_RING {
            self.table.ring(g, w, |m| {
                if m != i
                    && !excluded[m]
                    && let Some(d) = self.disp[m]
                {
                    xs.push(d[0]);
                    ys.push(d[1]);
                }
            });
            if xs.len() >= self.need {
                break;
            }
        }
        if xs.is_empty() {
            self.fallback
        } else {
            [median(&mut xs), median(&mut ys)]
        }
    }
}

/// One pass of the index-pair check with predicted displacements `pred`: which usable index
/// pairs (`paired[i] = Some(j)`) disagree with the mutual nearest neighbours (within the radius
/// of `grad_set`)
/// between predicted reference positions `r + pred` and the usable gradient dots.
///
/// Same result as a full mutual-nearest-neighbour pass (pair `i` disagrees when the mutual
/// partner of `i` is another dot, or `j` is the mutual partner of another reference dot),
/// but the backward queries (nearest predicted reference position to a gradient dot) are
/// only run where a disagreement is possible: where the nearest gradient dot to `r_i + pred_i`
/// is not `j`, or where `j` is the nearest gradient dot of another reference dot too.
fn index_pair_check(
    ref_pos: &[[f64; 2]],
    grad_pos: &[[f64; 2]],
    use_ref: &[bool],
    grad_set: &RadiusSet,
    paired: &[Option<usize>],
    pred: &[[f64; 2]],
) -> Vec<bool> {
    let n = ref_pos.len();
    let predicted: Vec<[f64; 2]> = (0..n)
        .map(|i| [ref_pos[i][0] + pred[i][0], ref_pos[i][1] + pred[i][1]])
        .collect();
    // forward: nearest usable gradient dot within the radius (each dot on its own: rayon,
    // collected in dot order)
    let forward: Vec<Option<usize>> = (0..n)
        .into_par_iter()
        .with_min_len(PAR_MIN)
        .map(|i| {
            if !use_ref[i] {
                return None;
            }
            grad_set.nearest(&predicted[i]).map(|(k, _)| k)
        })
        .collect();
    let mut hits = vec![0u32; grad_pos.len()];
    for k in forward.iter().flatten() {
        hits[*k] = hits[*k].saturating_add(1);
    }
    // backward: nearest predicted position of a usable reference dot, built only when some
    // pair needs a backward query (the conditions below)
    let needs_backward = (0..n).any(|i| {
        paired[i].is_some_and(|j| {
            forward[i].is_some_and(|k| k != j) || hits[j] > u32::from(forward[i] == Some(j))
        })
    });
    // (a backward query starts at a gradient dot some forward query found within the radius:
    // the nearest predicted position lies within it too)
    let pred_set =
        needs_backward.then(|| RadiusSet::new(&predicted, |i| use_ref[i], grad_set.radius()));
    let backward = |g: &[f64; 2]| -> Option<usize> {
        pred_set.as_ref().and_then(|s| s.nearest(g)).map(|(m, _)| m)
    };
    (0..n)
        .into_par_iter()
        .with_min_len(PAR_MIN)
        .map(|i| {
            let Some(j) = paired[i] else { return false };
            let own = forward[i] == Some(j);
            // the mutual partner of i is another dot k
            if let Some(k) = forward[i]
                && k != j
                && backward(&grad_pos[k]) == Some(i)
            {
                return true;
            }
            // j is the mutual partner of another reference dot m
            if hits[j] > u32::from(own)
                && let Some(m) = backward(&grad_pos[j])
                && m != i
                && forward[m] == Some(j)
            {
                return true;
            }
            false
        })
        .collect()
}

/// Grid-index mode; pushes the pairs and returns the passes of the index-pair check.
fn by_grid_index(
    reference: &[DotFit],
    gradient: &[DotFit],
    ref_pos: &[[f64; 2]],
    grad_pos: &[[f64; 2]],
    use_ref: &[bool],
    use_grad: &[bool],
    cfg: &MatchConfig,
    pairs: &mut Vec<Pair>,
) -> usize {
    // 1. pairs by index (first occurrence of a duplicated index wins)
    let table = GridTable::new(reference.iter().map(|d| d.index));
    let mut ref_partner: Vec<Option<usize>> = vec![None; reference.len()];
    let mut grad_taken = vec![false; gradient.len()];
    for (j, d) in gradient.iter().enumerate() {
        if let Some(i) = table.get(d.index)
            && ref_partner[i].is_none()
        {
            ref_partner[i] = Some(j);
            grad_taken[j] = true;
        }
    }

    // 2. check every usable index pair against a mutual-nearest-neighbour matching of all
    //    usable records around the displacement predicted by the neighbouring index pairs
    let init = cfg.nearest.initial_displacement.unwrap_or([0.0, 0.0]);
    let paired: Vec<Option<usize>> = (0..reference.len())
        .map(|i| ref_partner[i].filter(|&j| use_ref[i] && use_grad[j]))
        .collect();
    let predictor = IndexPredictor::new(
        reference,
        &table,
        ref_pos,
        grad_pos,
        &paired,
        cfg.nearest.predictor_neighbours,
        init,
    );
    let predict_all = |want: &[bool], excluded: &[bool]| -> Vec<[f64; 2]> {
        (0..want.len())
            .into_par_iter()
            .with_min_len(PAR_MIN)
            .map(|i| {
                if want[i] {
                    predictor.predict(i, excluded)
                } else {
                    init
                }
            })
            .collect()
    };
    let mut flagged = vec![false; reference.len()];
    let mut passes = 0;
    if paired.iter().any(Option::is_some) {
        let grad_set = RadiusSet::new(grad_pos, |j| use_grad[j], cfg.nearest.radius);
        loop {
            let pred = predict_all(use_ref, &flagged);
            let next = index_pair_check(ref_pos, grad_pos, use_ref, &grad_set, &paired, &pred);
            passes += 1;
            // the next pass would predict from the same pairs: nothing can change
            let settled = next == flagged;
            flagged = next;
            if settled || passes > cfg.nearest.iterations {
                break;
            }
        }
    }
    for (i, p) in ref_partner.iter().enumerate() {
        let Some(j) = *p else { continue };
        pairs.push(Pair {
            reference: i,
            gradient: j,
            by: MatchedBy::GridIndex,
            flags: if flagged[i] {
                DotFlags::GRID_MISMATCH
            } else {
                DotFlags::NONE
            },
        });
    }

    // 3. fall-back: usable leftovers matched among themselves, predicted from the trusted
    //    (unflagged) index pairs nearby (or, without any, by the iterated matcher alone)
    let left_ref: Vec<bool> = (0..reference.len())
        .map(|i| use_ref[i] && ref_partner[i].is_none())
        .collect();
    let left_grad: Vec<bool> = (0..gradient.len())
        .map(|j| use_grad[j] && !grad_taken[j])
        .collect();
    if !left_ref.iter().any(|&b| b) || !left_grad.iter().any(|&b| b) {
        return passes;
    }
    let trusted = (0..reference.len()).any(|i| paired[i].is_some() && !flagged[i]);
    let fallback = if trusted {
        let pred = predict_all(&left_ref, &flagged);
        mutual_pass_sets(
            ref_pos,
            grad_pos,
            &left_ref,
            &left_grad,
            &pred,
            cfg.nearest.radius,
        )
    } else {
        iterate(ref_pos, grad_pos, &left_ref, &left_grad, init, &cfg.nearest).0
    };
    for (i, p) in fallback.iter().enumerate() {
        let Some(j) = *p else { continue };
        let gi = gradient[j].index;
        let mut flags = DotFlags::NONE;
        // the gradient dot carries the index of another reference dot: the indices contradict
        if gi != reference[i].index && table.get(gi).is_some() {
            flags.insert(DotFlags::GRID_MISMATCH);
        }
        pairs.push(Pair {
            reference: i,
            gradient: j,
            by: MatchedBy::Nearest,
            flags,
        });
    }
    passes
}
