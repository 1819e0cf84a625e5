//! What the user knows of the target, and the few tuning knobs (serde, unknown keys rejected).

use crate::DetectError;
use serde::{Deserialize, Serialize};

/// Lattice type of the target.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LatticeKind {
    /// Square grid \[default\]: `b` is `a` turned by about +90° (towards +y).
    #[default]
    Square,
    /// Hexagonal grid: `b` is `a` turned by about +60° (towards +y), as
    /// [`bostrack_core::Lattice::hexagonal`].
    Hexagonal,
}

/// Dot polarity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    /// Bright dots on a dark background \[default\].
    #[default]
    Bright,
    /// Dark dots on a bright background: the image is negated before detection (every
    /// threshold works on differences, so no offset is needed).
    Dark,
}

impl Polarity {
    /// +1 for bright dots, -1 for dark ones: detection works on `sign · I`.
    pub(crate) fn sign(self) -> f64 {
        match self {
            Polarity::Bright => 1.0,
            Polarity::Dark => -1.0,
        }
    }
}

/// Configuration of [`crate::detect`] and [`crate::track`]. Every field has a default (in
/// brackets); as TOML (e.g. the `[detect]` table of `pipeline.toml`):
///
/// ```toml
/// spacing = 8.0          # approximate dot pitch, px [estimated from the image]
/// diameter = 6.5         # approximate dot diameter 4σ, px [estimated from the image]
/// lattice = "square"     # or "hexagonal"
/// polarity = "bright"    # or "dark"
/// min_snr = 4.0
/// missing_ratio = 0.1
/// faint_ratio = 0.5
/// map_degree = 3
/// # window_half_width = 4   [automatic, see below]
/// search_radius = 0.45
/// ```
///
/// The hints are priors, not constraints: the lattice is always measured from the image (the
/// shortest clear peak of the image's autocorrelation). A spacing hint only sizes the analysed
/// crop, and [`crate::DetectStats::spacing_hint_ratio`] reports measured / hint. A diameter
/// hint replaces the autocorrelation's estimate in the choice of the band-pass filter; the dot
/// size used afterwards (template, centroid) is measured on the located dots whenever at least
/// five well-surrounded dots allow it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectConfig {
    /// Approximate dot spacing (nearest-neighbour distance), px \[None: estimated\].
    pub spacing: Option<f64>,
    /// Approximate dot diameter d = 4σ, px \[None: estimated\].
    pub diameter: Option<f64>,
    /// Square or hexagonal lattice \[square\]. The measured basis angle must agree within 15°.
    pub lattice: LatticeKind,
    /// Bright dots on dark or dark dots on bright \[bright\].
    pub polarity: Polarity,
    /// A site counts as a dot only if its matched-filter statistic reaches `min_snr` times the
    /// statistic's spread where there is no dot, i.e. a signal-to-noise ratio \[4.0\] (see the
    /// crate documentation, step 5) ...
    pub min_snr: f64,
    /// ... and its amplitude `missing_ratio` times its neighbours' median \[0.1\]; otherwise the
    /// site is MISSING.
    pub missing_ratio: f64,
    /// A found dot below `faint_ratio` times its neighbours' median amplitude is FAINT \[0.5\].
    pub faint_ratio: f64,
    /// Total degree of the polynomial grid → image map, 1 (affine) to 4 \[3\]; lowered
    /// automatically when too few dots support it.
    pub map_degree: u8,
    /// Half-width of the square fit window, px [None: `max(2, min(round(spacing/2), ceil(1.5 d)))`,
    /// i.e. the dot's Voronoi cell on a square lattice, smaller for small dots].
    pub window_half_width: Option<usize>,
    /// [`crate::track`]: radius, as a fraction of the spacing, within which a dot is searched
    /// around its reference position without a predictor \[0.45\]; must lie in (0, 0.5].
    pub search_radius: f64,
}

/// Accepted `spacing` (px): dots closer than 2 px are not resolved, and a spacing above 1024 px
/// leaves a handful of dots in the largest image.
pub const SPACING_RANGE: std::ops::RangeInclusive<f64> = 2.0..=1024.0;

/// Accepted `diameter` d = 4σ (px).
pub const DIAMETER_RANGE: std::ops::RangeInclusive<f64> = 0.5..=256.0;

impl Default for DetectConfig {
    fn default() -> Self {
        DetectConfig {
            spacing: None,
            diameter: None,
            lattice: LatticeKind::Square,
            polarity: Polarity::Bright,
            min_snr: 4.0,
            missing_ratio: 0.1,
            faint_ratio: 0.5,
            map_degree: 3,
            window_half_width: None,
            search_radius: 0.45,
        }
    }
}

fn invalid(field: &'static str, problem: String) -> DetectError {
    DetectError::InvalidConfig { field, problem }
}

impl DetectConfig {
    /// Check every value; the error names the offending field.
    pub fn validate(&self) -> Result<(), DetectError> {
        // both scale the work: the number of lattice sites, the matched filter's size
        for (field, v, range) in [
            ("spacing", self.spacing, SPACING_RANGE),
            ("diameter", self.diameter, DIAMETER_RANGE),
        ] {
            if let Some(v) = v
                && !range.contains(&v)
            {
                return Err(invalid(
                    field,
                    format!(
                        "must lie in [{}, {}] px, got {v}",
                        range.start(),
                        range.end()
                    ),
                ));
            }
        }
        if !(self.min_snr.is_finite() && self.min_snr > 0.0) {
            return Err(invalid(
                "min_snr",
                format!("must be finite and > 0, got {}", self.min_snr),
            ));
        }
        if !(self.missing_ratio >= 0.0 && self.missing_ratio < 1.0) {
            return Err(invalid(
                "missing_ratio",
                format!("must lie in [0, 1), got {}", self.missing_ratio),
            ));
        }
        if !(self.faint_ratio >= self.missing_ratio && self.faint_ratio <= 1.0) {
            return Err(invalid(
                "faint_ratio",
                format!(
                    "must lie in [missing_ratio, 1], got {} (missing_ratio {})",
                    self.faint_ratio, self.missing_ratio
                ),
            ));
        }
        if !(1..=4).contains(&self.map_degree) {
            return Err(invalid(
                "map_degree",
                format!("must be 1 to 4, got {}", self.map_degree),
            ));
        }
        if let Some(h) = self.window_half_width
            && !(1..=256).contains(&h)
        {
            return Err(invalid(
                "window_half_width",
                format!("must be 1 to 256, got {h}"),
            ));
        }
        if !(self.search_radius > 0.0 && self.search_radius <= 0.5) {
            return Err(invalid(
                "search_radius",
                format!("must lie in (0, 0.5], got {}", self.search_radius),
            ));
        }
        Ok(())
    }
}
