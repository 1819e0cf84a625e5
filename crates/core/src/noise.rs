use serde::{Deserialize, Serialize};

/// Pixel noise that grows with the signal (read + shot noise):
/// `variance(mean) = read_variance + gain · max(mean - offset, 0)`, in counts².
///
/// `gain` is in counts per photo-electron (0 for pure read noise); `offset` is the dark level
/// that carries no shot noise.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoiseModel {
    pub read_variance: f64,
    pub gain: f64,
    pub offset: f64,
}

impl NoiseModel {
    /// Signal-independent Gaussian read noise of standard deviation `sigma`.
    pub fn read(sigma: f64) -> Self {
        NoiseModel {
            read_variance: sigma * sigma,
            gain: 0.0,
            offset: 0.0,
        }
    }
    /// Noise variance at mean intensity `mean` (never below the read variance, never < tiny).
    #[inline]
    pub fn variance(&self, mean: f64) -> f64 {
        (self.read_variance + self.gain * (mean - self.offset).max(0.0)).max(1e-12)
    }
    /// Noise standard deviation at `mean`.
    pub fn sigma(&self, mean: f64) -> f64 {
        self.variance(mean).sqrt()
    }
    /// Whether the variance does not depend on the signal.
    pub fn is_constant(&self) -> bool {
        self.gain == 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variance_grows_with_signal() {
        let n = NoiseModel {
            read_variance: 225.0,
            gain: 0.7,
            offset: 100.0,
        };
        assert_eq!(n.variance(50.0), 225.0);
        assert!((n.variance(1100.0) - 925.0).abs() < 1e-9);
        assert!(NoiseModel::read(3.0).is_constant());
    }
}
