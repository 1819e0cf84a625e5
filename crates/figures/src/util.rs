//! Small numerical helpers: percentiles, "nice" numbers, tick formatting.

/// Finite values of `v`, sorted ascending.
pub(crate) fn sorted_finite(v: impl IntoIterator<Item = f64>) -> Vec<f64> {
    let mut s: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
    s.sort_by(f64::total_cmp);
    s
}

/// Percentile `p` (0–100) of sorted data by linear interpolation between order statistics
/// (the "linear" definition: rank `p/100 · (n-1)`). `None` for empty data.
pub(crate) fn percentile(sorted: &[f64], p: f64) -> Option<f64> {
    let n = sorted.len();
    if n == 0 {
        return None;
    }
    let r = (p / 100.0).clamp(0.0, 1.0) * (n - 1) as f64;
    let i = r.floor() as usize;
    let f = r - i as f64;
    if i + 1 < n {
        Some(sorted[i] + f * (sorted[i + 1] - sorted[i]))
    } else {
        Some(sorted[n - 1])
    }
}

/// The largest number of the form {1, 2, 5}·10^k that is ≤ `v` (v > 0, finite).
pub(crate) fn nice_floor(v: f64) -> f64 {
    if !(v.is_finite() && v > 0.0) {
        return 1.0;
    }
    let e = v.log10().floor();
    let base = 10f64.powf(e);
    let m = v / base;
    let nm = if m >= 5.0 {
        5.0
    } else if m >= 2.0 {
        2.0
    } else {
        1.0
    };
    nm * base
}

/// Makes `(lo, hi)` a usable non-empty axis range: a zero range is widened by 10 % of the value
/// (or ±0.5 around 0).
pub(crate) fn widen_zero_range(lo: f64, hi: f64) -> (f64, f64) {
    if hi > lo {
        (lo, hi)
    } else {
        let pad = if lo.abs() > 0.0 { 0.1 * lo.abs() } else { 0.5 };
        (lo - pad, hi + pad)
    }
}

/// Number of decimals for the tick labels plotters puts on a linear axis `lo..hi` with at
/// most `n` labels: its ticks are multiples of a step 1, 2 or 5 × 10^k, and the step sets the
/// decimals (0.02 → 2, 0.5 → 1, 5 → 0).
pub(crate) fn tick_decimals(lo: f64, hi: f64, n: usize) -> usize {
    use plotters::coord::ranged1d::Ranged;
    use plotters::coord::types::RangedCoordf64;
    if !(lo.is_finite() && hi.is_finite()) || lo == hi {
        return 2;
    }
    let kp = RangedCoordf64::from(lo.min(hi)..lo.max(hi)).key_points(n);
    let step = match kp.as_slice() {
        [a, b, ..] => (b - a).abs(),
        _ => (hi - lo).abs() / n.max(1) as f64,
    };
    if step.is_finite() && step > 0.0 {
        (-step.log10() - 1e-9).ceil().clamp(0.0, 8.0) as usize
    } else {
        2
    }
}

/// Formats a tick value with a fixed number of decimals, switching to scientific notation
/// for very large or very small magnitudes.
pub(crate) fn fmt_fixed(v: f64, decimals: usize) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-4..1e6).contains(&a) {
        return fmt_sci(v);
    }
    let s = format!("{v:.decimals$}");
    // avoid "-0.00"
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// Formats a number compactly: up to 4 significant digits, trailing zeros removed,
/// scientific for very large or very small magnitudes.
pub(crate) fn fmt_num(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if a == 0.0 {
        return "0".to_string();
    }
    if !(1e-3..1e5).contains(&a) {
        return fmt_sci(v);
    }
    let digits = (3 - a.log10().floor() as i32).clamp(0, 8) as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn fmt_sci(v: f64) -> String {
    let s = format!("{v:.2e}");
    // "1.00e-5" -> "1e-5", "2.50e6" -> "2.5e6"
    match s.split_once('e') {
        Some((m, e)) => {
            let m = if m.contains('.') {
                m.trim_end_matches('0').trim_end_matches('.')
            } else {
                m
            };
            format!("{m}e{e}")
        }
        None => s,
    }
}

/// Thousands separated by a thin space, for counts in legends ("12 034").
pub(crate) fn fmt_count(n: usize) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push('\u{2009}');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_matches_linear_definition() {
        let s: Vec<f64> = (0..=100).map(f64::from).collect();
        assert_eq!(percentile(&s, 1.0), Some(1.0));
        assert_eq!(percentile(&s, 99.0), Some(99.0));
        assert_eq!(percentile(&[1.0, 3.0], 50.0), Some(2.0));
        assert_eq!(percentile(&[], 50.0), None);
    }

    #[test]
    fn nice_floor_picks_1_2_5() {
        assert_eq!(nice_floor(7.3), 5.0);
        assert_eq!(nice_floor(19.0), 10.0);
        assert_eq!(nice_floor(0.031), 0.02);
        assert_eq!(nice_floor(0.0), 1.0);
    }

    #[test]
    fn number_formats() {
        assert_eq!(fmt_num(0.0213), "0.0213");
        assert_eq!(fmt_num(12.5), "12.5");
        assert_eq!(fmt_num(2e-5), "2e-5");
        assert_eq!(fmt_fixed(-0.0001, 2), "0.00");
        assert_eq!(fmt_fixed(0.25, 2), "0.25");
        assert_eq!(fmt_count(12034), "12\u{2009}034");
        assert_eq!(tick_decimals(0.0, 1.0, 6), 1);
        assert_eq!(tick_decimals(0.0, 1000.0, 6), 0);
        assert_eq!(tick_decimals(0.011, 0.057, 7), 2);
    }
}
