//! The Cramér-Rao bound of the effective dot: the paper's Eq. 35, its generalisation to ρ ≠ 0
//! (NOTES.md §2) and the exact discrete bound of the pixel model (NOTES.md §1, §3).

use bostrack_core::{Gaussian2D, NoiseModel, Window};
use bostrack_model::{ModelKind, Sampling, crlb};
use std::f64::consts::PI;

/// Half-width of the exact bound's window in units of the larger sigma, when not given.
pub const WINDOW_SIGMAS: f64 = 4.0;
/// Smallest automatic half-width (px).
pub const MIN_HALF_WIDTH: usize = 3;
/// Largest automatic half-width (px); beyond it the window is capped (flag `window_capped`).
pub const MAX_HALF_WIDTH: usize = 50;

/// The paper's Eq. 35: `std(X0) = 2 sqrt(2π) σn η_x^(3/2) η_y^(1/2) / α0` and `std(Y0)` with x
/// and y exchanged, for white noise σn (counts) and exposure α0 (counts·px², so the paper's
/// `γ d_r` is absorbed), sigmas in px. The continuum bound of an untruncated, axis-aligned,
/// point-sampled Gaussian whose peak is tied to its exposure by Eq. 29 (the diagonal of J equals
/// the bound only because ρ = 0: NOTES.md §1). Returns `[std(X0), std(Y0)]` px.
pub fn eq35(sigma_n: f64, exposure: f64, sigma_x: f64, sigma_y: f64) -> [f64; 2] {
    let k = 2.0 * (2.0 * PI).sqrt() * sigma_n / exposure;
    [
        k * sigma_x.powf(1.5) * sigma_y.sqrt(),
        k * sigma_y.powf(1.5) * sigma_x.sqrt(),
    ]
}

/// Eq. 35 generalised to a correlated dot (NOTES.md §2): Eq. 35 times `(1 - ρ²)^(1/4)`, i.e.
/// `var(x0) = (2/π) (σn/I0)² (σx/σy) / sqrt(1 - ρ²)` with `I0` from Eq. 29
/// (`bostrack_model::crlb_closed_form` in terms of the exposure).
pub fn eq35_rho(sigma_n: f64, exposure: f64, sigma_x: f64, sigma_y: f64, rho: f64) -> [f64; 2] {
    let f = (1.0 - rho * rho).powf(0.25);
    let b = eq35(sigma_n, exposure, sigma_x, sigma_y);
    [b[0] * f, b[1] * f]
}

/// The window of the exact bound: centred on the dot, half-width `half` px when given, else
/// `ceil(4 σ_max)` clamped to [`MIN_HALF_WIDTH`, `MAX_HALF_WIDTH`]. Returns the window and
/// whether the automatic half-width was capped.
pub fn bound_window(dot: &Gaussian2D, half: Option<usize>) -> (Window, bool) {
    let (h, capped) = match half {
        Some(h) => (h, false),
        None => {
            let want = (WINDOW_SIGMAS * dot.sigma_x.max(dot.sigma_y)).ceil();
            let want = if want.is_finite() {
                want.max(0.0) as usize
            } else {
                usize::MAX
            };
            (
                want.clamp(MIN_HALF_WIDTH, MAX_HALF_WIDTH),
                want > MAX_HALF_WIDTH,
            )
        }
    };
    (Window::centred(dot.x0, dot.y0, h), capped)
}

/// Exact Cramér-Rao bound `[std(x0), std(y0)]` (px) of the predicted dot: the diagonal of the
/// inverse Fisher matrix (NOTES.md §1) of the pixel-integrated elliptical Gaussian
/// (`Sampling::Integrated`, all 7 parameters free, `ModelKind::Elliptical`) over `window`, for
/// the given noise model. `None` if the Fisher matrix is singular.
pub fn exact_bound(dot: &Gaussian2D, window: Window, noise: &NoiseModel) -> Option<[f64; 2]> {
    crlb(
        dot,
        window,
        noise,
        Sampling::Integrated,
        ModelKind::Elliptical,
    )
    .map(|b| [b.std[0], b.std[1]])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effective::peak_from_exposure;
    use bostrack_model::crlb_closed_form;

    #[test]
    fn eq35_hand_value() {
        // 2 sqrt(2π) * 10 / 5000 * 2^1.5 * 1^0.5 = 0.0100265... * 2.828427 = 0.0283593
        let b = eq35(10.0, 5000.0, 2.0, 1.0);
        let k = 2.0 * (2.0 * PI).sqrt() * 10.0 / 5000.0;
        assert!((b[0] - k * 8f64.sqrt()).abs() < 1e-15 && (b[1] - k * 2f64.sqrt()).abs() < 1e-15);
        assert!((b[0] - 0.028_359_3).abs() < 1e-7, "{}", b[0]);
        // Eq. 36: no blur, η² law
        let b = eq35(10.0, 5000.0, 1.5, 1.5);
        assert!((b[0] - k * 2.25).abs() < 1e-15 && b[0] == b[1]);
    }

    /// Eq. 35 (and its ρ generalisation) is the model crate's closed form with the peak of
    /// Eq. 29: the two derivations agree to rounding.
    #[test]
    fn eq35_is_the_closed_form_at_fixed_exposure() {
        for (sx, sy, rho) in [
            (1.5, 1.5, 0.0),
            (2.5, 1.2, 0.0),
            (2.0, 1.4, 0.6),
            (1.1, 3.0, -0.8),
        ] {
            let e = 12_000.0;
            let g = Gaussian2D {
                x0: 0.0,
                y0: 0.0,
                amplitude: peak_from_exposure(e, sx, sy, rho),
                sigma_x: sx,
                sigma_y: sy,
                rho,
                background: 0.0,
            };
            let c = crlb_closed_form(&g, 7.0);
            let p = eq35_rho(7.0, e, sx, sy, rho);
            for k in 0..2 {
                assert!(
                    (c[k] / p[k] - 1.0).abs() < 1e-12,
                    "{sx} {sy} {rho}: {c:?} vs {p:?}"
                );
            }
        }
    }

    #[test]
    fn window_rule() {
        let g = Gaussian2D::circular(10.3, 4.6, 100.0, 1.6, 0.0);
        assert_eq!(
            bound_window(&g, None),
            (Window::centred(10.3, 4.6, 7), false)
        );
        assert_eq!(bound_window(&g, Some(5)).0, Window::centred(10.3, 4.6, 5));
        let small = Gaussian2D {
            sigma_x: 0.3,
            sigma_y: 0.3,
            ..g
        };
        assert_eq!(bound_window(&small, None).0.width, 7);
        let huge = Gaussian2D { sigma_x: 40.0, ..g };
        assert_eq!(
            bound_window(&huge, None),
            (Window::centred(10.3, 4.6, MAX_HALF_WIDTH), true)
        );
    }
}
