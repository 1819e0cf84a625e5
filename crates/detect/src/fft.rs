//! A small radix-2 complex FFT (iterative Cooley-Tukey) and its 2-D form, enough for the
//! autocorrelation of one image crop. Unnormalised in both directions.

pub(crate) struct Fft {
    n: usize,
    cos: Vec<f64>,
    sin: Vec<f64>,
    rev: Vec<usize>,
}

impl Fft {
    /// Plan for length `n` (a power of two, at least 2).
    pub(crate) fn new(n: usize) -> Self {
        debug_assert!(n.is_power_of_two() && n >= 2);
        let bits = n.trailing_zeros();
        let rev = (0..n)
            .map(|k| k.reverse_bits() >> (usize::BITS - bits))
            .collect();
        let (sin, cos) = (0..n / 2)
            .map(|k| (2.0 * std::f64::consts::PI * k as f64 / n as f64).sin_cos())
            .unzip();
        Fft { n, cos, sin, rev }
    }

    /// In-place transform of `(re, im)`: forward `X_k = Σ x_t e^{-2πi kt/n}`, inverse with `+i`.
    pub(crate) fn run(&self, re: &mut [f64], im: &mut [f64], inverse: bool) {
        let n = self.n;
        for k in 0..n {
            let r = self.rev[k];
            if r > k {
                re.swap(k, r);
                im.swap(k, r);
            }
        }
        let sgn = if inverse { 1.0 } else { -1.0 };
        let mut len = 2;
        while len <= n {
            let half = len / 2;
            let step = n / len;
            for start in (0..n).step_by(len) {
                for k in 0..half {
                    let (c, s) = (self.cos[k * step], sgn * self.sin[k * step]);
                    let (p, q) = (start + k, start + k + half);
                    let vr = re[q] * c - im[q] * s;
                    let vi = re[q] * s + im[q] * c;
                    re[q] = re[p] - vr;
                    im[q] = im[p] - vi;
                    re[p] += vr;
                    im[p] += vi;
                }
            }
            len *= 2;
        }
    }

    /// 2-D transform of an `n x n` row-major array (rows, then columns).
    pub(crate) fn run_2d(&self, re: &mut [f64], im: &mut [f64], inverse: bool) {
        let n = self.n;
        for y in 0..n {
            self.run(
                &mut re[y * n..(y + 1) * n],
                &mut im[y * n..(y + 1) * n],
                inverse,
            );
        }
        let (mut cr, mut ci) = (vec![0.0; n], vec![0.0; n]);
        for x in 0..n {
            for y in 0..n {
                cr[y] = re[y * n + x];
                ci[y] = im[y * n + x];
            }
            self.run(&mut cr, &mut ci, inverse);
            for y in 0..n {
                re[y * n + x] = cr[y];
                im[y * n + x] = ci[y];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_direct_dft_and_inverts() {
        let n = 16;
        let x: Vec<f64> = (0..n).map(|t| ((t * 7 + 3) % 11) as f64 - 4.0).collect();
        let (mut re, mut im) = (x.clone(), vec![0.0; n]);
        let f = Fft::new(n);
        f.run(&mut re, &mut im, false);
        for k in 0..n {
            let (mut dr, mut di) = (0.0, 0.0);
            for (t, v) in x.iter().enumerate() {
                let a = -2.0 * std::f64::consts::PI * (k * t) as f64 / n as f64;
                dr += v * a.cos();
                di += v * a.sin();
            }
            assert!((re[k] - dr).abs() < 1e-9 && (im[k] - di).abs() < 1e-9);
        }
        f.run(&mut re, &mut im, true);
        for t in 0..n {
            assert!((re[t] / n as f64 - x[t]).abs() < 1e-12 && im[t].abs() < 1e-9);
        }
    }
}
