//! Pairing the dots of a gradient image with those of the reference image, and validating the
//! displacements.
//!
//! - [`match_dots`]: [`DotFit`](bostrack_core::DotFit) records paired by grid index (the
//!   primary path; detection keeps the reference indices, docs/CONVENTIONS.md), with mutual
//!   nearest neighbours as fall-back for records whose index has no partner, and a check of
//!   every index pair against the geometry around the displacement predicted by its lattice
//!   neighbours ([`DotFlags::GRID_MISMATCH`](bostrack_core::DotFlags::GRID_MISMATCH), see
//!   [`MatchMode::GridIndex`]).
//! - [`match_points`]: plain point sets, mutual nearest neighbours within a search radius
//!   (default 0.4 × spacing), one-to-one, iterated with the local median displacement of the
//!   matched neighbours as predictor, so smooth fields larger than the radius are followed.
//! - [`validate`]: displacement threshold and the normalised median test for scattered data
//!   (Westerweel & Scarano 2005, Exp. Fluids 39:1096):
//!   `r = |d_0 - median(d_i)| / (median(|d_i - median(d_i)|) + ε)` per component over the k
//!   nearest neighbours (default k = 8, threshold 2, ε = 0.1 px), flagging
//!   [`DotFlags::OUTLIER`](bostrack_core::DotFlags::OUTLIER); replacement by the neighbours'
//!   median only on request.
//!
//! Nearest-neighbour queries use kiddo's immutable kd-tree (the design's choice; a hand-written
//! bucket grid was 2-5x faster here but duplicates what kiddo does). Ties in distance go to the
//! lower index, so the results do not depend on the search order. For ~12k dots, matching by
//! grid index takes ~2x a kd-tree build plus 12k nearest queries, the median test ~4.6x
//! (rayon over dots; `benches/matching.rs`).
//!
//! # What the index check cannot see
//!
//! An index error shared by a whole region, typically every gradient dot carrying the index of
//! its neighbour one lattice step over after tracking a motion of more than half the spacing,
//! looks locally exactly like a correct pairing with a displacement one lattice vector
//! larger (or smaller): a uniform shift of 0.7 spacing tracked correctly and the same shift
//! aliased to −0.3 spacing are both smooth fields. No local test can tell them apart, and
//! [`match_dots`] trusts the indices: inside such a region it raises neither
//! `GRID_MISMATCH` nor, the field being smooth, an `OUTLIER`. What you see is a displacement
//! map offset by one lattice vector over the region (|d| of about the spacing where the flow
//! is small, or a plateau with a step of one spacing at its edge), with `GRID_MISMATCH` and
//! `OUTLIER` only along the region's border, where its dots meet correctly indexed
//! neighbours; a wholly aliased image shows no flag at all. Getting the indices right for
//! motions beyond half the spacing is the tracking stage's job (`bostrack_detect::track`
//! anchors the lattice on the largest group of dots that barely moved); [`match_points`] (no
//! indices) resolves it only with [`NearestConfig::initial_displacement`].
//!
//! ```
//! use bostrack_match::{NearestConfig, ValidationConfig, match_points, validate};
//! // a 20 x 20 lattice of spacing 8 px, moved by a uniform (0.7, -0.3) px
//! let reference: Vec<[f64; 2]> = (0..400)
//!     .map(|k| [8.0 * (k % 20) as f64, 8.0 * (k / 20) as f64])
//!     .collect();
//! let mut gradient: Vec<[f64; 2]> =
//!     reference.iter().map(|p| [p[0] + 0.7, p[1] - 0.3]).collect();
//! gradient[55][0] += 2.0; // one bad vector
//! let m = match_points(&reference, &gradient, &NearestConfig::for_spacing(8.0)).unwrap();
//! assert_eq!(m.pairs.len(), 400);
//! assert!(m.pairs.iter().all(|&(i, j)| i == j));
//!
//! let d: Vec<[f64; 2]> = m
//!     .pairs
//!     .iter()
//!     .map(|&(i, j)| [gradient[j][0] - reference[i][0], gradient[j][1] - reference[i][1]])
//!     .collect();
//! let pos: Vec<[f64; 2]> = m.pairs.iter().map(|&(i, _)| reference[i]).collect();
//! let v = validate(&pos, &d, &ValidationConfig::default()).unwrap();
//! assert_eq!(v.outliers(), 1);
//! assert!(v.checks[55].is_outlier());
//! ```

mod dots;
mod error;
mod nearest;
mod points;
mod validate;

pub use dots::{MatchConfig, MatchMode, MatchedBy, Matches, Pair, match_dots};
pub use error::MatchError;
pub use nearest::{NearestConfig, PointMatches, match_points};
pub use validate::{
    MedianTest, NeighbourLists, Validation, ValidationConfig, VectorCheck, Verdict, validate,
    validate_at,
};
