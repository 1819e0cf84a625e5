//! Mutual-nearest-neighbour matching of two point sets with a local-median displacement
//! predictor.

use crate::error::MatchError;
use crate::points::{PointSet, RadiusSet, median};

/// Settings of the nearest-neighbour matcher ([`match_points`], and the nearest-neighbour parts
/// of [`crate::match_dots`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearestConfig {
    /// Search radius (px) around a reference dot's predicted position in the gradient image.
    /// [`NearestConfig::for_spacing`] sets 0.4 × the dot spacing: below half the spacing, so
    /// that a dot's neighbour can never be closer than the radius when the prediction is off by
    /// less than 0.1 spacing.
    pub radius: f64,
    /// Predictor passes after the first (0: plain mutual nearest neighbours). Each pass
    /// predicts every reference dot's displacement from its matched neighbours and matches
    /// again; the passes stop early when the matching no longer changes. Default 4.
    pub iterations: usize,
    /// How many nearest matched reference dots (the dot itself included when it is matched)
    /// give the predicted displacement, as the median of each component. Default 8. (Grid-index
    /// mode takes the lattice neighbours instead, widening the ring until half this number
    /// is found.)
    pub predictor_neighbours: usize,
    /// Displacement (px) predicted for every dot before any match is known (`None`: zero).
    /// Needed by [`match_points`] when the whole image moved by more than about 0.4 spacing
    /// (camera motion). In grid-index mode ([`crate::MatchMode::GridIndex`]) the index pairs
    /// predict the displacement; this value only serves dots without any usable index pair
    /// within 3 lattice steps.
    pub initial_displacement: Option<[f64; 2]>,
}

impl NearestConfig {
    /// Default settings for a dot pattern of the given spacing (px): radius 0.4 × spacing.
    pub fn for_spacing(spacing: f64) -> Self {
        NearestConfig {
            radius: 0.4 * spacing,
            iterations: 4,
            predictor_neighbours: 8,
            initial_displacement: None,
        }
    }

    pub(crate) fn check(&self) -> Result<(), MatchError> {
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Err(MatchError::Config(format!(
                "search radius must be a positive number of px, got {}",
                self.radius
            )));
        }
        if self.predictor_neighbours == 0 {
            return Err(MatchError::Config(
                "predictor_neighbours must be at least 1".into(),
            ));
        }
        if let Some(d) = self.initial_displacement
            && !(d[0].is_finite() && d[1].is_finite())
        {
            return Err(MatchError::Config(format!(
                "initial displacement must be finite, got {d:?}"
            )));
        }
        Ok(())
    }
}

/// Result of [`match_points`]: every input index appears exactly once, either in `pairs` or in
/// one of the unmatched lists.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointMatches {
    /// `(reference index, gradient index)`, one-to-one, sorted by reference index.
    pub pairs: Vec<(usize, usize)>,
    /// Reference points with no partner (also those with a non-finite position), ascending.
    pub unmatched_reference: Vec<usize>,
    /// Gradient points with no partner, ascending.
    pub unmatched_gradient: Vec<usize>,
    /// Matching passes run (1 + predictor passes that were needed).
    pub passes: usize,
}

/// Match gradient points to reference points: mutual nearest neighbours within
/// `cfg.radius` of each reference point's predicted position, one-to-one.
///
/// Pass 1 predicts the displacement `cfg.initial_displacement` (zero if `None`) everywhere: a
/// reference point `r_i` with predicted position `p_i = r_i + d̂_i` and a gradient point `g_j`
/// are a pair when `g_j` is the nearest gradient point to `p_i`, `p_i` is the nearest predicted
/// position to `g_j`, and `|g_j - p_i| <= radius`. Each further pass (at most
/// `cfg.iterations`) sets `d̂_i` to the component-wise median displacement `g - r` of the
/// `cfg.predictor_neighbours` matched reference points nearest to `r_i` and matches again, so a
/// smooth displacement field larger than the radius is followed from the region where it is
/// small. A region whose displacement exceeds half the spacing everywhere is ambiguous to any
/// nearest-neighbour rule: give `initial_displacement` (or match by grid index).
///
/// Points with a non-finite coordinate are never matched. Errors only for a bad configuration.
pub fn match_points(
    reference: &[[f64; 2]],
    gradient: &[[f64; 2]],
    cfg: &NearestConfig,
) -> Result<PointMatches, MatchError> {
    cfg.check()?;
    let use_ref = vec![true; reference.len()];
    let use_grad = vec![true; gradient.len()];
    let init = cfg.initial_displacement.unwrap_or([0.0, 0.0]);
    let (partner, passes) = iterate(reference, gradient, &use_ref, &use_grad, init, cfg);
    Ok(collect(&partner, gradient.len(), passes))
}

/// Turn a partner table into a [`PointMatches`].
fn collect(partner: &[Option<usize>], n_grad: usize, passes: usize) -> PointMatches {
    let mut out = PointMatches {
        passes,
        ..PointMatches::default()
    };
    let mut taken = vec![false; n_grad];
    for (i, p) in partner.iter().enumerate() {
        match p {
            Some(j) => {
                out.pairs.push((i, *j));
                taken[*j] = true;
            }
            None => out.unmatched_reference.push(i),
        }
    }
    out.unmatched_gradient = (0..n_grad).filter(|&j| !taken[j]).collect();
    out
}

