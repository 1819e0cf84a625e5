//! Fast evaluation of the dot model over a window (the solver's own evaluation; checked against
//! `bostrack_model` in the tests).
//!
//! Internal parameters `θ = [x0, y0, A, ln σx, ln σy, atanh ρ, B]`. With `X = x - x0`,
//! `Y = y - y0` the model is `f = B + A·E`, `E = exp(-(a X² + 2b XY + c Y²)/2)`, where
//! `(a, b; b, c)` is the precision matrix Σ⁻¹:
//!
//! `a = cosh²t e^{-2u}`, `b = -½ sinh 2t e^{-u-v}`, `c = cosh²t e^{-2v}` (`u = ln σx`,
//! `v = ln σy`, `ρ = tanh t`, so `1/(1-ρ²) = cosh²t`).
//!
//! Every derivative of `f` is a linear combination of the seven basis functions
//! `φ = [E, EX, EY, EX², EXY, EY², 1]`:
//!
//! | parameter | ∂f/∂θ |
//! |---|---|
//! | x0 | `A(a·EX + b·EY)` |
//! | y0 | `A(b·EX + c·EY)` |
//! | A | `E` |
//! | u = ln σx | `A(a·EX² + b·EXY)` |
//! | v = ln σy | `A(b·EXY + c·EY²)` |
//! | t = atanh ρ | `A(tₐ·EX² + t_b·EXY + t_c·EY²)`, `tₐ = -½ sinh2t e^{-2u}`, `t_b = cosh2t e^{-u-v}`, `t_c = -½ sinh2t e^{-2v}` |
//! | B | `1` |
//!
//! so the normal matrix is `C G Cᵀ` with `G = Σ w φ φᵀ` (7×7) and `C` the coefficients above.
//! For the point-sampled model every entry of `G` is a moment `Σ w E^k X^m Y^n`, accumulated
//! as row sums of `X^m` (per row, then multiplied by `Y^n`): 14 multiply-adds per pixel
//! instead of the 35 of a direct `JᵀJ`. For the pixel-integrated model `φ` is replaced by its
//! pixel mean `φ̄` (closed-form erf moments when ρ is fixed at 0, Gauss-Legendre nodes otherwise)
//! and `G` is accumulated directly.
//!
//! `E` over a window needs only 8 values of `exp` ([`exp_grid`], computed together:
//! `simd::exp8`): along a row the exponent is quadratic in the column, so
//! `E(i+1) = E(i)·r(i)` with `r(i+1) = r(i)·e^{-a}`; the row-to-row step multiplies every column
//! by `e^{-bX_i}` (a vector product, no serial dependence).

use crate::simd;
use bostrack_core::{Gaussian2D, NoiseModel};
use bostrack_model::Sampling;
use std::sync::OnceLock;

/// Index of x0 in θ.
pub(crate) const IX: usize = 0;
/// Index of y0 in θ.
pub(crate) const IY: usize = 1;
/// Index of the amplitude in θ.
pub(crate) const IA: usize = 2;
/// Index of ln σx in θ.
pub(crate) const IU: usize = 3;
/// Index of ln σy in θ.
pub(crate) const IV: usize = 4;
/// Index of atanh ρ in θ.
pub(crate) const IT: usize = 5;
/// Index of the background in θ.
pub(crate) const IB: usize = 6;

/// Internal parameter vector `[x0, y0, A, ln σx, ln σy, atanh ρ, B]`.
pub(crate) type Theta = [f64; 7];

pub(crate) fn theta_from_gaussian(g: &Gaussian2D) -> Theta {
    [
        g.x0,
        g.y0,
        g.amplitude,
        g.sigma_x.ln(),
        g.sigma_y.ln(),
        g.rho.clamp(-0.999_999, 0.999_999).atanh(),
        g.background,
    ]
}

pub(crate) fn gaussian_from_theta(t: &Theta) -> Gaussian2D {
    Gaussian2D {
        x0: t[IX],
        y0: t[IY],
        amplitude: t[IA],
        sigma_x: t[IU].exp(),
        sigma_y: t[IV].exp(),
        rho: t[IT].tanh(),
        background: t[IB],
    }
}

/// Variance of a uniform pixel of unit side: the pixel-integrated dot of covariance Σ has
/// covariance Σ + I/12.
const PIXEL_VAR: f64 = 1.0 / 12.0;

/// The smallest conditional sigma of θ's shape, `min(σx, σy)·sqrt(1-ρ²)`: the width that sets
/// how far the pixel-integrated dot is from its pixel-blurred Gaussian.
pub(crate) fn conditional_sigma(t: &Theta) -> f64 {
    let r = t[IT].tanh();
    t[IU].min(t[IV]).exp() * (1.0 - r * r).max(0.0).sqrt()
}

/// θ of the pixel-blurred dot: covariance Σ + I/12, amplitude scaled to the same volume
/// (`A·sqrt(det Σ / det Σ')`); centre and background unchanged.
pub(crate) fn pixel_blur(t: &Theta) -> Theta {
    let (sx, sy, r) = (t[IU].exp(), t[IV].exp(), t[IT].tanh());
    blur_with(t, sx, sy, r)
}

/// [`pixel_blur`] of θ whose `exp(u)`, `exp(v)` and `tanh(t)` are `sx`, `sy` and `r` (only
/// θ's centre, amplitude and background are read).
pub(crate) fn blur_with(t: &Theta, sx: f64, sy: f64, r: f64) -> Theta {
    let (vx, vy) = (sx * sx + PIXEL_VAR, sy * sy + PIXEL_VAR);
    let c = r * sx * sy;
    let det = sx * sx * sy * sy * (1.0 - r * r);
    let det_b = vx * vy - c * c;
    let mut b = *t;
    b[IU] = 0.5 * vx.ln();
    b[IV] = 0.5 * vy.ln();
    b[IT] = (c / (vx * vy).sqrt()).atanh();
    b[IA] = t[IA] * (det / det_b).sqrt();
    b
}

/// The conditional σ of `g`'s shape ([`conditional_sigma`]) and θ of the pixel-blurred `g`
/// ([`pixel_blur`] of [`theta_from_gaussian`]), from `g`'s own σx, σy and ρ (ρ clamped as θ
/// clamps it) instead of those of its θ: three calls of libm (two `ln`, one `atanh`) where the
/// way through θ took nine; equal to it to a few ulp (closer to the truth at |ρ| near 1, where
/// ρ through `atanh` and `tanh` loses digits of 1 − ρ²). Every pixel-blurred θ of a fit's
/// parameters that is compared with another (a neighbour model's, the linear map's, a look's)
/// is made here.
pub(crate) fn blurred_of(g: &Gaussian2D) -> (f64, Theta) {
    let (sx, sy) = (g.sigma_x, g.sigma_y);
    let r = g.rho.clamp(-0.999_999, 0.999_999);
    let cs = sx.min(sy) * (1.0 - r * r).max(0.0).sqrt();
    let t = [g.x0, g.y0, g.amplitude, 0.0, 0.0, 0.0, g.background];
    (cs, blur_with(&t, sx, sy, r))
}

/// The unblurred shape of the pixel-blurred θ `b` (covariance Σ' − I/12): its variances `vx`,
/// `vy`, covariance `c` and the amplitude factor `sqrt(det Σ' / det Σ)`; `None` where Σ' − I/12
/// is not positive definite.
fn unblurred_shape(b: &Theta) -> Option<(f64, f64, f64, f64)> {
    let (sx, sy, r) = (b[IU].exp(), b[IV].exp(), b[IT].tanh());
    let (vx, vy) = (sx * sx - PIXEL_VAR, sy * sy - PIXEL_VAR);
    let c = r * sx * sy;
    let det = vx * vy - c * c;
    if !(vx > 0.0 && vy > 0.0 && det > 0.0 && det.is_finite()) {
        return None;
    }
    let det_b = sx * sx * sy * sy * (1.0 - r * r);
    Some((vx, vy, c, (det_b / det).sqrt()))
}

/// The parameters of the dot whose pixel-blurred θ is `b`: [`gaussian_from_theta`] of
/// [`pixel_unblur`], from `b`'s own `exp` and `tanh` (three calls of libm where the way through
/// the unblurred θ took nine), equal to it to a few ulp; `None` where [`pixel_unblur`] is.
pub(crate) fn unblurred_params(b: &Theta) -> Option<Gaussian2D> {
    let (vx, vy, c, scale) = unblurred_shape(b)?;
    Some(Gaussian2D {
        x0: b[IX],
        y0: b[IY],
        amplitude: b[IA] * scale,
        sigma_x: vx.sqrt(),
        sigma_y: vy.sqrt(),
        rho: c / (vx * vy).sqrt(),
        background: b[IB],
    })
}

/// Inverse of [`pixel_blur`]; `None` when Σ' - I/12 is not positive definite.
pub(crate) fn pixel_unblur(b: &Theta) -> Option<Theta> {
    let (vx, vy, c, scale) = unblurred_shape(b)?;
    let mut t = *b;
    t[IU] = 0.5 * vx.ln();
    t[IV] = 0.5 * vy.ln();
    t[IT] = (c / (vx * vy).sqrt()).atanh();
    t[IA] = b[IA] * scale;
    Some(t)
}

/// Precision-matrix coefficients and the ρ-derivative coefficients of a shape (u, v, t).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Shape {
    pub a: f64,
    pub b: f64,
    pub c: f64,
    pub ta: f64,
    pub tb: f64,
    pub tc: f64,
    /// Second derivatives of `a` and `c` by t (`2 cosh 2t e^{-2u}`, `2 cosh 2t e^{-2v}`).
    pub att: f64,
    pub ctt: f64,
}

impl Shape {
    pub fn new(u: f64, v: f64, t: f64) -> Shape {
        // three calls of libm instead of five (one per evaluation and per rendered neighbour):
        // sinh t = (m + m/(1+m))/2 with m = e^t - 1 (accurate for small t), cosh t = sinh t + e^-t
        let m = t.exp_m1();
        let sh = 0.5 * (m + m / (1.0 + m));
        let ch = sh + 1.0 / (1.0 + m);
        let ch2 = ch * ch;
        let s2t = 2.0 * sh * ch;
        let c2t = ch2 + sh * sh;
        let (eu, ev) = ((-u).exp(), (-v).exp());
        let eu2 = eu * eu;
        let ev2 = ev * ev;
        let euv = eu * ev;
        Shape {
            a: ch2 * eu2,
            b: -0.5 * s2t * euv,
            c: ch2 * ev2,
            ta: -0.5 * s2t * eu2,
            tb: c2t * euv,
            tc: -0.5 * s2t * ev2,
            att: 2.0 * c2t * eu2,
            ctt: 2.0 * c2t * ev2,
        }
    }
    pub fn of(theta: &Theta) -> Shape {
        Shape::new(theta[IU], theta[IV], theta[IT])
    }
}

/// Which parameters are free, and how a free parameter's derivative is made of the basis φ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    Elliptical,
    AxisAligned,
    Circular,
    /// Position, amplitude and background only, the shape (σx, σy, ρ) held where it starts.
    FixedShape,
    /// Amplitude and background only (a linear fit: shape and position held).
    Linear,
}

