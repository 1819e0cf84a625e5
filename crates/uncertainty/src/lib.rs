//! Reference position uncertainty from a no-flow stack.
//!
//! K images of the target without flow differ only by noise and by a common-mode shift per image
//! (camera or target motion). With `x_ik` the fitted position of dot `i` in image `k`, the model
//! is `x_ik = μ_i + s_k + e_ik`. [`stack_scatter`] removes `s_k` (robust median over the dots,
//! [`CommonMode`]) and returns per dot
//!
//! - the mean position `m_i` (the "reference position = stack mean" option),
//! - `u_ref = sqrt( Σ_k (x_ik - s_k - m_i)² / (K_i - 1) )` in x and y: the standard
//!   uncertainty of a *single* image's position of that dot,
//! - K_i (images in which the dot was fitted) and the relative standard error of `u_ref`,
//!   `1/sqrt(2(K_i - 1))` (docs/paper/NOTES.md §4: 24 % for K = 10).
//!
//! Dots fitted in fewer than `min_images` (default 3) images get no `u_ref`
//! ([`StackStatus::TooFewImages`]). The displacement uncertainty then follows as
//! `u_d² = u_refpos² + (AR · u_ref)²` with `u_refpos = u_ref` (one reference image) or
//! `u_ref / sqrt(K_i)` (reference position = stack mean); see `bostrack-displacement`.
//!
//! The sample standard deviation is the usual estimator, not corrected for its small bias:
//! `E[u] = c4(K) σ` (c4 = 0.973 at K = 10), while `E[u²] = σ²`.
//!
//! [`reference_stack`] does the same from fitted dots matched by grid index.
//!
//! ```
//! use bostrack_uncertainty::{StackConfig, StackStatus, stack_scatter};
//! // three dots in five images; image 2 moved by (+1, 0) px as a whole; dot 2 missing in image 4
//! let jitter = [0.0, 0.01, 0.0, -0.01, 0.005];
//! let samples: Vec<Vec<Option<[f64; 2]>>> = (0..5)
//!     .map(|k| {
//!         let shift = if k == 2 { 1.0 } else { 0.0 };
//!         (0..3)
//!             .map(|i| (k != 4 || i != 2).then(|| [10.0 * i as f64 + shift + jitter[k], 5.0]))
//!             .collect()
//!     })
//!     .collect();
//! let s = stack_scatter(&samples, &StackConfig::default()).unwrap();
//! assert_eq!((s.dots[0].images, s.dots[2].images), (5, 4));
//! assert_eq!(s.dots[2].status, StackStatus::Ok);
//! assert!((s.shifts[2][0] - s.shifts[0][0] - 1.0).abs() < 0.02); // the motion was found ...
//! assert!(s.dots[0].u.unwrap()[0] < 0.02); // ... and removed from the scatter
//! //! ```

mod error;
mod stack;

pub use error::StackError;
pub use stack::{
    CommonMode, DotScatter, ReferenceStack, Scatter, StackConfig, StackDot, StackStatus,
    reference_stack, stack_scatter,
};
