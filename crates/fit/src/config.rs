//! Configuration of the fit stage (embedded in `pipeline.toml` as the `[fit]` table).

use crate::FitError;
use bostrack_model::{ModelKind, Sampling};
use serde::{Deserialize, Serialize};

/// Which estimator produces the [`bostrack_core::DotFit`] record.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Estimator {
    /// Least-squares Gaussian fit (weighted by the noise model): all parameters, the default.
    #[default]
    Lsg,
    /// Intensity-weighted centroid of the background-subtracted pixels above 10 % of the peak
    /// (reached from the peak without climbing towards another dot), with second-moment
    /// estimates of the shape (corrected for the threshold). No iterations.
    Iwc,
    /// Three-point Gaussian: a parabola through the logarithms of the peak pixel and its two
    /// neighbours, per axis. Estimates x0, y0, σx, σy, amplitude; **ρ is not estimated (NaN)**.
    Tpg,
}

impl Estimator {
    pub fn as_str(self) -> &'static str {
        match self {
            Estimator::Lsg => "lsg",
            Estimator::Iwc => "iwc",
            Estimator::Tpg => "tpg",
        }
    }
}

/// How the fit evaluates the dot model over a pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FitSampling {
    /// Pixel-integrated where it matters, fast elsewhere (the default): a dot whose smallest
    /// conditional sigma (`σx·sqrt(1-ρ²)` or `σy·sqrt(1-ρ²)`) is at least [`AUTO_SIGMA`] px is
    /// fitted as the point-sampled Gaussian of covariance `Σ + I/12` (the pixel-integrated dot
    /// has exactly that covariance; its higher cumulants differ by the box's, -1/120 px⁴ per
    /// axis), and the record reports `Σ` and the amplitude of the same volume; narrower dots
    /// use the pixel-integrated model. About 4x faster than `integrated` at σ ≈ 1.6 px, and
    /// indistinguishable in position (test `auto_sampling_matches_integrated`).
    #[default]
    Auto,
    /// The mean of the model over the pixel (erf / Gauss-Legendre), for every dot.
    Integrated,
    /// The model's value at the pixel centre: for data that really is point-sampled (and for
    /// the error-vs-time study); biased on real dots below σ ≈ 0.8 px.
    Point,
}

/// Smallest conditional sigma (px) fitted with the pixel-blurred point model by
/// [`FitSampling::Auto`]. At 1 px the position difference to the pixel-integrated fit is
/// below 1e-4 px on noise-free dots (test `auto_sampling_matches_integrated`).
pub const AUTO_SIGMA: f64 = 1.0;

impl FitSampling {
    pub fn as_str(self) -> &'static str {
        match self {
            FitSampling::Auto => "auto",
            FitSampling::Integrated => "integrated",
            FitSampling::Point => "point",
        }
    }
    /// The image model the dots are assumed to follow (for bounds and moment corrections):
    /// pixel-integrated unless `Point`.
    pub fn image_model(self) -> Sampling {
        match self {
            FitSampling::Point => Sampling::Point,
            FitSampling::Auto | FitSampling::Integrated => Sampling::Integrated,
        }
    }
}

impl From<Sampling> for FitSampling {
    fn from(s: Sampling) -> Self {
        match s {
            Sampling::Point => FitSampling::Point,
            Sampling::Integrated => FitSampling::Integrated,
        }
    }
}

/// Which least-squares solver fits [`Estimator::Lsg`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Solver {
    /// Specialised Levenberg-Marquardt: normal equations accumulated over the pixels as
    /// moments, fixed-size arrays, no allocation per dot. The default (about 10x faster).
    #[default]
    Fast,
    /// The `levenberg-marquardt` crate (MINPACK-style trust region on the QR of the weighted
    /// Jacobian), with the same model, parameterisation and weights.
    LmCrate,
}

impl Solver {
    pub fn as_str(self) -> &'static str {
        match self {
            Solver::Fast => "fast",
            Solver::LmCrate => "lm_crate",
        }
    }
}

