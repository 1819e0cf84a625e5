//! Small statistics and timing helpers of the pair pipeline.

use std::time::Instant;

/// Median of the finite values ([`bostrack_core::median`]); `None` when there is none.
pub(crate) fn median(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    let m = bostrack_core::median(&mut values.into_iter().collect::<Vec<f64>>());
    (!m.is_nan()).then_some(m)
}

/// Percentile `p` ∈ [0, 100] of the finite values, linear interpolation between order
/// statistics (position `p/100 · (n - 1)`); `None` when there is none.
pub(crate) fn percentile(values: impl IntoIterator<Item = f64>, p: f64) -> Option<f64> {
    let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let pos = (p / 100.0).clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(v.len() - 1);
    Some(v[lo] + (pos - lo as f64) * (v[hi] - v[lo]))
}

/// Per-axis median of `[x, y]` values.
pub(crate) fn median2(values: impl Iterator<Item = [f64; 2]> + Clone) -> [Option<f64>; 2] {
    [
        median(values.clone().map(|v| v[0])),
        median(values.map(|v| v[1])),
    ]
}

/// Wall-clock stopwatch for stage times.
pub(crate) struct Stopwatch(Instant);

impl Stopwatch {
    pub(crate) fn start() -> Self {
        Stopwatch(Instant::now())
    }
    /// Seconds since the start (or the last lap), and restart.
    pub(crate) fn lap(&mut self) -> f64 {
        let now = Instant::now();
        let s = now.duration_since(self.0).as_secs_f64();
        self.0 = now;
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_percentile_of_known_sets() {
        assert_eq!(median([3.0, 1.0, f64::NAN, 2.0]), Some(2.0));
        assert_eq!(median([4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median([f64::NAN]), None);
        let v: Vec<f64> = (0..=100).map(f64::from).collect();
        assert_eq!(percentile(v.iter().copied(), 99.0), Some(99.0));
        assert_eq!(percentile([1.0, 2.0], 50.0), Some(1.5));
        assert_eq!(percentile([], 50.0), None);
    }
}
