//! The specialised Levenberg-Marquardt solver: normal equations from one fused pass over the
//! pixels, fixed-size arrays, no allocation.

use crate::eval::{
    IA, IB, IT, IU, IV, IX, IY, Kind, Pass, Theta, Workspace, evaluate_h, newton_matrix,
    normal_equations, pass_from_factor, resum, start_linear, weight_change, weight_change_at_model,
};
use bostrack_core::{FitStatus, NoiseModel};
use bostrack_model::Sampling;

/// Box constraints of the internal parameters (documented in the crate doc).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Bounds {
    pub u_min: f64,
    pub u_max: f64,
    pub t_max: f64,
    pub amp_min: f64,
    /// Pixel area of the window: the centre must stay in [x_lo, x_hi] × [y_lo, y_hi].
    pub x_lo: f64,
    pub x_hi: f64,
    pub y_lo: f64,
    pub y_hi: f64,
}

/// Smallest sigma (px) the fit may reach.
pub(crate) const SIGMA_MIN: f64 = 0.1;
/// Largest |ρ| the fit may reach.
pub(crate) const RHO_MAX: f64 = 0.999;

impl Bounds {
    pub fn for_window(wx: i64, wy: i64, w: usize, h: usize) -> Bounds {
        Bounds {
            u_min: SIGMA_MIN.ln(),
            u_max: (w.max(h) as f64).max(1.0).ln(),
            t_max: RHO_MAX.atanh(),
            amp_min: 1e-9,
            x_lo: wx as f64 - 0.5,
            x_hi: (wx + w as i64) as f64 - 0.5,
            y_lo: wy as f64 - 0.5,
            y_hi: (wy + h as i64) as f64 - 0.5,
        }
    }
    /// Clamps the shape parameters and the amplitude; returns whether any was clamped.
    pub fn project(&self, t: &mut Theta) -> bool {
        let before = *t;
        t[IU] = t[IU].clamp(self.u_min, self.u_max);
        t[IV] = t[IV].clamp(self.u_min, self.u_max);
        let t_max = self.t_bound(t);
        t[IT] = t[IT].clamp(-t_max, t_max);
        t[IA] = t[IA].max(self.amp_min);
        before != *t
    }
    /// The largest |atanh ρ| at θ's sigmas: [`RHO_MAX`], and no narrower than `SIGMA_MIN` along
    /// the ellipse's minor axis (the smallest eigenvalue of Σ at least `SIGMA_MIN²`, i.e.
    /// `ρ² ≤ (1 − s²/σx²)(1 − s²/σy²)`): a dot does not become a line through the window
    /// whatever ρ's step (issue 17: at σ 0.3 px trial shapes with ρ → ±0.999 were 5 % of the
    /// evaluations and 30 % of the instructions, their model neither factorable nor resolved
    /// by the quadrature's nodes).
    pub fn t_bound(&self, t: &Theta) -> f64 {
        // (without exp: both sigmas at least 5 × SIGMA_MIN bound |ρ| at 1 − 1/25 = 0.96 or
        // more, so |atanh ρ| ≤ atanh 0.96 = ln 7 is inside; the projection and `at_bound` then
        // see no difference from RHO_MAX's bound)
        if t[IU].min(t[IV]) >= self.u_min + 5f64.ln() && t[IT].abs() <= 7f64.ln() {
            return self.t_max;
        }
        let s2 = self.u_min.exp().powi(2);
        let (vx, vy) = ((2.0 * t[IU]).exp(), (2.0 * t[IV]).exp());
        let r2 = ((1.0 - s2 / vx).max(0.0) * (1.0 - s2 / vy).max(0.0)).min(RHO_MAX * RHO_MAX);
        r2.sqrt().atanh().min(self.t_max)
    }
    /// Whether a shape parameter or the amplitude sits on its bound.
    pub fn at_bound(&self, t: &Theta) -> bool {
        let eps = 1e-9;
        t[IU] <= self.u_min + eps
            || t[IU] >= self.u_max - eps
            || t[IV] <= self.u_min + eps
            || t[IV] >= self.u_max - eps
            || t[IT].abs() >= self.t_bound(t) - eps
            || t[IA] <= self.amp_min * (1.0 + eps)
    }
    pub fn inside(&self, t: &Theta) -> bool {
        t[IX] >= self.x_lo && t[IX] <= self.x_hi && t[IY] >= self.y_lo && t[IY] <= self.y_hi
    }
}

/// `L D Lᵀ` factor (unit lower `L`, no square roots) of the leading n×n block of
/// `N + λ diag N`, with the reciprocal pivots stored: a solve has no division.
#[derive(Clone, Debug)]
pub(crate) struct Factor {
    l: [[f64; 7]; 7],
    inv_d: [f64; 7],
    n: usize,
}

