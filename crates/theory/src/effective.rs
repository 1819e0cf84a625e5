//! The effective dot image (paper Eqs. 11-29), generalised to the full covariance.

use crate::optics::Aperture;
use bostrack_core::Gaussian2D;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Covariance of the blur caused by the density field's second derivatives, `[Σxx, Σxy, Σyy]`
/// in px² (paper Eqs. 19-26 and their off-diagonal counterpart).
///
/// Inputs: `sensitivity_px` the shift sensitivity `S` in px per kg/m⁴ (Eq. 6: `M K Z_D Δz /
/// (n0 d_r)` for BOS, `M K ζ² / (n0 d_r)` for a particle at depth ζ), `lever_m` the distance ℓ
/// from the dot to the field along which the ray offsets grow (Eq. 16: ℓ = ζ; ℓ = Z_D for BOS),
/// `cone_angle` the full cone angle Δθ0 (Eq. 24, rad), `aperture` the ray-angle distribution
/// (Eq. 22), and `hessian = [ρxx, ρxy, ρyy]` the camera-frame transverse second derivatives of
/// the density (kg/m⁵, path-averaged).
///
/// Derivation (the paper's, in matrix form, which also gives the cross term). Ray r leaves the
/// dot at angle `θ0 + δθ_r` and crosses the field at `t_r = t_0 + ℓ δθ_r` (Eq. 16). Each ray is
/// displaced by `-S ∇⊥ρ(t_r)` (Eq. 6), and to first order in the Taylor expansion of Eq. 15,
/// `∇⊥ρ(t_r) = ∇⊥ρ(t_0) + H ℓ δθ_r`, with `H = [[ρxx, ρxy], [ρxy, ρyy]]`; so
/// `X_r - X_0 = -S ℓ H δθ_r` (Eq. 20). The ray offsets average to zero, so the centroid is
/// shifted by the bisector's deflection only (Eq. 17-18). The second moments of the image are,
/// as in Eq. 19 but for every pair of axes (each ray's spot is an isotropic Gaussian of
/// variance η², which adds η² to the diagonal and nothing to the cross moment),
///
/// `Σ = η² I + (1/N_R) Σ_r (X_r - X_0)(X_r - X_0)ᵀ = η² I + S² ℓ² H E[δθ δθᵀ] Hᵀ`.
///
/// With Eq. 22-23 (independent, uniform angles over the cone: `E[δθ δθᵀ] = c Δθ0² I`, `c =
/// 1/12`; `c = 1/16` for a round pupil) and H symmetric, `Σ_blur = c (S ℓ Δθ0)² H²`:
///
/// - `Σxx = c (S ℓ Δθ0)² (ρxx² + ρxy²)` (Eq. 25, the paper's `(MKζ²/n0)² ζ² Δθ0²/12 (…)`),
/// - `Σyy = c (S ℓ Δθ0)² (ρxy² + ρyy²)` (Eq. 26),
/// - `Σxy = c (S ℓ Δθ0)² ρxy (ρxx + ρyy)` (not in the paper; gives the dot's correlation ρ).
pub fn blur_covariance(
    sensitivity_px: f64,
    lever_m: f64,
    cone_angle: f64,
    aperture: Aperture,
    hessian: [f64; 3],
) -> [f64; 3] {
    let scale = aperture.angle_variance_factor() * (sensitivity_px * lever_m * cone_angle).powi(2);
    let [hxx, hxy, hyy] = hessian;
    [
        scale * (hxx * hxx + hxy * hxy),
        scale * hxy * (hxx + hyy),
        scale * (hxy * hxy + hyy * hyy),
    ]
}

/// Covariance of the effective dot, `η² I + Σ_blur` (Eqs. 19, 25, 26), `[Σxx, Σxy, Σyy]` px².
pub fn effective_covariance(eta_px: f64, blur: [f64; 3]) -> [f64; 3] {
    let e2 = eta_px * eta_px;
    [e2 + blur[0], blur[1], e2 + blur[2]]
}

/// `(σx, σy, ρ)` of a covariance `[Σxx, Σxy, Σyy]`: `σ = sqrt(Σ_ii)`, `ρ = Σxy / (σx σy)`
/// (0 when a variance is zero).
pub fn covariance_to_shape(cov: [f64; 3]) -> (f64, f64, f64) {
    let sx = cov[0].max(0.0).sqrt();
    let sy = cov[2].max(0.0).sqrt();
    let rho = if sx > 0.0 && sy > 0.0 {
        (cov[1] / (sx * sy)).clamp(-1.0, 1.0)
    } else {
        0.0
    };
    (sx, sy, rho)
}

