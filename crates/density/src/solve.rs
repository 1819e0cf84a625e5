//! The normal equations, their sparse Cholesky factor (faer, supernodal LLᵀ with an AMD
//! ordering), the solution and the diagonal of its covariance.

use crate::system::System;
use crate::{DensityError, IntegrationConfig, Method, Node};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, Mat, MatRef, Par, Side};
use rayon::prelude::*;

pub(crate) struct Solution {
    /// ρ − ρ_ref at each unknown.
    pub x: Vec<f64>,
    /// Variance of each unknown (without the reference density's).
    pub variance: Option<Vec<f64>>,
    pub factor_nnz: usize,
    pub residual_rms: Option<f64>,
}

/// The lower triangle of the normal matrix `Σ_groups Gᵀ W G` over the unknowns, and its
/// right-hand side (the Dirichlet nodes hold ρ − ρ_ref = 0, so they drop out).
pub(crate) fn normal_equations(
    sys: &System,
    unknown: &[usize],
) -> (Vec<Triplet<usize, usize, f64>>, Vec<f64>, usize) {
    let n = unknown.iter().filter(|&&k| k != usize::MAX).count();
    let mut trip = Vec::new();
    let mut rhs = vec![0.0; n];
    for g in &sys.groups {
        let m = g.rows.len();
        for a in 0..m {
            for b in 0..m {
                let w = g.weight[a * m + b];
                for &(p, cp) in &g.rows[a] {
                    let kp = unknown[p];
                    if kp == usize::MAX {
                        continue;
                    }
                    rhs[kp] += cp * w * g.obs[b];
                    for &(q, cq) in &g.rows[b] {
                        let kq = unknown[q];
                        if kq != usize::MAX && kq >= kp {
                            trip.push(Triplet::new(kq, kp, cp * w * cq));
                        }
                    }
                }
            }
        }
    }
    (trip, rhs, n)
}

/// The supernodal Cholesky factor `P A Pᵀ = L Lᵀ`.
pub(crate) struct Factor {
    pub symbolic: SymbolicCholesky<usize>,
    pub values: Vec<f64>,
}

