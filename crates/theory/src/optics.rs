//! Imaging geometry and ray deflection: paper Eqs. 5, 6, 9, 10 and 24, with the corrections of
//! `docs/paper/NOTES.md` and docs/theory.md.
//!
//! Frames. The *flow frame* holds the density derivatives given by the user. The *camera frame*
//! has x to the right and y down as in the image (docs/CONVENTIONS.md) and z along the line of
//! sight from the camera towards the target (right-handed). Head-on viewing (all angles zero):
//! the two frames coincide.

use serde::{Deserialize, Serialize};

/// Gladstone-Dale constant of air, K = 0.225e-3 m³/kg (paper, Sec. 2.1.1; visible light).
pub const GLADSTONE_DALE_AIR: f64 = 0.225e-3;
/// Ambient refractive index of air, n0 = 1.000278.
pub const N0_AIR: f64 = 1.000278;

/// Magnification of a thin lens focused on an object at `object_distance_m` (paper Eq. 5, as a
/// magnitude): `M = f / (Z - f)`.
///
/// Eq. 5 reads `M = (1 - Z/f)^-1 = -f/(Z - f)`: negative, because the image is inverted. Image
/// coordinates in bostrack are those of the displayed (upright) image, so only `|M|` enters,
/// as in Eq. 18. For a particle at depth ζ behind the focal plane, pass `Z + ζ`. Returns NaN
/// unless `0 < f < Z`.
pub fn magnification(focal_length_m: f64, object_distance_m: f64) -> f64 {
    if focal_length_m > 0.0 && object_distance_m > focal_length_m {
        focal_length_m / (object_distance_m - focal_length_m)
    } else {
        f64::NAN
    }
}

/// Diameter of the diffraction spot on the sensor, `d_diff = 2.44 f# (M + 1) λ` (Adrian &
/// Westerweel, *Particle Image Velocimetry*, 2011), in the units of `wavelength`.
///
/// The formula printed below the paper's Eq. 7 does not match this (NOTES.md §4); bostrack takes
/// the diffraction diameter as an input in px, optionally from this formula, and equates it
/// with the Gaussian's `4η` (the project's diameter convention d = 4σ). The best-fitting
/// Gaussian to the Airy core is narrower (σ ≈ 0.42 λ f# (M+1), i.e. 4σ ≈ 0.69 d_diff).
pub fn diffraction_diameter(f_number: f64, magnification: f64, wavelength: f64) -> f64 {
    2.44 * f_number * (magnification + 1.0) * wavelength
}

/// Full angle of the ray cone from a point on the target to the lens aperture (the first term
/// of Eq. 24): `Δθ0 = (1/f#) (1 + 1/M)^-1 = M / ((1 + M) f#)`, which is `D / Z` (aperture
/// diameter over object distance) for a thin lens. Radians.
pub fn cone_angle_geometric(f_number: f64, magnification: f64) -> f64 {
    magnification / ((1.0 + magnification) * f_number)
}

/// The cone angle of Eq. 24 and what became of it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConeAngle {
    /// The geometric cone angle `M / ((1 + M) f#)` (rad).
    pub geometric: f64,
    /// The bracket of Eq. 24, `geometric - K ζ (∂ρ/∂x + ∂ρ/∂y) / (2 n0)` (rad); may be negative.
    pub bracket: f64,
    /// The angle used: `max(bracket, 0)` (rad).
    pub value: f64,
    /// Whether the bracket was negative and clamped to zero (NOTES.md §4).
    pub clamped: bool,
}

/// Cone angle of the paper's Eq. 24:
///
/// `Δθ0 = (1/f#) (1 + 1/M)^-1 - K ζ / (2 n0) · (∂ρ/∂x + ∂ρ/∂y)`,
///
/// where the second term is meant to account for the mean deflection of the cone. `path_m` is
/// the path length through the gradient field (ζ; the slab thickness Δz for BOS: the cone's mean
/// deflection angle is `K Δz ∇ρ / n0`), `gradient` the camera-frame transverse density gradient
/// (kg/m⁴). The bracket can go negative for strong first derivatives: it is then clamped to zero
/// and flagged (NOTES.md §4). The ray tracer shows that a uniform gradient does not change the
/// spread of the cone at all (docs/theory.md); [`ConeAngleModel::Geometric`] leaves the term
/// out.
pub fn cone_angle_eq24(
    f_number: f64,
    magnification: f64,
    gladstone_dale: f64,
    n0: f64,
    path_m: f64,
    gradient: [f64; 2],
) -> ConeAngle {
    let geometric = cone_angle_geometric(f_number, magnification);
    let bracket = geometric - gladstone_dale * path_m / (2.0 * n0) * (gradient[0] + gradient[1]);
    ConeAngle {
        geometric,
        bracket,
        value: bracket.max(0.0),
        clamped: bracket < 0.0,
    }
}

