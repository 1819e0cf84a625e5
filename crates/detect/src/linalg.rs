//! Small dense linear algebra: symmetric positive-definite solves for the normal equations.

/// Solve `A x = b` for a symmetric positive-definite `n x n` matrix `a` (row-major, only the
/// lower triangle is read) by Cholesky factorisation, in place: `b` becomes `x`. Returns `false`
/// (leaving `b` unusable) when a pivot is not positive relative to the diagonal scale.
pub(crate) fn solve_spd(a: &mut [f64], b: &mut [f64], n: usize) -> bool {
    debug_assert!(a.len() >= n * n && b.len() >= n);
    let scale = (0..n).map(|k| a[k * n + k].abs()).fold(0.0, f64::max);
    if !scale.is_finite() || scale <= 0.0 {
        return false;
    }
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if d.is_nan() || d <= 1e-13 * scale {
            return false;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i * n + k] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= a[k * n + i] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
    b[..n].iter().all(|v| v.is_finite())
}

/// The workspace's median (finite values only; NaN when none): [`bostrack_core::median`].
pub(crate) use bostrack_core::median;

/// `out[k] = exp(c · (d0 + k)²)` for `k = 0..out.len()` (a sampled Gaussian when `c < 0`), by
/// the recurrence `g(t+1) = g(t)·r(t)`, `r(t+1) = r(t)·q` with `q = exp(2c)` (passed in, so that
/// it is computed once per σ) run outwards from the sample nearest the centre: two `exp` calls
/// instead of one per sample; the relative error stays at a few ulp times the length.
pub(crate) fn gauss_samples(out: &mut [f64], d0: f64, c: f64, q: f64) {
    let n = out.len();
    if n == 0 {
        return;
    }
    let k0 = round_exact(-d0).clamp(0.0, (n - 1) as f64) as usize;
    let t0 = d0 + k0 as f64;
    let g0 = (c * t0 * t0).exp();
    out[k0] = g0;
    // Rightwards: g(t+1)/g(t) = exp(c(2t+1)).
    let rr = (c * (2.0 * t0 + 1.0)).exp();
    let (mut g, mut r) = (g0, rr);
    for v in out[k0 + 1..].iter_mut() {
        g *= r;
        r *= q;
        *v = g;
    }
    // Leftwards: g(t-1)/g(t) = exp(c(1-2t)) = q / exp(c(2t+1)).
    let (mut g, mut r) = (g0, q / rr);
    for v in out[..k0].iter_mut().rev() {
        g *= r;
        r *= q;
        *v = g;
    }
}

/// `f64::round` (half away from zero) without the library call (the baseline x86-64 target
/// has no rounding instruction); exactly equal to it for every input.
#[inline]
pub(crate) fn round_exact(x: f64) -> f64 {
    if x.abs() >= 4.0e15 || x.is_nan() {
        return x.round();
    }
    let t = x as i64 as f64; // truncated, exact
    let frac = x - t; // exact
    let r = if frac >= 0.5 {
        t + 1.0
    } else if frac <= -0.5 {
        t - 1.0
    } else {
        t
    };
    r.copysign(x) // -0.0 for small negative x, as `round`
}

/// Exactly `x.hypot(y) > t`, without libm's `hypot` where the sum of squares decides (nearly
/// always): `x² + y²` rounded is within a few ulp of its value and `hypot` within one ulp of
/// its root, so beyond a relative margin of 1e-12 either side of `t²` the answer is known; at
/// the margin, with a non-finite input, or where the squares may underflow, `hypot` decides.
#[inline]
pub(crate) fn hypot_exceeds(x: f64, y: f64, t: f64) -> bool {
    let (s, t2) = (x * x + y * y, t * t);
    if t > 0.0 && s.is_finite() && t2.is_finite() && t2 >= 1e-280 {
        if s > t2 * (1.0 + 1e-12) {
            return true;
        }
        if s < t2 * (1.0 - 1e-12) {
            return false;
        }
    }
    x.hypot(y) > t
}

