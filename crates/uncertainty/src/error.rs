use thiserror::Error;

/// Errors of the stack statistics: only bad arguments. Dots with too few images are data
/// ([`crate::StackStatus::TooFewImages`]).
#[derive(Debug, Error, Clone, PartialEq)]
pub enum StackError {
    /// A setting outside its allowed range.
    #[error("invalid stack setting: {0}")]
    Config(String),
    /// The images of a sample matrix list different numbers of dots.
    #[error("stack image {image} lists {len} dots, the first lists {expected}")]
    Shape {
        image: usize,
        len: usize,
        expected: usize,
    },
}