/// Whether the cone angle of the effective model includes the gradient term of Eq. 24.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ConeAngleModel {
    /// Eq. 24 as printed (clamped at zero, NOTES.md §4).
    #[default]
    Paper,
    /// The geometric cone angle only (what the ray tracer does).
    Geometric,
}

/// Distribution of ray angles over the aperture (paper Eq. 22).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Aperture {
    /// The paper's Eq. 22: θx and θy independent and uniform over the full cone angle Δθ0, i.e.
    /// a square pupil; per-axis variance `Δθ0² / 12` and no correlation (Eq. 23 a-c).
    #[default]
    Square,
    /// A round lens pupil: directions uniform over a disc of diameter Δθ0; per-axis variance
    /// `Δθ0² / 16` (a disc of radius R has `E[x²] = R²/4`), no correlation. The blur variance is
    /// 3/4 of the paper's.
    Circular,
}

impl Aperture {
    /// Per-axis variance of the ray angles in units of `Δθ0²`: 1/12 or 1/16.
    pub fn angle_variance_factor(self) -> f64 {
        match self {
            Aperture::Square => 1.0 / 12.0,
            Aperture::Circular => 1.0 / 16.0,
        }
    }
}

/// Shift sensitivity of a BOS setup (paper Eq. 6 in its BOS form, below Eq. 26):
/// `S = M K Z_D Δz / n0`, the image-plane displacement per unit path-averaged density gradient
/// (metres of image per kg/m⁴ when `Z_D`, `Δz` are in metres). Divide by the pixel pitch for px.
///
/// Derivation: a ray from the target crossing a slab of thickness Δz centred `Z_D` in front of
/// the target is turned by `ε = (K/n0) ∫ ∇⊥ρ dz ≈ K Δz ∇⊥ρ / n0`; traced back straight from the
/// camera it seems to leave the target plane from `-Z_D ε` (in general `-(K/n0) ∫ z ∇⊥ρ dz`, z
/// measured from the target, which is exactly `-Z_D Δz` times the mean gradient for a slab); the
/// camera images that point with magnification M.
pub fn bos_sensitivity(
    magnification: f64,
    gladstone_dale: f64,
    n0: f64,
    z_d_m: f64,
    delta_z_m: f64,
) -> f64 {
    magnification * gladstone_dale * z_d_m * delta_z_m / n0
}

/// Shift sensitivity of a particle at depth ζ inside the gradient field (paper Eq. 6 as
/// printed): `S = M K ζ² / n0`.
///
/// Note: Eq. 6's integral `(MK/n0) ∫ ∇ρ dz` lacks the lever arm (it is an angle, not a
/// length); the ray equation gives `-(MK/n0) ∫₀^ζ z ∇⊥ρ dz`, which for a uniform gradient is
/// `ζ²/2` times it, half the printed `ζ²`. The printed form is kept for reproducing the paper.
pub fn volumetric_sensitivity(
    magnification: f64,
    gladstone_dale: f64,
    n0: f64,
    depth_m: f64,
) -> f64 {
    magnification * gladstone_dale * depth_m * depth_m / n0
}

/// Apparent displacement of the dot (paper Eqs. 6 and 18): `ΔX = -S ∇⊥ρ`, with `S` from
/// [`bos_sensitivity`] or [`volumetric_sensitivity`] and `∇⊥ρ` the camera-frame transverse
/// gradient at the cone's bisector (path-averaged).
///
/// Sign: a ray bends towards higher refractive index (higher density), so the dot appears
/// displaced towards lower density, i.e. against the gradient, in image coordinates aligned
/// with the flow's transverse axes. The paper writes `+M K ζ² ∇ρ / n0` with the (negative,
/// inverted-image) M of Eq. 5; only the magnitude matters for the bound. Eq. 18 also prints a
/// stray `1/N_R`, which Eq. 17 shows cancels.
pub fn apparent_displacement(sensitivity: f64, gradient: [f64; 2]) -> [f64; 2] {
    [-sensitivity * gradient[0], -sensitivity * gradient[1]]
}