/// The iterated mutual-NN matching over the points allowed by `use_ref` / `use_grad`.
/// Returns the gradient partner of every reference point and the number of passes run.
pub(crate) fn iterate(
    reference: &[[f64; 2]],
    gradient: &[[f64; 2]],
    use_ref: &[bool],
    use_grad: &[bool],
    init: [f64; 2],
    cfg: &NearestConfig,
) -> (Vec<Option<usize>>, usize) {
    let grad_set = RadiusSet::new(gradient, |j| use_grad[j], cfg.radius);
    let mut pred = vec![init; reference.len()];
    let mut partner = mutual_pass(reference, gradient, use_ref, &grad_set, &pred);
    let mut passes = 1;
    for _ in 0..cfg.iterations {
        if partner.iter().all(Option::is_none) {
            break;
        }
        pred = local_predictor(
            reference,
            gradient,
            &partner,
            use_ref,
            cfg.predictor_neighbours,
            init,
        );
        let next = mutual_pass(reference, gradient, use_ref, &grad_set, &pred);
        passes += 1;
        if next == partner {
            break;
        }
        partner = next;
    }
    (partner, passes)
}

/// Predicted displacement of every reference point with `want[i]`: the component-wise median
/// of `g - r` over the `k` matched points (per `partner`) nearest to it; `fallback` where
/// nothing is matched.
pub(crate) fn local_predictor(
    reference: &[[f64; 2]],
    gradient: &[[f64; 2]],
    partner: &[Option<usize>],
    want: &[bool],
    k: usize,
    fallback: [f64; 2],
) -> Vec<[f64; 2]> {
    let matched = PointSet::new(reference, |i| partner[i].is_some());
    let mut pred = vec![fallback; reference.len()];
    let mut nb = Vec::with_capacity(k);
    let (mut bx, mut by) = (Vec::with_capacity(k), Vec::with_capacity(k));
    for (i, r) in reference.iter().enumerate() {
        if !want[i] {
            continue;
        }
        matched.nearest_n(r, k, None, &mut nb);
        bx.clear();
        by.clear();
        for &(_, m) in &nb {
            // the index holds matched points only
            if let Some(j) = partner[m as usize] {
                bx.push(gradient[j][0] - reference[m as usize][0]);
                by.push(gradient[j][1] - reference[m as usize][1]);
            }
        }
        if bx.is_empty() {
            continue;
        }
        pred[i] = [median(&mut bx), median(&mut by)];
    }
    pred
}

/// One mutual-nearest-neighbour pass between the allowed points of both sets.
pub(crate) fn mutual_pass_sets(
    reference: &[[f64; 2]],
    gradient: &[[f64; 2]],
    use_ref: &[bool],
    use_grad: &[bool],
    pred: &[[f64; 2]],
    radius: f64,
) -> Vec<Option<usize>> {
    let grad_set = RadiusSet::new(gradient, |j| use_grad[j], radius);
    mutual_pass(reference, gradient, use_ref, &grad_set, pred)
}

/// One mutual-nearest-neighbour pass with predicted displacements `pred`.
pub(crate) fn mutual_pass(
    reference: &[[f64; 2]],
    gradient: &[[f64; 2]],
    use_ref: &[bool],
    grad_set: &RadiusSet,
    pred: &[[f64; 2]],
) -> Vec<Option<usize>> {
    let predicted: Vec<[f64; 2]> = reference
        .iter()
        .zip(pred)
        .map(|(r, d)| [r[0] + d[0], r[1] + d[1]])
        .collect();
    // (the backward query starts at a gradient dot within the radius of predicted[i]: the
    // nearest predicted position lies within it too)
    let pred_set = RadiusSet::new(&predicted, |i| use_ref[i], grad_set.radius());
    let mut partner = vec![None; reference.len()];
    for (i, p) in predicted.iter().enumerate() {
        if !use_ref[i] {
            continue;
        }
        let Some((j, _)) = grad_set.nearest(p) else {
            continue;
        };
        if pred_set.nearest(&gradient[j]).map(|(back, _)| back) == Some(i) {
            partner[i] = Some(j);
        }
    }
    partner
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_to_one_and_radius() {
        let r = [[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [f64::NAN, 0.0]];
        // gradient: partner of 0 and of 1 shifted by 1 px; a point claimed by nobody; no partner of 2
        let g = [[11.0, 0.0], [1.0, 0.0], [40.0, 0.0]];
        let m = match_points(&r, &g, &NearestConfig::for_spacing(10.0)).unwrap();
        assert_eq!(m.pairs, vec![(0, 1), (1, 0)]);
        assert_eq!(m.unmatched_reference, vec![2, 3]);
        assert_eq!(m.unmatched_gradient, vec![2]);
        // two reference points competing for one gradient point: only the nearer gets it
        let m = match_points(
            &[[0.0, 0.0], [3.0, 0.0]],
            &[[2.0, 0.0]],
            &NearestConfig::for_spacing(10.0),
        )
        .unwrap();
        assert_eq!(m.pairs, vec![(1, 0)]);
        assert_eq!(m.unmatched_reference, vec![0]);
    }

    #[test]
    fn bad_config_is_an_error() {
        let mut c = NearestConfig::for_spacing(10.0);
        c.radius = -1.0;
        assert!(match_points(&[], &[], &c).is_err());
        let mut c = NearestConfig::for_spacing(10.0);
        c.predictor_neighbours = 0;
        assert!(match_points(&[], &[], &c).is_err());
        let m = match_points(&[], &[], &NearestConfig::for_spacing(10.0)).unwrap();
        assert!(m.pairs.is_empty());
    }
}
