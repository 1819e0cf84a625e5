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
    let mut s = String::with_capacity(16);
    write_number(&mut s, v);
    s
}

/// Appends [`number`]`(v)` to `out`: exactly the text of `format!("{v:.6}")` (the exact decimal
/// value of `v` rounded half to even at the sixth decimal, `-` on every negative value and on
/// -0), by integer arithmetic instead of `core::fmt`'s general float machinery, which took most
/// of the time of writing a table (issue 17). `v = m · 2^e` exactly, so `round(v · 10⁶)` is
/// `m · 10⁶` (< 2^73) shifted by `e` with the remainder compared to one half, in `u128`; values
/// of 2^103 and more (never a pixel quantity) go through `format!`. No crate does this exactly:
/// `ryu` writes the shortest round-trip form, not a fixed number of decimals.
pub fn write_number(out: &mut String, v: f64) {
    const SCALE: u128 = 1_000_000; // 10^DECIMALS
    if !v.is_finite() {
        return;
    }
    let bits = v.to_bits();
    let biased = ((bits >> 52) & 0x7ff) as i32;
    let fraction = u128::from(bits & ((1u64 << 52) - 1));
    let (m, e) = if biased == 0 {
        (fraction, -1074)
    } else {
        (fraction | (1u128 << 52), biased - 1075)
    };
    let q: u128 = if e >= 0 {
        if e > 50 {
            use std::fmt::Write as _;
            let _ = write!(out, "{v:.DECIMALS$}");
            return;
        }
        (m * SCALE) << e
    } else if e <= -74 {
        0 // m · 10⁶ < 2^73 ≤ half of 2^-e: below one half of the last decimal
    } else {
        let n = m * SCALE;
        let s = (-e) as u32;
        let (q, r, half) = (n >> s, n & ((1u128 << s) - 1), 1u128 << (s - 1));
        q + u128::from(r > half || (r == half && q & 1 == 1))
    };
    if bits >> 63 == 1 {
        out.push('-');
    }
    let mut buf = itoa::Buffer::new();
    // u64 arithmetic below 1.8e13 (every pixel quantity; u128 division is a library call)
    let frac = match u64::try_from(q) {
        Ok(q) => {
            out.push_str(buf.format(q / 1_000_000));
            (q % 1_000_000) as u32
        }
        Err(_) => {
            out.push_str(buf.format(q / SCALE));
            (q % SCALE) as u32
        }
    };
    out.push('.');
    out.push_str(&buf.format(frac + 1_000_000)[1..]); // the six digits, zero-padded
}

/// [`number`] of a value that may be absent (`None`: the empty field).
pub fn optional(v: Option<f64>) -> String {
    v.map_or_else(String::new, number)
}

/// Significant digits of a cell in SI units ([`scientific`]).
pub const SIGNIFICANT: usize = 7;

/// A floating-point cell in SI units (metres, kg/m³, kg/m⁴: the density's columns): scientific
/// notation with [`SIGNIFICANT`] significant digits, `format!("{v:.6e}")` (`1.204000e0`,
/// `-8.123457e-5`), so that small values keep their digits (fixed decimals would give a u_ρ of
/// 1e-4 kg/m³ two of them); unknown values (NaN, ±∞) are the empty field as in [`number`].
///
/// ```
/// use bostrack_core::table::scientific;
/// assert_eq!(scientific(1.204), "1.204000e0");
/// assert_eq!(scientific(-1.23456789e-5), "-1.234568e-5");
/// assert_eq!(scientific(f64::NAN), "");
/// assert_eq!("1.234568e-5".parse::<f64>().unwrap(), 1.234568e-5);
/// ```
pub fn scientific(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.prec$e}", prec = SIGNIFICANT - 1)
    } else {
        String::new()
    }
}

/// [`scientific`] of a value that may be absent (`None`: the empty field).
pub fn optional_scientific(v: Option<f64>) -> String {
    v.map_or_else(String::new, scientific)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fast path against `core::fmt` on every kind of value: ties at the sixth decimal
    /// (multiples of 2^-7 .. 2^-20), values that round to zero (negative ones keep their `-`),
    /// subnormals, the largest values and random bit patterns.
    #[test]
    fn numbers_are_exactly_those_of_format() {
        let check = |v: f64| assert_eq!(number(v), format!("{v:.6}"), "{v:e}");
        for v in [
            0.0,
            -0.0,
            1e-7,
            -1e-7,
            5e-7,
            -5e-7,
            4.9999999e-7,
            0.5,
            1.5,
            2.5,
            1e15,
            -1e15,
        ] {
            check(v);
        }
        for k in 7..=20 {
            for n in -300i32..300 {
                check(f64::from(n) / f64::from(1u32 << k));
            }
        }
        for v in [
            f64::MIN_POSITIVE,
            5e-324,
            -5e-324,
            f64::MAX,
            f64::MIN,
            2f64.powi(102),
            2f64.powi(103),
            2f64.powi(104),
        ] {
            check(v);
        }
    }

    proptest::proptest! {
        #[test]
        fn random_numbers_are_exactly_those_of_format(bits in proptest::prelude::any::<u64>(), scale in -30i32..30) {
            let v = f64::from_bits(bits);
            if v.is_finite() {
                proptest::prop_assert_eq!(number(v), format!("{v:.6}"));
                let w = (v.abs().log2().clamp(-60.0, 60.0).fract() + f64::from(scale)).exp2();
                proptest::prop_assert_eq!(number(w), format!("{w:.6}"));
                proptest::prop_assert_eq!(number(-w), format!("{:.6}", -w));
            }
        }
    }

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