/// How [`crate::fit_dots`] deals with the tails of neighbouring dots inside a fit window.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Neighbours {
    /// Fit each window as it is.
    None,
    /// Fit every dot once, subtract the fitted neighbours' dots (without background) from each
    /// window, and fit again from the first result. The default: on an 8 px pitch with σ ≈ 1.6
    /// px a ±4 px window holds ~4 % of each edge neighbour's peak.
    #[default]
    Subtract,
}

/// Configuration of the fit stage. Every field has a default (shown), unknown keys are
/// rejected:
///
/// ```toml
/// model = "elliptical"      # "elliptical" (7 parameters) | "axis_aligned" (rho = 0) | "circular"
/// sampling = "auto"         # "auto" | "integrated" (mean over the pixel) | "point" (value at the centre)
/// estimator = "lsg"         # "lsg" | "iwc" | "tpg"
/// solver = "fast"           # "fast" | "lm_crate"
/// max_iterations = 50       # Levenberg-Marquardt iterations (rejected steps included)
/// tolerance = 0.05          # converged when a step is below this many standard deviations
/// neighbours = "subtract"   # "subtract" | "none"
/// neighbour_passes = 40     # at most this many neighbour passes (1 to 100)
/// neighbour_tolerance = 0.1 # a dot is converged with its neighbours below this (bound units)
/// ghosts = true             # model the lattice sites just outside the image as neighbours
/// frame_map = true          # solve a gradient frame's still part on the reference's linear map
/// residual_false_alarm = 1e-6 # χ² test of each window's residual ("residual" flag); 0: off
/// bound = true              # compute the per-dot Cramér-Rao bound (crlb_x, crlb_y)
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FitConfig {
    /// Which parameters are free. Default `elliptical`.
    pub model: ModelKind,
    /// Point-sampled or pixel-integrated model. Default `auto` (pixel-integrated, evaluated as
    /// the pixel-blurred Gaussian where that is exact enough): the position bias of a
    /// point-sampled fit to real (pixel-integrated) dots grows quickly below σ ≈ 0.8 px, and a
    /// point-sampled σ over-states the dot by the pixel's own variance (σ² + 1/12).
    pub sampling: FitSampling,
    /// Default `lsg`.
    pub estimator: Estimator,
    /// Default `fast`.
    pub solver: Solver,
    /// Default 50.
    pub max_iterations: u32,
    /// Convergence: the Mahalanobis length of the next Gauss-Newton step, `sqrt(δᵀ N δ)` with
    /// `N` the Fisher matrix under the noise model, i.e. the step in units of the parameters'
    /// standard deviations; a step below it is taken and the fit stops. Default 0.05: what is
    /// left after that step is of second order. On the real sample (24,465 fits) positions
    /// differ from fits to 1e-3 by a median 2e-4 and at most 0.018 of their bound (0.01: at
    /// most 0.003, for ~15 % more evaluations).
    pub tolerance: f64,
    /// Default `subtract`.
    pub neighbours: Neighbours,
    /// With `neighbours = "subtract"`: the largest number of neighbour passes (1 to
    /// [`MAX_NEIGHBOUR_PASSES`], default 40). Each pass refits, with its neighbours' latest fits
    /// subtracted, every dot whose neighbours' models over its window changed by more than
    /// `neighbour_tolerance` since it was last fitted (block Jacobi with an active set); the
    /// passes stop when no dot is left to refit. A dot still not converged after the last pass
    /// is flagged `unconverged`.
    pub neighbour_passes: u32,
    /// With `neighbours = "subtract"`: the convergence tolerance of the neighbour iteration, in
    /// standard deviations of a dot's position (default 0.1). From pass 3 on a dot is looked at
    /// again when the **pull** owed to it since it was last fitted exceeds this: the sum, over
    /// the neighbours that moved, of how far each moved (the Mahalanobis length of its change
    /// without background) times the square root of the share of its squared profile inside this
    /// dot's window (a Cauchy-Schwarz bound, up to the shape of the change). It is then refitted
    /// only if one Gauss-Newton step of its last fit, with the change of its neighbours' models
    /// over its window since that fit, moves its position by more than this (Mahalanobis length
    /// of the position part). The passes stop when no dot is left to refit. Without noise on a
    /// lattice of spacing 7 px at σ 1.6 px the worst dot ends 0.13 of its bound from the joint
    /// solution (test `converged_fits_reach_the_joint_solution_on_a_dense_lattice`). A dot whose
    /// pull (or own last move) is still above 5 × this after the last pass is flagged
    /// `unconverged`.
    pub neighbour_tolerance: f64,
    /// With `neighbours = "subtract"`: model the lattice sites just outside the image whose
    /// light reaches into it (default true). From pass 2 on, each site one lattice step beyond
    /// the outermost seeds (extrapolated along the lattice from their fits) is a **ghost**: a
    /// dot of the image's median shape at that position whose amplitude and background are
    /// fitted on the part of its window inside the image (kept where its amplitude reaches 3.5
    /// standard deviations); it is subtracted from its neighbours' windows like any neighbour
    /// and never reported. Without them the windows along the image edge of a dense target hold
    /// light no model accounts for: on `testdata/scenes/dense_vortex` (spacing 7 px, σ 1.6 px)
    /// 97.1 % of the dots were valid, the edge ones failing the χ² test; with them 99.0 %.
    pub ghosts: bool,
    /// With `neighbours = "subtract"` and least squares: solve the still part of a gradient
    /// frame (dots that, like their neighbours, lie within 5 % of σ of the reference fits
    /// after the frame's common shift) on the reference's linear coupling map instead of
    /// refitting them in every pass (default true). The pipeline then shares the no-flow
    /// stack's map with the frames, or (without a stack, for 10 frames or more) makes the
    /// reference's own. On the real sample the frame's fit stage takes ~20 % less CPU and its
    /// positions lie as far from the deep joint solution as the passes' do (median 0.030
    /// against 0.029 of the bound, 99th percentile 0.16 against 0.14). On a crowded synthetic
    /// campaign (σ 1.6 px, spacing 7 px, 10 frames of a bump) the map lands on the deep joint
    /// solution (displacement rms error within 0.07 % of it) where the passes, stopped at
    /// their tolerance a little short of it on the side of their prior (the reference's fit,
    /// an independent measurement of a still dot), come out 0.2-0.3 % lower; `false` keeps the
    /// passes.
    pub frame_map: bool,
    /// False-alarm rate of the per-dot χ² test of the window residual (default 1e-6; 0 turns the
    /// test off; checked at 0.01 on synthetic images, test
    /// `residual_test_flags_at_its_false_alarm_rate_and_catches_a_speck`). Real dots have heavier
    /// tails than the model: on the real sample's reference 573 of 12,236 dots (4.7 %) are
    /// flagged at 1e-3, 328 at 1e-4, 164 (1.3 %) at 1e-6, 122 at 1e-8: a dot whose weighted residual sum of squares exceeds the `1 - rate` quantile of
    /// the χ² distribution with `pixels - parameters` degrees of freedom, the noise model scaled
    /// by the image's median reduced χ² where that exceeds 1, is flagged `residual`.
    pub residual_false_alarm: f64,
    /// Compute `crlb_x`, `crlb_y` (default true). For the fast solver it is the inverse of
    /// the final normal matrix (the Fisher matrix of the pixels used, no extra cost); for the
    /// other estimators it is `bostrack_model::crlb_masked` at the estimated parameters.
    pub bound: bool,
}