impl Factor {
    /// `None` if a diagonal entry of `N` is not positive and finite, or a pivot falls below
    /// 1e-14 of its diagonal entry of `N` (the unit diagonal of the Jacobi-scaled matrix).
    pub fn new(nm: &[[f64; 7]; 7], n: usize, lambda: f64) -> Option<Factor> {
        // fixed sizes: the loops unroll and lose their bounds checks
        match n {
            7 => Factor::new_n::<7>(nm, lambda),
            6 => Factor::new_n::<6>(nm, lambda),
            5 => Factor::new_n::<5>(nm, lambda),
            4 => Factor::new_n::<4>(nm, lambda),
            3 => Factor::new_n::<3>(nm, lambda),
            2 => Factor::new_n::<2>(nm, lambda),
            1 => Factor::new_n::<1>(nm, lambda),
            _ => None,
        }
    }

    fn new_n<const N: usize>(nm: &[[f64; 7]; 7], lambda: f64) -> Option<Factor> {
        let mut l = [[0.0; 7]; 7];
        let mut inv_d = [0.0; 7];
        ldlt_n::<N, 7>(nm, lambda, &mut l, &mut inv_d).then_some(Factor { l, inv_d, n: N })
    }

    pub fn solve(&self, g: &[f64; 7]) -> [f64; 7] {
        match self.n {
            7 => self.solve_n::<7>(g),
            6 => self.solve_n::<6>(g),
            5 => self.solve_n::<5>(g),
            4 => self.solve_n::<4>(g),
            3 => self.solve_n::<3>(g),
            2 => self.solve_n::<2>(g),
            _ => self.solve_n::<1>(g),
        }
    }

    /// The factor of the matrix times `f > 0` (`L` unchanged, `D` times `f`).
    pub fn scaled(&self, f: f64) -> Factor {
        let mut out = self.clone();
        for v in out.inv_d.iter_mut().take(self.n) {
            *v /= f;
        }
        out
    }

    /// `xᵀ (L D Lᵀ) x` (the factored matrix's quadratic form, λ included).
    pub fn quad_form(&self, x: &[f64; 7]) -> f64 {
        let n = self.n;
        let mut s = 0.0;
        for k in 0..n {
            // (Lᵀx)_k = x_k + Σ_{i>k} L_ik x_i
            let mut t = x[k];
            for i in k + 1..n {
                t += self.l[i][k] * x[i];
            }
            s += t * t / self.inv_d[k];
        }
        s
    }

    fn solve_n<const N: usize>(&self, g: &[f64; 7]) -> [f64; 7] {
        ldlt_solve_n::<N, 7>(&self.l, &self.inv_d, g)
    }
}

/// The `L D Lᵀ` factor of the leading `N × N` block of `N + λ diag N` into `l` (unit lower,
/// below the diagonal) and `inv_d` (the reciprocal pivots), arrays of any size `M ≥ N`;
/// `false` under [`Factor::new`]'s conditions.
#[inline(always)]
fn ldlt_n<const N: usize, const M: usize>(
    nm: &[[f64; 7]; 7],
    lambda: f64,
    l: &mut [[f64; M]; M],
    inv_d: &mut [f64; M],
) -> bool {
    for (k, row) in nm.iter().enumerate().take(N) {
        let v = row[k];
        if !(v > 0.0 && v.is_finite()) {
            return false;
        }
    }
    // ld[i][k] = L_ik D_k
    let mut ld = [[0.0; N]; N];
    for j in 0..N {
        let mut p = nm[j][j] * (1.0 + lambda);
        for k in 0..j {
            p -= ld[j][k] * l[j][k];
        }
        if p.is_nan() || p <= 1e-14 * nm[j][j] {
            return false;
        }
        let inv = 1.0 / p;
        inv_d[j] = inv;
        for i in j + 1..N {
            let mut s = nm[i][j];
            for k in 0..j {
                s -= ld[i][k] * l[j][k];
            }
            ld[i][j] = s;
            l[i][j] = s * inv;
        }
    }
    true
}

/// `(L D Lᵀ)⁻¹ g` for the factor of [`ldlt_n`].
#[inline(always)]
fn ldlt_solve_n<const N: usize, const M: usize>(
    l: &[[f64; M]; M],
    inv_d: &[f64; M],
    g: &[f64; 7],
) -> [f64; 7] {
    let mut x = [0.0; 7];
    for i in 0..N {
        let mut s = g[i];
        for k in 0..i {
            s -= l[i][k] * x[k];
        }
        x[i] = s;
    }
    for i in 0..N {
        x[i] *= inv_d[i];
    }
    for i in (0..N).rev() {
        let mut s = x[i];
        for k in i + 1..N {
            s -= l[k][i] * x[k];
        }
        x[i] = s;
    }
    x
}