impl Factor {
    pub(crate) fn new(
        n: usize,
        trip: &[Triplet<usize, usize, f64>],
    ) -> Result<Factor, DensityError> {
        let fail = |e: String| DensityError::Factorization(e);
        let a = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, trip)
            .map_err(|e| fail(format!("{e:?}")))?;
        let symbolic = factorize_symbolic_cholesky(
            a.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )
        .map_err(|e| fail(format!("{e:?}")))?;
        let mut values = vec![0.0; symbolic.len_val()];
        let mut mem = MemBuffer::new(
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
        );
        symbolic
            .factorize_numeric_llt(
                &mut values,
                a.as_ref(),
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| {
                fail(format!(
                    "{e:?} (the normal matrix is not positive definite)"
                ))
            })?;
        Ok(Factor { symbolic, values })
    }

    /// Solves `A X = B` in place.
    pub(crate) fn solve(&self, b: &mut Mat<f64>) {
        let llt = LltRef::new(&self.symbolic, &self.values);
        let mut mem = MemBuffer::new(
            self.symbolic
                .solve_in_place_scratch::<f64>(b.ncols(), Par::Seq),
        );
        llt.solve_in_place_with_conj(Conj::No, b.as_mut(), Par::Seq, MemStack::new(&mut mem));
    }

    /// The diagonal of `A⁻¹` by selected inversion on the supernodal factor (Takahashi, Golub
    /// & Sanders 1973, in the block form of Lin et al., SelInv, ACM TOMS 37:40, 2011): with
    /// `Z = (LLᵀ)⁻¹`, for each supernode (columns J, rows R below them) from the last to the
    /// first, `Y = L_RJ L_JJ⁻¹`, `Z_RJ = −Z_RR Y` and `Z_JJ = L_JJ⁻ᵀ L_JJ⁻¹ − Yᵀ Z_RJ`. Every
    /// entry of `Z_RR` lies in the pattern of L (the filled graph is chordal), so Z is computed
    /// only there: `O(nnz(L))` memory, about the work of the factorisation, dense blocks.
    pub(crate) fn inverse_diagonal(&self) -> Vec<f64> {
        let SymbolicCholeskyRaw::Supernodal(s) = self.symbolic.raw() else {
            unreachable!("the factor is supernodal (FORCE_SUPERNODAL)");
        };
        let n = s.nrows();
        let (begin, end) = (s.supernode_begin(), s.supernode_end());
        let (rptr, vptr, ridx) = (s.col_ptr_for_row_idx(), s.col_ptr_for_val(), s.row_idx());
        let ns = s.n_supernodes();
        let ncols = |t: usize| end[t] - begin[t];
        let nrows = |t: usize| (vptr[t + 1] - vptr[t]) / ncols(t);
        let pattern = |t: usize| &ridx[rptr[t]..rptr[t] + nrows(t) - ncols(t)];
        let mut owner = vec![0usize; n];
        for t in 0..ns {
            owner[begin[t]..end[t]].fill(t);
        }
        let l = &self.values;
        let mut z = vec![0.0; l.len()];
        let mut local = vec![usize::MAX; n];
        for t in (0..ns).rev() {
            let (w, b) = (ncols(t), begin[t]);
            let rows = nrows(t);
            let pat = pattern(t);
            let r = pat.len();
            let lt = MatRef::from_column_major_slice(&l[vptr[t]..vptr[t + 1]], rows, w);
            let (l_jj, l_rj) = lt.split_at_row(w);
            // L_JJ⁻¹ (lower triangular)
            let mut l_inv = Mat::<f64>::identity(w, w);
            faer::linalg::triangular_solve::solve_lower_triangular_in_place(
                l_jj,
                l_inv.as_mut(),
                Par::Seq,
            );
            // Y = L_RJ L_JJ⁻¹
            let y = l_rj * &l_inv;
            // Z_RR gathered from the later supernodes (pattern sorted ascending)
            let mut z_rr = Mat::<f64>::zeros(r, r);
            let mut a = 0;
            while a < r {
                let o = owner[pat[a]];
                let (ow, orows) = (ncols(o), nrows(o));
                for (k, &g) in pattern(o).iter().enumerate() {
                    local[g] = ow + k;
                }
                let zo = &z[vptr[o]..vptr[o + 1]];
                let mut a_end = a;
                while a_end < r && owner[pat[a_end]] == o {
                    a_end += 1;
                }
                for c in a..a_end {
                    let col = pat[c] - begin[o];
                    for c2 in c..r {
                        let g = pat[c2];
                        let row = if g < end[o] { g - begin[o] } else { local[g] };
                        let v = zo[col * orows + row];
                        z_rr[(c2, c)] = v;
                        z_rr[(c, c2)] = v;
                    }
                }
                for &g in pattern(o) {
                    local[g] = usize::MAX;
                }
                a = a_end;
            }
            let z_rj = -(&z_rr * &y);
            let z_jj = l_inv.transpose() * &l_inv - y.transpose() * &z_rj;
            let zt = &mut z[vptr[t]..vptr[t + 1]];
            for c in 0..w {
                for i in 0..w {
                    zt[c * rows + i] = z_jj[(i, c)];
                }
                for i in 0..r {
                    zt[c * rows + w + i] = z_rj[(i, c)];
                }
            }
            let _ = b;
        }
        // back to the original order: (P A Pᵀ)_{ij} = A_{fwd[i], fwd[j]}
        let diag = |i: usize| {
            let t = owner[i];
            let c = i - begin[t];
            z[vptr[t] + c * nrows(t) + c]
        };
        let mut out = vec![0.0; n];
        match self.symbolic.perm() {
            Some(perm) => {
                let (fwd, _) = perm.arrays();
                for (i, &f) in fwd.iter().enumerate() {
                    out[f] = diag(i);
                }
            }
            None => {
                for (i, o) in out.iter_mut().enumerate() {
                    *o = diag(i);
                }
            }
        }
        out
    }
}

/// Columns per block of the blocked solves (Poisson's covariance).
const BLOCK: usize = 64;

