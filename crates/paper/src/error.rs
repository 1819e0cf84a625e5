use bostrack_figures::FigureError;
use bostrack_theory::TheoryError;
use thiserror::Error;

/// Errors of the paper crate: a study that cannot run, or output that cannot be written.
/// Problems of one draw or one fit (a failed fit, a singular bound) are counted in the results,
/// never errors.
#[derive(Debug, Error)]
pub enum PaperError {
    /// A study parameter is out of range; `field` names it.
    #[error("invalid study configuration: `{field}` {problem}")]
    InvalidConfig { field: String, problem: String },
    /// The setup of one draw was rejected by the theory crate (a range that produces an
    /// impossible experiment).
    #[error("draw {draw}: {source}")]
    Setup {
        draw: usize,
        #[source]
        source: TheoryError,
    },
    /// Writing a CSV table failed.
    #[error("writing the {what} CSV: {source}")]
    Csv {
        what: &'static str,
        #[source]
        source: csv::Error,
    },
    /// Writing a text table failed.
    #[error("writing the {what}: {source}")]
    Io {
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// Drawing a figure failed.
    #[error("figure `{what}`: {source}")]
    Figure {
        what: &'static str,
        #[source]
        source: FigureError,
    },
}

pub(crate) fn invalid(field: &str, problem: impl std::fmt::Display) -> PaperError {
    PaperError::InvalidConfig {
        field: field.to_string(),
        problem: problem.to_string(),
    }
}