/// Solves `(N + λ diag N) δ = g` for the leading `n × n` block. `None` if not positive definite.
pub(crate) fn solve_damped(
    nm: &[[f64; 7]; 7],
    g: &[f64; 7],
    n: usize,
    lambda: f64,
) -> Option<[f64; 7]> {
    // the factor's arithmetic and the solve's, without the factor as a value (it was built,
    // wrapped in an `Option` and copied for one solve: a tenth of the time of `locate` went
    // to copies of such arrays)
    match n {
        7 => solve_damped_n::<7>(nm, g, lambda),
        6 => solve_damped_n::<6>(nm, g, lambda),
        5 => solve_damped_n::<5>(nm, g, lambda),
        4 => solve_damped_n::<4>(nm, g, lambda),
        3 => solve_damped_n::<3>(nm, g, lambda),
        2 => solve_damped_n::<2>(nm, g, lambda),
        1 => solve_damped_n::<1>(nm, g, lambda),
        _ => None,
    }
}

/// [`Factor::new`] then [`Factor::solve`] for `N` unknowns, on local arrays (no factor value).
fn solve_damped_n<const N: usize>(
    nm: &[[f64; 7]; 7],
    g: &[f64; 7],
    lambda: f64,
) -> Option<[f64; 7]> {
    let mut l = [[0.0; N]; N];
    let mut inv_d = [0.0; N];
    ldlt_n::<N, N>(nm, lambda, &mut l, &mut inv_d).then(|| ldlt_solve_n::<N, N>(&l, &inv_d, g))
}

/// `sqrt((N⁻¹)₀₀)`, `sqrt((N⁻¹)₁₁)`: the bound of x0 and y0 (both free parameters come first).
pub(crate) fn position_bound(nm: &[[f64; 7]; 7], n: usize) -> Option<[f64; 2]> {
    let f = Factor::new(nm, n, 0.0)?;
    let mut e = [0.0; 7];
    e[0] = 1.0;
    let x = f.solve(&e)[0];
    e = [0.0; 7];
    e[1] = 1.0;
    let y = f.solve(&e)[1];
    (x > 0.0 && y > 0.0).then(|| [x.sqrt(), y.sqrt()])
}

/// `xᵀ N x` over the leading n×n block.
pub(crate) fn quad_form(nm: &[[f64; 7]; 7], x: &[f64; 7], n: usize) -> f64 {
    // fixed sizes: the loops unroll
    match n {
        7 => quad_form_n::<7>(nm, x),
        6 => quad_form_n::<6>(nm, x),
        5 => quad_form_n::<5>(nm, x),
        4 => quad_form_n::<4>(nm, x),
        3 => quad_form_n::<3>(nm, x),
        2 => quad_form_n::<2>(nm, x),
        1 => quad_form_n::<1>(nm, x),
        _ => 0.0,
    }
}

fn quad_form_n<const N: usize>(nm: &[[f64; 7]; 7], x: &[f64; 7]) -> f64 {
    let mut s = 0.0;
    for i in 0..N {
        for j in 0..N {
            s += x[i] * nm[i][j] * x[j];
        }
    }
    s
}

/// Outcome of a least-squares solve.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Outcome {
    pub theta: Theta,
    pub status: FitStatus,
    pub iterations: u32,
    pub at_bound: bool,
    /// Normal matrix (Fisher information of the free parameters) at `theta`.
    pub fisher: [[f64; 7]; 7],
    /// Σ keep r² at `theta`.
    pub ssr: f64,
    /// Σ w r² at `theta` with the solve's weights (the χ² of the window under the noise model).
    pub cost: f64,
    /// Position bound from `fisher` (filled by the caller).
    pub bound: Option<[f64; 2]>,
    /// A solve that converged to a minimum whose position bound exceeds a pixel (its status
    /// set to `Singular` by the caller).
    pub unbounded: bool,
    /// An elliptical model's intermediate fit made with ρ held at 0 (`Fitter::solve_integrated`):
    /// ρ one Gauss-Newton step of the full model from its solution (NaN: none).
    pub rho_held: Option<f64>,
}