impl Kind {
    pub fn from_model(k: bostrack_model::ModelKind) -> Kind {
        match k {
            bostrack_model::ModelKind::Elliptical => Kind::Elliptical,
            bostrack_model::ModelKind::AxisAligned => Kind::AxisAligned,
            bostrack_model::ModelKind::Circular => Kind::Circular,
        }
    }
    /// θ indices of the free parameters (Circular: IU stands for the common ln σ).
    pub fn free(self) -> &'static [usize] {
        match self {
            Kind::Elliptical => &[IX, IY, IA, IU, IV, IT, IB],
            Kind::AxisAligned => &[IX, IY, IA, IU, IV, IB],
            Kind::Circular => &[IX, IY, IA, IU, IB],
            Kind::FixedShape => &[IX, IY, IA, IB],
            Kind::Linear => &[IA, IB],
        }
    }
    pub fn n_free(self) -> usize {
        self.free().len()
    }
    /// Whether a point-sampled pass also makes the residual's moments of degree 3 and 4 (the
    /// Newton term of a free shape, [`newton_matrix`]).
    pub fn hess(self) -> bool {
        matches!(self, Kind::Elliptical | Kind::AxisAligned | Kind::Circular)
    }
    /// Coefficients C (rows: free parameters, columns: basis φ), row-major 7×7 (unused rows 0).
    pub fn coefficients(self, theta: &Theta, s: &Shape) -> [[f64; 7]; 7] {
        let am = theta[IA];
        let mut c = [[0.0; 7]; 7];
        for (k, &p) in self.free().iter().enumerate() {
            c[k] = match p {
                IX => [0.0, am * s.a, am * s.b, 0.0, 0.0, 0.0, 0.0],
                IY => [0.0, am * s.b, am * s.c, 0.0, 0.0, 0.0, 0.0],
                IA => [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                IU if self == Kind::Circular => {
                    [0.0, 0.0, 0.0, am * s.a, 2.0 * am * s.b, am * s.c, 0.0]
                }
                IU => [0.0, 0.0, 0.0, am * s.a, am * s.b, 0.0, 0.0],
                IV => [0.0, 0.0, 0.0, 0.0, am * s.b, am * s.c, 0.0],
                IT => [0.0, 0.0, 0.0, am * s.ta, am * s.tb, am * s.tc, 0.0],
                _ => [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            };
        }
        c
    }
    /// Adds a step in free-parameter space to θ.
    pub fn apply_step(self, theta: &Theta, step: &[f64; 7]) -> Theta {
        let mut t = *theta;
        for (k, &p) in self.free().iter().enumerate() {
            t[p] += step[k];
        }
        if self == Kind::Circular {
            t[IV] = t[IU];
        }
        t
    }
    /// Puts θ on the model's manifold (ρ = 0, σy = σx as the kind requires).
    pub fn constrain(self, theta: &mut Theta) {
        match self {
            Kind::Elliptical | Kind::FixedShape | Kind::Linear => {}
            Kind::AxisAligned => theta[IT] = 0.0,
            Kind::Circular => {
                let m = 0.5 * (theta[IU] + theta[IV]);
                theta[IU] = m;
                theta[IV] = m;
                theta[IT] = 0.0;
            }
        }
    }
}

/// Fills `out[j*w + i] = exp(-(a X² + 2b XY + c Y²)/2)` with `X = x_first + i`,
/// `Y = y_first + j`, for a `w × h` grid, using 8 values of `exp` (at once:
/// [`simd::exp8`]) and two multiplications per point (see the module doc). Falls back
/// to one `exp` per point when an intermediate factor could leave the normal floating-point
/// range (very narrow dots in wide windows).
pub(crate) fn exp_grid(
    a: f64,
    b: f64,
    c: f64,
    x_first: f64,
    y_first: f64,
    w: usize,
    h: usize,
    out: &mut [f64],
    v: &mut [f64],
    q: &mut [f64],
) {
    let out = &mut out[..w * h];
    let xm = x_first.abs().max((x_first + w as f64 - 1.0).abs()) + 1.0;
    let ym = y_first.abs().max((y_first + h as f64 - 1.0).abs()) + 1.0;
    let reach = 0.5 * a * xm * xm + b.abs() * xm * ym + 0.5 * c * ym * ym;
    if reach.is_nan() || reach >= 600.0 || w == 0 || h == 0 {
        for j in 0..h {
            let y = y_first + j as f64;
            for i in 0..w {
                let x = x_first + i as f64;
                out[j * w + i] = (-0.5 * (a * x * x + 2.0 * b * x * y + c * y * y)).exp();
            }
        }
        return;
    }
    let (v, q) = (&mut v[..w], &mut q[..w]);
    // the eight factors at once (`simd::exp8`)
    let arch = simd::arch();
    let [ea, mut vi, mut r, eb, mut qi, ec, gy, s] = simd::exp8(
        arch,
        [
            -a,
            -(0.5 * a * x_first * x_first + b * x_first * y_first),
            -(0.5 * a * (2.0 * x_first + 1.0) + b * y_first),
            -b,
            -b * x_first,
            -c,
            -0.5 * c * y_first * y_first,
            -0.5 * c * (2.0 * y_first + 1.0),
        ],
    );
    // first row without its y-only factor: exp(-(a X²/2 + b X Y0))
    for slot in v.iter_mut() {
        *slot = vi;
        vi *= r;
        r *= ea;
    }
    // row-to-row factor exp(-b X)
    for slot in q.iter_mut() {
        *slot = qi;
        qi *= eb;
    }
    // y-only factor exp(-c Y²/2): ec, gy, s
    simd::exp_rows(
        arch,
        simd::ExpRows {
            out,
            v,
            q,
            w,
            gy,
            s,
            ec,
        },
    );
}

/// Gauss-Legendre nodes and weights on [-1/2, 1/2] (weights sum to 1), n = 1..=12, computed
/// once by Newton's iteration on the Legendre polynomial P_n (three-term recurrence).
pub(crate) fn gl_rule(n: usize) -> (&'static [f64], &'static [f64]) {
    static RULES: OnceLock<Vec<(Vec<f64>, Vec<f64>)>> = OnceLock::new();
    let rules = RULES.get_or_init(|| (0..=12).map(gl_compute).collect());
    let r = &rules[n.clamp(1, 12)];
    (&r.0, &r.1)
}

fn gl_compute(n: usize) -> (Vec<f64>, Vec<f64>) {
    if n <= 1 {
        return (vec![0.0], vec![1.0]);
    }
    let legendre = |x: f64| {
        let (mut p0, mut p1) = (1.0, x);
        for k in 2..=n {
            let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
            p0 = p1;
            p1 = p2;
        }
        (p1, n as f64 * (x * p1 - p0) / (x * x - 1.0))
    };
    let mut nodes = Vec::with_capacity(n);
    let mut weights = Vec::with_capacity(n);
    for k in 0..n {
        let mut x = (std::f64::consts::PI * (k as f64 + 0.75) / (n as f64 + 0.5)).cos();
        for _ in 0..50 {
            let (p, d) = legendre(x);
            let dx = p / d;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        let (_, d) = legendre(x);
        nodes.push(0.5 * x);
        weights.push(1.0 / ((1.0 - x * x) * d * d));
    }
    // exactly symmetric about the pixel's centre (the factored quadrature pairs s and −s)
    for k in 0..n / 2 {
        nodes[n - 1 - k] = -nodes[k];
        weights[n - 1 - k] = weights[k];
    }
    if n % 2 == 1 {
        nodes[n / 2] = 0.0;
    }
    (nodes, weights)
}

/// The most error the pixel-integrated model's quadrature may have, relative to the dot's
/// amplitude, where nothing says more is allowed ([`gl_order`]): a thousandth of the noise of a
/// dot with peak SNR 1000.
pub(crate) const QUADRATURE_TOLERANCE: f64 = 1e-6;

/// The largest error of the n-point Gauss-Legendre pixel integral (n = 1..=12, columns) on a
/// unit-amplitude round dot of σ (rows, [`QUADRATURE_SIGMAS`]), over sub-pixel positions (from
/// the ignored test `print_quadrature_table`; the error falls with σ, so a row bounds every
/// larger σ up to the next).
const QUADRATURE_ERRORS: [[f64; 12]; 22] = [
    [
        8.6e-1, 1.2e-1, 7.4e-2, 1.9e-2, 5.2e-3, 1.1e-3, 2.1e-4, 3.5e-5, 5.2e-6, 7.1e-7, 8.8e-8,
        1.0e-8,
    ],
    [
        7.5e-1, 1.2e-1, 3.5e-2, 6.3e-3, 9.5e-4, 1.2e-4, 1.3e-5, 1.3e-6, 1.1e-7, 8.4e-9, 5.9e-10,
        3.8e-11,
    ],
    [
        6.4e-1, 9.4e-2, 1.6e-2, 2.0e-3, 2.0e-4, 1.6e-5, 1.1e-6, 7.1e-8, 3.9e-9, 1.9e-10, 8.8e-12,
        3.6e-13,
    ],
    [
        5.4e-1, 6.6e-2, 7.9e-3, 6.7e-4, 4.7e-5, 2.7e-6, 1.3e-7, 5.7e-9, 2.2e-10, 7.6e-12, 2.4e-13,
        4.1e-15,
    ],
    [
        4.5e-1, 4.6e-2, 3.9e-3, 2.5e-4, 1.3e-5, 5.4e-7, 2.0e-8, 6.3e-10, 1.8e-11, 4.6e-13, 1.2e-14,
        3.9e-15,
    ],
    [
        3.7e-1, 3.1e-2, 2.1e-3, 1.0e-4, 4.0e-6, 1.3e-7, 3.6e-9, 8.8e-11, 1.9e-12, 3.7e-14, 2.1e-15,
        3.7e-15,
    ],
    [
        3.2e-1, 2.2e-2, 1.1e-3, 4.4e-5, 1.4e-6, 3.5e-8, 7.8e-10, 1.5e-11, 2.6e-13, 3.9e-15,
        1.3e-15, 1.8e-15,
    ],
    [
        2.7e-1, 1.6e-2, 6.6e-4, 2.1e-5, 5.2e-7, 1.1e-8, 2.0e-10, 3.1e-12, 4.2e-14, 2.9e-15,
        1.6e-15, 1.1e-15,
    ],
    [
        2.3e-1, 1.1e-2, 4.0e-4, 1.0e-5, 2.1e-7, 3.7e-9, 5.5e-11, 7.1e-13, 8.8e-15, 3.3e-15,
        3.4e-15, 2.6e-15,
    ],
    [
        2.0e-1, 8.4e-3, 2.5e-4, 5.4e-6, 9.4e-8, 1.4e-9, 1.7e-11, 1.8e-13, 2.9e-15, 3.2e-15,
        8.9e-16, 2.6e-15,
    ],
    [
        1.5e-1, 4.8e-3, 1.0e-4, 1.7e-6, 2.2e-8, 2.3e-10, 2.1e-12, 1.8e-14, 3.3e-15, 2.1e-15,
        1.8e-15, 1.1e-15,
    ],
    [
        1.2e-1, 2.9e-3, 4.9e-5, 6.1e-7, 6.0e-9, 4.9e-11, 3.4e-13, 5.8e-15, 3.4e-15, 1.9e-15,
        1.7e-15, 1.7e-15,
    ],
    [
        9.6e-2, 1.9e-3, 2.5e-5, 2.4e-7, 1.9e-9, 1.2e-11, 6.5e-14, 1.9e-15, 2.1e-15, 2.3e-15,
        2.3e-15, 1.9e-15,
    ],
    [
        7.9e-2, 1.3e-3, 1.4e-5, 1.1e-7, 6.8e-10, 3.5e-12, 1.7e-14, 1.0e-15, 1.0e-15, 1.6e-15,
        2.0e-15, 2.2e-15,
    ],
    [
        6.6e-2, 8.8e-4, 7.8e-6, 5.1e-8, 2.7e-10, 1.1e-12, 4.8e-15, 1.8e-15, 2.0e-15, 1.8e-15,
        1.0e-15, 2.3e-15,
    ],
    [
        5.6e-2, 6.3e-4, 4.7e-6, 2.6e-8, 1.1e-10, 4.1e-13, 2.3e-15, 2.0e-15, 1.7e-15, 2.4e-15,
        8.9e-16, 2.7e-15,
    ],
    [
        4.1e-2, 3.5e-4, 1.9e-6, 7.6e-9, 2.5e-11, 6.7e-14, 2.0e-15, 1.7e-15, 2.8e-15, 1.4e-15,
        1.7e-15, 1.3e-15,
    ],
    [
        3.2e-2, 2.0e-4, 8.5e-7, 2.6e-9, 6.5e-12, 1.3e-14, 1.0e-15, 1.1e-15, 1.4e-15, 1.4e-15,
        6.7e-16, 1.2e-15,
    ],
    [
        2.5e-2, 1.3e-4, 4.2e-7, 1.0e-9, 2.0e-12, 4.2e-15, 1.0e-15, 1.4e-15, 1.1e-15, 1.1e-15,
        1.4e-15, 1.1e-15,
    ],
    [
        2.1e-2, 8.5e-5, 2.3e-7, 4.5e-10, 7.1e-13, 1.1e-15, 1.1e-15, 7.8e-16, 6.7e-16, 1.3e-15,
        1.0e-15, 1.3e-15,
    ],
    [
        1.3e-2, 3.5e-5, 6.0e-8, 7.6e-11, 7.7e-14, 1.0e-15, 1.3e-15, 8.9e-16, 1.2e-15, 1.9e-15,
        1.1e-15, 1.4e-15,
    ],
    [
        9.2e-3, 1.7e-5, 2.0e-8, 1.8e-11, 1.3e-14, 1.0e-15, 1.9e-15, 8.9e-16, 1.1e-15, 1.6e-15,
        1.6e-15, 1.6e-15,
    ],
];

/// The σ (px) of the rows of [`QUADRATURE_ERRORS`].
const QUADRATURE_SIGMAS: [f64; 22] = [
    0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.4, 1.6,
    1.8, 2.0, 2.5, 3.0,
];

/// Gauss-Legendre points per axis for the pixel-integrated model with ρ ≠ 0, from the smaller
/// sigma: the smallest order (at least 3) whose error on a unit-amplitude dot is below
/// `tolerance` at the table's σ just below `sigma_min` (12 below its first row; test
/// `quadrature_order_is_accurate`). The order is chosen once per fit, from the start, with the
/// fit's tolerance ([`quadrature_tolerance`]).
pub(crate) fn gl_order(sigma_min: f64, tolerance: f64) -> usize {
    let Some(row) = QUADRATURE_SIGMAS.iter().rposition(|&s| s <= sigma_min) else {
        return 12;
    };
    QUADRATURE_ERRORS[row]
        .iter()
        // (the table's two digits: a tenth of margin)
        .position(|&e| e <= 0.9 * tolerance)
        .map_or(12, |k| (k + 1).max(3))
}

/// The quadrature's tolerance for a fit (relative to the amplitude, as [`gl_order`] takes it):
/// the model's error a thousandth of the pixel noise at the dot's background, so that its bias
/// of the position stays below ~0.3 % of the bound (a dot's few pixels, each off by 1e-3 of its
/// noise); between [`QUADRATURE_TOLERANCE`] and 1e-4. Issue 17: on bench/trackpy's σ 0.3 px
/// scene (noise 30 counts at the background, amplitude 1500: 2e-5) 6 or 7 nodes per axis
/// where 1e-6 took 7 to 12.
pub(crate) fn quadrature_tolerance(theta: &Theta, noise: &NoiseModel) -> f64 {
    let t = 1e-3 * noise.sigma(theta[IB]) / theta[IA];
    if t.is_finite() && t > 0.0 {
        t.clamp(QUADRATURE_TOLERANCE, 1e-4)
    } else {
        QUADRATURE_TOLERANCE
    }
}

/// Scratch buffers and the pixels of one window. Reused from dot to dot (no allocation per dot
/// once the buffers have grown to the largest window).
#[derive(Debug, Default, Clone)]
pub(crate) struct Workspace {
    /// Window origin (pixel indices of the first column and row) and size.
    pub wx: i64,
    pub wy: i64,
    pub w: usize,
    pub h: usize,
    /// Samples (0 where not usable).
    pub data: Vec<f64>,
    /// 1 for usable pixels, 0 otherwise.
    pub keep: Vec<f64>,
    pub n_used: usize,
    /// The solve's fixed weights (keep / variance of the model at the solve's start), and
    /// scratch for refreshed ones.
    pub w_cur: Vec<f64>,
    pub w_new: Vec<f64>,
    /// E (point) or φ̄0 (integrated) of the last evaluation, and the other φ̄ components.
    pub e: Vec<f64>,
    pub phi: [Vec<f64>; 5],
    pub tmp: Vec<f64>,
    pub v: Vec<f64>,
    pub q: Vec<f64>,
    pub xp: Vec<[f64; 5]>,
    /// Scratch for the start estimate.
    pub sort_buf: Vec<f64>,
    pub stack: Vec<u32>,
    pub mark: Vec<bool>,
    /// Gauss-Legendre order fixed for the current fit (0: chosen from θ at each evaluation).
    pub gl_n: usize,
    /// Partial sums over the quadrature nodes of one node row.
    pub acc: [Vec<f64>; 3],
    /// Column accumulators of the point-sampled pass ([`simd::acc_len`]).
    pub cols: Vec<f64>,
    /// The node factors' tables of the factored quadrature ([`fill_phi_integrated`]).
    pub tables: Vec<f64>,
}

impl Workspace {
    /// Sizes the buffers for a `w × h` window.
    pub fn resize(&mut self, wx: i64, wy: i64, w: usize, h: usize) {
        self.wx = wx;
        self.wy = wy;
        self.w = w;
        self.h = h;
        let n = w * h;
        for buf in [
            &mut self.data,
            &mut self.keep,
            &mut self.w_cur,
            &mut self.w_new,
            &mut self.e,
            &mut self.tmp,
        ] {
            // every buffer is written before it is read: no clearing
            buf.resize(n, 0.0);
        }
        for buf in self.phi.iter_mut() {
            buf.resize(n, 0.0);
        }
        let m = w.max(h);
        self.v.resize(m, 0.0);
        self.q.resize(m, 0.0);
        self.xp.resize(w + h, [0.0; 5]);
        self.mark.resize(n, false);
        for buf in self.acc.iter_mut() {
            buf.resize(n, 0.0);
        }
        self.cols.resize(simd::acc_len(w), 0.0);
    }

    pub fn len(&self) -> usize {
        self.w * self.h
    }
}

/// What one evaluation pass returns.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Pass {
    /// Σ w r² with the solve's fixed weights (`w_cur`; `keep / read variance` with constant
    /// noise).
    pub cost: f64,
    /// Σ keep r² (unweighted residual sum of squares).
    pub ssr: f64,
    /// Gram matrix of the basis φ with the same weights (symmetric, full).
    pub gram: [[f64; 7]; 7],
    /// Σ w r φ.
    pub grad: [f64; 7],
    pub finite: bool,
    /// The shape coefficients at the evaluated θ (for [`normal_equations`]).
    pub shape: Shape,
    /// `Σ w r E XᵐYⁿ` for (m, n) = (3, 0), (2, 1), (1, 2), (0, 3), (4, 0), (3, 1), (2, 2),
    /// (1, 3), (0, 4), where the pass made them (`has_rh`: a point-sampled pass asked for
    /// them): with [`Pass::grad`] the moments of the Newton step's second-order term
    /// ([`newton_matrix`]).
    pub rh: [f64; 9],
    pub has_rh: bool,
}

/// Basis description: (power of E, power of X, power of Y) of φ_0..φ_6.
const BASIS: [(usize, usize, usize); 7] = [
    (1, 0, 0),
    (1, 1, 0),
    (1, 0, 1),
    (1, 2, 0),
    (1, 1, 1),
    (1, 0, 2),
    (0, 0, 0),
];

/// Evaluates the model at θ over the workspace window, with the Gram matrix and gradient.
/// Weights: with signal-dependent noise `w_cur` holds the solve's fixed weights
/// ([`set_weights`]); with constant noise the sums use `keep` and 1/variance.
pub(crate) fn evaluate(
    ws: &mut Workspace,
    theta: &Theta,
    sampling: Sampling,
    kind: Kind,
    noise: &NoiseModel,
) -> Pass {
    evaluate_h(ws, theta, sampling, kind, noise, false)
}

/// [`evaluate`], with the residual's moments of degree 3 and 4 where `hess` and the pass is
/// point-sampled ([`Pass::rh`]).
pub(crate) fn evaluate_h(
    ws: &mut Workspace,
    theta: &Theta,
    sampling: Sampling,
    kind: Kind,
    noise: &NoiseModel,
    hess: bool,
) -> Pass {
    match sampling {
        Sampling::Point => {
            eval_point_moments(ws, theta, &Shape::of(theta), noise, hess && kind.hess())
        }
        Sampling::Integrated => {
            fill_phi_integrated(ws, theta, kind);
            eval_general(ws, theta, noise)
        }
    }
}

/// Point-sampled pass with the moment accumulation ([`crate::simd::column_sums`] of a `MomentsIn`: per
/// column over the rows, then folded with the columns' X powers).
fn eval_point_moments(
    ws: &mut Workspace,
    theta: &Theta,
    s: &Shape,
    noise: &NoiseModel,
    hess: bool,
) -> Pass {
    let x_first = ws.wx as f64 - theta[IX];
    let y_first = ws.wy as f64 - theta[IY];
    exp_grid(
        s.a, s.b, s.c, x_first, y_first, ws.w, ws.h, &mut ws.e, &mut ws.v, &mut ws.q,
    );
    point_sums(ws, theta, s, noise, hess)
}

/// The weighted sums of the point-sampled pass from the unit dot `E` at θ already in `ws.e`.
fn point_sums(
    ws: &mut Workspace,
    theta: &Theta,
    s: &Shape,
    noise: &NoiseModel,
    hess: bool,
) -> Pass {
    let (w, h) = (ws.w, ws.h);
    let x_first = ws.wx as f64 - theta[IX];
    let y_first = ws.wy as f64 - theta[IY];
    let variable = !noise.is_constant();
    // constant noise: accumulate with the 0/1 keep and apply 1/variance at the end
    let scale = if variable {
        1.0
    } else {
        1.0 / noise.variance(f64::NEG_INFINITY)
    };
    let n = w * h;
    let inp = simd::MomentsIn {
        e: &ws.e[..n],
        d: &ws.data[..n],
        keep: &ws.keep[..n],
        wt: if variable {
            &ws.w_cur[..n]
        } else {
            &ws.keep[..n]
        },
        w,
        h,
        amp: theta[IA],
        bg: theta[IB],
        x_first,
        y_first,
        hess,
    };
    let simd::Moments {
        mut m2,
        mut m1,
        mut r1,
        mut rh,
        mut m0,
        mut r0,
        mut cost,
        ssr,
    } = simd::column_sums(simd::arch(), &inp, &mut ws.cols);
    if !variable {
        cost *= scale;
        m0 *= scale;
        r0 *= scale;
        for row in m2.iter_mut() {
            row.iter_mut().for_each(|v| *v *= scale);
        }
        for (a, b) in m1.iter_mut().zip(r1.iter_mut()) {
            a.iter_mut().for_each(|v| *v *= scale);
            b.iter_mut().for_each(|v| *v *= scale);
        }
        if hess {
            for row in rh.iter_mut() {
                row.iter_mut().for_each(|v| *v *= scale);
            }
        }
    }
    let mut gram = [[0.0; 7]; 7];
    let mut grad = [0.0; 7];
    for (bi, &(eb, xb, yb)) in BASIS.iter().enumerate() {
        grad[bi] = if eb == 1 { r1[xb][yb] } else { r0 };
        for (ci, &(ec, xc, yc)) in BASIS.iter().enumerate() {
            gram[bi][ci] = match (eb, ec) {
                (1, 1) => m2[xb + xc][yb + yc],
                (1, 0) => m1[xb][yb],
                (0, 1) => m1[xc][yc],
                _ => m0,
            };
        }
    }
    let finite = cost.is_finite() && gram[0][0].is_finite() && gram[3][3].is_finite();
    Pass {
        cost,
        ssr,
        gram,
        grad,
        finite,
        shape: *s,
        rh: [
            rh[3][0], rh[2][1], rh[1][2], rh[0][3], rh[4][0], rh[3][1], rh[2][2], rh[1][3],
            rh[0][4],
        ],
        has_rh: hess,
    }
}

/// The point-sampled pass at θ from the unit dot `E` that [`dot_factor`] left in `ws.tmp` at
/// θ's centre and shape (as [`start_linear`] does): the same sums as [`evaluate_h`] without
/// rendering `E` again (`ws.tmp` and `ws.e` are swapped; `dot_factor` calls the same
/// `exp_grid` with the same arguments, so the bits are the same).
pub(crate) fn pass_from_factor(
    ws: &mut Workspace,
    theta: &Theta,
    noise: &NoiseModel,
    hess: bool,
) -> Pass {
    std::mem::swap(&mut ws.e, &mut ws.tmp);
    point_sums(ws, theta, &Shape::of(theta), noise, hess)
}

/// 1-D pixel moments of g(X) = exp(-a X²/2) over [X - 1/2, X + 1/2], `(∫g, ∫Xg, ∫X²g)` in the
/// first three entries of `out[i]`, for the pixels `X = first + i`: each pixel edge's `erfc`
/// and `exp` once, shared by the two pixels it bounds (issue 17: half the special functions of
/// the closed-form pass, which pass 1 of an undersampled scene's dots takes), the pixel that
/// holds the centre by `erf` (no cancellation).
fn axis_moments(a: f64, first: f64, out: &mut [[f64; 5]]) {
    let s = (0.5 * a).sqrt();
    let scale = 0.5 * std::f64::consts::PI.sqrt() / s;
    // edge values at t = s·e: erfc(|t|) and exp(−t²)
    let edge = |e: f64| {
        let t = s * e;
        (t, libm::erfc(t.abs()), (-t * t).exp())
    };
    let mut lo = first - 0.5;
    let (mut tl, mut el, mut gl) = edge(lo);
    for (i, o) in out.iter_mut().enumerate() {
        let hi = (first + (i + 1) as f64) - 0.5;
        let (th, eh, gh) = edge(hi);
        let diff = if tl > 0.0 {
            el - eh
        } else if th < 0.0 {
            eh - el
        } else {
            libm::erf(th) - libm::erf(tl)
        };
        let i0 = scale * diff;
        let i1 = (gl - gh) / a;
        let i2 = (i0 + lo * gl - hi * gh) / a;
        *o = [i0, i1, i2, 0.0, 0.0];
        (lo, tl, el, gl) = (hi, th, eh, gh);
    }
}

/// Fills ws.e (φ̄0) and ws.phi (φ̄1..φ̄5) with the pixel means of the basis at θ.
pub(crate) fn fill_phi_integrated(ws: &mut Workspace, theta: &Theta, kind: Kind) {
    let (w, h) = (ws.w, ws.h);
    let s = Shape::of(theta);
    let x_first = ws.wx as f64 - theta[IX];
    let y_first = ws.wy as f64 - theta[IY];
    if matches!(kind, Kind::AxisAligned | Kind::Circular) || theta[IT] == 0.0 {
        // separable and exact: E = gx(X) gy(Y) (xp: the w columns' moments, then the h rows')
        let [p1, p2, p3, p4, p5] = &mut ws.phi;
        let (xm, ym) = ws.xp[..w + h].split_at_mut(w);
        axis_moments(s.a, x_first, xm);
        axis_moments(s.c, y_first, ym);
        for (j, &[j0, j1, j2, _, _]) in ym.iter().enumerate() {
            for (i, &[i0, i1, i2, _, _]) in xm.iter().enumerate() {
                let k = j * w + i;
                ws.e[k] = i0 * j0;
                p1[k] = i1 * j0;
                p2[k] = i0 * j1;
                p3[k] = i2 * j0;
                p4[k] = i1 * j1;
                p5[k] = i0 * j2;
            }
        }
        return;
    }
    let order = if ws.gl_n > 0 {
        ws.gl_n
    } else {
        gl_order(theta[IU].min(theta[IV]).exp(), QUADRATURE_TOLERANCE)
    };
    if !integrated_factored(ws, &s, x_first, y_first, order) {
        integrated_by_nodes(ws, &s, x_first, y_first, order);
        pixel_means_from_sums(ws, x_first, y_first);
    }
}

/// Most Gauss-Legendre nodes per axis of [`integrated_factored`] (the rules go to 12).
const FACTORED_MAX_NODES: usize = simd::MAX_NODES;

/// [`fill_phi_integrated`]'s pixel means of the basis (`φ̄0` into `ws.e`, `φ̄1..φ̄5` into
/// `ws.phi`) from its node sums `S0, Sx, Sy, Sxx, Sxy, Syy` (as [`pixel_means_from_sums`]), with
/// the factor at every node split into parts of one or two indices:
/// with `X, Y` the pixel's centre and `s_k, s_l` the node offsets,
///
/// `E(X + s_k, Y + s_l) = G(X, Y) · U(X, k) · V(Y, l) · P(X, l) · Q(k, Y) · T(k, l)`,
///
/// `G = exp(−(aX² + 2bXY + cY²)/2)` (one [`exp_grid`]), `U = exp(−a s_k X − a s_k²/2)`,
/// `V = exp(−c s_l Y − c s_l²/2)`, `P = exp(−b s_l X)`, `Q = exp(−b s_k Y)`,
/// `T = exp(−b s_k s_l)`, each made along its grid by a geometric recurrence. Per pixel the sums
/// are then `G αᵀ T β` with `α_k = w_k U Q`, `β_l = w_l V P` (and `α∘s`, `β∘s`, ...): ~110 exps
/// per evaluation at 7 nodes per axis where one `exp_grid` per node pair took ~400, and one pass
/// over the window instead of one per node pair (issue 17: the undersampled scene spent 66 % of
/// its instructions in those grids). The per-pixel sums `τ_n = T_n β` and `αᵀτ_n` run with the
/// columns as SIMD lanes ([`simd::factored_sums`]): at every order, the σ 0.75 px scene's 5 nodes
/// included (there the node grids had cost as much as the scalar sums; 1.28 → 1.03 G
/// instructions for its `bostrack locate` with [`eval_general`]'s lanes). Same sums to rounding (test
/// `factored_quadrature_equals_the_node_grids`). `false` (nothing written) where a factor could
/// leave the normal floating-point range or the rule is longer than [`FACTORED_MAX_NODES`]: the
/// caller sums the node grids ([`integrated_by_nodes`]).
fn integrated_factored(
    ws: &mut Workspace,
    s: &Shape,
    x_first: f64,
    y_first: f64,
    order: usize,
) -> bool {
    let (w, h) = (ws.w, ws.h);
    let (nodes, weights) = gl_rule(order);
    let m = nodes.len();
    if m > FACTORED_MAX_NODES || w == 0 || h == 0 {
        return false;
    }
    // (each factor but G is exp of at most half a node's reach times the window's: within the
    // normal range below 600; G, the product's other part, only ever underflows, where the
    // node values are far below the peak)
    let xm = x_first.abs().max((x_first + w as f64 - 1.0).abs()) + 1.0;
    let ym = y_first.abs().max((y_first + h as f64 - 1.0).abs()) + 1.0;
    let big = 0.5 * s.a.max(s.c).max(s.b.abs()) * xm.max(ym) + s.a.max(s.c).max(s.b.abs());
    if big.is_nan() || big >= 600.0 {
        return false;
    }
    let (a, b, c) = (s.a, s.b, s.c);
    exp_grid(
        a,
        b,
        c,
        x_first,
        y_first,
        w,
        h,
        &mut ws.tmp,
        &mut ws.v,
        &mut ws.q,
    );
    // per node: U and P along the columns (w values), V and Q along the rows (h values), each
    // `exp(−coef s_k (first + i) − [coef s_k²/2])` by a geometric recurrence; the rule is
    // symmetric (`s_{m−1−k} = −s_k`), so the second half's start and ratio come from the
    // first half's by a division (and `exp(−coef s_k²)` where the square term is there)
    let geometric = |coef: f64, square: bool, first: f64, len: usize, out: &mut Vec<f64>| {
        let (mut starts, mut ratios) = ([0.0f64; FACTORED_MAX_NODES], [0.0f64; FACTORED_MAX_NODES]);
        for (k, &sk) in nodes.iter().enumerate() {
            let mirror = m - 1 - k;
            let (start, ratio) = if sk == 0.0 {
                (1.0, 1.0)
            } else if mirror < k {
                let q = if square { (-coef * sk * sk).exp() } else { 1.0 };
                (q / starts[mirror], 1.0 / ratios[mirror])
            } else {
                let sq = if square { 0.5 * coef * sk * sk } else { 0.0 };
                ((-coef * sk * first - sq).exp(), (-coef * sk).exp())
            };
            (starts[k], ratios[k]) = (start, ratio);
            let mut v = start;
            for _ in 0..len {
                out.push(v);
                v *= ratio;
            }
        }
    };
    // tables [node][index], node-major, in one buffer of the workspace (kept from dot to dot)
    let tables = &mut ws.tables;
    tables.clear();
    geometric(a, true, x_first, w, tables);
    geometric(b, false, x_first, w, tables);
    geometric(c, true, y_first, h, tables);
    geometric(b, false, y_first, h, tables);
    // the coupling of the nodes, after the tables: T = exp(−b s_k s_l) and T s_l, T s_l² (m × m), or where the
    // products stay small, cosh/sinh over the pairs ±s of the symmetric rule (half the work)
    let (half, symmetric) = (m / 2, pairs_nodes(b, nodes));
    let n2 = half * half;
    let t_at = tables.len();
    if symmetric {
        tables.resize(t_at + 6 * n2, 0.0);
        let mats = &mut tables[t_at..];
        for k in 0..half {
            for l in 0..half {
                let (sl, at) = (nodes[l], k * half + l);
                // (one expm1: sinh x = (e + e/(1+e))/2, cosh x = sinh x + 1/(1+e), e = eˣ − 1,
                // accurate for small x)
                let e = (b * nodes[k] * sl).exp_m1();
                let sh = 0.5 * (e + e / (1.0 + e));
                let (c, d) = (sh + 1.0 / (1.0 + e), -sh);
                mats[at] = c;
                mats[n2 + at] = d;
                mats[2 * n2 + at] = c * sl;
                mats[3 * n2 + at] = d * sl;
                mats[4 * n2 + at] = c * sl * sl;
                mats[5 * n2 + at] = d * sl * sl;
            }
        }
    } else {
        tables.resize(t_at + 3 * m * m, 0.0);
        let (t0, t12) = tables[t_at..].split_at_mut(m * m);
        for k in 0..m {
            for l in 0..=k {
                let e = (-b * nodes[k] * nodes[l]).exp();
                t0[k * m + l] = e;
                t0[l * m + k] = e;
            }
        }
        let (t1, t2) = t12.split_at_mut(m * m);
        for (at, &e) in t0.iter().enumerate() {
            let sl = nodes[at % m];
            t1[at] = e * sl;
            t2[at] = e * sl * sl;
        }
    }
    // the weights into the row tables (α's and β's row factors)
    let (cols, rest) = ws.tables.split_at_mut(2 * m * w);
    let (tu, tp) = cols.split_at(m * w);
    let (rows, t) = rest.split_at_mut(2 * m * h);
    let (tv, tq) = rows.split_at_mut(m * h);
    for (k, &wk) in weights.iter().enumerate() {
        tv[k * h..(k + 1) * h].iter_mut().for_each(|v| *v *= wk);
        tq[k * h..(k + 1) * h].iter_mut().for_each(|v| *v *= wk);
    }
    let coupling = if symmetric {
        simd::Coupling::Symmetric(std::array::from_fn(|q| &t[q * n2..(q + 1) * n2]))
    } else {
        simd::Coupling::Full(std::array::from_fn(|q| &t[q * m * m..(q + 1) * m * m]))
    };
    let [p1, p2, p3, p4, p5] = &mut ws.phi;
    simd::factored_sums(
        simd::arch(),
        simd::FactoredSums {
            nodes,
            u: tu,
            p: tp,
            aq: tq,
            bv: tv,
            coupling,
            g: &ws.tmp,
            w,
            h,
            x_first,
            y_first,
            s0: &mut ws.e,
            out: [p1, p2, p3, p4, p5],
        },
    );
    true
}

/// Largest `|b| s²` (over the rule's outermost node) for which [`integrated_factored`] pairs the
/// nodes ([`simd::Coupling::Symmetric`]): the cancellation in `cosh x − sinh x` then costs at
/// most a factor `e⁴` of the relative precision (~1e-14).
const SYMMETRIC_MAX_X: f64 = 2.0;

/// Whether [`integrated_factored`] pairs the nodes ±s of the (symmetric) rule `nodes` for the
/// coupling `b` (see [`SYMMETRIC_MAX_X`]).
fn pairs_nodes(b: f64, nodes: &[f64]) -> bool {
    nodes.len() > 1 && b.abs() * nodes[0] * nodes[0] <= SYMMETRIC_MAX_X
}

/// [`fill_phi_integrated`]'s node sums by one [`exp_grid`] per node pair.
fn integrated_by_nodes(ws: &mut Workspace, s: &Shape, x_first: f64, y_first: f64, order: usize) {
    let (w, h) = (ws.w, ws.h);
    let (nodes, weights) = gl_rule(order);
    let n = w * h;
    // Per pixel, with node offsets (s_k, s_l) and E_kl the factor at the node:
    //   S0 = Σ w_k w_l E_kl, Sx = Σ w_k w_l s_k E_kl, Sxx = Σ ... s_k² E_kl, Sy, Sxy, Syy likewise,
    // summed over k first (acc = T0, T1, T2 for one y node l); then with X, Y at the pixel
    //   φ̄0 = S0, φ̄1 = X S0 + Sx, φ̄2 = Y S0 + Sy, φ̄3 = X² S0 + 2X Sx + Sxx,
    //   φ̄4 = XY S0 + X Sy + Y Sx + Sxy, φ̄5 = Y² S0 + 2Y Sy + Syy.
    for p in ws.phi.iter_mut() {
        p[..n].fill(0.0);
    }
    ws.e[..n].fill(0.0);
    for (&sy, &wy) in nodes.iter().zip(weights) {
        for a in ws.acc.iter_mut() {
            a[..n].fill(0.0);
        }
        for (&sx, &wx) in nodes.iter().zip(weights) {
            exp_grid(
                s.a,
                s.b,
                s.c,
                x_first + sx,
                y_first + sy,
                w,
                h,
                &mut ws.tmp,
                &mut ws.v,
                &mut ws.q,
            );
            let (w1, w2) = (wx * sx, wx * sx * sx);
            let [t0, t1, t2] = &mut ws.acc;
            for (((&e, a0), a1), a2) in ws.tmp[..n]
                .iter()
                .zip(&mut t0[..n])
                .zip(&mut t1[..n])
                .zip(&mut t2[..n])
            {
                *a0 += wx * e;
                *a1 += w1 * e;
                *a2 += w2 * e;
            }
        }
        // Sxx and Sxy reuse phi[2] and phi[3] as accumulators; Sx phi[0], Sy phi[1], Syy phi[4]
        let (v1, v2) = (wy * sy, wy * sy * sy);
        let [sx_, sy_, sxx, sxy, syy] = &mut ws.phi;
        let [t0, t1, t2] = &ws.acc;
        for k in 0..n {
            let (a0, a1, a2) = (t0[k], t1[k], t2[k]);
            ws.e[k] += wy * a0;
            sx_[k] += wy * a1;
            sxx[k] += wy * a2;
            sy_[k] += v1 * a0;
            sxy[k] += v1 * a1;
            syy[k] += v2 * a0;
        }
    }
}

/// The pixel means of the basis from the node sums: with `X, Y` at the pixel,
/// `φ̄0 = S0, φ̄1 = X S0 + Sx, φ̄2 = Y S0 + Sy, φ̄3 = X² S0 + 2X Sx + Sxx`,
/// `φ̄4 = XY S0 + X Sy + Y Sx + Sxy, φ̄5 = Y² S0 + 2Y Sy + Syy`.
fn pixel_means_from_sums(ws: &mut Workspace, x_first: f64, y_first: f64) {
    let (w, h) = (ws.w, ws.h);
    let [p1, p2, p3, p4, p5] = &mut ws.phi;
    for j in 0..h {
        let y = y_first + j as f64;
        for i in 0..w {
            let x = x_first + i as f64;
            let k = j * w + i;
            let (s0, sx_, sy_, sxx, sxy, syy) = (ws.e[k], p1[k], p2[k], p3[k], p4[k], p5[k]);
            p1[k] = x * s0 + sx_;
            p2[k] = y * s0 + sy_;
            p3[k] = x * x * s0 + 2.0 * x * sx_ + sxx;
            p4[k] = x * y * s0 + x * sy_ + y * sx_ + sxy;
            p5[k] = y * y * s0 + 2.0 * y * sy_ + syy;
        }
    }
}

/// Fills ws.e and ws.phi with the point-sampled basis at θ (for the generic pass and the
/// levenberg-marquardt crate path).
pub(crate) fn fill_phi_point(ws: &mut Workspace, theta: &Theta) {
    let (w, h) = (ws.w, ws.h);
    let s = Shape::of(theta);
    let x_first = ws.wx as f64 - theta[IX];
    let y_first = ws.wy as f64 - theta[IY];
    exp_grid(
        s.a, s.b, s.c, x_first, y_first, w, h, &mut ws.e, &mut ws.v, &mut ws.q,
    );
    let [p1, p2, p3, p4, p5] = &mut ws.phi;
    for j in 0..h {
        let y = y_first + j as f64;
        for i in 0..w {
            let x = x_first + i as f64;
            let k = j * w + i;
            let e = ws.e[k];
            p1[k] = e * x;
            p2[k] = e * y;
            p3[k] = e * x * x;
            p4[k] = e * x * y;
            p5[k] = e * y * y;
        }
    }
}

/// Fills the basis for any sampling.
pub(crate) fn fill_phi(ws: &mut Workspace, theta: &Theta, sampling: Sampling, kind: Kind) {
    match sampling {
        Sampling::Point => fill_phi_point(ws, theta),
        Sampling::Integrated => fill_phi_integrated(ws, theta, kind),
    }
}

/// Generic pass from the per-pixel basis in ws.e / ws.phi: G = Σ w φ φᵀ accumulated with the
/// columns as SIMD lanes ([`simd::column_sums`] of a `BasisIn`; issue 17: 9.5 % of the σ 0.75 px scene's
/// instructions as a scalar loop, 0.6 % now).
pub(crate) fn eval_general(ws: &mut Workspace, theta: &Theta, noise: &NoiseModel) -> Pass {
    let variable = !noise.is_constant();
    let inv_var = 1.0 / noise.variance(f64::NEG_INFINITY);
    let [p1, p2, p3, p4, p5] = &ws.phi;
    let inp = simd::BasisIn {
        phi: [&ws.e, p1, p2, p3, p4, p5],
        d: &ws.data,
        keep: &ws.keep,
        // (constant noise: the weights are `keep`, the sums scaled by 1/variance after)
        wt: if variable { &ws.w_cur } else { &ws.keep },
        w: ws.w,
        h: ws.h,
        amp: theta[IA],
        bg: theta[IB],
    };
    let simd::BasisSums {
        gram: mut g,
        mut grad,
        mut cost,
        ssr,
    } = simd::column_sums(simd::arch(), &inp, &mut ws.cols);
    if !variable {
        g.iter_mut().for_each(|v| *v *= inv_var);
        grad.iter_mut().for_each(|v| *v *= inv_var);
        cost *= inv_var;
    }
    // g: the 6 × 6 upper triangle in row order, then Σ w φ_b (21..27), Σ w (27)
    let mut gram = [[0.0; 7]; 7];
    let mut idx = 0;
    for b in 0..6 {
        for c in b..6 {
            gram[b][c] = g[idx];
            gram[c][b] = g[idx];
            idx += 1;
        }
        gram[b][6] = g[21 + b];
        gram[6][b] = g[21 + b];
    }
    gram[6][6] = g[27];
    let finite = cost.is_finite() && g.iter().all(|v| v.is_finite());
    Pass {
        cost,
        ssr,
        gram,
        grad,
        finite,
        shape: Shape::of(theta),
        rh: [0.0; 9],
        has_rh: false,
    }
}

/// Sparse rows of C: three (basis index, coefficient) pairs per free parameter, zero
/// coefficients padding the shorter ones (the table in the module doc).
fn sparse_rows(kind: Kind, theta: &Theta, s: &Shape) -> [[(usize, f64); 3]; 7] {
    let am = theta[IA];
    let mut rows = [[(0usize, 0.0f64); 3]; 7];
    for (k, &p) in kind.free().iter().enumerate() {
        rows[k] = match p {
            IX => [(1, am * s.a), (2, am * s.b), (0, 0.0)],
            IY => [(1, am * s.b), (2, am * s.c), (0, 0.0)],
            IA => [(0, 1.0), (0, 0.0), (0, 0.0)],
            IU if kind == Kind::Circular => [(3, am * s.a), (4, 2.0 * am * s.b), (5, am * s.c)],
            IU => [(3, am * s.a), (4, am * s.b), (0, 0.0)],
            IV => [(4, am * s.b), (5, am * s.c), (0, 0.0)],
            IT => [(3, am * s.ta), (4, am * s.tb), (5, am * s.tc)],
            _ => [(6, 1.0), (0, 0.0), (0, 0.0)],
        };
    }
    rows
}

/// Normal matrix `N = C G Cᵀ` and gradient `g = C h` of the free parameters (n × n in the top
/// left of a 7 × 7 array); `pass` is the evaluation at `theta`.
pub(crate) fn normal_equations(
    kind: Kind,
    theta: &Theta,
    pass: &Pass,
) -> ([[f64; 7]; 7], [f64; 7]) {
    // (every row three entries, zero coefficients padding: fixed loops, no lengths;
    // `C G` first, then its products with the rows of `C`. The double sum over entry pairs
    // with their lengths had been 6 % of `bostrack locate`'s instructions on bench/trackpy's
    // peak-SNR-6 scene: 693 → 681 M, σ 0.3 1,221 → 1,208 M; test
    // `normal_equations_are_the_dense_products`)
    let rows = sparse_rows(kind, theta, &pass.shape);
    let n = kind.n_free();
    let gram = &pass.gram;
    let mut cg = [[0.0; 7]; 7];
    let mut g = [0.0; 7];
    for k in 0..n {
        let [(b0, c0), (b1, c1), (b2, c2)] = rows[k];
        for c in 0..7 {
            cg[k][c] = c0 * gram[b0][c] + c1 * gram[b1][c] + c2 * gram[b2][c];
        }
        g[k] = c0 * pass.grad[b0] + c1 * pass.grad[b1] + c2 * pass.grad[b2];
    }
    let mut nm = [[0.0; 7]; 7];
    for k in 0..n {
        for l in k..n {
            let [(b0, c0), (b1, c1), (b2, c2)] = rows[l];
            let v = c0 * cg[k][b0] + c1 * cg[k][b1] + c2 * cg[k][b2];
            nm[k][l] = v;
            nm[l][k] = v;
        }
    }
    (nm, g)
}

/// The Newton matrix `H = N − R` of the free parameters at the pass's θ (n × n in the top left;
/// `nm` is the pass's normal matrix `N`), with `R = Σ w r ∂²μ/∂θ∂θᵀ` the second-order term
/// that Gauss-Newton leaves out: `½∇² Σ w r² = H` for the solve's fixed weights. `None` for a
/// pass without the residual's moments of degree 3 and 4 where the kind's shape is free, and
/// for the linear kind (R = 0); an entry that is not finite is left for the factorisation to
/// refuse (the step is then Gauss-Newton's).
///
/// With `μ = B + A·E`, `E = exp(−Q/2)`, `Q = aX² + 2bXY + cY²`: `∂²μ/∂p∂q = A·E·(¼ Q_p Q_q − ½
/// Q_pq)` for p, q among the centre and shape, `∂²μ/∂A∂q = −½ Q_q E`, zero for the rest. Every
/// `Q_p` is `−2 p̂` with `p̂` the Jacobian's coefficients on the basis over `A` (at most three
/// monomials of degree ≤ 2), every `Q_pq` a quadratic too, so `R` is the residual's moments
/// `S(m, n) = Σ w r E XᵐYⁿ` (m + n ≤ 4) contracted with them: `R_pq = A (p̂ M q̂ᵀ − ½ Σ Q_pq S)`
/// with `M_ij = S(mono_i + mono_j)` over the monomials 1, X, Y, X², XY, Y²; `R_Ap = p̂ · S`.
/// Test `newton_matrix_is_the_residual_hessian`.
pub(crate) fn newton_matrix(
    kind: Kind,
    theta: &Theta,
    pass: &Pass,
    nm: &[[f64; 7]; 7],
) -> Option<[[f64; 7]; 7]> {
    if kind == Kind::Linear || (kind.hess() && !pass.has_rh) {
        return None;
    }
    // (a held shape uses the moments of degree ≤ 2 only: its rows of degree 3, 4 are unread)
    let [s30, s21, s12, s03, s40, s31, s22, s13, s04] = pass.rh;
    let g = &pass.grad;
    let (s00, s10, s01, s20, s11, s02) = (g[0], g[1], g[2], g[3], g[4], g[5]);
    let mm = [
        [s00, s10, s01, s20, s11, s02],
        [s10, s20, s11, s30, s21, s12],
        [s01, s11, s02, s21, s12, s03],
        [s20, s30, s21, s40, s31, s22],
        [s11, s21, s12, s31, s22, s13],
        [s02, s12, s03, s22, s13, s04],
    ];
    let sh = &pass.shape;
    let (a, b, c) = (sh.a, sh.b, sh.c);
    let (ta, tb, tc) = (sh.ta, sh.tb, sh.tc);
    // p̂ of x0, y0, u, v, t: (monomial, coefficient) × 3
    let rows: [[(usize, f64); 3]; 5] = [
        [(1, a), (2, b), (0, 0.0)],
        [(1, b), (2, c), (0, 0.0)],
        [(3, a), (4, b), (0, 0.0)],
        [(4, b), (5, c), (0, 0.0)],
        [(3, ta), (4, tb), (5, tc)],
    ];
    let mut cm = [[0.0; 6]; 5];
    for (p, row) in rows.iter().enumerate() {
        let [(i0, c0), (i1, c1), (i2, c2)] = *row;
        for j in 0..6 {
            cm[p][j] = c0 * mm[i0][j] + c1 * mm[i1][j] + c2 * mm[i2][j];
        }
    }
    let quad = |p: usize, q: usize| {
        let [(i0, c0), (i1, c1), (i2, c2)] = rows[q];
        c0 * cm[p][i0] + c1 * cm[p][i1] + c2 * cm[p][i2]
    };
    // (a, b, c) differentiated by u, v, t, and twice
    let d1 = [
        (-2.0 * a, -b, 0.0),
        (0.0, -b, -2.0 * c),
        (-2.0 * ta, -tb, -2.0 * tc),
    ];
    let d2 = |i: usize, j: usize| match (i, j) {
        (0, 0) => (4.0 * a, b, 0.0),
        (0, 1) => (0.0, b, 0.0),
        (1, 1) => (0.0, b, 4.0 * c),
        (0, 2) => (4.0 * ta, tb, 0.0),
        (1, 2) => (0.0, tb, 4.0 * tc),
        _ => (sh.att, 4.0 * b, sh.ctt),
    };
    const NL: [usize; 5] = [IX, IY, IU, IV, IT];
    let mut r = [[0.0; 7]; 7];
    let am = theta[IA];
    let mut set = |p: usize, q: usize, v: f64| {
        r[NL[p]][NL[q]] = v;
        r[NL[q]][NL[p]] = v;
    };
    set(0, 0, am * (quad(0, 0) - a * s00));
    set(0, 1, am * (quad(0, 1) - b * s00));
    set(1, 1, am * (quad(1, 1) - c * s00));
    for k in 0..3 {
        let (da, db, dc) = d1[k];
        set(0, k + 2, am * (quad(0, k + 2) + da * s10 + db * s01));
        set(1, k + 2, am * (quad(1, k + 2) + db * s10 + dc * s01));
        for l in k..3 {
            let (ea, eb, ec) = d2(k, l);
            let w = ea * s20 + 2.0 * eb * s11 + ec * s02;
            set(k + 2, l + 2, am * (quad(k + 2, l + 2) - 0.5 * w));
        }
    }
    let s1 = [s00, s10, s01, s20, s11, s02];
    for (p, row) in rows.iter().enumerate() {
        let [(i0, c0), (i1, c1), (i2, c2)] = *row;
        let v = c0 * s1[i0] + c1 * s1[i1] + c2 * s1[i2];
        r[IA][NL[p]] = v;
        r[NL[p]][IA] = v;
    }
    // onto the free parameters (the circular model's IU is u and v together); an entry that
    // is not finite fails the factorisation, and the step is Gauss-Newton's
    let mut h = *nm;
    if kind == Kind::Elliptical {
        for (hk, (nk, rk)) in h.iter_mut().zip(nm.iter().zip(r.iter())) {
            for (x, (a, b)) in hk.iter_mut().zip(nk.iter().zip(rk.iter())) {
                *x = a - b;
            }
        }
        return Some(h);
    }
    if kind == Kind::Circular {
        for row in r.iter_mut() {
            row[IU] += row[IV];
        }
        let v = r[IV];
        for (x, y) in r[IU].iter_mut().zip(v) {
            *x += y;
        }
    }
    let free = kind.free();
    for (k, &p) in free.iter().enumerate() {
        for (l, &q) in free.iter().enumerate() {
            h[k][l] = nm[k][l] - r[p][q];
        }
    }
    Some(h)
}

/// Fills `ws.tmp` with the unit-amplitude factor `E` of the dot θ over the workspace window,
/// for subtracting a neighbour: point-sampled, or for the integrated model the box average by
/// its Taylor series to 4th order (`E·[1 + (Eₓₓ+E_yy)/24E + (Eₓₓₓₓ+E_yyyy)/1920E + Eₓₓ_yy/576E]`
/// with the Hermite forms of the Gaussian's derivatives): 8 values of `exp` instead of a
/// quadrature, error below 2e-4 of the amplitude for σ ≥ 1 px, 2e-5 in the tails 8 px out (test
/// `neighbour_rendering_is_accurate`). Leaves data/keep alone.
pub(crate) fn dot_factor(ws: &mut Workspace, theta: &Theta, sampling: Sampling) {
    let x_first = ws.wx as f64 - theta[IX];
    let y_first = ws.wy as f64 - theta[IY];
    factor_grid(
        theta,
        sampling,
        x_first,
        y_first,
        ws.w,
        ws.h,
        &mut ws.tmp,
        &mut ws.v,
        &mut ws.q,
    );
}

/// [`dot_factor`] over any `w × h` grid whose first point is at `(x_first, y_first)` relative
/// to the centre, into `out` (`v`, `q`: scratch of at least `max(w, h)`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn factor_grid(
    theta: &Theta,
    sampling: Sampling,
    x_first: f64,
    y_first: f64,
    w: usize,
    h: usize,
    out: &mut [f64],
    v: &mut [f64],
    q: &mut [f64],
) {
    let s = Shape::of(theta);
    exp_grid(s.a, s.b, s.c, x_first, y_first, w, h, out, v, q);
    if sampling == Sampling::Point {
        return;
    }
    let (a, b, c) = (s.a, s.b, s.c);
    for j in 0..h {
        let y = y_first + j as f64;
        for i in 0..w {
            let x = x_first + i as f64;
            let u = a * x + b * y;
            let v = b * x + c * y;
            let (u2, v2) = (u * u, v * v);
            let fxx = u2 - a;
            let fyy = v2 - c;
            let fxxxx = u2 * u2 - 6.0 * a * u2 + 3.0 * a * a;
            let fyyyy = v2 * v2 - 6.0 * c * v2 + 3.0 * c * c;
            let fxxyy = fxx * fyy - 4.0 * b * u * v + 2.0 * b * b;
            out[j * w + i] *= 1.0 + (fxx + fyy) / 24.0 + (fxxxx + fyyyy) / 1920.0 + fxxyy / 576.0;
        }
    }
}

