use thiserror::Error;

/// Errors of the theory crate: a setup that cannot describe an experiment. Conditions under
/// which a prediction is computed but less trustworthy (clamped cone angle, undersampled dot…)
/// are [`crate::TheoryFlags`] on the prediction, never errors.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum TheoryError {
    /// A setup value is out of range or inconsistent; `field` names it (TOML path).
    #[error("invalid setup: `{field}` {problem}")]
    InvalidSetup { field: String, problem: String },
    /// The TOML text could not be parsed (unknown key, wrong type…).
    #[error("invalid setup TOML: {0}")]
    Toml(String),
    /// The requested computation does not support this setup.
    #[error("unsupported: {0}")]
    Unsupported(String),
}

pub(crate) fn invalid(field: &str, problem: impl std::fmt::Display) -> TheoryError {
    TheoryError::InvalidSetup {
        field: field.to_string(),
        problem: problem.to_string(),
    }
}

pub(crate) fn positive(field: &str, v: f64) -> Result<f64, TheoryError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(invalid(field, format!("must be finite and > 0, got {v}")))
    }
}

pub(crate) fn non_negative(field: &str, v: f64) -> Result<f64, TheoryError> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(invalid(field, format!("must be finite and >= 0, got {v}")))
    }
}

pub(crate) fn finite(field: &str, v: f64) -> Result<f64, TheoryError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(invalid(field, format!("must be finite, got {v}")))
    }
}