const LAMBDA_START: f64 = 1e-3;
/// Solves whose tolerance is at most this take Newton steps (the final fits, tolerance 0.05 by
/// default); intermediate fits (tolerance 1, from the window's moments several standard
/// deviations away) converge in about two Gauss-Newton steps, where Newton's steps overshot
/// (issue 17, bench/trackpy's peak-SNR-6 scene: 4,811 → 7,107 trial evaluations with 2,009
/// steps rejected).
const NEWTON_TOLERANCE_MAX: f64 = 0.5;
/// Longest Newton step taken (its length² in the Fisher metric, i.e. 2 standard deviations):
/// beyond it the quadratic model of a start far away is not trusted and the step is
/// Gauss-Newton's.
const NEWTON_REACH2: f64 = 4.0;
/// Newton steps only where the amplitude's signal-to-noise ratio at the start (about the
/// amplitude over its bound with the other parameters known; [`takes_newton`]) is below this:
/// Gauss-Newton's linear rate is the size of the residual's term against `N`, which falls as
/// 1/SNR; at the peak-SNR-6 scene's (10-15) its steps shrink by ~0.4 each (3.3 evaluations per
/// final fit, 2.1 with Newton's); at σ 1.25 px and peak SNR ~40 (110-120) and on the real
/// sample (90-170) both take the same evaluations, and the residual's moments would only cost.
const NEWTON_Z_MAX: f64 = 30.0;
/// Nor below this SNR (near the detection limit, where a fit's amplitude may end at 0 and the
/// presence test decides: Gauss-Newton's path there as before; pipeline test `faint`'s peak SNR
/// 3.5 missed 13 instead of 12 of 2,401 dots with Newton steps down to 0).
const NEWTON_Z_MIN: f64 = 8.0;
const LAMBDA_MIN: f64 = 1e-9;
const LAMBDA_MAX: f64 = 1e10;

/// Weights change beyond which the Fisher matrix is recomputed with the weights at the
/// solution.
const REWEIGHT: f64 = 0.02;
/// Weights change beyond which the solve is repeated with the weights at its solution (on the
/// real sample, single solves from the moments: positions then agree with the
/// levenberg-marquardt crate's two-round reweighting to a median 5e-4 of the bound; with 0.2
/// the median was 0.04 and 4 % of the dots differed by more than 0.1 of the bound).
const RESOLVE: f64 = 0.05;

/// Levenberg-Marquardt from `theta0` (already projected into the bounds), with the weights of
/// the noise model fixed at the start's model (so that Gauss-Newton converges quadratically
/// and a pass needs no division per pixel). With signal-dependent noise the weights are then
/// checked at the solution: if one changed by more than 5 % the solve is repeated from there
/// with the new weights (iteratively reweighted least squares, same fixed point); if by more
/// than 2 %, only the Fisher matrix (the bound) is recomputed with them (the estimate of
/// weights that close moves by a few hundredths of its standard deviation). `reweight = false`
/// skips that for intermediate fits (a neighbour pass that is refitted from its solution).
///
/// With `reweight`, the weights are also set again during the solve, after an accepted step
/// that changed one by more than 5 % (the model at the step is the evaluation's: only the
/// weighted sums are redone), so that the check at the solution rarely asks for a second solve
/// (issue 17: at σ 0.3 px a dot's amplitude moves by 5-40 % when its correlation is freed, and
/// 3,160 of ~4,700 final solves were repeated, each with a full evaluation and two renderings).
/// The check at the solution and the refreshed Fisher matrix take the last evaluation's model
/// where it is at the solution (or one step shorter than the tolerance from it).
#[allow(clippy::too_many_arguments)]
pub(crate) fn solve_fast(
    ws: &mut Workspace,
    theta0: Theta,
    kind: Kind,
    sampling: Sampling,
    noise: &NoiseModel,
    bounds: &Bounds,
    max_iterations: u32,
    tolerance: f64,
    reweight: bool,
) -> Outcome {
    let mut theta0 = theta0;
    start_linear(ws, &mut theta0, sampling, noise, bounds.amp_min);
    let reweight = reweight && !noise.is_constant();
    // the first pass from the unit dot the linear start rendered (point-sampled: `E` does not
    // depend on the amplitude and background it set; the pass's own `exp_grid` again gave the
    // same bits)
    let newton = takes_newton(tolerance, sampling, kind, &theta0, noise);
    let first = (sampling == Sampling::Point)
        .then(|| pass_from_factor(ws, &theta0, noise, newton && kind.hess()));
    let (mut out, mut model_at) = lm_loop(
        ws,
        theta0,
        first,
        kind,
        sampling,
        noise,
        bounds,
        max_iterations,
        tolerance,
        reweight,
        newton,
    );
    for _ in 0..3 {
        if !reweight || !out.status.is_ok() {
            break;
        }
        let change = match model_at {
            Some(at) => weight_change_at_model(ws, &at, noise),
            None => weight_change(ws, &out.theta, sampling, noise),
        };
        if change <= REWEIGHT {
            break;
        }
        std::mem::swap(&mut ws.w_cur, &mut ws.w_new);
        // the pass at the solution with the new weights: the last evaluation's model summed
        // again, or a new evaluation (with the moments the repeated solve's Newton steps need,
        // decided there)
        let at = model_at.unwrap_or(out.theta);
        let newton = takes_newton(tolerance, sampling, kind, &at, noise);
        let pass = match model_at {
            Some(_) => resum(ws, &at, sampling, kind, noise, newton),
            None => evaluate_h(ws, &at, sampling, kind, noise, newton),
        };
        if change <= RESOLVE {
            // the estimate moves by a second-order amount only: keep it, but give the Fisher
            // matrix (the bound) and the cost the weights at the solution
            if pass.finite {
                out.fisher = normal_equations(kind, &at, &pass).0;
                out.ssr = pass.ssr;
                out.cost = pass.cost;
            }
            break;
        }
        let again;
        (again, model_at) = lm_loop(
            ws,
            at,
            Some(pass),
            kind,
            sampling,
            noise,
            bounds,
            max_iterations.saturating_sub(out.iterations).max(1),
            tolerance,
            reweight,
            newton,
        );
        out = Outcome {
            iterations: out.iterations + again.iterations,
            ..again
        };
    }
    out
}

