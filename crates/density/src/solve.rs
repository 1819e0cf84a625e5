//! The normal equations, their sparse Cholesky factor (faer, supernodal LLᵀ with an AMD
//! ordering), the solution and the diagonal of its covariance.

use crate::system::System;
use crate::{DensityError, IntegrationConfig, Method, Node};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Accum, Conj, Mat, MatMut, MatRef, Par, Side};
use rayon::prelude::*;

pub(crate) struct Solution {
    /// ρ − ρ_ref at each unknown.
    pub x: Vec<f64>,
    /// Variance of each unknown (without the reference density's).
    pub variance: Option<Vec<f64>>,
    /// The estimated effect of the stencils' truncation error on each unknown, `δ` (with the
    /// variance).
    pub truncation: Option<Vec<f64>>,
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
            truncation: cfg.uncertainty.then(Vec::new),
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
    // the truncation error's effect on ρ, estimated from the solution: δ = A⁻¹ Gᵀ W τ̂
    let truncation = cfg.uncertainty.then(|| {
        let r = project(sys, unknown, n, &row_truncation(sys, unknown, &x, nodes));
        let mut d = Mat::from_fn(n, 1, |i, _| r[i]);
        factor.solve(&mut d);
        (0..n).map(|i| d[(i, 0)]).collect()
    });

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
        truncation,
        factor_nnz: factor.values.len(),
        residual_rms,
    })
}

/// The estimated truncation error of every row (the groups' rows in order; 0 where a row has
/// no estimate): `τ̂ = Σ d_k (ρ̂_k − g · X_k)` with `ρ̂` the solution (ρ − ρ_ref: 0 on the
/// Dirichlet nodes) and `g` the row's dot's gradient, so that `G ρ ≈ obs + τ̂`.
pub(crate) fn row_truncation(
    sys: &System,
    unknown: &[usize],
    x: &[f64],
    nodes: &[Node],
) -> Vec<f64> {
    let mut out = Vec::new();
    for g in &sys.groups {
        let gp = nodes[g.dot].gradient;
        for terms in &g.truncation {
            out.push(
                terms
                    .iter()
                    .map(|&(q, d)| {
                        let rho = if unknown[q] == usize::MAX {
                            0.0
                        } else {
                            x[unknown[q]]
                        };
                        let xq = nodes[q].position;
                        d * (rho - gp[0] * xq[0] - gp[1] * xq[1])
                    })
                    .sum(),
            );
        }
    }
    out
}

/// `Gᵀ W t` over the unknowns for one value `t` per row (the groups' rows in order): the
/// right-hand side whose solution is the effect of `t` on ρ.
pub(crate) fn project(sys: &System, unknown: &[usize], n: usize, t: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; n];
    let mut at = 0;
    for g in &sys.groups {
        let m = g.rows.len();
        let tg = &t[at..at + m];
        at += m;
        for a in 0..m {
            let wt: f64 = (0..m).map(|c| g.weight[a * m + c] * tg[c]).sum();
            for &(p, cp) in &g.rows[a] {
                if unknown[p] != usize::MAX {
                    out[unknown[p]] += cp * wt;
                }
            }
        }
    }
    out
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