/// Round half away from zero without a library call (the baseline x86-64 target has no
/// rounding instruction); exact for |x| < 2^52.
#[inline]
pub(crate) fn round_i64(x: f64) -> i64 {
    if x >= 0.0 {
        (x + 0.5) as i64
    } else {
        -((0.5 - x) as i64)
    }
}

/// `Window::centred` with [`round_i64`]: the `(2·half+1)²` window centred on the pixel nearest
/// to `(cx, cy)`.
#[inline]
pub(crate) fn window_centred(cx: f64, cy: f64, half: usize) -> bostrack_core::Window {
    let side = 2 * half + 1;
    bostrack_core::Window::new(
        round_i64(cx) - half as i64,
        round_i64(cy) - half as i64,
        side,
        side,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_samples_match_exp() {
        let mut g = [0.0; 13];
        for (d0, c) in [(-6.3, -0.4), (0.2, -2.0), (-20.0, -0.05), (3.0, -1.0)] {
            gauss_samples(&mut g, d0, c, (2.0 * c).exp());
            for (k, v) in g.iter().enumerate() {
                let t = d0 + k as f64;
                let want = (c * t * t).exp();
                assert!(
                    (v - want).abs() <= 1e-12 * want.max(1e-300) + 1e-300,
                    "{d0} {c} {k}: {v} vs {want}"
                );
            }
        }
        for x in [
            0.5,
            -0.5,
            1.5,
            2.5,
            -2.5,
            0.49999999999999994,
            -0.49999999999999994,
            4503599627370495.5,
            -7.3,
            1e300,
            -0.0,
            f64::INFINITY,
        ] {
            assert_eq!(round_exact(x).to_bits(), x.round().to_bits(), "{x}");
        }
        assert!(round_exact(f64::NAN).is_nan());
        assert_eq!(round_i64(2.5), 3);
        assert_eq!(round_i64(-2.5), -3);
        assert_eq!(round_i64(-0.4), 0);
        assert_eq!(round_i64(7.49), 7);
    }

    #[test]
    fn hypot_exceeds_is_hypots_comparison() {
        // a deterministic spread of lengths and thresholds, the thresholds also at the length
        // itself and one ulp either side, plus the special values
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let special = [
            0.0,
            -0.0,
            1e-320,
            1e-160,
            1e160,
            1e300,
            f64::MAX,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        let mut cases = Vec::new();
        for _ in 0..20_000 {
            let scale = 10f64.powf(12.0 * next() - 6.0);
            let (x, y) = ((next() - 0.5) * scale, (next() - 0.5) * scale);
            let h = x.hypot(y);
            for t in [h, h.next_up(), h.next_down(), scale * next(), 0.1 * h, -h] {
                cases.push((x, y, t));
            }
        }
        for &a in &special {
            for &b in &special {
                for t in [
                    0.0,
                    -0.0,
                    -0.8,
                    1e-150,
                    0.8,
                    2.0,
                    1e300,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::NAN,
                ] {
                    cases.push((a, b, t));
                    cases.push((a, 0.8, t));
                }
            }
        }
        for (x, y, t) in cases {
            assert_eq!(hypot_exceeds(x, y, t), x.hypot(y) > t, "{x:e} {y:e} {t:e}");
        }
    }

    #[test]
    fn solves_a_known_system() {
        // A = [[4, 2, 0], [2, 5, 1], [0, 1, 3]], x = [1, -2, 3] -> b = A x.
        let mut a = vec![4.0, 2.0, 0.0, 2.0, 5.0, 1.0, 0.0, 1.0, 3.0];
        let mut b = vec![0.0, -5.0, 7.0];
        assert!(solve_spd(&mut a, &mut b, 3));
        for (x, t) in b.iter().zip([1.0, -2.0, 3.0]) {
            assert!((x - t).abs() < 1e-12, "{b:?}");
        }
        let mut singular = vec![1.0, 1.0, 1.0, 1.0];
        assert!(!solve_spd(&mut singular, &mut [1.0, 2.0], 2));
    }
}
