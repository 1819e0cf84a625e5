//! Why detection or tracking of a whole image failed (per-dot problems are flags, not errors).

use crate::LatticeKind;
use thiserror::Error;

/// A whole-image failure of [`crate::detect`] or [`crate::track`]. `image` names the source
/// file (from [`bostrack_core::ImageMeta::source`]) or says `in-memory image`.
#[derive(Clone, Debug, PartialEq, Error)]
pub enum DetectError {
    #[error("invalid detect configuration: `{field}` {problem}")]
    InvalidConfig {
        field: &'static str,
        problem: String,
    },
    #[error(
        "{image}: the mask is {mask_width}x{mask_height} pixels but the image is {width}x{height}"
    )]
    MaskSize {
        image: String,
        width: usize,
        height: usize,
        mask_width: usize,
        mask_height: usize,
    },
    #[error("{image}: the mask keeps no pixel")]
    EmptyMask { image: String },
    #[error("{image}: {width}x{height} pixels is too small for detection (at least {min}x{min})")]
    ImageTooSmall {
        image: String,
        width: usize,
        height: usize,
        min: usize,
    },
    #[error("{image}: no contrast (constant image or no finite sample)")]
    NoContrast { image: String },
    #[error("{image}: no dot lattice found: {reason}")]
    NoLattice { image: String, reason: String },
    #[error(
        "{image}: the measured lattice basis makes {angle_deg:.1}° which does not fit a {expected:?} lattice"
    )]
    LatticeMismatch {
        image: String,
        expected: LatticeKind,
        angle_deg: f64,
    },
    #[error("{image}: only {found} dots found on the lattice, at least {min} needed")]
    TooFewDots {
        image: String,
        found: usize,
        min: usize,
    },
    #[error(
        "{image}: the image is {width}x{height} pixels but the reference detection was made on {ref_width}x{ref_height}"
    )]
    ReferenceSize {
        image: String,
        width: usize,
        height: usize,
        ref_width: usize,
        ref_height: usize,
    },
    #[error("the reference detection has no seeds")]
    EmptyReference,
}