impl Default for FitConfig {
    fn default() -> Self {
        FitConfig {
            model: ModelKind::Elliptical,
            sampling: FitSampling::Auto,
            estimator: Estimator::Lsg,
            solver: Solver::Fast,
            max_iterations: 50,
            tolerance: 0.05,
            neighbours: Neighbours::Subtract,
            neighbour_passes: 40,
            neighbour_tolerance: 0.1,
            ghosts: true,
            frame_map: true,
            residual_false_alarm: 1e-6,
            bound: true,
        }
    }
}

impl FitConfig {
    /// Checks the numbers (the enums are valid by construction).
    pub fn validate(&self) -> Result<(), FitError> {
        if !(1..=MAX_ITERATIONS).contains(&self.max_iterations) {
            return Err(FitError::InvalidConfig(format!(
                "max_iterations must lie in 1..={MAX_ITERATIONS}, got {}",
                self.max_iterations
            )));
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(FitError::InvalidConfig(format!(
                "tolerance must be a positive number, got {}",
                self.tolerance
            )));
        }
        if !(1..=MAX_NEIGHBOUR_PASSES).contains(&self.neighbour_passes)
            && self.neighbours == Neighbours::Subtract
        {
            return Err(FitError::InvalidConfig(format!(
                "neighbour_passes must lie in 1..={MAX_NEIGHBOUR_PASSES}, got {}",
                self.neighbour_passes
            )));
        }
        if !(self.neighbour_tolerance.is_finite() && self.neighbour_tolerance > 0.0) {
            return Err(FitError::InvalidConfig(format!(
                "neighbour_tolerance must be a positive number, got {}",
                self.neighbour_tolerance
            )));
        }
        if !(0.0..0.5).contains(&self.residual_false_alarm) {
            return Err(FitError::InvalidConfig(format!(
                "residual_false_alarm must lie in [0, 0.5), got {}",
                self.residual_false_alarm
            )));
        }
        Ok(())
    }
}