/// The exact diagonal of `A⁻¹ Dᵀ Σ_b D A⁻¹` for the Poisson (edge) equations, `Σ_b = J Σ Jᵀ`
/// (each edge's right-hand side `b_e = v_e · (g_p + g_q)` shares its dots with the neighbouring
/// edges). With `B = Σ^{1/2} Jᵀ D` (one sparse row per dot and axis: the dot's edges' ends,
/// ≤ 5 nodes), `Var_i = ‖B A⁻¹ e_i‖²`. For every unknown, in blocks of [`BLOCK`] consecutive
/// columns of the factor's (postordered) order and in parallel over the blocks:
/// `Y = L⁻¹ P E` by a supernodal forward solve that skips the supernodes the block's columns do
/// not reach (only their paths to the root of the elimination tree are non-zero), `X = L⁻ᵀ Y`
/// (every supernode: dense), then `Var = Σ_rows (B X)²` with the block's columns contiguous in
/// memory. `O(N nnz(L))` time, `O(nnz(L) + threads · N · BLOCK)` memory, exact.
fn sandwich_diagonal(
    factor: &Factor,
    sys: &System,
    unknown: &[usize],
    n: usize,
    nodes: &[Node],
) -> Vec<f64> {
    let SymbolicCholeskyRaw::Supernodal(s) = factor.symbolic.raw() else {
        unreachable!("the factor is supernodal (FORCE_SUPERNODAL)");
    };
    // the factor's index of each unknown: (P A Pᵀ)_{ij} = A_{fwd[i], fwd[j]}
    let (fwd, inv): (Vec<usize>, Vec<usize>) = match factor.symbolic.perm() {
        Some(perm) => {
            let (f, i) = perm.arrays();
            (f.to_vec(), i.to_vec())
        }
        None => ((0..n).collect(), (0..n).collect()),
    };
    let b = sandwich_rows(sys, unknown, &inv, nodes);
    let (begin, end) = (s.supernode_begin(), s.supernode_end());
    let (rptr, vptr, ridx) = (s.col_ptr_for_row_idx(), s.col_ptr_for_val(), s.row_idx());
    let ns = s.n_supernodes();
    let mut owner = vec![0usize; n];
    for t in 0..ns {
        owner[begin[t]..end[t]].fill(t);
    }
    let l = &factor.values;
    // per supernode: width, the dense block (rows × width, column-major) and its row pattern
    // below the diagonal block
    let panel = |t: usize| {
        let w = end[t] - begin[t];
        let rows = (vptr[t + 1] - vptr[t]) / w;
        let lt = MatRef::from_column_major_slice(&l[vptr[t]..vptr[t + 1]], rows, w);
        let pat = &ridx[rptr[t]..rptr[t] + rows - w];
        (w, lt, pat)
    };
    let starts: Vec<usize> = (0..n).step_by(BLOCK).collect();
    let var_perm: Vec<Vec<f64>> = starts
        .par_iter()
        .map_init(Vec::<f64>::new, |x, &s0| {
            let m = BLOCK.min(n - s0);
            block_variance(&panel, &owner, begin, end, ns, &b, x, s0, m)
        })
        .collect();
    let mut out = vec![0.0; n];
    for (i, v) in var_perm.into_iter().flatten().enumerate() {
        out[fwd[i]] = v;
    }
    out
}

/// The variances of the unknowns `s0 .. s0 + m` (the factor's order): `X = (L Lᵀ)⁻¹ E` in the
/// row-major buffer `x` (`n × m`: a row's m values contiguous), then `Σ_rows (B X)²`.
#[allow(clippy::too_many_arguments)]
fn block_variance<'a>(
    panel: &impl Fn(usize) -> (usize, MatRef<'a, f64>, &'a [usize]),
    owner: &[usize],
    begin: &[usize],
    end: &[usize],
    ns: usize,
    b: &Rows,
    x: &mut Vec<f64>,
    s0: usize,
    m: usize,
) -> Vec<f64> {
    let n = owner.len();
    let arch = pulp::Arch::new();
    x.clear();
    x.resize(n * m, 0.0);
    let mut tmp = Vec::<f64>::new();
    let mut active = vec![false; ns];
    for c in 0..m {
        x[(s0 + c) * m + c] = 1.0;
        active[owner[s0 + c]] = true;
    }
    // forward: L Y = P E, only the supernodes the columns reach
    for t in 0..ns {
        if !active[t] {
            continue;
        }
        let (w, lt, pat) = panel(t);
        let (l_jj, l_rj) = lt.split_at_row(w);
        let (b0, b1) = (begin[t] * m, end[t] * m);
        solve_lower_triangular_in_place(
            l_jj,
            MatMut::from_row_major_slice_mut(&mut x[b0..b1], w, m),
            Par::Seq,
        );
        let r = pat.len();
        if r == 0 {
            continue;
        }
        if tmp.len() < r * m {
            tmp.resize(r * m, 0.0);
        }
        matmul(
            MatMut::from_row_major_slice_mut(&mut tmp[..r * m], r, m),
            Accum::Replace,
            l_rj,
            MatRef::from_row_major_slice(&x[b0..b1], w, m),
            1.0,
            Par::Seq,
        );
        arch.dispatch(Scatter {
            x,
            tmp: &tmp[..r * m],
            pat,
            m,
        });
        active[owner[pat[0]]] = true;
    }
    // backward: Lᵀ X = Y, every supernode
    for t in (0..ns).rev() {
        let (w, lt, pat) = panel(t);
        let (l_jj, l_rj) = lt.split_at_row(w);
        let (b0, b1) = (begin[t] * m, end[t] * m);
        let r = pat.len();
        if r > 0 {
            if tmp.len() < r * m {
                tmp.resize(r * m, 0.0);
            }
            for (k, &g) in pat.iter().enumerate() {
                tmp[k * m..(k + 1) * m].copy_from_slice(&x[g * m..(g + 1) * m]);
            }
            matmul(
                MatMut::from_row_major_slice_mut(&mut x[b0..b1], w, m),
                Accum::Add,
                l_rj.transpose(),
                MatRef::from_row_major_slice(&tmp[..r * m], r, m),
                -1.0,
                Par::Seq,
            );
        }
        solve_upper_triangular_in_place(
            l_jj.transpose(),
            MatMut::from_row_major_slice_mut(&mut x[b0..b1], w, m),
            Par::Seq,
        );
    }
    let mut var = vec![0.0f64; m];
    arch.dispatch(SumOfSquares {
        b,
        x,
        m,
        var: &mut var,
    });
    var
}

