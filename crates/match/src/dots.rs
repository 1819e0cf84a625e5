//! Matching fitted dots ([`DotFit`] records): by grid index first, kd-tree as fall-back and as
//! an independent check of the indices.

use crate::error::MatchError;
use crate::nearest::{NearestConfig, iterate, local_predictor, mutual_pass_sets};
use bostrack_core::{DotFit, DotFlags, GridIndex};
use std::collections::HashMap;

/// How [`match_dots`] pairs the records.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum MatchMode {
    /// The primary path when detection kept the reference grid indices in the gradient image
    /// (docs/CONVENTIONS.md): records with the same [`GridIndex`] are a pair, whatever their
    /// fit status. Usable records (fit status ok, finite position) left without a partner are
    /// matched by the kd-tree among themselves. Every index pair of usable records is checked
    /// against an independent kd-tree matching of all usable records (which uses no index
    /// information); a disagreement flags [`DotFlags::GRID_MISMATCH`]. When the whole image
    /// moved by more than about 0.4 spacing, set [`NearestConfig::initial_displacement`] or
    /// every index pair is flagged.
    #[default]
    GridIndex,
    /// kd-tree only (mutual nearest neighbours with the local-median predictor, see
    /// [`crate::match_points`]) over the usable records. With `compare_indices`, a pair whose
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
    /// Grid-index mode with the kd-tree settings of [`NearestConfig::for_spacing`].
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
    /// Mutual nearest neighbours (kd-tree).
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
    /// Passes of the kd-tree matching (grid-index mode: of the independent check).
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

/// Whether a record takes part in kd-tree matching: fit usable and position finite.
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

/// Grid-index mode; pushes the pairs and returns the passes of the independent check.
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
    let mut ref_map: HashMap<GridIndex, usize> = HashMap::with_capacity(reference.len());
    for (i, d) in reference.iter().enumerate() {
        ref_map.entry(d.index).or_insert(i);
    }
    let mut ref_partner: Vec<Option<usize>> = vec![None; reference.len()];
    let mut grad_taken = vec![false; gradient.len()];
    for (j, d) in gradient.iter().enumerate() {
        if let Some(&i) = ref_map.get(&d.index)
            && ref_partner[i].is_none()
        {
            ref_partner[i] = Some(j);
            grad_taken[j] = true;
        }
    }

    // 2. independent kd-tree matching of all usable records: it must not borrow anything from
    //    the indices, or a whole image indexed with an offset would go unnoticed
    let init = cfg.nearest.initial_displacement.unwrap_or([0.0, 0.0]);
    let (kd, passes) = iterate(ref_pos, grad_pos, use_ref, use_grad, init, &cfg.nearest);
    let mut kd_inverse: Vec<Option<usize>> = vec![None; gradient.len()];
    for (i, p) in kd.iter().enumerate() {
        if let Some(j) = *p {
            kd_inverse[j] = Some(i);
        }
    }

    // 3. check the index pairs against it
    let mut trusted: Vec<Option<usize>> = vec![None; reference.len()];
    for (i, p) in ref_partner.iter().enumerate() {
        let Some(j) = *p else { continue };
        let mut flags = DotFlags::NONE;
        if use_ref[i] && use_grad[j] {
            let ref_disagrees = kd[i].is_some_and(|k| k != j);
            let grad_disagrees = kd_inverse[j].is_some_and(|k| k != i);
            if ref_disagrees || grad_disagrees {
                flags.insert(DotFlags::GRID_MISMATCH);
            } else {
                trusted[i] = Some(j);
            }
        }
        pairs.push(Pair {
            reference: i,
            gradient: j,
            by: MatchedBy::GridIndex,
            flags,
        });
    }

    // 4. fall-back: usable leftovers matched among themselves, predicted from the trusted
    //    index pairs (or, without any, by the iterated matcher alone)
    let left_ref: Vec<bool> = (0..reference.len())
        .map(|i| use_ref[i] && ref_partner[i].is_none())
        .collect();
    let left_grad: Vec<bool> = (0..gradient.len())
        .map(|j| use_grad[j] && !grad_taken[j])
        .collect();
    if !left_ref.iter().any(|&b| b) || !left_grad.iter().any(|&b| b) {
        return passes;
    }
    let fallback = if trusted.iter().any(Option::is_some) {
        let pred = local_predictor(
            ref_pos,
            grad_pos,
            &trusted,
            &left_ref,
            cfg.nearest.predictor_neighbours,
            init,
        );
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
        if gi != reference[i].index && ref_map.contains_key(&gi) {
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
