//! The one median of the workspace.

/// Median of the **finite** values of `v`: NaN and ±∞ are left out (the slice is reordered in
/// place, the finite values first); NaN when no finite value is left. For an even count, the
/// mean of the two middle values.
///
/// Equal to the middle of a stably sorted copy of the finite values, bit for bit for up to 24 of
/// them (zeros of either sign included); above that, equal in value (the sign of a zero median
/// may differ). Short slices, the neighbourhoods of the detection and matching stages, take a
/// sorting network (up to 8 values) or an insertion sort (up to 24); longer ones a selection.
///
/// ```
/// use bostrack_core::median;
/// assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
/// assert_eq!(median(&mut [4.0, f64::NAN, 1.0, 3.0, f64::INFINITY, 2.0]), 2.5);
/// assert!(median(&mut [f64::NAN]).is_nan());
/// ```
pub fn median(v: &mut [f64]) -> f64 {
    if v.len() <= 8
        && let Some(m) = median8(v)
    {
        return m;
    }
    // the finite values to the front
    let mut n = 0;
    for k in 0..v.len() {
        if v[k].is_finite() {
            v.swap(n, k);
            n += 1;
        }
    }
    let v = &mut v[..n];
    if n == 0 {
        return f64::NAN;
    }
    if n <= 24 {
        // Insertion sort (stable): cheaper than selection for short slices.
        for k in 1..n {
            let x = v[k];
            let mut m = k;
            while m > 0 && v[m - 1] > x {
                v[m] = v[m - 1];
                m -= 1;
            }
            v[m] = x;
        }
        return if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
    }
    let mid = n / 2;
    let (_, &mut m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    if n % 2 == 1 {
        m
    } else {
        let lo = v[..mid].iter().copied().fold(f64::NEG_INFINITY, f64::max);
        0.5 * (lo + m)
    }
}

/// The 19-comparator sorting network for 8 values (used by [`median8`]), on eight locals: a
/// loop over a table of its pairs kept the values in memory (~16 instructions per comparator,
/// 10 % of a real gradient frame's instructions went to medians).
#[inline(always)]
fn sort8<T: Ord + Copy>(s: [T; 8]) -> [T; 8] {
    let [
        mut s0,
        mut s1,
        mut s2,
        mut s3,
        mut s4,
        mut s5,
        mut s6,
        mut s7,
    ] = s;
    macro_rules! cx {
        ($a:ident, $b:ident) => {
            let (lo, hi) = ($a.min($b), $a.max($b));
            $a = lo;
            $b = hi;
        };
    }
    cx!(s0, s1);
    cx!(s2, s3);
    cx!(s4, s5);
    cx!(s6, s7);
    cx!(s0, s2);
    cx!(s1, s3);
    cx!(s4, s6);
    cx!(s5, s7);
    cx!(s1, s2);
    cx!(s5, s6);
    cx!(s0, s4);
    cx!(s3, s7);
    cx!(s1, s5);
    cx!(s2, s6);
    cx!(s1, s4);
    cx!(s3, s6);
    cx!(s2, s4);
    cx!(s3, s5);
    cx!(s3, s4);
    [s0, s1, s2, s3, s4, s5, s6, s7]
}

/// Median of 1 to 8 values by a branch-free sorting network (padded with values above all
/// others), or `None` when there is none or a value is zero or not finite. Without zeros (whose
/// sign a sort may order either way) and non-finite values, equal values are identical, so every
/// sort gives the same sorted sequence and this median is exactly that of the insertion sort.
/// The slice is not reordered.
#[inline]
fn median8(v: &[f64]) -> Option<f64> {
    let n = v.len();
    if n == 0 {
        return None;
    }
    // Finite non-zero values as integers of the same order (the bits of a positive value;
    // those of a negative one with the magnitude bits flipped): the network then runs on
    // integer `min`/`max`, which compile to conditional moves.
    // (eight values whatever `n`, the padding the largest finite value, as large as any key:
    // a loop of fixed length the compiler unrolls and vectorises)
    let mut x = [f64::MAX; 8];
    x[..n.min(8)].copy_from_slice(&v[..n.min(8)]);
    let s: [i64; 8] = std::array::from_fn(|k| {
        let b = x[k].to_bits() as i64;
        b ^ ((b >> 63) & i64::MAX)
    });
    // Finite and non-zero: the magnitude bits lie in 1..=the largest finite value.
    let bad = x
        .iter()
        .map(|x| usize::from((x.to_bits() & (u64::MAX >> 1)).wrapping_sub(1) >= f64::MAX.to_bits()))
        .sum::<usize>();
    if bad > 0 {
        return None;
    }
    let s = sort8(s);
    let val = |k: i64| f64::from_bits((k ^ ((k >> 63) & i64::MAX)) as u64);
    Some(if n % 2 == 1 {
        val(s[n / 2])
    } else {
        0.5 * (val(s[n / 2 - 1]) + val(s[n / 2]))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The middle of a stably sorted copy of the finite values (NaN when none).
    fn by_sorting(v: &[f64]) -> f64 {
        let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        s.sort_by(|a, b| a.partial_cmp(b).unwrap()); // stable
        let n = s.len();
        match n {
            0 => f64::NAN,
            n if n % 2 == 1 => s[n / 2],
            n => 0.5 * (s[n / 2 - 1] + s[n / 2]),
        }
    }

    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(&mut []).is_nan());
    }

    #[test]
    fn non_finite_values_are_left_out() {
        let (nan, inf) = (f64::NAN, f64::INFINITY);
        assert_eq!(median(&mut [3.0, nan, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [nan, 1.0, -inf, 4.0, inf]), 2.5);
        assert!(median(&mut [nan, inf, -inf]).is_nan());
        // the long (selection) path too: 30 finite values among NaNs and infinities
        let mut v: Vec<f64> = (0..40)
            .map(|k| match k % 4 {
                0 if k < 20 => nan,
                0 => -inf,
                _ => k as f64,
            })
            .collect();
        let want = by_sorting(&v);
        assert_eq!(median(&mut v), want);
        assert!(v[..30].iter().all(|x| x.is_finite()));
    }

    /// The median equals the middle of a stably sorted copy of the finite values, ties and zero
    /// signs included, bit for bit up to 24 values; NaN and infinities mixed in change nothing.
    #[test]
    fn median_matches_sorting() {
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            state >> 33
        };
        for n in 1..=40 {
            for _ in 0..300 {
                // Few distinct values, so that ties (and -0.0 next to 0.0) are common.
                let v: Vec<f64> = (0..n)
                    .map(|_| match next() % 9 {
                        0 => 0.0,
                        1 => -0.0,
                        2 => 1e300,
                        3 if n % 3 == 0 => f64::NAN,
                        4 if n % 5 == 0 => f64::NEG_INFINITY,
                        k => (k as f64 - 3.0) * 0.25 + (next() % 3) as f64,
                    })
                    .collect();
                let want = by_sorting(&v);
                let got = median(&mut v.clone());
                let finite = v.iter().filter(|x| x.is_finite()).count();
                if finite == 0 {
                    assert!(got.is_nan(), "{v:?}");
                } else if finite <= 24 {
                    assert_eq!(got.to_bits(), want.to_bits(), "{v:?}: {got} vs {want}");
                } else {
                    assert_eq!(got, want, "{v:?}");
                }
            }
        }
        // The network sorts every 0-1 input (the 0-1 principle: then it sorts any input).
        for bits in 0u32..256 {
            let s = sort8(std::array::from_fn(|k| (bits >> k) & 1));
            assert!(s.windows(2).all(|w| w[0] <= w[1]), "{bits:08b}");
        }
    }
}