/// `x[pat[k]] −= tmp[k]` row by row (`m` values a row), with the machine's vector instructions
/// (`pulp` compiles the plain loops for the features found at run time).
struct Scatter<'a> {
    x: &'a mut [f64],
    tmp: &'a [f64],
    pat: &'a [usize],
    m: usize,
}

impl pulp::WithSimd for Scatter<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let m = self.m;
        for (k, &g) in self.pat.iter().enumerate() {
            let row = &mut self.x[g * m..(g + 1) * m];
            for (a, v) in row.iter_mut().zip(&self.tmp[k * m..(k + 1) * m]) {
                *a -= v;
            }
        }
    }
}

/// `var[c] += Σ_rows (Σ_terms coef · x[k, c])²`: the squared norms of the columns of `B X`.
struct SumOfSquares<'a> {
    b: &'a Rows,
    x: &'a [f64],
    m: usize,
    var: &'a mut [f64],
}

impl pulp::WithSimd for SumOfSquares<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let (m, x) = (self.m, self.x);
        let (mut a0, mut a1) = (vec![0.0f64; m], vec![0.0f64; m]);
        for row in self.b.ptr.windows(2) {
            let terms = &self.b.terms[row[0]..row[1]];
            let (k, [c0, c1]) = terms[0];
            for ((a, b), v) in a0.iter_mut().zip(a1.iter_mut()).zip(&x[k * m..(k + 1) * m]) {
                *a = c0 * v;
                *b = c1 * v;
            }
            for &(k, [c0, c1]) in &terms[1..] {
                for ((a, b), v) in a0.iter_mut().zip(a1.iter_mut()).zip(&x[k * m..(k + 1) * m]) {
                    *a += c0 * v;
                    *b += c1 * v;
                }
            }
            for ((v, a), b) in self.var.iter_mut().zip(&a0).zip(&a1) {
                *v += a * a + b * b;
            }
        }
    }
}

/// `B = Σ^{1/2} Jᵀ D` as sparse rows, the two rows of a dot (its two axes) together: the
/// unknowns of the dot's edges (the factor's order) and the two coefficients of each.
struct Rows {
    ptr: Vec<usize>,
    terms: Vec<(usize, [f64; 2])>,
}

fn sandwich_rows(sys: &System, unknown: &[usize], inv: &[usize], nodes: &[Node]) -> Rows {
    // per dot: (factor index, coefficients) of each edge end, merged below
    let mut per: Vec<Vec<(usize, [f64; 2])>> = vec![Vec::new(); nodes.len()];
    for (g, src) in sys.groups.iter().zip(&sys.edge_sources) {
        let (q, p) = (g.rows[0][0].0, g.rows[0][1].0);
        let v = src[0].1;
        for dot in [src[0].0, src[1].0] {
            for (node, sign) in [(q, 1.0), (p, -1.0)] {
                if unknown[node] != usize::MAX {
                    per[dot].push((inv[unknown[node]], [sign * v[0], sign * v[1]]));
                }
            }
        }
    }
    let mut ptr = vec![0];
    let mut terms: Vec<(usize, [f64; 2])> = Vec::new();
    for (dot, mut t) in per.into_iter().enumerate() {
        let u = nodes[dot].u_gradient;
        t.sort_unstable_by_key(|e| e.0);
        let start = terms.len();
        for (k, c) in t {
            let c = [u[0] * c[0], u[1] * c[1]];
            let len = terms.len();
            if len > start && terms[len - 1].0 == k {
                terms[len - 1].1[0] += c[0];
                terms[len - 1].1[1] += c[1];
            } else {
                terms.push((k, c));
            }
        }
        if terms.len() > start {
            ptr.push(terms.len());
        }
    }
    Rows { ptr, terms }
}
