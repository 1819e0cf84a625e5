//! The error type of the crate.

/// Why a figure could not be built or rendered.
///
/// Building a figure validates its data ([`FigureError::NoData`], [`FigureError::InvalidInput`]);
/// rendering it can fail in plotters or in the PNG encoder ([`FigureError::Plot`],
/// [`FigureError::Encode`]). No function of this crate panics on bad data.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FigureError {
    /// Nothing drawable: no points, or no finite value (all NaN, or all ≤ 0 on a log axis).
    #[error("{figure}: no data to plot ({reason})")]
    NoData {
        /// Which figure (e.g. "displacement map").
        figure: String,
        /// What was missing.
        reason: String,
    },
    /// Inconsistent input (zero image size, mask of another size, bad option).
    #[error("{figure}: invalid input: {reason}")]
    InvalidInput {
        /// Which figure.
        figure: String,
        /// What is wrong.
        reason: String,
    },
    /// plotters reported an error while drawing.
    #[error("drawing failed: {0}")]
    Plot(String),
    /// The PNG encoder failed.
    #[error("PNG encoding failed: {0}")]
    Encode(String),
    /// The embedded font could not be registered with plotters.
    #[error("the embedded DejaVu Sans font could not be registered")]
    Font,
}

impl FigureError {
    pub(crate) fn no_data(figure: &str, reason: impl Into<String>) -> Self {
        FigureError::NoData {
            figure: figure.to_string(),
            reason: reason.into(),
        }
    }
    pub(crate) fn invalid(figure: &str, reason: impl Into<String>) -> Self {
        FigureError::InvalidInput {
            figure: figure.to_string(),
            reason: reason.into(),
        }
    }
}

/// Converts a plotters drawing error (any backend) into [`FigureError::Plot`].
pub(crate) fn plot_err<E: std::error::Error + Send + Sync>(
    e: plotters::drawing::DrawingAreaErrorKind<E>,
) -> FigureError {
    FigureError::Plot(e.to_string())
}