pub(crate) fn solve(
    sys: &System,
    unknown: &[usize],
    n: usize,
    nodes: &[Node],
    cfg: &IntegrationConfig,
) -> Result<Solution, DensityError> {
    if n == 0 {
        return Ok(Solution {
            x: Vec::new(),
            variance: cfg.uncertainty.then(Vec::new),
            factor_nnz: 0,
            residual_rms: None,
        });
    }
    let (trip, rhs, _) = normal_equations(sys, unknown);
    let factor = Factor::new(n, &trip)?;
    let mut b = Mat::from_fn(n, 1, |i, _| rhs[i]);
    factor.solve(&mut b);
    let x: Vec<f64> = (0..n).map(|i| b[(i, 0)]).collect();
    let residual_rms = residual_rms(sys, unknown, &x);
    let variance = if !cfg.uncertainty {
        None
    } else {
        Some(match cfg.method {
            Method::Wls => factor.inverse_diagonal(),
            Method::Poisson => sandwich_diagonal(&factor, sys, unknown, n, nodes),
        })
    };
    Ok(Solution {
        x,
        variance,
        factor_nnz: factor.values.len(),
        residual_rms,
    })
}

/// RMS of the whitened residuals `W^{1/2} (G x − obs)` over all rows.
fn residual_rms(sys: &System, unknown: &[usize], x: &[f64]) -> Option<f64> {
    let value = |row: &[(usize, f64)]| -> f64 {
        row.iter()
            .map(|&(p, c)| {
                let k = unknown[p];
                if k == usize::MAX { 0.0 } else { c * x[k] }
            })
            .sum()
    };
    let (mut ss, mut count) = (0.0, 0usize);
    for g in &sys.groups {
        let m = g.rows.len();
        let r: Vec<f64> = (0..m).map(|a| value(&g.rows[a]) - g.obs[a]).collect();
        for a in 0..m {
            for b in 0..m {
                ss += r[a] * g.weight[a * m + b] * r[b];
            }
        }
        count += m;
    }
    (count > 0).then(|| (ss / count as f64).sqrt())
}

/// The exact diagonal of `A⁻¹ Dᵀ Σ_b D A⁻¹` for the Poisson (edge) equations: for every
/// unknown i, `z = A⁻¹ e_i` (solves in blocks of columns, in parallel), `y = D z` over the
/// edges, and `Var = Σ_dots wᵀ Σ_dot w` with `w = Σ_{edges of the dot} y_e v_e`.
fn sandwich_diagonal(
    factor: &Factor,
    sys: &System,
    unknown: &[usize],
    n: usize,
    nodes: &[Node],
) -> Vec<f64> {
    // flat edges: the unknowns at both ends (usize::MAX: a Dirichlet node, 0 there), the two
    // dots and the vector multiplying their gradients
    struct Edge {
        kq: usize,
        kp: usize,
        p: usize,
        q: usize,
        v: [f64; 2],
    }
    let edges: Vec<Edge> = sys
        .groups
        .iter()
        .zip(&sys.edge_sources)
        .map(|(g, src)| Edge {
            kq: unknown[g.rows[0][0].0],
            kp: unknown[g.rows[0][1].0],
            p: src[0].0,
            q: src[1].0,
            v: src[0].1,
        })
        .collect();
    let u2: Vec<[f64; 2]> = nodes
        .iter()
        .map(|d| [d.u_gradient[0].powi(2), d.u_gradient[1].powi(2)])
        .collect();
    let starts: Vec<usize> = (0..n).step_by(BLOCK).collect();
    let blocks: Vec<Vec<f64>> = starts
        .par_iter()
        .map(|&s0| {
            let m = BLOCK.min(n - s0);
            let mut z = Mat::<f64>::zeros(n, m);
            for c in 0..m {
                z[(s0 + c, c)] = 1.0;
            }
            factor.solve(&mut z);
            let mut w = vec![[0.0f64; 2]; nodes.len()];
            (0..m)
                .map(|c| {
                    let zc = z.col(c).try_as_col_major().expect("contiguous").as_slice();
                    let at = |k: usize| if k == usize::MAX { 0.0 } else { zc[k] };
                    for e in &edges {
                        let y = at(e.kq) - at(e.kp);
                        let d = [y * e.v[0], y * e.v[1]];
                        w[e.p][0] += d[0];
                        w[e.p][1] += d[1];
                        w[e.q][0] += d[0];
                        w[e.q][1] += d[1];
                    }
                    let mut var = 0.0;
                    for (wd, u) in w.iter_mut().zip(&u2) {
                        var += wd[0] * wd[0] * u[0] + wd[1] * wd[1] * u[1];
                        *wd = [0.0, 0.0];
                    }
                    var
                })
                .collect()
        })
        .collect();
    blocks.into_iter().flatten().collect()
}