/// Largest accepted `neighbour_passes`.
pub const MAX_NEIGHBOUR_PASSES: u32 = 100;

/// Largest accepted `max_iterations` (the default is 50; a fit that has not converged in a few
/// hundred Levenberg-Marquardt steps does not converge).
pub const MAX_ITERATIONS: u32 = 1000;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toml_round_trip_and_defaults() {
        let c: FitConfig =
            toml::from_str("model = \"circular\"\nsampling = \"point\"\nsolver = \"lm_crate\"")
                .unwrap();
        assert_eq!(c.model, ModelKind::Circular);
        assert_eq!(c.sampling, FitSampling::Point);
        assert_eq!(c.solver, Solver::LmCrate);
        assert_eq!(c.max_iterations, 50);
        let d: FitConfig = toml::from_str("").unwrap();
        assert_eq!(d, FitConfig::default());
        let back: FitConfig = toml::from_str(&toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
        assert!(toml::from_str::<FitConfig>("modle = \"circular\"").is_err());
        assert!(toml::from_str::<FitConfig>("neighbours = \"maybe\"").is_err());
    }

    #[test]
    fn doc_example_parses_to_defaults() {
        let doc = "model = \"elliptical\"\nsampling = \"auto\"\nestimator = \"lsg\"\nsolver = \"fast\"\n\
                   max_iterations = 50\ntolerance = 0.05\nneighbours = \"subtract\"\nneighbour_passes = 40\n\
                   neighbour_tolerance = 0.1\nresidual_false_alarm = 1e-6\nbound = true\n";
        assert_eq!(
            toml::from_str::<FitConfig>(doc).unwrap(),
            FitConfig::default()
        );
    }

    #[test]
    fn validate_rejects_bad_numbers() {
        assert!(FitConfig::default().validate().is_ok());
        assert!(
            FitConfig {
                max_iterations: 0,
                ..Default::default()
            }
            .validate()
            .is_err()
        );
        assert!(
            FitConfig {
                tolerance: -1.0,
                ..Default::default()
            }
            .validate()
            .is_err()
        );
        assert!(
            FitConfig {
                tolerance: f64::NAN,
                ..Default::default()
            }
            .validate()
            .is_err()
        );
    }
}
