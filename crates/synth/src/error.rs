use thiserror::Error;

/// Errors of the synthetic-image generator. Per-dot conditions (missing, border, saturated)
/// are [`bostrack_core::DotFlags`] on the truth, never errors.
#[derive(Debug, Error)]
pub enum SynthError {
    /// A configuration value is out of range; `field` names it (TOML path).
    #[error("invalid scene configuration: `{field}` {problem}")]
    InvalidConfig { field: String, problem: String },
    /// The TOML text could not be parsed (unknown key, wrong type…).
    #[error("invalid scene configuration TOML: {0}")]
    Toml(String),
    /// A truth dot handed to the renderer has invalid parameters.
    #[error("truth dot ({i}, {j}) has invalid parameters (sigma <= 0, |rho| >= 1 or not finite)")]
    InvalidDot { i: i32, j: i32 },
    /// Writing or reading the truth CSV failed.
    #[error("truth CSV: {0}")]
    Csv(#[from] csv::Error),
    /// A truth CSV field could not be read.
    #[error("truth CSV line {line}: {problem}")]
    CsvField { line: u64, problem: String },
}