/// Whether a solve from θ takes Newton steps: a point-sampled final fit (tolerance at most
/// [`NEWTON_TOLERANCE_MAX`]) of a dot with a free centre (R = 0 for the linear fit) whose
/// amplitude SNR is in the Newton band ([`NEWTON_Z_MIN`], [`NEWTON_Z_MAX`]); its evaluations
/// then make the residual's moments that the Newton matrix needs. The SNR from θ: a round
/// Gaussian's Σ E² over the plane is π σx σy (less by √(1 − ρ²) for an elliptical one), at
/// least the one pixel a narrow dot sits on, the variance the model's halfway up the dot.
fn takes_newton(
    tolerance: f64,
    sampling: Sampling,
    kind: Kind,
    theta: &Theta,
    noise: &NoiseModel,
) -> bool {
    tolerance <= NEWTON_TOLERANCE_MAX && sampling == Sampling::Point && kind != Kind::Linear && {
        let e2 = (std::f64::consts::PI * (theta[IU] + theta[IV]).exp()).max(1.0);
        let z2 = theta[IA] * theta[IA] * e2 / noise.variance(theta[IB] + 0.5 * theta[IA]);
        (NEWTON_Z_MIN * NEWTON_Z_MIN..NEWTON_Z_MAX * NEWTON_Z_MAX).contains(&z2)
    }
}

