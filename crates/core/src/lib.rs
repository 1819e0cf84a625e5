//! Shared types of bostrack.
//!
//! Every stage crate (detect, fit, match, displacement, uncertainty) speaks in these types and
//! depends on nothing else of the workspace but [`bostrack-core`](crate) and `bostrack-model`.
//! Conventions (see `docs/CONVENTIONS.md`): pixel centres at integer coordinates, origin at the
//! centre of the top-left pixel, x to the right, y down, all lengths in px; Gaussian sigma in px,
//! dot diameter d = 4 sigma; displacement = gradient - reference.
//!
//! ```
//! use bostrack_core::{Image, Gaussian2D};
//! let img = Image::from_fn(5, 4, |x, y| (x + 10 * y) as f64);
//! assert_eq!(img.get(2, 3), 32.0);
//! let g = Gaussian2D::circular(2.0, 1.5, 100.0, 1.2, 10.0);
//! assert_eq!(g.diameter_x(), 4.8);
//! ```

mod dot;
mod flags;
mod grid;
mod image;
mod lattice;
mod noise;
mod simd;
mod stats;
pub mod table;
mod window;

#[doc(hidden)]
pub use serde as __serde;

pub use dot::{DotFit, FitStatus, Gaussian2D, GridIndex};
pub use flags::DotFlags;
pub use grid::GridTable;
pub use image::{Image, ImageMeta, Mask, Photometric, SampleFormat, ShapeError};
pub use lattice::Lattice;
pub use noise::NoiseModel;
pub use simd::{dispatch, simd_arch};
pub use stats::median;
pub use window::{Seed, Window};
