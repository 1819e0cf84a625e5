//! Errors of the fit crate (per-dot problems are `FitStatus`/`DotFlags`, never errors).

use bostrack_core::{Image, Mask};
use thiserror::Error;

/// What can go wrong with the inputs of the fit stage as a whole.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FitError {
    /// The mask is not the size of the image.
    #[error("mask is {mask_w}x{mask_h} pixels but the image is {img_w}x{img_h}")]
    MaskSize {
        mask_w: usize,
        mask_h: usize,
        img_w: usize,
        img_h: usize,
    },
    /// A configuration value is out of range.
    #[error("invalid fit configuration: {0}")]
    InvalidConfig(String),
    /// A no-flow stack needs at least two images.
    #[error("a no-flow stack needs at least 2 images, got {0}")]
    StackTooShort(usize),
    /// The images of a stack differ in size.
    #[error(
        "image {index} of the stack is {width}x{height} pixels, the first is {first_w}x{first_h}"
    )]
    StackSize {
        index: usize,
        width: usize,
        height: usize,
        first_w: usize,
        first_h: usize,
    },
    /// Too few usable pixels (or intensity levels) to estimate the noise.
    #[error("cannot estimate the noise: {0}")]
    Noise(String),
}

/// [`FitError::MaskSize`] unless `mask` (if any) is the size of `img`.
pub(crate) fn check_mask(img: &Image, mask: Option<&Mask>) -> Result<(), FitError> {
    match mask {
        Some(m) if !m.matches(img) => Err(FitError::MaskSize {
            mask_w: m.width(),
            mask_h: m.height(),
            img_w: img.width(),
            img_h: img.height(),
        }),
        _ => Ok(()),
    }
}
