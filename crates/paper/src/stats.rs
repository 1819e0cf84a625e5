//! Small statistics helpers.

/// Running mean and variance (Welford), numerically stable in one pass.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Running {
    n: usize,
    mean: f64,
    m2: f64,
}

impl Running {
    pub(crate) fn push(&mut self, v: f64) {
        self.n += 1;
        let d = v - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d * (v - self.mean);
    }
    pub(crate) fn count(&self) -> usize {
        self.n
    }
    /// Mean (NaN when empty).
    pub(crate) fn mean(&self) -> f64 {
        if self.n == 0 { f64::NAN } else { self.mean }
    }
    /// Sample standard deviation (n − 1; NaN below two values).
    pub(crate) fn std(&self) -> f64 {
        if self.n < 2 {
            f64::NAN
        } else {
            (self.m2 / (self.n - 1) as f64).sqrt()
        }
    }
}

/// Median of the finite values (NaN if none): [`bostrack_core::median`].
pub(crate) fn median(values: impl IntoIterator<Item = f64>) -> f64 {
    bostrack_core::median(&mut values.into_iter().collect::<Vec<f64>>())
}

/// Mean and standard error of the mean of the finite values (NaN if fewer than two).
pub(crate) fn mean_se(values: impl IntoIterator<Item = f64>) -> (f64, f64) {
    let mut r = Running::default();
    for v in values.into_iter().filter(|x| x.is_finite()) {
        r.push(v);
    }
    (r.mean(), r.std() / (r.count() as f64).sqrt())
}

/// Minimum and maximum of the finite values (NaN if none).
pub(crate) fn min_max(values: impl IntoIterator<Item = f64>) -> (f64, f64) {
    values
        .into_iter()
        .filter(|x| x.is_finite())
        .fold((f64::NAN, f64::NAN), |(lo, hi), v| {
            (
                if lo.is_nan() { v } else { lo.min(v) },
                if hi.is_nan() { v } else { hi.max(v) },
            )
        })
}

/// SplitMix64 of a seed and a stream index: independent, reproducible seeds for each draw,
/// whatever order the draws run in.
pub(crate) fn mix(seed: u64, index: u64) -> u64 {
    let mut z = seed
        ^ index
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(0x632B_E59B_D9B4_E019);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn running_matches_two_pass() {
        let v = [1.0, 4.0, 2.5, -3.0, 7.25, 0.5];
        let mut r = Running::default();
        v.iter().for_each(|&x| r.push(x));
        let m = v.iter().sum::<f64>() / 6.0;
        let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / 5.0;
        assert!((r.mean() - m).abs() < 1e-14 && (r.std() - var.sqrt()).abs() < 1e-14);
        assert!(Running::default().std().is_nan());
    }

    #[test]
    fn median_and_extremes() {
        assert_eq!(median([3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median([4.0, 1.0, f64::NAN, 2.0, 3.0]), 2.5);
        assert!(median([f64::NAN]).is_nan());
        assert_eq!(min_max([2.0, f64::NAN, -1.0, 5.0]), (-1.0, 5.0));
        let (m, se) = mean_se([1.0, 3.0]);
        assert_eq!(m, 2.0);
        assert!((se - 1.0).abs() < 1e-15);
    }

    #[test]
    fn mix_separates_streams() {
        assert_ne!(mix(1, 0), mix(1, 1));
        assert_ne!(mix(1, 0), mix(2, 0));
        assert_eq!(mix(7, 3), mix(7, 3));
    }
}