/// Rotation from the flow frame to the camera frame (paper Eq. 9, `R = R_φ R_θ R_ψ`):
/// `v_cam = R v_flow`, with pitch φ about x, yaw θ about y and roll ψ about z (radians), each a
/// passive (frame) rotation:
///
/// `R_φ = [[1, 0, 0], [0, cφ, sφ], [0, -sφ, cφ]]`, `R_θ = [[cθ, 0, -sθ], [0, 1, 0], [sθ, 0, cθ]]`,
/// `R_ψ = [[cψ, sψ, 0], [-sψ, cψ, 0], [0, 0, 1]]`.
///
/// All angles zero is head-on viewing (the paper's Sec. 2.1.2 uses a frame in which head-on is
/// "one angle 90°"; here it is the identity).
pub fn rotation_matrix(pitch: f64, yaw: f64, roll: f64) -> [[f64; 3]; 3] {
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    let (sr, cr) = roll.sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, cp, sp], [0.0, -sp, cp]];
    let ry = [[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]];
    let rz = [[cr, sr, 0.0], [-sr, cr, 0.0], [0.0, 0.0, 1.0]];
    mat_mul(&mat_mul(&rx, &ry), &rz)
}

pub(crate) fn mat_mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

/// Second derivatives of the density (kg/m⁵), a symmetric 3x3 tensor (the Hessian).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Hessian {
    /// ∂²ρ/∂x² \[0\].
    pub xx: f64,
    /// ∂²ρ/∂y² \[0\].
    pub yy: f64,
    /// ∂²ρ/∂z² \[0\].
    pub zz: f64,
    /// ∂²ρ/∂x∂y \[0\].
    pub xy: f64,
    /// ∂²ρ/∂x∂z \[0\].
    pub xz: f64,
    /// ∂²ρ/∂y∂z \[0\].
    pub yz: f64,
}

impl Hessian {
    /// The full symmetric matrix.
    pub fn matrix(&self) -> [[f64; 3]; 3] {
        [
            [self.xx, self.xy, self.xz],
            [self.xy, self.yy, self.yz],
            [self.xz, self.yz, self.zz],
        ]
    }
    /// A Hessian from a symmetric matrix (the upper triangle is read).
    pub fn from_matrix(m: &[[f64; 3]; 3]) -> Self {
        Hessian {
            xx: m[0][0],
            yy: m[1][1],
            zz: m[2][2],
            xy: m[0][1],
            xz: m[0][2],
            yz: m[1][2],
        }
    }
    /// Whether every component is zero.
    pub fn is_zero(&self) -> bool {
        self.matrix().iter().flatten().all(|&v| v == 0.0)
    }
}

/// The density gradient in the camera frame (paper Eq. 10): `∇'ρ = R ∇ρ` (a gradient is a
/// vector). Eq. 10 prints `1/R_jk`; the components of a vector in a rotated frame are `R_jk v_k`.
pub fn camera_gradient(r: &[[f64; 3]; 3], gradient: [f64; 3]) -> [f64; 3] {
    let mut g = [0.0; 3];
    for i in 0..3 {
        g[i] = (0..3).map(|k| r[i][k] * gradient[k]).sum();
    }
    g
}

