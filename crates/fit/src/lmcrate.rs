//! The same least-squares problem solved by the `levenberg-marquardt` crate (MINPACK's trust
//! region on the QR factorisation of the weighted Jacobian): the baseline the fast solver is
//! checked and timed against.

use crate::eval::{
    IA, IB, IX, IY, Kind, Shape, Theta, Workspace, evaluate, fill_phi, normal_equations,
    set_weights,
};
use crate::solver::{Bounds, Outcome};
use bostrack_core::{FitStatus, NoiseModel};
use bostrack_model::Sampling;
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt, TerminationReason};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

struct Problem<'a> {
    ws: &'a mut Workspace,
    kind: Kind,
    sampling: Sampling,
    bounds: Bounds,
    theta: Theta,
    /// sqrt(weight) of the usable pixels, and their indices.
    sqrt_w: Vec<f64>,
    used: Vec<usize>,
    resid: DVector<f64>,
    jac: DMatrix<f64>,
    clamped_centre: bool,
}

impl Problem<'_> {
    fn free_vector(&self) -> DVector<f64> {
        DVector::from_iterator(
            self.kind.n_free(),
            self.kind.free().iter().map(|&p| self.theta[p]),
        )
    }
    fn compute(&mut self) {
        let t = self.theta;
        fill_phi(self.ws, &t, self.sampling, self.kind);
        let s = Shape::of(&t);
        let c = self.kind.coefficients(&t, &s);
        let n = self.kind.n_free();
        for (row, &k) in self.used.iter().enumerate() {
            let phi = [
                self.ws.e[k],
                self.ws.phi[0][k],
                self.ws.phi[1][k],
                self.ws.phi[2][k],
                self.ws.phi[3][k],
                self.ws.phi[4][k],
                1.0,
            ];
            let sw = self.sqrt_w[row];
            self.resid[row] = sw * (t[IB] + t[IA] * phi[0] - self.ws.data[k]);
            for col in 0..n {
                let d: f64 = (0..7).map(|b| c[col][b] * phi[b]).sum();
                self.jac[(row, col)] = sw * d;
            }
        }
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        let mut step = [0.0; 7];
        for (k, &p) in self.kind.free().iter().enumerate() {
            step[k] = x[k] - self.theta[p];
        }
        let mut t = self.kind.apply_step(&self.theta, &step);
        self.bounds.project(&mut t);
        self.kind.constrain(&mut t);
        // keep the centre in the window (the crate cannot reject a step)
        let (cx, cy) = (
            t[IX].clamp(self.bounds.x_lo, self.bounds.x_hi),
            t[IY].clamp(self.bounds.y_lo, self.bounds.y_hi),
        );
        self.clamped_centre = cx != t[IX] || cy != t[IY];
        t[IX] = cx;
        t[IY] = cy;
        self.theta = t;
        self.compute();
    }
    fn params(&self) -> DVector<f64> {
        self.free_vector()
    }
    fn residuals(&self) -> Option<DVector<f64>> {
        Some(self.resid.clone())
    }
    fn jacobian(&self) -> Option<DMatrix<f64>> {
        Some(self.jac.clone())
    }
}

/// Fit with the levenberg-marquardt crate. The weights are those of the noise model at the
/// start; with signal-dependent noise the fit is repeated once with the weights at the first
/// solution (iteratively reweighted least squares).
pub(crate) fn solve_lm_crate(
    ws: &mut Workspace,
    theta0: Theta,
    kind: Kind,
    sampling: Sampling,
    noise: &NoiseModel,
    bounds: &Bounds,
    max_iterations: u32,
    tolerance: f64,
) -> Outcome {
    let used: Vec<usize> = (0..ws.len()).filter(|&k| ws.keep[k] > 0.0).collect();
    let m = used.len();
    let n = kind.n_free();
    let rounds = if noise.is_constant() { 1 } else { 2 };
    let mut theta = theta0;
    let mut evaluations = 0u32;
    let mut termination = TerminationReason::NoParameters;
    let mut clamped_centre = false;
    for _ in 0..rounds {
        // weights at the current point
        fill_phi(ws, &theta, sampling, kind);
        let sqrt_w: Vec<f64> = used
            .iter()
            .map(|&k| 1.0 / noise.variance(theta[IB] + theta[IA] * ws.e[k]).sqrt())
            .collect();
        let mut problem = Problem {
            ws: &mut *ws,
            kind,
            sampling,
            bounds: *bounds,
            theta,
            sqrt_w,
            used: used.clone(),
            resid: DVector::zeros(m),
            jac: DMatrix::zeros(m, n),
            clamped_centre: false,
        };
        problem.compute();
        let patience = (max_iterations as usize / (n + 1)).max(1);
        let lm = LevenbergMarquardt::new()
            .with_patience(patience)
            .with_ftol(1e-10 * tolerance)
            .with_xtol(1e-7 * tolerance)
            .with_gtol(1e-10 * tolerance);
        let (solved, report) = lm.minimize(problem);
        theta = solved.theta;
        clamped_centre = solved.clamped_centre;
        evaluations += report.number_of_evaluations as u32;
        termination = report.termination;
    }
    let status = if !theta.iter().all(|v| v.is_finite()) {
        FitStatus::NonFinite
    } else if clamped_centre {
        FitStatus::LeftWindow
    } else {
        match termination {
            TerminationReason::Converged { .. }
            | TerminationReason::Orthogonal
            | TerminationReason::ResidualsZero
            | TerminationReason::NoImprovementPossible(_) => FitStatus::Converged,
            TerminationReason::LostPatience => FitStatus::IterationLimit,
            TerminationReason::Numerical(_) => FitStatus::NonFinite,
            _ => FitStatus::Singular,
        }
    };
    // Fisher matrix at the solution with the fast evaluation
    set_weights(ws, &theta, sampling, noise);
    let pass = evaluate(ws, &theta, sampling, kind, noise);
    let (fisher, _) = normal_equations(kind, &theta, &pass);
    Outcome {
        theta,
        status,
        iterations: evaluations,
        at_bound: bounds.at_bound(&theta),
        fisher,
        ssr: pass.ssr,
        cost: pass.cost,
        bound: None,
        unbounded: false,
        rho_held: None,
    }
}