/// Fills `w_cur` with `keep / variance(μ)` of the model θ (signal-dependent noise only; with
/// constant noise the passes use `keep` and the read variance). The model is rendered with
/// [`dot_factor`] (exact for point sampling, the 4th-order box average otherwise: weights
/// need far less than its 2e-4 accuracy).
pub(crate) fn set_weights(
    ws: &mut Workspace,
    theta: &Theta,
    sampling: Sampling,
    noise: &NoiseModel,
) {
    if noise.is_constant() {
        return;
    }
    dot_factor(ws, theta, sampling);
    weights_from_factor(ws, theta, noise);
}

/// `w_cur = keep / variance(model)` for the dot θ whose unit-amplitude factor is in `ws.tmp`.
fn weights_from_factor(ws: &mut Workspace, theta: &Theta, noise: &NoiseModel) {
    let (amp, bg) = (theta[IA], theta[IB]);
    let n = ws.len();
    for k in 0..n {
        ws.w_cur[k] = ws.keep[k] / noise.variance(bg + amp * ws.tmp[k]);
    }
}

/// Sets the amplitude and background of the start θ to those that fit the loaded pixels best
/// for its position and shape (unweighted linear least squares over the used pixels: the
/// model is linear in both), then the weights at that start as [`set_weights`] does, from the
/// same rendering of the dot. A start whose amplitude or background is off (a window border
/// lifted by the neighbours' tails puts the moments' background ~4 % of the peak too high on
/// the real sample) otherwise costs Gauss-Newton iterations for nothing, and weights set from
/// it may trigger a second solve. θ is left as it was if the 2×2 system is singular or gives
/// an amplitude below `amp_min`.
pub(crate) fn start_linear(
    ws: &mut Workspace,
    theta: &mut Theta,
    sampling: Sampling,
    noise: &NoiseModel,
    amp_min: f64,
) {
    dot_factor(ws, theta, sampling);
    let n = ws.len();
    let (mut s1, mut sg, mut sgg, mut sd, mut sgd) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for k in 0..n {
        let (kp, g, d) = (ws.keep[k], ws.tmp[k], ws.data[k]);
        let kg = kp * g;
        s1 += kp;
        sg += kg;
        sgg += kg * g;
        sd += kp * d;
        sgd += kg * d;
    }
    let det = sgg * s1 - sg * sg;
    if det > 1e-9 * sgg * s1 && det.is_finite() {
        let amp = (sgd * s1 - sg * sd) / det;
        let bg = (sgg * sd - sg * sgd) / det;
        if amp >= amp_min && amp.is_finite() && bg.is_finite() {
            theta[IA] = amp;
            theta[IB] = bg;
        }
    }
    if !noise.is_constant() {
        weights_from_factor(ws, theta, noise);
    }
}

