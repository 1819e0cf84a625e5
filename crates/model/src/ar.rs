//! The amplification ratio (paper Eq. 37, corrected per docs/paper/NOTES.md §2).

use bostrack_core::Gaussian2D;
use serde::{Deserialize, Serialize};

/// Which formula for the amplification ratio.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ArVariant {
    /// NOTES.md §2 (follows from the continuum bound, Eq. 34 generalised to ρ ≠ 0):
    /// `AR_x = (I0_ref/I0_grad) · sqrt((σx_g/σx_r)(σy_r/σy_g)) · ((1-ρ_r²)/(1-ρ_g²))^(1/4)`.
    #[default]
    Notes,
    /// The ratio of the exact per-dot Cramér-Rao bounds of the two fits, `crlb_grad /
    /// crlb_ref` per axis (each from its fit's parameters, window, pixels used and the noise
    /// model). Equal to [`ArVariant::Notes`] for untruncated, well-sampled dots under the same
    /// signal-independent noise; it also holds under shot noise (which the closed form does not
    /// take: there it over-states the ratio for dimmer, blurred dots), pixelation, truncation
    /// and masked pixels. Needs the fits' bounds, not only their shapes: computed by
    /// [`bound_ratio`]; [`amplification_ratio`] returns NaN for it.
    Bounds,
    /// As published, only for reproducing published numbers: the intensity ratio *inside* the
    /// square root (Eq. 37 as printed) and the ρ factor of the published reference code,
    /// `((1-ρ_g²)/(1-ρ_r²))^(+1/4)`. Under-states AR (e.g. by 1.67 at ρ_g = 0.8, ρ_r = 0).
    Published,
}

/// `[AR_x, AR_y]` of [`ArVariant::Bounds`]: `gradient / reference` per axis from the two fits'
/// position bounds (px). NaN unless both bounds of an axis are finite and positive.
pub fn bound_ratio(reference: [f64; 2], gradient: [f64; 2]) -> [f64; 2] {
    [0, 1].map(|a| {
        let (r, g) = (reference[a], gradient[a]);
        if r.is_finite() && g.is_finite() && r > 0.0 && g > 0.0 {
            g / r
        } else {
            f64::NAN
        }
    })
}

/// `[AR_x, AR_y]`: the ratio of the position uncertainty of the same dot in the gradient image to
/// that in the reference image, from the fitted amplitudes, sigmas and ρ. NaN if either dot has
/// non-positive amplitude or an invalid shape (the caller flags it), and for
/// [`ArVariant::Bounds`] (see [`bound_ratio`]).
pub fn amplification_ratio(
    reference: &Gaussian2D,
    gradient: &Gaussian2D,
    v: ArVariant,
) -> [f64; 2] {
    if !(reference.is_valid()
        && gradient.is_valid()
        && reference.amplitude > 0.0
        && gradient.amplitude > 0.0)
    {
        return [f64::NAN; 2];
    }
    let (r, g) = (reference, gradient);
    let intensity = r.amplitude / g.amplitude;
    let shape_x = (g.sigma_x / r.sigma_x) * (r.sigma_y / g.sigma_y);
    let shape_y = (g.sigma_y / r.sigma_y) * (r.sigma_x / g.sigma_x);
    let rho = (1.0 - r.rho * r.rho) / (1.0 - g.rho * g.rho);
    match v {
        ArVariant::Bounds => [f64::NAN; 2],
        ArVariant::Notes => {
            let f = intensity * rho.powf(0.25);
            [f * shape_x.sqrt(), f * shape_y.sqrt()]
        }
        ArVariant::Published => {
            let f = rho.powf(-0.25);
            [
                f * (shape_x * intensity).sqrt(),
                f * (shape_y * intensity).sqrt(),
            ]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_dots_have_unit_ratio() {
        let d = Gaussian2D {
            x0: 0.0,
            y0: 0.0,
            amplitude: 900.0,
            sigma_x: 1.6,
            sigma_y: 1.2,
            rho: 0.3,
            background: 10.0,
        };
        for v in [ArVariant::Notes, ArVariant::Published] {
            let ar = amplification_ratio(&d, &d, v);
            assert!((ar[0] - 1.0).abs() < 1e-15 && (ar[1] - 1.0).abs() < 1e-15);
        }
    }

    #[test]
    fn notes_variant_against_hand_values() {
        let r = Gaussian2D::circular(0.0, 0.0, 1000.0, 1.5, 0.0);
        // blurred in x only, intensity halved (volume conserved would be sigma 3, amp 500)
        let g = Gaussian2D {
            sigma_x: 3.0,
            amplitude: 500.0,
            ..r
        };
        let ar = amplification_ratio(&r, &g, ArVariant::Notes);
        assert!(
            (ar[0] - 2.0 * 2f64.sqrt()).abs() < 1e-12 && (ar[1] - 2.0 / 2f64.sqrt()).abs() < 1e-12
        );
        // rho factor: rho_g = 0.8, rho_r = 0 → (1/0.36)^(1/4) and the published one is its inverse
        let g = Gaussian2D { rho: 0.8, ..r };
        let n = amplification_ratio(&r, &g, ArVariant::Notes);
        let p = amplification_ratio(&r, &g, ArVariant::Published);
        assert!((n[0] - (1.0f64 / 0.36).powf(0.25)).abs() < 1e-12);
        assert!((n[0] / p[0] - (1.0f64 / 0.36).sqrt()).abs() < 1e-12); // 1.67
        assert!(
            amplification_ratio(
                &r,
                &Gaussian2D {
                    amplitude: 0.0,
                    ..r
                },
                ArVariant::Notes
            )[0]
            .is_nan()
        );
        assert!(amplification_ratio(&r, &g, ArVariant::Bounds)[0].is_nan());
    }

    #[test]
    fn bound_ratio_per_axis_and_invalid_bounds() {
        assert_eq!(bound_ratio([0.01, 0.02], [0.03, 0.01]), [3.0, 0.5]);
        for bad in [0.0, -0.01, f64::NAN, f64::INFINITY] {
            let r = bound_ratio([bad, 0.02], [0.03, 0.01]);
            assert!(r[0].is_nan() && r[1] == 0.5);
            let r = bound_ratio([0.01, 0.02], [0.03, bad]);
            assert!(r[0] == 3.0 && r[1].is_nan());
        }
    }
}