/// The Hessian in the camera frame, `H' = R H Rᵀ` (a second-rank tensor).
pub fn camera_hessian(r: &[[f64; 3]; 3], h: &Hessian) -> Hessian {
    let m = h.matrix();
    let mut rt = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            rt[i][j] = r[j][i];
        }
    }
    Hessian::from_matrix(&mat_mul(&mat_mul(r, &m), &rt))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn magnification_of_a_105_mm_lens_at_1_5_m() {
        // hand: 0.105 / (1.5 - 0.105) = 0.105 / 1.395
        assert!((magnification(0.105, 1.5) - 0.075_268_817_204_3).abs() < 1e-12);
        assert!(magnification(0.1, 0.05).is_nan());
        // a 1:1 macro setup at 2f
        assert!((magnification(0.05, 0.1) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn diffraction_and_cone_angle_hand_values() {
        // 2.44 * 11 * 1.1 * 532e-9 = 29.524 * 532e-9 = 15.706768e-6 m
        assert!((diffraction_diameter(11.0, 0.1, 532e-9) - 15.706_768e-6).abs() < 1e-18);
        // M/((1+M) f#) = 0.1/(1.1*11) = 1/121; equals D/Z for the thin lens
        let m = magnification(0.105, 1.5);
        let c = cone_angle_geometric(11.0, m);
        assert!((cone_angle_geometric(11.0, 0.1) - 1.0 / 121.0).abs() < 1e-15);
        assert!((c - 0.105 / 11.0 / 1.5).abs() < 1e-15);
    }

    #[test]
    fn eq24_subtracts_the_mean_deflection_and_clamps() {
        // K ζ/(2 n0) (gx + gy) with K = 2e-4, ζ = 0.05, n0 = 1, g = (100, 0): 2e-4*0.05/2*100 = 5e-4
        let c = cone_angle_eq24(10.0, 1.0, 2e-4, 1.0, 0.05, [100.0, 0.0]);
        assert!((c.geometric - 0.05).abs() < 1e-15);
        assert!((c.bracket - (0.05 - 5e-4)).abs() < 1e-15);
        assert!(!c.clamped && c.value == c.bracket);
        let c = cone_angle_eq24(10.0, 1.0, 2e-4, 1.0, 0.05, [8000.0, 4000.0]);
        assert!(c.clamped && c.value == 0.0 && c.bracket < 0.0);
    }

    #[test]
    fn sensitivity_and_shift_hand_values() {
        // M K Z_D Δz / n0 = 0.1 * 2.25e-4 * 0.5 * 0.05 / 1.000278
        let s = bos_sensitivity(0.1, GLADSTONE_DALE_AIR, N0_AIR, 0.5, 0.05);
        assert!((s - 5.623_436_7e-7).abs() < 1e-13, "{s}");
        let d = apparent_displacement(s, [10.0, -4.0]);
        assert!((d[0] + 10.0 * s).abs() < 1e-20 && (d[1] - 4.0 * s).abs() < 1e-20);
        // volumetric: ζ² replaces Z_D Δz
        let v = volumetric_sensitivity(
            0.1,
            GLADSTONE_DALE_AIR,
            N0_AIR,
            0.5f64.sqrt() * 0.05f64.sqrt(),
        );
        assert!((v - s).abs() < 1e-18);
    }

    #[test]
    fn rotation_is_orthonormal_and_matches_hand_cases() {
        let r = rotation_matrix(0.3, -0.7, 1.1);
        let rrt = mat_mul(
            &r,
            &[
                [r[0][0], r[1][0], r[2][0]],
                [r[0][1], r[1][1], r[2][1]],
                [r[0][2], r[1][2], r[2][2]],
            ],
        );
        for i in 0..3 {
            for j in 0..3 {
                assert!((rrt[i][j] - if i == j { 1.0 } else { 0.0 }).abs() < 1e-14);
            }
        }
        assert_eq!(
            rotation_matrix(0.0, 0.0, 0.0),
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        );
        // yaw 90°: the flow's z axis becomes the camera's x axis, flow x becomes camera -z...
        let r = rotation_matrix(0.0, FRAC_PI_2, 0.0);
        let g = camera_gradient(&r, [1.0, 2.0, 3.0]);
        assert!(
            (g[0] + 3.0).abs() < 1e-12 && (g[1] - 2.0).abs() < 1e-12 && (g[2] - 1.0).abs() < 1e-12
        );
        // yaw θ: the camera sees g_x' = cos θ g_x - sin θ g_z
        let th: f64 = 0.2;
        let g = camera_gradient(&rotation_matrix(0.0, th, 0.0), [5.0, 0.0, 7.0]);
        assert!((g[0] - (th.cos() * 5.0 - th.sin() * 7.0)).abs() < 1e-12);
        // roll 90°: camera x' = flow y, camera y' = -flow x
        let g = camera_gradient(&rotation_matrix(0.0, 0.0, FRAC_PI_2), [1.0, 2.0, 0.0]);
        assert!((g[0] - 2.0).abs() < 1e-12 && (g[1] + 1.0).abs() < 1e-12);
    }

    #[test]
    fn hessian_rotation_keeps_invariants() {
        let h = Hessian {
            xx: 3.0,
            yy: -1.0,
            zz: 2.0,
            xy: 0.5,
            xz: -0.7,
            yz: 1.2,
        };
        let r = rotation_matrix(0.4, 0.1, -0.9);
        let hr = camera_hessian(&r, &h);
        assert!(((hr.xx + hr.yy + hr.zz) - 4.0).abs() < 1e-12);
        let fro = |h: &Hessian| h.matrix().iter().flatten().map(|v| v * v).sum::<f64>();
        assert!((fro(&hr) - fro(&h)).abs() < 1e-12);
        // roll 90° about z: xx' = yy, yy' = xx, xy' = -xy
        let hr = camera_hessian(&rotation_matrix(0.0, 0.0, FRAC_PI_2), &h);
        assert!(
            (hr.xx + 1.0).abs() < 1e-12
                && (hr.yy - 3.0).abs() < 1e-12
                && (hr.xy + 0.5).abs() < 1e-12
        );
    }
}
