//! Displacement fields (closed-form value and Jacobian) and the blur model.

use crate::config::{DisplacementField, FlowConfig};
use bostrack_core::Gaussian2D;

/// A displacement `[dx, dy]` (px) and its Jacobian `J[r][c] = ∂d_r/∂p_c` at one point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldValue {
    pub d: [f64; 2],
    pub jacobian: [[f64; 2]; 2],
}

impl DisplacementField {
    /// The displacement and its Jacobian at `p` (px), from the closed forms documented on each
    /// variant.
    pub fn eval(&self, p: [f64; 2]) -> FieldValue {
        match *self {
            DisplacementField::Zero => FieldValue {
                d: [0.0; 2],
                jacobian: [[0.0; 2]; 2],
            },
            DisplacementField::Uniform { dx, dy } => FieldValue {
                d: [dx, dy],
                jacobian: [[0.0; 2]; 2],
            },
            DisplacementField::Affine {
                centre,
                offset,
                matrix: m,
            } => {
                let (u, v) = (p[0] - centre[0], p[1] - centre[1]);
                FieldValue {
                    d: [
                        offset[0] + m[0][0] * u + m[0][1] * v,
                        offset[1] + m[1][0] * u + m[1][1] * v,
                    ],
                    jacobian: m,
                }
            }
            DisplacementField::Vortex {
                centre,
                strength,
                core,
            } => {
                // d = f(r²) (-v, u), f(s) = strength (1 - exp(-s/c²)) / s.
                let (u, v) = (p[0] - centre[0], p[1] - centre[1]);
                let s = u * u + v * v;
                let c2 = core * core;
                let (f, fp) = vortex_profile(s, c2);
                let (f, fp) = (strength * f, strength * fp);
                // ∂f/∂u = f'(s)·2u; d_x = -v f, d_y = u f.
                let jac = [
                    [-v * fp * 2.0 * u, -f - v * fp * 2.0 * v],
                    [f + u * fp * 2.0 * u, u * fp * 2.0 * v],
                ];
                FieldValue {
                    d: [-v * f, u * f],
                    jacobian: jac,
                }
            }
            DisplacementField::GaussianBump {
                centre,
                amplitude,
                width,
            } => {
                // d = -A (p - c)/s² · e, e = exp(-r²/(2s²));
                // ∂d_i/∂p_j = -A/s² · e · (δ_ij - (p-c)_i (p-c)_j / s²).
                let (u, v) = (p[0] - centre[0], p[1] - centre[1]);
                let s2 = width * width;
                let e = (-(u * u + v * v) / (2.0 * s2)).exp();
                let k = -amplitude / s2 * e;
                FieldValue {
                    d: [k * u, k * v],
                    jacobian: [
                        [k * (1.0 - u * u / s2), -k * u * v / s2],
                        [-k * u * v / s2, k * (1.0 - v * v / s2)],
                    ],
                }
            }
        }
    }
}

/// `f(s) = (1 - exp(-s/c²))/s` and `f'(s)`, accurate near `s = 0` (series below s/c² < 1e-4).
fn vortex_profile(s: f64, c2: f64) -> (f64, f64) {
    let t = s / c2;
    if t < 1e-4 {
        // 1 - e^-t = t - t²/2 + t³/6 - …  →  f = (1 - t/2 + t²/6)/c², f' = (-1/2 + t/3)/c⁴.
        (
            (1.0 - t / 2.0 + t * t / 6.0) / c2,
            (-0.5 + t / 3.0) / (c2 * c2),
        )
    } else {
        let em = (-t).exp();
        let f = -(-t).exp_m1() / s;
        // f' = (e^-t/c² · s - (1 - e^-t)) / s²
        let fp = (em / c2 - f) / s;
        (f, fp)
    }
}