/// The largest relative change of the weights if they were set at θ (0 with constant noise);
/// leaves the new weights in `w_new`. The dot is rendered with [`dot_factor`]; where the last
/// evaluation was at θ, [`weight_change_at_model`] takes its model instead.
pub(crate) fn weight_change(
    ws: &mut Workspace,
    theta: &Theta,
    sampling: Sampling,
    noise: &NoiseModel,
) -> f64 {
    if noise.is_constant() {
        return 0.0;
    }
    dot_factor(ws, theta, sampling);
    let tmp = std::mem::take(&mut ws.tmp);
    let change = change_to(&tmp[..ws.len()], ws, theta, noise);
    ws.tmp = tmp;
    change
}

/// [`weight_change`] at the θ of the last [`evaluate`], from the unit dot it left in `ws.e` (the
/// exact model, no rendering).
pub(crate) fn weight_change_at_model(ws: &mut Workspace, theta: &Theta, noise: &NoiseModel) -> f64 {
    if noise.is_constant() {
        return 0.0;
    }
    let e = std::mem::take(&mut ws.e);
    let change = change_to(&e[..ws.len()], ws, theta, noise);
    ws.e = e;
    change
}

/// `w_new = keep / variance(bg + amp · unit)` and its largest relative change from `w_cur`.
fn change_to(unit: &[f64], ws: &mut Workspace, theta: &Theta, noise: &NoiseModel) -> f64 {
    let (amp, bg) = (theta[IA], theta[IB]);
    let mut worst: f64 = 0.0;
    for (k, &u) in unit.iter().enumerate() {
        let w = ws.keep[k] / noise.variance(bg + amp * u);
        ws.w_new[k] = w;
        if ws.w_cur[k] > 0.0 {
            worst = worst.max((w / ws.w_cur[k] - 1.0).abs());
        }
    }
    if worst.is_nan() { f64::INFINITY } else { worst }
}