/// Peak intensity of the effective dot from its exposure (paper Eq. 29 with Eq. 27 for a
/// correlated Gaussian): `I0 = α0 / (2π σx σy sqrt(1 - ρ²))`, the exposure α0 (integrated
/// counts, counts·px²) being conserved by the blur (Eq. 28).
pub fn peak_from_exposure(exposure: f64, sigma_x: f64, sigma_y: f64, rho: f64) -> f64 {
    exposure / (2.0 * PI * sigma_x * sigma_y * (1.0 - rho * rho).sqrt())
}

/// The effective Gaussian image of one dot (paper Eq. 11, with the cross term).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EffectiveDot {
    /// Centroid shift `[ΔX, ΔY]` (px), Eq. 18.
    pub shift: [f64; 2],
    /// Covariance `[Σxx, Σxy, Σyy]` (px²).
    pub covariance: [f64; 3],
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
    /// Peak intensity above background (counts), Eq. 29.
    pub peak: f64,
    /// Exposure α0 (counts·px²), Eq. 27-28.
    pub exposure: f64,
}

impl EffectiveDot {
    /// Assemble the dot from its shift, the diffraction (reference) sigma η, the blur covariance
    /// and the exposure.
    pub fn new(shift: [f64; 2], eta_px: f64, blur: [f64; 3], exposure: f64) -> Self {
        let covariance = effective_covariance(eta_px, blur);
        let (sigma_x, sigma_y, rho) = covariance_to_shape(covariance);
        EffectiveDot {
            shift,
            covariance,
            sigma_x,
            sigma_y,
            rho,
            peak: peak_from_exposure(exposure, sigma_x, sigma_y, rho),
            exposure,
        }
    }

    /// The dot as a [`Gaussian2D`] whose undeflected image is at `position` (px), on
    /// `background` (counts).
    pub fn gaussian(&self, position: [f64; 2], background: f64) -> Gaussian2D {
        Gaussian2D {
            x0: position[0] + self.shift[0],
            y0: position[1] + self.shift[1],
            amplitude: self.peak,
            sigma_x: self.sigma_x,
            sigma_y: self.sigma_y,
            rho: self.rho,
            background,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_hand_values() {
        // S ℓ Δθ0 = 2 * 0.5 * 0.01 = 0.01; scale = 1e-4/12
        let b = blur_covariance(2.0, 0.5, 0.01, Aperture::Square, [300.0, 100.0, -50.0]);
        let s = 1e-4 / 12.0;
        assert!((b[0] - s * (90000.0 + 10000.0)).abs() < 1e-12);
        assert!((b[1] - s * 100.0 * 250.0).abs() < 1e-12);
        assert!((b[2] - s * (10000.0 + 2500.0)).abs() < 1e-12);
        // round pupil: 3/4 of it
        let c = blur_covariance(2.0, 0.5, 0.01, Aperture::Circular, [300.0, 100.0, -50.0]);
        for k in 0..3 {
            assert!((c[k] - 0.75 * b[k]).abs() < 1e-12);
        }
        // no curvature, no blur
        assert_eq!(
            blur_covariance(2.0, 0.5, 0.01, Aperture::Square, [0.0; 3]),
            [0.0; 3]
        );
    }

    #[test]
    fn effective_dot_hand_values() {
        // η = 1, blur [3, 1, 0]: Σ = [4, 1, 1], σx = 2, σy = 1, ρ = 0.5
        let d = EffectiveDot::new([0.5, -0.25], 1.0, [3.0, 1.0, 0.0], 1000.0);
        assert!((d.sigma_x - 2.0).abs() < 1e-15 && (d.sigma_y - 1.0).abs() < 1e-15);
        assert!((d.rho - 0.5).abs() < 1e-15);
        // Eq. 29: 1000 / (2π · 2 · 1 · sqrt(0.75))
        assert!((d.peak - 1000.0 / (2.0 * PI * 2.0 * 0.75f64.sqrt())).abs() < 1e-12);
        let g = d.gaussian([10.0, 20.0], 100.0);
        assert_eq!((g.x0, g.y0, g.background), (10.5, 19.75, 100.0));
        // the volume of the Gaussian is the exposure (Eq. 27-28)
        assert!((g.volume() - 1000.0).abs() < 1e-9);
    }

    #[test]
    fn unblurred_dot_is_the_diffraction_spot() {
        let d = EffectiveDot::new([0.0; 2], 1.3, [0.0; 3], 500.0);
        assert_eq!((d.sigma_x, d.sigma_y, d.rho), (1.3, 1.3, 0.0));
        assert!((d.peak - 500.0 / (2.0 * PI * 1.69)).abs() < 1e-12);
    }
}
