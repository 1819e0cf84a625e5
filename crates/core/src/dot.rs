use crate::DotFlags;
use serde::{Deserialize, Serialize};
use std::fmt;

/// Index of a dot on the target lattice: position ≈ origin + i·a + j·b (see [`crate::Lattice`]).
/// `i` runs along the basis vector closest to +x, `j` along the one closest to +y.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct GridIndex {
    pub i: i32,
    pub j: i32,
}

impl GridIndex {
    pub const fn new(i: i32, j: i32) -> Self {
        GridIndex { i, j }
    }
}

/// Elliptical Gaussian dot on a constant background:
///
/// `I(x, y) = background + amplitude · exp(-q / (2 (1 - rho²)))`, with
/// `q = (x-x0)²/sigma_x² - 2 rho (x-x0)(y-y0)/(sigma_x sigma_y) + (y-y0)²/sigma_y²`.
///
/// `amplitude` is the peak height above the background (I0 in the paper); sigmas in px;
/// `rho` in (-1, 1) is the correlation coefficient (positive rho: the dot leans along x = y,
/// which with y down is a "\" shape on screen).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Gaussian2D {
    pub x0: f64,
    pub y0: f64,
    pub amplitude: f64,
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
    pub background: f64,
}

impl Gaussian2D {
    /// A round dot (sigma_x = sigma_y = sigma, rho = 0).
    pub fn circular(x0: f64, y0: f64, amplitude: f64, sigma: f64, background: f64) -> Self {
        Gaussian2D {
            x0,
            y0,
            amplitude,
            sigma_x: sigma,
            sigma_y: sigma,
            rho: 0.0,
            background,
        }
    }
    /// Dot diameter along x, d = 4 sigma_x.
    pub fn diameter_x(&self) -> f64 {
        4.0 * self.sigma_x
    }
    /// Dot diameter along y, d = 4 sigma_y.
    pub fn diameter_y(&self) -> f64 {
        4.0 * self.sigma_y
    }
    /// Integrated intensity above background, E = 2π I0 σx σy sqrt(1 - rho²).
    pub fn volume(&self) -> f64 {
        2.0 * std::f64::consts::PI
            * self.amplitude
            * self.sigma_x
            * self.sigma_y
            * (1.0 - self.rho * self.rho).sqrt()
    }
    /// The seven parameters in their order of declaration: `[x0, y0, amplitude, sigma_x,
    /// sigma_y, rho, background]`.
    pub fn to_array(&self) -> [f64; 7] {
        [
            self.x0,
            self.y0,
            self.amplitude,
            self.sigma_x,
            self.sigma_y,
            self.rho,
            self.background,
        ]
    }
    /// Whether every parameter is finite and the shape is valid (sigmas > 0, |rho| < 1).
    pub fn is_valid(&self) -> bool {
        self.to_array().iter().all(|v| v.is_finite())
            && self.sigma_x > 0.0
            && self.sigma_y > 0.0
            && self.rho.abs() < 1.0
    }
}

/// Why a fit (or estimator) stopped. Problems that do not stop a fit (saturated pixels,
/// truncation by border or mask) are [`DotFlags`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FitStatus {
    /// Converged: the step or the relative cost change fell below tolerance.
    Converged,
    /// Stopped at the iteration limit before converging.
    IterationLimit,
    /// The normal matrix could not be factorised or the position bound exceeds a pixel
    /// (degenerate window, no dot), also with the shape held (see `DotFlags::SHAPE_FIXED`).
    Singular,
    /// The centre left its window.
    LeftWindow,
    /// Too few usable pixels (masked, saturated or non-finite) for the model.
    TooFewPixels,
    /// The estimate is not finite (the parameters are then not to be used).
    NonFinite,
    /// No fit was attempted (e.g. the dot was flagged missing by detection).
    NotFitted,
}

impl FitStatus {
    /// Every status, in declaration order (for documentation and help texts generated from the
    /// code; a test checks that no status is missing).
    pub const ALL: [FitStatus; 7] = [
        FitStatus::Converged,
        FitStatus::IterationLimit,
        FitStatus::Singular,
        FitStatus::LeftWindow,
        FitStatus::TooFewPixels,
        FitStatus::NonFinite,
        FitStatus::NotFitted,
    ];

    /// Snake-case name used in CSV files.
    pub fn as_str(&self) -> &'static str {
        match self {
            FitStatus::Converged => "converged",
            FitStatus::IterationLimit => "iteration_limit",
            FitStatus::Singular => "singular",
            FitStatus::LeftWindow => "left_window",
            FitStatus::TooFewPixels => "too_few_pixels",
            FitStatus::NonFinite => "non_finite",
            FitStatus::NotFitted => "not_fitted",
        }
    }
    /// Whether the parameters of this fit can be used.
    pub fn is_ok(&self) -> bool {
        matches!(self, FitStatus::Converged | FitStatus::IterationLimit)
    }
}

impl fmt::Display for FitStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The record every estimator (least-squares Gaussian, centroid, three-point Gaussian) returns
/// for one dot. Estimators that do not estimate a parameter leave it NaN *and* say so in their
/// documentation; `status` is never `Converged` with a non-finite position.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DotFit {
    pub index: GridIndex,
    pub params: Gaussian2D,
    /// Exact per-dot Cramér-Rao bound (standard deviation, px) of x0 and y0 from the fitted
    /// parameters and the noise model; NaN if not computed.
    pub crlb_x: f64,
    pub crlb_y: f64,
    /// Root-mean-square residual of the fit over the used pixels (counts).
    pub rms: f64,
    pub iterations: u32,
    pub status: FitStatus,
    pub flags: DotFlags,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_lists_every_status_once_in_order() {
        // No wildcard: a new status does not compile until it is given a position here, which
        // is the reminder to put it at that position in `ALL`; the order is checked below.
        let position = |s: FitStatus| match s {
            FitStatus::Converged => 0,
            FitStatus::IterationLimit => 1,
            FitStatus::Singular => 2,
            FitStatus::LeftWindow => 3,
            FitStatus::TooFewPixels => 4,
            FitStatus::NonFinite => 5,
            FitStatus::NotFitted => 6,
        };
        for (k, s) in FitStatus::ALL.into_iter().enumerate() {
            assert_eq!(position(s), k, "{s}");
        }
        let mut names: Vec<_> = FitStatus::ALL.iter().map(FitStatus::as_str).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), FitStatus::ALL.len());
    }
}
