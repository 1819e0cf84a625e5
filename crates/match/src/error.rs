use thiserror::Error;

/// Errors of the matching and validation functions: only bad arguments. Per-dot problems
/// (no partner, index disagreement, outlier) are data in the results.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum MatchError {
    /// A setting outside its allowed range.
    #[error("invalid matching/validation setting: {0}")]
    Config(String),
    /// `validate` needs one position per vector.
    #[error("validation needs one position per vector: {positions} positions, {vectors} vectors")]
    Length { positions: usize, vectors: usize },
}
