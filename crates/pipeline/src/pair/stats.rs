//! Small statistics and timing helpers of the pair pipeline.

use std::time::Instant;

/// Median of the finite values ([`bostrack_core::median`]); `None` when there is none.
pub(crate) fn median(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    median_of(&mut collected(values))
}

/// [`median`] of the values of `v` (reordered).
pub(crate) fn median_of(v: &mut [f64]) -> Option<f64> {
    let m = bostrack_core::median(v);
    (!m.is_nan()).then_some(m)
}

/// The values in a vector sized for the most the iterator says it may give (a filtered column
/// of a frame's dots: collected without growing by copies).
fn collected(values: impl IntoIterator<Item = f64>) -> Vec<f64> {
    let it = values.into_iter();
    let (lo, hi) = it.size_hint();
    let mut v = Vec::with_capacity(hi.unwrap_or(lo));
    v.extend(it);
    v
}

/// Percentile `p` ∈ [0, 100] of the finite values, linear interpolation between order
/// statistics (position `p/100 · (n - 1)`); `None` when there is none.
#[cfg(test)]
pub(crate) fn percentile(values: impl IntoIterator<Item = f64>, p: f64) -> Option<f64> {
    percentile_of(&mut collected(values), p)
}

/// [`percentile`] of the values of `v` (its non-finite values dropped, the rest reordered).
pub(crate) fn percentile_of(v: &mut Vec<f64>, p: f64) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    let pos = (p / 100.0).clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let lo = pos.floor() as usize;
    // the two order statistics by selection (those of the sorted values: the same numbers)
    let (_, &mut at_lo, above) = v.select_nth_unstable_by(lo, f64::total_cmp);
    let at_hi = above
        .iter()
        .copied()
        .min_by(f64::total_cmp)
        .unwrap_or(at_lo);
    Some(at_lo + (pos - lo as f64) * (at_hi - at_lo))
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

    /// The selection gives the interpolation of the sorted values, bit for bit (ties, signed
    /// zeros and non-finite values included).
    #[test]
    fn percentile_is_that_of_the_sorted_values() {
        let sorted_percentile = |values: &[f64], p: f64| {
            let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
            if v.is_empty() {
                return None;
            }
            v.sort_by(f64::total_cmp);
            let pos = (p / 100.0).clamp(0.0, 1.0) * (v.len() - 1) as f64;
            let lo = pos.floor() as usize;
            let hi = (lo + 1).min(v.len() - 1);
            Some(v[lo] + (pos - lo as f64) * (v[hi] - v[lo]))
        };
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for n in [1usize, 2, 3, 7, 100, 1001, 12_236] {
            let values: Vec<f64> = (0..n)
                .map(|_| match next() % 16 {
                    0 => 0.0,
                    1 => -0.0,
                    2 => f64::NAN,
                    3 => f64::INFINITY,
                    4 => 1.25,
                    _ => (next() >> 11) as f64 / (1u64 << 53) as f64 * 4.0 - 1.0,
                })
                .collect();
            for p in [0.0, 1.0, 50.0, 99.0, 99.9, 100.0] {
                let got = percentile(values.iter().copied(), p);
                let want = sorted_percentile(&values, p);
                assert_eq!(
                    got.map(f64::to_bits),
                    want.map(f64::to_bits),
                    "n {n}, p {p}"
                );
            }
        }
    }
}