/// The pass of the last [`evaluate`] (at `theta`) summed again with the weights now in `w_cur`:
/// the model and its basis are kept, only the weighted sums are redone.
pub(crate) fn resum(
    ws: &mut Workspace,
    theta: &Theta,
    sampling: Sampling,
    kind: Kind,
    noise: &NoiseModel,
    hess: bool,
) -> Pass {
    let hess = hess && kind.hess();
    match sampling {
        Sampling::Point => point_sums(ws, theta, &Shape::of(theta), noise, hess),
        Sampling::Integrated => eval_general(ws, theta, noise),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bostrack_core::Window;
    use bostrack_model::{ModelKind, pixel_gradient, pixel_value};

    fn ws_for(win: Window) -> Workspace {
        let mut ws = Workspace::default();
        ws.resize(win.x, win.y, win.width, win.height);
        ws
    }

    /// The conditional σ and the pixel-blurred θ of a dot's parameters, made from its σx, σy
    /// and ρ, are those made through its θ to a few ulp (relative 1e-14, 1e-8 at |ρ| near the
    /// clamp; centre and background exactly), for equal and unequal sigmas from 0.15 to 3 px
    /// and every sign of the correlation.
    #[test]
    fn blurred_parameters_are_the_blurred_theta() {
        let mut checked = 0;
        for sx in [0.15, 0.4, 1.0, 1.3, 3.0] {
            for sy in [0.15, 0.9, 1.3, 2.2] {
                for rho in [-1.0, -0.93, -0.4, 0.0, 0.2, 0.7, 0.999_999_9] {
                    // (at the clamp, 1 - ρ² through atanh and tanh keeps ~6 of its digits: the
                    // values from ρ itself are the more accurate ones)
                    let tol = if f64::abs(rho) > 0.99 { 1e-8 } else { 1e-14 };
                    let near = |a: f64, b: f64| (a - b).abs() <= tol * a.abs().max(b.abs());
                    let g = Gaussian2D {
                        x0: 3.2,
                        y0: -1.5,
                        amplitude: 120.0,
                        sigma_x: sx,
                        sigma_y: sy,
                        rho,
                        background: 40.0,
                    };
                    let th = theta_from_gaussian(&g);
                    let (cs, b) = blurred_of(&g);
                    assert!(near(cs, conditional_sigma(&th)), "{sx} {sy} {rho}");
                    let want = pixel_blur(&th);
                    for k in 0..7 {
                        assert!(
                            near(b[k], want[k]),
                            "{sx} {sy} {rho} [{k}]: {} {}",
                            b[k],
                            want[k]
                        );
                    }
                    for k in [IX, IY, IB] {
                        assert_eq!(b[k].to_bits(), g.to_array()[k].to_bits());
                    }
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 140);
    }

    /// The unblurred parameters of a pixel-blurred θ are those through the unblurred θ to a
    /// few ulp (relative 1e-14; 1e-8 for ρ near ±1, where `atanh` and `tanh` lose digits of
    /// 1 − ρ²), and `None` exactly where that θ is.
    #[test]
    fn unblurred_parameters_are_those_of_the_unblurred_theta() {
        let mut checked = 0;
        for u in [-2.6, -1.3, -0.5, 0.0, 0.4, 1.1] {
            for v in [-1.3, -0.2, 0.3, 1.1] {
                for t in [-4.0, -0.9, 0.0, 0.3, 2.5, 7.0] {
                    let b = [3.2, -1.5, 120.0, u, v, t, 40.0];
                    let want = pixel_unblur(&b).map(|t| gaussian_from_theta(&t));
                    let got = unblurred_params(&b);
                    assert_eq!(got.is_some(), want.is_some(), "{u} {v} {t}");
                    let (Some(g), Some(w)) = (got, want) else {
                        continue;
                    };
                    let tol = if w.rho.abs() > 0.99 { 1e-8 } else { 1e-14 };
                    for (x, y) in g.to_array().iter().zip(w.to_array()) {
                        assert!(
                            (x - y).abs() <= tol * x.abs().max(y.abs()),
                            "{u} {v} {t}: {g:?} {w:?}"
                        );
                    }
                    checked += 1;
                }
            }
        }
        assert!(checked > 30, "{checked}");
    }

    #[test]
    fn exp_grid_matches_direct() {
        for &(a, b, c) in &[
            (0.4, 0.1, 0.3),
            (2.0, -1.5, 1.9),
            (0.01, 0.0, 0.02),
            (11.0, 3.0, 9.0),
        ] {
            let (w, h) = (13, 11);
            let mut out = vec![0.0; w * h];
            let (mut v, mut q) = (vec![0.0; w], vec![0.0; w]);
            exp_grid(a, b, c, -6.3, -4.8, w, h, &mut out, &mut v, &mut q);
            for j in 0..h {
                for i in 0..w {
                    let (x, y) = (-6.3 + i as f64, -4.8 + j as f64);
                    let d = (-0.5 * (a * x * x + 2.0 * b * x * y + c * y * y)).exp();
                    let got = out[j * w + i];
                    assert!(
                        (got - d).abs() <= 1e-13 * d + 1e-300,
                        "{a} {b} {c} ({i},{j}): {got} vs {d}"
                    );
                }
            }
        }
    }

    fn dot() -> Gaussian2D {
        Gaussian2D {
            x0: 10.3,
            y0: 9.6,
            amplitude: 700.0,
            sigma_x: 1.4,
            sigma_y: 1.1,
            rho: 0.35,
            background: 40.0,
        }
    }

    /// The fast basis reproduces bostrack_model's values and derivatives (chain rule to σ, ρ).
    #[test]
    fn basis_matches_model_crate() {
        let win = Window::new(6, 5, 9, 9);
        for sampling in [Sampling::Point, Sampling::Integrated] {
            for (kind, rho) in [
                (Kind::Elliptical, 0.35),
                (Kind::Elliptical, -0.8),
                (Kind::AxisAligned, 0.0),
            ] {
                let g = Gaussian2D { rho, ..dot() };
                let theta = theta_from_gaussian(&g);
                let mut ws = ws_for(win);
                fill_phi(&mut ws, &theta, sampling, kind);
                let s = Shape::of(&theta);
                let c = kind.coefficients(&theta, &s);
                for j in 0..win.height {
                    for i in 0..win.width {
                        let k = j * win.width + i;
                        let (px, py) = ((win.x + i as i64) as f64, (win.y + j as i64) as f64);
                        let (mu, grad) = pixel_gradient(&g, px, py, sampling);
                        let phi = [
                            ws.e[k],
                            ws.phi[0][k],
                            ws.phi[1][k],
                            ws.phi[2][k],
                            ws.phi[3][k],
                            ws.phi[4][k],
                            1.0,
                        ];
                        let mine = g.background + g.amplitude * phi[0];
                        // the two quadrature orders differ by < 1e-6 of the amplitude
                        let tol = if sampling == Sampling::Point {
                            1e-9
                        } else {
                            2e-6
                        } * g.amplitude;
                        assert!((mine - mu).abs() < tol, "{sampling:?} value {mine} vs {mu}");
                        // chain rule: d/du = σx d/dσx, d/dt = (1-ρ²) d/dρ
                        let want = [
                            grad[0],
                            grad[1],
                            grad[2],
                            grad[3] * g.sigma_x,
                            grad[4] * g.sigma_y,
                            grad[5] * (1.0 - g.rho * g.rho),
                            grad[6],
                        ];
                        for (row, &p) in kind.free().iter().enumerate() {
                            let got: f64 = (0..7).map(|b| c[row][b] * phi[b]).sum();
                            assert!(
                                // (derivatives carry ~10x the quadrature error of the values)
                                (got - want[p]).abs()
                                    < 10.0 * tol * (1.0 + want[p].abs() / g.amplitude),
                                "{sampling:?} {kind:?} param {p} at ({i},{j}): {got} vs {}",
                                want[p]
                            );
                        }
                    }
                }
            }
        }
    }

    /// `normal_equations` (sparse rows, `C G` first) equals the dense `C G Cᵀ` and `C h` with
    /// `C` from `Kind::coefficients` (checked against the model crate above), for every kind.
    #[test]
    fn normal_equations_are_the_dense_products() {
        let win = Window::new(6, 5, 9, 9);
        let g = Gaussian2D { rho: 0.35, ..dot() };
        let theta = theta_from_gaussian(&g);
        let truth = Gaussian2D {
            x0: g.x0 + 0.2,
            ..g
        };
        let mut ws = ws_for(win);
        ws.data
            .copy_from_slice(&bostrack_model::render(&truth, win, Sampling::Point));
        ws.keep.fill(1.0);
        let noise = NoiseModel::read(10.0);
        for kind in [
            Kind::Elliptical,
            Kind::AxisAligned,
            Kind::Circular,
            Kind::FixedShape,
            Kind::Linear,
        ] {
            let pass = evaluate(&mut ws, &theta, Sampling::Point, kind, &noise);
            let (nm, gr) = normal_equations(kind, &theta, &pass);
            let c = kind.coefficients(&theta, &pass.shape);
            let n = kind.n_free();
            for k in 0..n {
                let want_g: f64 = (0..7).map(|b| c[k][b] * pass.grad[b]).sum();
                assert!(
                    (gr[k] - want_g).abs() <= 1e-12 * (1.0 + want_g.abs()),
                    "{kind:?} g{k}"
                );
                for l in 0..n {
                    let want: f64 = (0..7)
                        .flat_map(|b| (0..7).map(move |d| (b, d)))
                        .map(|(b, d)| c[k][b] * pass.gram[b][d] * c[l][d])
                        .sum();
                    assert!(
                        (nm[k][l] - want).abs() <= 1e-12 * (1.0 + want.abs()),
                        "{kind:?} N{k}{l}: {} vs {want}",
                        nm[k][l]
                    );
                }
            }
        }
    }

    /// The Newton matrix is the Jacobian of the gradient: `g = Σ w r ∂μ/∂θ = −½∇cost`, so
    /// `∂g/∂θ = −H`, checked by central differences of `g` on a window whose data are another
    /// dot plus a fixed pattern (a residual of every shape, so that `R` is far from 0), for
    /// every kind, a tilted and an upright dot; without the residual's moments a free shape
    /// has none, the linear kind never.
    #[test]
    fn newton_matrix_is_the_residual_hessian() {
        let win = Window::new(4, 3, 13, 12);
        for (rho, sy) in [(0.35, 1.1), (0.0, 1.4), (-0.6, 0.9)] {
            let g = Gaussian2D {
                rho,
                sigma_y: sy,
                ..dot()
            };
            let truth = Gaussian2D {
                x0: g.x0 + 0.4,
                y0: g.y0 - 0.3,
                sigma_x: g.sigma_x * 1.2,
                amplitude: g.amplitude * 0.8,
                ..g
            };
            let mut ws = ws_for(win);
            let rendered = bostrack_model::render(&truth, win, Sampling::Point);
            for (k, (d, v)) in ws.data.iter_mut().zip(&rendered).enumerate() {
                *d = v + 30.0 * ((k * 37 % 11) as f64 - 5.0);
            }
            ws.keep.fill(1.0);
            let noise = NoiseModel::read(10.0);
            for kind in [
                Kind::Elliptical,
                Kind::AxisAligned,
                Kind::Circular,
                Kind::FixedShape,
            ] {
                let mut theta = theta_from_gaussian(&g);
                kind.constrain(&mut theta);
                let n = kind.n_free();
                let pass = evaluate_h(&mut ws, &theta, Sampling::Point, kind, &noise, true);
                let (nm, _) = normal_equations(kind, &theta, &pass);
                let h = newton_matrix(kind, &theta, &pass, &nm).expect("a Newton matrix");
                let grad_at = |ws: &mut Workspace, t: &Theta| {
                    let p = evaluate(ws, t, Sampling::Point, kind, &noise);
                    normal_equations(kind, t, &p).1
                };
                for l in 0..n {
                    let step = if kind.free()[l] == IA { 1.0 } else { 1e-4 };
                    let mut d = [0.0; 7];
                    d[l] = step;
                    let gp = grad_at(&mut ws, &kind.apply_step(&theta, &d));
                    d[l] = -step;
                    let gm = grad_at(&mut ws, &kind.apply_step(&theta, &d));
                    for k in 0..n {
                        let fd = -(gp[k] - gm[k]) / (2.0 * step);
                        let scale = (nm[k][k] * nm[l][l]).sqrt();
                        assert!(
                            (h[k][l] - fd).abs() <= 1e-6 * scale,
                            "{kind:?} ρ {rho} H{k}{l}: {} vs {fd} (N {})",
                            h[k][l],
                            nm[k][l]
                        );
                    }
                }
                // R is not negligible here (else the test would not see it)
                let r_size = (0..n)
                    .flat_map(|k| (0..n).map(move |l| (k, l)))
                    .map(|(k, l)| (h[k][l] - nm[k][l]).abs() / (nm[k][k] * nm[l][l]).sqrt())
                    .fold(0.0, f64::max);
                assert!(r_size > 1e-2, "{kind:?} ρ {rho}: R/N only {r_size}");
                if kind != Kind::FixedShape {
                    let plain = evaluate(&mut ws, &theta, Sampling::Point, kind, &noise);
                    assert!(newton_matrix(kind, &theta, &plain, &nm).is_none());
                }
            }
            let theta = theta_from_gaussian(&g);
            let pass = evaluate_h(&mut ws, &theta, Sampling::Point, Kind::Linear, &noise, true);
            let (nm, _) = normal_equations(Kind::Linear, &theta, &pass);
            assert!(newton_matrix(Kind::Linear, &theta, &pass, &nm).is_none());
        }
    }

    /// The pass from the linear start's rendering is the evaluation's, bit for bit (the
    /// solver takes it instead of rendering the dot again).
    #[test]
    fn pass_from_the_start_factor_is_the_evaluation() {
        let win = Window::new(3, 2, 11, 12);
        let truth = Gaussian2D { rho: -0.3, ..dot() };
        let noise = NoiseModel {
            read_variance: 100.0,
            gain: 0.8,
            offset: 20.0,
        };
        for hess in [false, true] {
            let mut ws = ws_for(win);
            ws.data
                .copy_from_slice(&bostrack_model::render(&truth, win, Sampling::Integrated));
            ws.keep.fill(1.0);
            ws.keep[5] = 0.0;
            let mut theta = theta_from_gaussian(&Gaussian2D {
                x0: truth.x0 - 0.3,
                amplitude: 300.0,
                background: 0.0,
                ..truth
            });
            start_linear(&mut ws, &mut theta, Sampling::Point, &noise, 1e-9);
            assert!(theta[IA] > 300.0, "the linear start set the amplitude");
            let a = pass_from_factor(&mut ws, &theta, &noise, hess);
            let b = evaluate_h(
                &mut ws,
                &theta,
                Sampling::Point,
                Kind::Elliptical,
                &noise,
                hess,
            );
            assert_eq!(
                (a.cost, a.ssr, a.gram, a.grad, a.rh, a.has_rh),
                (b.cost, b.ssr, b.gram, b.grad, b.rh, b.has_rh)
            );
        }
    }

    fn truth_theta(g: &Gaussian2D) -> Theta {
        theta_from_gaussian(g)
    }

    #[test]
    fn moment_pass_equals_direct_pass() {
        let win = Window::new(6, 5, 9, 9);
        let g = dot();
        let theta = theta_from_gaussian(&g);
        let truth = Gaussian2D {
            x0: 10.1,
            sigma_x: 1.5,
            rho: 0.2,
            ..g
        };
        let mut ws = ws_for(win);
        let data = bostrack_model::render(&truth, win, Sampling::Point);
        ws.data.copy_from_slice(&data);
        ws.keep.fill(1.0);
        ws.keep[7] = 0.0;
        ws.data[7] = 0.0;
        let noise = NoiseModel {
            read_variance: 100.0,
            gain: 0.8,
            offset: 20.0,
        };
        set_weights(&mut ws, &truth_theta(&truth), Sampling::Point, &noise);
        let a = eval_point_moments(&mut ws, &theta, &Shape::of(&theta), &noise, false);
        // the pass with the residual's moments of degree 3, 4: the same sums besides
        let ah = eval_point_moments(&mut ws, &theta, &Shape::of(&theta), &noise, true);
        assert!(ah.has_rh && !a.has_rh);
        assert_eq!(
            (a.cost, a.ssr, a.gram, a.grad),
            (ah.cost, ah.ssr, ah.gram, ah.grad)
        );
        fill_phi_point(&mut ws, &theta);
        let b = eval_general(&mut ws, &theta, &noise);
        assert!((a.cost - b.cost).abs() < 1e-9 * b.cost);
        assert!((a.ssr - b.ssr).abs() < 1e-9 * b.ssr);
        for i in 0..7 {
            assert!((a.grad[i] - b.grad[i]).abs() < 1e-9 * (1.0 + b.grad[i].abs()));
            for j in 0..7 {
                assert!((a.gram[i][j] - b.gram[i][j]).abs() < 1e-9 * (1.0 + b.gram[i][j].abs()));
            }
        }
    }

    /// The weights from the last evaluation's model are those of the exact model (the
    /// model crate's rendering), and the pass summed again with new weights equals a new
    /// evaluation with them.
    #[test]
    fn reweighting_from_the_evaluated_model_equals_a_new_evaluation() {
        let win = Window::new(6, 5, 9, 9);
        let g = Gaussian2D {
            sigma_x: 0.45,
            sigma_y: 0.6,
            ..dot()
        };
        let theta = theta_from_gaussian(&g);
        let moved = theta_from_gaussian(&Gaussian2D {
            x0: g.x0 + 0.2,
            amplitude: 1.3 * g.amplitude,
            ..g
        });
        let noise = NoiseModel {
            read_variance: 100.0,
            gain: 0.8,
            offset: 20.0,
        };
        for sampling in [Sampling::Point, Sampling::Integrated] {
            let mut ws = ws_for(win);
            let data = bostrack_model::render(&g, win, sampling);
            ws.data.copy_from_slice(&data);
            ws.keep.fill(1.0);
            ws.keep[7] = 0.0;
            ws.data[7] = 0.0;
            set_weights(&mut ws, &moved, sampling, &noise);
            let _ = evaluate(&mut ws, &theta, sampling, Kind::Elliptical, &noise);
            let w_start = ws.w_cur.clone();
            let change = weight_change_at_model(&mut ws, &theta, &noise);
            let model = bostrack_model::render(&gaussian_from_theta(&theta), win, sampling);
            // (the quadrature: 1e-6 of the amplitude)
            let tol = if sampling == Sampling::Point {
                1e-12
            } else {
                1e-6
            };
            let mut worst: f64 = 0.0;
            for k in 0..model.len() {
                let want = ws.keep[k] / noise.variance(model[k]);
                let d = (ws.w_new[k] - want).abs() / want.max(f64::MIN_POSITIVE);
                assert!(d <= tol, "{sampling:?} {k}: {d}");
                if w_start[k] > 0.0 {
                    worst = worst.max((want / w_start[k] - 1.0).abs());
                }
            }
            assert!(
                worst > 0.05 && (change - worst).abs() <= tol,
                "{sampling:?}"
            );
            // the weights at θ: the pass summed again equals the pass evaluated with them
            let _ = evaluate(&mut ws, &theta, sampling, Kind::Elliptical, &noise);
            let _ = weight_change_at_model(&mut ws, &theta, &noise);
            std::mem::swap(&mut ws.w_cur, &mut ws.w_new);
            let again = resum(&mut ws, &theta, sampling, Kind::Elliptical, &noise, false);
            let fresh = evaluate(&mut ws, &theta, sampling, Kind::Elliptical, &noise);
            assert!(
                (again.cost - fresh.cost).abs() <= 1e-12 * fresh.cost,
                "{sampling:?}"
            );
            for i in 0..7 {
                assert!(
                    (again.grad[i] - fresh.grad[i]).abs() <= 1e-9 * (1.0 + fresh.grad[i].abs())
                );
                for j in 0..7 {
                    let (a, b) = (again.gram[i][j], fresh.gram[i][j]);
                    assert!(
                        (a - b).abs() <= 1e-12 * (1.0 + b.abs()),
                        "{sampling:?} {i}{j}"
                    );
                }
            }
        }
    }

    #[test]
    #[ignore]
    fn print_quadrature_table() {
        // (the rows of QUADRATURE_ERRORS)
        for sigma in QUADRATURE_SIGMAS {
            let mut line = format!("{sigma:5}");
            for order in 1..=12 {
                let mut worst: f64 = 0.0;
                for (ox, oy) in [(0.0, 0.0), (0.37, -0.21), (0.5, 0.5), (0.13, 0.29)] {
                    let g = Gaussian2D::circular(5.0 + ox, 5.0 + oy, 1.0, sigma, 0.0);
                    let win = Window::new(0, 0, 11, 11);
                    let exact = bostrack_model::render(&g, win, Sampling::Integrated);
                    let (nodes, weights) = gl_rule(order);
                    let s = Shape::new(sigma.ln(), sigma.ln(), 0.0);
                    let mut acc = vec![0.0; 121];
                    let mut tmp = vec![0.0; 121];
                    let (mut v, mut q) = (vec![0.0; 11], vec![0.0; 11]);
                    for (sy, wy) in nodes.iter().zip(weights) {
                        for (sx, wx) in nodes.iter().zip(weights) {
                            exp_grid(
                                s.a,
                                s.b,
                                s.c,
                                -5.0 - ox + sx,
                                -5.0 - oy + sy,
                                11,
                                11,
                                &mut tmp,
                                &mut v,
                                &mut q,
                            );
                            for k in 0..121 {
                                acc[k] += wx * wy * tmp[k];
                            }
                        }
                    }
                    worst = worst.max(
                        exact
                            .iter()
                            .zip(&acc)
                            .map(|(a, b)| (a - b).abs())
                            .fold(0.0, f64::max),
                    );
                }
                line += &format!(" {worst:8.1e}");
            }
            println!("{line}");
        }
    }

    /// The factored quadrature gives the node grids' sums to rounding, for every rule length,
    /// rotated and elongated dots, centres on and off the window, and falls back where a factor
    /// could leave the floating-point range.
    #[test]
    fn factored_quadrature_equals_the_node_grids() {
        let mut worst: f64 = 0.0;
        let (mut cases, mut paired) = (0, 0);
        for order in 1..=12 {
            for (sx, sy, rho) in [
                (0.3, 0.45, 0.6),
                (0.8, 0.5, -0.9),
                (1.3, 1.3, 0.2),
                (2.5, 0.9, -0.3),
            ] {
                for (cx, cy, ww, hh) in [(4.3, 5.7, 11, 11), (-1.2, 2.0, 7, 5), (9.9, 0.1, 13, 9)] {
                    let g = Gaussian2D {
                        x0: cx,
                        y0: cy,
                        amplitude: 1.0,
                        sigma_x: sx,
                        sigma_y: sy,
                        rho,
                        background: 0.0,
                    };
                    let th = theta_from_gaussian(&g);
                    let s = Shape::of(&th);
                    let win = Window::new(-1, 0, ww, hh);
                    let (x_first, y_first) = (win.x as f64 - th[IX], win.y as f64 - th[IY]);
                    let mut a = ws_for(win);
                    let mut b = ws_for(win);
                    if !integrated_factored(&mut a, &s, x_first, y_first, order) {
                        continue;
                    }
                    integrated_by_nodes(&mut b, &s, x_first, y_first, order);
                    pixel_means_from_sums(&mut b, x_first, y_first);
                    if pairs_nodes(s.b, gl_rule(order).0) {
                        paired += 1;
                    }
                    let n = ww * hh;
                    let peak = b.e[..n].iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    let mut d = (0..n).map(|k| (a.e[k] - b.e[k]).abs()).fold(0.0, f64::max);
                    for c in 0..5 {
                        for k in 0..n {
                            d = d.max((a.phi[c][k] - b.phi[c][k]).abs());
                        }
                    }
                    worst = worst.max(d / peak);
                    cases += 1;
                }
            }
        }
        println!(
            "{cases} cases ({paired} with the nodes paired), worst difference {worst:e} of the peak"
        );
        assert!(cases > 100 && worst < 1e-12, "{cases} {worst:e}");
        // both couplings of the nodes were compared
        assert!(paired > 20 && cases - paired > 20, "{cases} {paired}");
        // a very narrow dot far from the window's centre: the node grids
        let th = theta_from_gaussian(&Gaussian2D {
            x0: 30.0,
            y0: 0.0,
            amplitude: 1.0,
            sigma_x: 0.05,
            sigma_y: 0.06,
            rho: 0.3,
            background: 0.0,
        });
        let mut a = ws_for(Window::new(0, 0, 9, 9));
        assert!(!integrated_factored(
            &mut a,
            &Shape::of(&th),
            -30.0,
            0.0,
            12
        ));
    }

    #[test]
    fn quadrature_order_is_accurate() {
        // ρ = 0 exactly has the erf answer; a tiny ρ takes the quadrature path
        for tolerance in [QUADRATURE_TOLERANCE, 1e-5, 1e-4] {
            for sigma in [
                0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.55, 0.7, 0.8, 1.0, 1.2, 1.6, 1.8, 2.5, 4.0,
            ] {
                for (ox, oy) in [(0.0, 0.0), (0.37, -0.21), (0.5, 0.5)] {
                    let g = Gaussian2D::circular(5.0 + ox, 5.0 + oy, 1.0, sigma, 0.0);
                    let win = Window::new(0, 0, 11, 11);
                    let exact = bostrack_model::render(&g, win, Sampling::Integrated);
                    let mut th = theta_from_gaussian(&g);
                    th[IT] = 1e-13;
                    let mut ws = ws_for(win);
                    ws.gl_n = gl_order(sigma, tolerance);
                    fill_phi_integrated(&mut ws, &th, Kind::Elliptical);
                    let worst = exact
                        .iter()
                        .zip(&ws.e)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0.0, f64::max);
                    assert!(worst < tolerance, "sigma {sigma}, {tolerance:e}: {worst:e}");
                }
            }
        }
        // the tolerance of a fit: a thousandth of the background's noise over the amplitude,
        // within [1e-6, 1e-4]
        let noise = NoiseModel {
            read_variance: 100.0,
            gain: 0.0,
            offset: 0.0,
        };
        let th = theta_from_gaussian(&Gaussian2D::circular(5.0, 5.0, 500.0, 0.3, 0.0));
        assert!((quadrature_tolerance(&th, &noise) - 2e-5).abs() < 1e-12);
        let mut faint = th;
        faint[IA] = 10.0;
        assert_eq!(quadrature_tolerance(&faint, &noise), 1e-4);
        faint[IA] = f64::NAN;
        assert_eq!(quadrature_tolerance(&faint, &noise), QUADRATURE_TOLERANCE);
        let _ = (
            ModelKind::Elliptical,
            pixel_value(&dot(), 0.0, 0.0, Sampling::Point),
        );
    }
    mod jacobian {
        use super::*;
        use proptest::prelude::*;

        fn value_at(
            ws: &mut Workspace,
            theta: &Theta,
            sampling: Sampling,
            kind: Kind,
            k: usize,
        ) -> f64 {
            fill_phi(ws, theta, sampling, kind);
            theta[IB] + theta[IA] * ws.e[k]
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(64))]
            /// The analytic derivative of every free parameter (the rows of C applied to φ)
            /// equals the central finite difference of the model value, for every model kind
            /// and both samplings.
            #[test]
            fn analytic_jacobian_matches_central_differences(
                x0 in 2.0f64..6.0, y0 in 2.0f64..6.0, amp in 50.0f64..2000.0,
                u in (0.5f64).ln()..(3.0f64).ln(), v in (0.5f64).ln()..(3.0f64).ln(),
                t in -1.5f64..1.5, bg in -100.0f64..500.0,
                kind_i in 0usize..3, point in any::<bool>(), pixel in 0usize..81,
            ) {
                let kind = [Kind::Elliptical, Kind::AxisAligned, Kind::Circular][kind_i];
                let sampling = if point { Sampling::Point } else { Sampling::Integrated };
                let mut theta = [x0, y0, amp, u, v, t, bg];
                kind.constrain(&mut theta);
                let mut ws = Workspace::default();
                ws.resize(0, 0, 9, 9);
                ws.gl_n = 6; // a fixed rule, so that the two sides do not switch orders
                fill_phi(&mut ws, &theta, sampling, kind);
                let phi = [ws.e[pixel], ws.phi[0][pixel], ws.phi[1][pixel], ws.phi[2][pixel], ws.phi[3][pixel], ws.phi[4][pixel], 1.0];
                let c = kind.coefficients(&theta, &Shape::of(&theta));
                for row in 0..kind.n_free() {
                    let analytic: f64 = (0..7).map(|b| c[row][b] * phi[b]).sum();
                    let h = 1e-5;
                    let mut step = [0.0; 7];
                    step[row] = h;
                    let plus = value_at(&mut ws, &kind.apply_step(&theta, &step), sampling, kind, pixel);
                    step[row] = -h;
                    let minus = value_at(&mut ws, &kind.apply_step(&theta, &step), sampling, kind, pixel);
                    let fd = (plus - minus) / (2.0 * h);
                    // truncation ~h² f''' / 6 plus rounding ~1e-16 |f| / h
                    let tol = 1e-6 * (amp + bg.abs()) + 1e-6 * analytic.abs();
                    prop_assert!((analytic - fd).abs() < tol, "{kind:?} {sampling:?} row {row}: {analytic} vs {fd}");
                }
            }
        }
    }

    #[test]
    fn neighbour_rendering_is_accurate() {
        // a neighbour 8 px away and one in the window, sigma >= 1, any rho
        for (sx, sy, rho) in [(1.0, 1.0, 0.0), (1.6, 1.3, 0.5), (2.5, 1.2, -0.7)] {
            for x0 in [4.3, 12.1] {
                let g = Gaussian2D {
                    x0,
                    y0: 4.6,
                    amplitude: 1.0,
                    sigma_x: sx,
                    sigma_y: sy,
                    rho,
                    background: 0.0,
                };
                let win = Window::new(0, 0, 9, 9);
                let exact = bostrack_model::render(&g, win, Sampling::Integrated);
                let mut ws = ws_for(win);
                dot_factor(&mut ws, &theta_from_gaussian(&g), Sampling::Integrated);
                let worst = exact
                    .iter()
                    .zip(&ws.tmp)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(worst < 2e-4, "{sx} {sy} {rho} {x0}: {worst}");
            }
        }
    }
}
