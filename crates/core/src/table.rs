//! The one convention of every table (CSV) bostrack writes.

/// Decimals of every floating-point cell (fixed-point, so that outputs are deterministic and
/// compare as text).
pub const DECIMALS: usize = 6;

/// A floating-point cell: fixed-point with [`DECIMALS`] decimals; an **unknown** value (NaN or
/// ±∞: not fitted, not estimated, not defined) is the **empty field**, never `NaN`.
///
/// ```
/// use bostrack_core::table::number;
/// assert_eq!(number(1.5), "1.500000");
/// assert_eq!(number(f64::NAN), "");
/// assert_eq!(number(f64::INFINITY), "");
/// ```
pub fn number(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.DECIMALS$}")
    } else {
        String::new()
    }
}

/// [`number`] of a value that may be absent (`None`: the empty field).
pub fn optional(v: Option<f64>) -> String {
    v.map_or_else(String::new, number)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_values_are_empty_fields() {
        assert_eq!(number(-0.25), "-0.250000");
        assert_eq!(number(1e-7), "0.000000");
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(number(v), "");
            assert_eq!(optional(Some(v)), "");
        }
        assert_eq!(optional(None), "");
        assert_eq!(optional(Some(2.0)), "2.000000");
    }
}
