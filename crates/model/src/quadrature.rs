//! Gauss-Legendre nodes and weights on [-1/2, 1/2] (weights sum to 1).

/// Nodes/weights for n = 2..=12 points, computed once by Newton iteration on P_n.
pub(crate) fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut nodes = Vec::with_capacity(n);
    let mut weights = Vec::with_capacity(n);
    for k in 0..n {
        // initial guess (Tricomi)
        let mut x = (std::f64::consts::PI * (k as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (p, d) = legendre(n, x);
            dp = d;
            let dx = p / d;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        let (_, d) = legendre(n, x);
        if d.is_finite() {
            dp = d;
        }
        nodes.push(0.5 * x);
        // weight on [-1, 1] is 2 / ((1 - x²) P'(x)²); on [-1/2, 1/2] half of it
        weights.push(1.0 / ((1.0 - x * x) * dp * dp));
    }
    (nodes, weights)
}

/// P_n(x) and P_n'(x) by the three-term recurrence.
fn legendre(n: usize, x: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, x);
    for k in 2..=n {
        let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
        p0 = p1;
        p1 = p2;
    }
    let d = n as f64 * (x * p1 - p0) / (x * x - 1.0);
    (p1, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integrates_polynomials_exactly() {
        for n in 2..=12 {
            let (x, w) = gauss_legendre(n);
            let s: f64 = w.iter().sum();
            assert!((s - 1.0).abs() < 1e-13, "n={n} sum={s}");
            // ∫_{-1/2}^{1/2} t^(2n-2) dt = 2 (1/2)^(2n-1) / (2n-1)
            let p = 2 * n - 2;
            let exact = 2.0 * 0.5f64.powi(p as i32 + 1) / (p as f64 + 1.0);
            let q: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(p as i32)).sum();
            assert!((q - exact).abs() < 1e-14, "n={n}");
        }
    }
}