/// The gradient-image dot of the reference dot `g` under `flow` (see [`FlowConfig`]): moved by
/// `d(p)` and blurred by `Σ' = Σ + blur · J Jᵀ`, amplitude scaled by `sqrt(det Σ / det Σ')` when
/// the intensity is conserved. The background is kept.
pub fn apply_flow(g: &Gaussian2D, flow: &FlowConfig) -> Gaussian2D {
    let fv = flow.displacement.eval([g.x0, g.y0]);
    let j = fv.jacobian;
    let cxy = g.rho * g.sigma_x * g.sigma_y;
    let (mut sxx, mut syy, mut sxy) = (g.sigma_x * g.sigma_x, g.sigma_y * g.sigma_y, cxy);
    let det0 = sxx * syy - sxy * sxy;
    if flow.blur > 0.0 {
        sxx += flow.blur * (j[0][0] * j[0][0] + j[0][1] * j[0][1]);
        syy += flow.blur * (j[1][0] * j[1][0] + j[1][1] * j[1][1]);
        sxy += flow.blur * (j[0][0] * j[1][0] + j[0][1] * j[1][1]);
    }
    let det1 = sxx * syy - sxy * sxy;
    let (sx, sy) = (sxx.sqrt(), syy.sqrt());
    let amplitude = if flow.conserve_intensity && det1 > 0.0 {
        g.amplitude * (det0 / det1).sqrt()
    } else {
        g.amplitude
    };
    Gaussian2D {
        x0: g.x0 + fv.d[0],
        y0: g.y0 + fv.d[1],
        amplitude,
        sigma_x: sx,
        sigma_y: sy,
        rho: sxy / (sx * sy),
        background: g.background,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fields() -> Vec<DisplacementField> {
        vec![
            DisplacementField::Zero,
            DisplacementField::Uniform { dx: 0.3, dy: -0.7 },
            DisplacementField::Affine {
                centre: [10.0, 20.0],
                offset: [0.1, 0.2],
                matrix: [[0.01, -0.02], [0.03, 0.005]],
            },
            DisplacementField::Vortex {
                centre: [50.0, 40.0],
                strength: 8.0,
                core: 6.0,
            },
            DisplacementField::GaussianBump {
                centre: [50.0, 40.0],
                amplitude: 30.0,
                width: 9.0,
            },
        ]
    }

    /// The Jacobian matches central finite differences of the displacement (step 1e-5 px,
    /// tolerance 1e-7 absolute: the truncation error is O(h²·d''') ≈ 1e-10 here).
    #[test]
    fn jacobian_matches_finite_differences() {
        let h = 1e-5;
        for f in fields() {
            for &p in &[
                [50.0, 40.0],
                [50.3, 40.1],
                [57.0, 33.0],
                [41.2, 49.9],
                [80.0, 10.0],
            ] {
                let j = f.eval(p).jacobian;
                for c in 0..2 {
                    let mut pp = p;
                    let mut pm = p;
                    pp[c] += h;
                    pm[c] -= h;
                    let (dp, dm) = (f.eval(pp).d, f.eval(pm).d);
                    for r in 0..2 {
                        let fd = (dp[r] - dm[r]) / (2.0 * h);
                        assert!(
                            (fd - j[r][c]).abs() < 1e-7,
                            "{f:?} at {p:?}: J[{r}][{c}] = {} vs fd {fd}",
                            j[r][c]
                        );
                    }
                }
            }
        }
    }

    /// Values against the formulas written out independently (different algebra).
    #[test]
    fn values_match_formulas() {
        // Affine.
        let f = DisplacementField::Affine {
            centre: [10.0, 20.0],
            offset: [0.1, 0.2],
            matrix: [[0.01, -0.02], [0.03, 0.005]],
        };
        let d = f.eval([15.0, 18.0]).d;
        assert!(
            (d[0] - (0.1 + 0.05 + 0.04)).abs() < 1e-15
                && (d[1] - (0.2 + 0.15 - 0.01)).abs() < 1e-15
        );
        // Vortex: |d| = strength/r (1 - exp(-r²/core²)), perpendicular to the radius, turning +x to +y.
        let f = DisplacementField::Vortex {
            centre: [0.0, 0.0],
            strength: 8.0,
            core: 6.0,
        };
        for r in [1e-6, 0.5, 3.0, 6.0, 6.725, 20.0] {
            let th: f64 = 0.7;
            let p = [r * th.cos(), r * th.sin()];
            let d = f.eval(p).d;
            let mag = -8.0 / r * (-r * r / 36.0f64).exp_m1();
            assert!(
                (d[0].hypot(d[1]) - mag).abs() < 1e-12 * mag.max(1.0),
                "r = {r}"
            );
            assert!((d[0] * p[0] + d[1] * p[1]).abs() < 1e-12, "tangential");
            assert!(
                p[0] * d[1] - p[1] * d[0] > 0.0,
                "positive strength turns +x towards +y"
            );
        }
        // Peak of the vortex ≈ 0.638 strength/core at r ≈ 1.121 core (documented).
        let peak = (1..4000)
            .map(|k| f.eval([k as f64 * 0.005, 0.0]).d[1])
            .fold(0.0, f64::max);
        assert!((peak / (8.0 / 6.0) - 0.638).abs() < 1e-3, "{peak}");
        // Gaussian bump: d = A ∇ exp(-r²/2s²): check by differentiating φ numerically.
        let f = DisplacementField::GaussianBump {
            centre: [3.0, -2.0],
            amplitude: 30.0,
            width: 9.0,
        };
        let phi = |x: f64, y: f64| 30.0 * (-((x - 3.0).powi(2) + (y + 2.0).powi(2)) / 162.0).exp();
        for &p in &[[3.0, -2.0], [12.0, -2.0], [0.0, 5.0], [20.0, 20.0]] {
            let d = f.eval(p).d;
            let h = 1e-5;
            let gx = (phi(p[0] + h, p[1]) - phi(p[0] - h, p[1])) / (2.0 * h);
            let gy = (phi(p[0], p[1] + h) - phi(p[0], p[1] - h)) / (2.0 * h);
            assert!(
                (d[0] - gx).abs() < 1e-8 && (d[1] - gy).abs() < 1e-8,
                "{p:?}: {d:?} vs {gx} {gy}"
            );
        }
        // Peak |d| = A e^(-1/2)/s at r = s.
        let d = f.eval([12.0, -2.0]).d;
        assert!((d[0].abs() - 30.0 * (-0.5f64).exp() / 9.0).abs() < 1e-12 && d[0] < 0.0);
    }

    #[test]
    fn blur_model() {
        let g = Gaussian2D {
            x0: 60.0,
            y0: 40.0,
            amplitude: 1000.0,
            sigma_x: 1.5,
            sigma_y: 1.2,
            rho: 0.2,
            background: 50.0,
        };
        // No blur: moved only.
        let flow = FlowConfig {
            displacement: DisplacementField::Uniform { dx: 0.25, dy: -0.5 },
            blur: 3.0,
            conserve_intensity: true,
        };
        let h = apply_flow(&g, &flow);
        assert_eq!((h.x0, h.y0), (60.25, 39.5));
        assert!(
            (h.sigma_x - g.sigma_x).abs() < 1e-15
                && (h.rho - g.rho).abs() < 1e-15
                && h.amplitude == g.amplitude
        );
        // Affine field with a known Jacobian: Σ' = Σ + k J Jᵀ by hand.
        let m = [[0.3, 0.1], [-0.2, 0.4]];
        let flow = FlowConfig {
            displacement: DisplacementField::Affine {
                centre: [0.0, 0.0],
                offset: [0.0, 0.0],
                matrix: m,
            },
            blur: 2.0,
            conserve_intensity: true,
        };
        let h = apply_flow(&g, &flow);
        let sxx = 1.5f64.powi(2) + 2.0 * (0.09 + 0.01);
        let syy = 1.2f64.powi(2) + 2.0 * (0.04 + 0.16);
        let sxy = 0.2 * 1.5 * 1.2 + 2.0 * (0.3 * -0.2 + 0.1 * 0.4);
        assert!((h.sigma_x - sxx.sqrt()).abs() < 1e-14 && (h.sigma_y - syy.sqrt()).abs() < 1e-14);
        assert!((h.rho - sxy / (sxx * syy).sqrt()).abs() < 1e-14);
        assert!(
            (h.x0 - (60.0 + 18.0 + 4.0)).abs() < 1e-12
                && (h.y0 - (40.0 - 12.0 + 16.0)).abs() < 1e-12
        );
        // Intensity conserved; peak drops.
        assert!((h.volume() / g.volume() - 1.0).abs() < 1e-14 && h.amplitude < g.amplitude);
        let h2 = apply_flow(
            &g,
            &FlowConfig {
                conserve_intensity: false,
                ..flow
            },
        );
        assert_eq!(h2.amplitude, g.amplitude);
        // BOS bump: blur largest at the centre (|Hessian| largest), none on the ring r = s√... where J vanishes along x.
        let bump = FlowConfig {
            displacement: DisplacementField::GaussianBump {
                centre: [60.0, 40.0],
                amplitude: 30.0,
                width: 9.0,
            },
            blur: 4.0,
            conserve_intensity: true,
        };
        let c = apply_flow(&g, &bump);
        let far = apply_flow(&Gaussian2D { x0: 200.0, ..g }, &bump);
        assert!(c.sigma_x > g.sigma_x * 1.1 && (far.sigma_x - g.sigma_x).abs() < 1e-12);
        // On the x axis at r = s: J_xx = 0 and J_xy = 0, so σx is unchanged while σy grows.
        let ring = apply_flow(&Gaussian2D { x0: 69.0, ..g }, &bump);
        let ring_ref_sx = g.sigma_x;
        assert!((ring.sigma_x - ring_ref_sx).abs() < 1e-12 && ring.sigma_y > g.sigma_y);
    }
}