/// One Levenberg-Marquardt solve from `theta0` (`first`: the pass at `theta0` with the current
/// weights, if already made; `newton`: [`takes_newton`] at `theta0`, with which `first` was
/// made, so that every pass of the solve has the moments its Newton matrix needs). Also returns the θ of the model that the workspace holds from
/// the last evaluation where that is the solution or a step shorter than the tolerance from it.
#[allow(clippy::too_many_arguments)]
fn lm_loop(
    ws: &mut Workspace,
    theta0: Theta,
    first: Option<Pass>,
    kind: Kind,
    sampling: Sampling,
    noise: &NoiseModel,
    bounds: &Bounds,
    max_iterations: u32,
    tolerance: f64,
    reweight: bool,
    newton: bool,
) -> (Outcome, Option<Theta>) {
    let n = kind.n_free();
    let mut theta = theta0;
    let mut pass: Pass =
        first.unwrap_or_else(|| evaluate_h(ws, &theta, sampling, kind, noise, newton));
    // whether the workspace's model (the last evaluation) is at θ
    let mut model_at_theta = true;
    let mut cost = pass.cost;
    let (mut nm, mut g) = normal_equations(kind, &theta, &pass);
    let hm_of = |kind, theta: &Theta, pass: &Pass, nm: &[[f64; 7]; 7]| {
        if newton {
            newton_matrix(kind, theta, pass, nm)
        } else {
            None
        }
    };
    // the Newton matrix at θ, made when a step is solved for (not after the last evaluation)
    let mut hm = None;
    let mut hm_fresh = false;
    let done = |theta: Theta, status, iterations, nm, pass: &Pass, model| {
        let out = Outcome {
            theta,
            status,
            iterations,
            at_bound: bounds.at_bound(&theta),
            fisher: nm,
            ssr: pass.ssr,
            cost: pass.cost,
            bound: None,
            unbounded: false,
            rho_held: None,
        };
        (out, model)
    };
    if !pass.finite {
        return done(theta, FitStatus::NonFinite, 0, nm, &pass, None);
    }
    let tol2 = tolerance * tolerance;
    // a step of √m2 standard deviations (the Fisher metric) moves a pixel's model by about √m2
    // of the pixel's noise σ at most, so its weight by gain·√m2/σ ≤ gain·√(m2 / read variance)
    let reweigh_step2 = RESOLVE * RESOLVE * noise.read_variance / (noise.gain * noise.gain);
    let mut lambda = LAMBDA_START;
    let mut left;
    let ia = kind.free().iter().position(|&p| p == IA);
    for it in 1..=max_iterations {
        // the Newton step where its matrix (damped as Gauss-Newton's) is positive definite,
        // else the Gauss-Newton one; `curv` the quadratic model's curvature along it
        if !hm_fresh {
            hm = hm_of(kind, &theta, &pass, &nm);
            hm_fresh = true;
        }
        // an amplitude on its lower bound that the gradient pushes further down is held there
        // (an active set): the step of the other parameters is the constrained problem's, not
        // the projection of a step that moved all of them (issue 17: linear fits of empty
        // lattice sites then crawled at λ = 1e10 to the iteration limit, the cost unchanged)
        let pinned = ia
            .filter(|&k| theta[IA] <= bounds.amp_min * (1.0 + 1e-9) && g[k] <= 0.0)
            .map(|k| {
                let (mut a, mut b, mut c) = (nm, g, hm);
                for m in [Some(&mut a), c.as_mut()].into_iter().flatten() {
                    let d = m[k][k];
                    for j in 0..n {
                        m[k][j] = 0.0;
                        m[j][k] = 0.0;
                    }
                    m[k][k] = d;
                }
                b[k] = 0.0;
                (a, b, c)
            });
        let (nm_s, g_s, hm_s) = match &pinned {
            Some((a, b, c)) => (a, b, c.as_ref()),
            None => (&nm, &g, hm.as_ref()),
        };
        let nstep = hm_s.and_then(|h| {
            let mut hd = *h;
            for k in 0..n {
                hd[k][k] += lambda * nm_s[k][k];
            }
            let d = solve_damped(&hd, g_s, n, 0.0)?;
            let len2 = quad_form(&nm, &d, n);
            (len2 <= NEWTON_REACH2).then(|| (d, len2, quad_form(h, &d, n)))
        });
        let (step, known) = match nstep {
            Some((d, len2, c)) => (Some(d), Some((len2, c))),
            None => (solve_damped(nm_s, g_s, n, lambda), None),
        };
        let Some(step) = step else {
            lambda *= 10.0;
            if lambda > LAMBDA_MAX {
                let model = model_at_theta.then_some(theta);
                return done(theta, FitStatus::Singular, it, nm, &pass, model);
            }
            continue;
        };
        let mut trial = kind.apply_step(&theta, &step);
        let clamped = bounds.project(&mut trial);
        kind.constrain(&mut trial);
        let finite = trial.iter().all(|v| v.is_finite());
        // the step's length² in the Fisher metric and gᵀδ: the linearised model's cost at the
        // trial is cost - 2 gᵀδ + δᵀ N δ
        let gd = (0..n).map(|k| g[k] * step[k]).sum::<f64>();
        let (step2, curv) = known.unwrap_or_else(|| {
            let s2 = quad_form(&nm, &step, n);
            (s2, s2)
        });
        // a Gauss-Newton step (λ small) shorter than the tolerance: take it and stop without
        // evaluating the trial (the cost cannot rise measurably over a step of 1e-2 standard
        // deviations, and what is left after it is of second order); the Fisher matrix is the
        // one at θ, a hundredth of a standard deviation away
        if finite && !clamped && lambda <= 1e-2 && bounds.inside(&trial) && step2 <= tol2 {
            // residual sum of squares at the trial by the linearised model:
            // Σ w (r - Jδ)² = cost - 2 gᵀδ + δᵀ N δ (the unweighted one scaled alike)
            let predicted = (cost - 2.0 * gd + curv).max(0.0);
            let ssr = if cost > 0.0 {
                pass.ssr * predicted / cost
            } else {
                pass.ssr
            };
            let model = model_at_theta.then_some(theta);
            let (out, model) = done(trial, FitStatus::Converged, it, nm, &pass, model);
            return (
                Outcome {
                    ssr,
                    cost: predicted,
                    ..out
                },
                model,
            );
        }
        let accepted = if !finite || !bounds.inside(&trial) {
            left = finite;
            false
        } else {
            left = false;
            let p = evaluate_h(ws, &trial, sampling, kind, noise, newton);
            model_at_theta = false;
            if p.finite && p.cost <= cost {
                // the step actually taken (after projection), in free coordinates
                let mut taken = [0.0; 7];
                for (k, &idx) in kind.free().iter().enumerate() {
                    taken[k] = trial[idx] - theta[idx];
                }
                let m2 = quad_form(&nm, &taken, n);
                let damped = lambda > 1.0;
                let gain = (cost - p.cost) / (2.0 * gd - curv).max(f64::MIN_POSITIVE);
                theta = trial;
                cost = p.cost;
                pass = p;
                model_at_theta = true;
                (nm, g) = normal_equations(kind, &theta, &pass);
                hm_fresh = false;
                // (a step that lowered the cost by less than a quarter of what the linear
                // model predicted: the model is poor over that length, the next step shorter;
                // issue 17: a held-shape fit of a σ 0.3 px dot, from its moments, crawled 50
                // full Gauss-Newton steps with gains of 0.3-6 %, ending at the iteration limit)
                lambda = if gain < 0.25 {
                    (lambda * 4.0).min(LAMBDA_MAX)
                } else {
                    (lambda * 0.1).max(LAMBDA_MIN)
                };
                if m2 <= tol2 && !damped {
                    let model = Some(theta);
                    return done(theta, FitStatus::Converged, it, nm, &pass, model);
                }
                // the weights at the new θ, where they moved by more than the check at the
                // solution lets pass: the same model summed again (not looked at after a step
                // too short to move one that far)
                if reweight
                    && m2 > reweigh_step2
                    && weight_change_at_model(ws, &theta, noise) > RESOLVE
                {
                    std::mem::swap(&mut ws.w_cur, &mut ws.w_new);
                    pass = resum(ws, &theta, sampling, kind, noise, newton);
                    if !pass.finite {
                        let model = Some(theta);
                        return done(theta, FitStatus::NonFinite, it, nm, &pass, model);
                    }
                    cost = pass.cost;
                    (nm, g) = normal_equations(kind, &theta, &pass);
                    hm_fresh = false;
                }
                true
            } else {
                false
            }
        };
        if !accepted {
            lambda *= 10.0;
            if lambda > LAMBDA_MAX {
                let model = model_at_theta.then_some(theta);
                if left {
                    return done(theta, FitStatus::LeftWindow, it, nm, &pass, model);
                }
                // no step lowers the cost: a (possibly constrained) minimum to rounding
                let gn = solve_damped(&nm, &g, n, 0.0);
                let small = gn.is_some_and(|d| quad_form(&nm, &d, n) <= 100.0 * tol2);
                let status = if small || clamped || bounds.at_bound(&theta) {
                    FitStatus::Converged
                } else {
                    FitStatus::Singular
                };
                return done(theta, status, it, nm, &pass, model);
            }
        }
    }
    done(
        theta,
        FitStatus::IterationLimit,
        max_iterations,
        nm,
        &pass,
        model_at_theta.then_some(theta),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn damped_solve_and_inverse() {
        let mut nm = [[0.0; 7]; 7];
        let a = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        for i in 0..3 {
            for j in 0..3 {
                nm[i][j] = a[i][j];
            }
        }
        let g = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0];
        let x = solve_damped(&nm, &g, 3, 0.0).unwrap();
        for i in 0..3 {
            let r: f64 = (0..3).map(|j| a[i][j] * x[j]).sum();
            assert!((r - g[i]).abs() < 1e-12);
        }
        let d = position_bound(&nm, 3).unwrap();
        // inverse of a 3x3 by cofactors: (A⁻¹)_00 = (a11 a22 - a12²) / det
        let det = 4.0 * (3.0 * 2.0 - 0.04) - 1.0 * (2.0 - 0.1) + 0.5 * (0.2 - 1.5);
        assert!((d[0] * d[0] - (3.0 * 2.0 - 0.04) / det).abs() < 1e-12);
        assert!((d[1] * d[1] - (4.0 * 2.0 - 0.25) / det).abs() < 1e-12);
        nm[2][2] = 0.0;
        assert!(solve_damped(&nm, &g, 3, 0.0).is_none());
    }

    /// The factor's quadratic form equals the matrix's (`xᵀ N x`), for every size.
    #[test]
    fn factor_quad_form_is_the_matrix_quad_form() {
        for n in 1..=7 {
            let mut nm = [[0.0; 7]; 7];
            for i in 0..n {
                for j in 0..n {
                    nm[i][j] = 1.0 / (1.0 + i as f64 + j as f64) + if i == j { 0.5 } else { 0.0 };
                }
            }
            let x: [f64; 7] = std::array::from_fn(|k| (k as f64 - 2.5) * 10f64.powi(k as i32 % 3));
            let f = Factor::new(&nm, n, 0.0).expect("positive definite");
            let (a, b) = (f.quad_form(&x), quad_form(&nm, &x, n));
            assert!((a - b).abs() <= 1e-12 * b.abs(), "n {n}: {a} {b}");
        }
    }

    /// The LDLᵀ factor for every size the fit uses, damped and undamped, against the residual
    /// of the system it solves; a rank-deficient matrix (two equal rows) is refused.
    #[test]
    fn ldlt_solves_the_damped_system_for_every_size() {
        for n in 1..=7 {
            // N = Aᵀ A + I/10 with a fixed, badly scaled A (entries over 8 decades)
            let mut nm = [[0.0; 7]; 7];
            for i in 0..n {
                for j in 0..n {
                    let mut acc = if i == j { 0.1 } else { 0.0 };
                    for k in 0..9 {
                        let a = |r: usize, c: usize| {
                            ((r * 7 + c * 3) % 11) as f64 - 5.0 + 10f64.powi(c as i32 - 3)
                        };
                        acc += a(k, i) * a(k, j) * 10f64.powi(i as i32 + j as i32 - 6);
                    }
                    nm[i][j] = acc;
                }
            }
            let g: [f64; 7] = std::array::from_fn(|k| (k as f64 + 1.0) * 10f64.powi(k as i32 - 3));
            for lambda in [0.0, 1e-3, 10.0] {
                let x = solve_damped(&nm, &g, n, lambda).expect("positive definite");
                // the fused solve is the factor's, bit for bit
                let f = Factor::new(&nm, n, lambda).expect("positive definite");
                assert_eq!(x, f.solve(&g), "n {n} λ {lambda}");
                for i in 0..n {
                    let r: f64 = (0..n)
                        .map(|j| (nm[i][j] + if i == j { lambda * nm[i][i] } else { 0.0 }) * x[j])
                        .sum();
                    let scale: f64 =
                        (0..n).map(|j| (nm[i][j] * x[j]).abs()).sum::<f64>() + g[i].abs();
                    assert!(
                        (r - g[i]).abs() <= 1e-12 * scale,
                        "n {n} λ {lambda} row {i}"
                    );
                }
            }
            if n >= 2 {
                let mut sing = nm;
                sing[n - 1] = sing[n - 2];
                for row in sing.iter_mut() {
                    row[n - 1] = row[n - 2];
                }
                assert!(solve_damped(&sing, &g, n, 0.0).is_none(), "n {n}");
            }
        }
    }

    /// The projection keeps the ellipse's minor axis at least `SIGMA_MIN` (smallest eigenvalue
    /// of Σ), leaves shapes inside the bounds unchanged, and `at_bound` sees the new bound.
    #[test]
    fn projection_keeps_the_minor_axis_at_least_sigma_min() {
        use crate::eval::{IB, IT, IU, IV};
        let b = Bounds::for_window(0, 0, 9, 9);
        let sigmas = [0.1, 0.12, 0.3, 0.5, 1.0, 2.5, 8.0];
        let rhos = [-0.9999, -0.99, -0.9, -0.5, 0.0, 0.3, 0.95, 0.999, 0.99999];
        for &sx in &sigmas {
            for &sy in &sigmas {
                for &r in &rhos {
                    let mut t = [
                        4.0,
                        4.0,
                        100.0,
                        f64::ln(sx),
                        f64::ln(sy),
                        f64::atanh(r),
                        10.0,
                    ];
                    let before = t;
                    let clamped = b.project(&mut t);
                    let (vx, vy, rr) = (t[IU].exp().powi(2), t[IV].exp().powi(2), t[IT].tanh());
                    // smallest eigenvalue of [[vx, c], [c, vy]]
                    let c = rr * (vx * vy).sqrt();
                    let lmin = 0.5 * (vx + vy - ((vx - vy).powi(2) + 4.0 * c * c).sqrt());
                    assert!(
                        lmin >= SIGMA_MIN * SIGMA_MIN * (1.0 - 1e-9),
                        "{sx} {sy} {r}: minor axis {}",
                        lmin.sqrt()
                    );
                    assert!(rr.abs() <= RHO_MAX + 1e-12);
                    // inside already: unchanged (minor axis clear of the bound by 1 %)
                    let (bx, by) = (sx * sx, sy * sy);
                    let c0 = r * sx * sy;
                    let l0 = 0.5 * (bx + by - ((bx - by).powi(2) + 4.0 * c0 * c0).sqrt());
                    if l0 > 1.0201 * SIGMA_MIN * SIGMA_MIN && r.abs() < RHO_MAX {
                        assert!(!clamped && t == before, "{sx} {sy} {r} moved");
                    }
                    if t[IT] != before[IT] {
                        assert!(
                            b.at_bound(&t),
                            "{sx} {sy} {r}: clamped rho not at its bound"
                        );
                    }
                    assert_eq!(t[IB], before[IB]);
                }
            }
        }
    }
}
