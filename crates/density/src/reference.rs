//! The dense reference: the same equations, the covariance from a dense inverse of the normal
//! matrix (`O(N²)` memory, `O(N³)` time), as the published density-integration code does it.
//! For the checks of the sparse path and the benchmark's ratio only.

use crate::lattice::{Lattice, islands};
use crate::solve::{normal_equations, project, row_truncation};
use crate::system::System;
use crate::{DensityError, IntegrationConfig, IslandStatus, Method, Node};
use faer::linalg::solvers::DenseSolveCore;
use faer::{Mat, Side};

/// Per node (input order) the 1σ uncertainty of ρ as [`crate::integrate`] defines it (the
/// truncation estimate δ included), from a dense inverse of the normal matrix (`None` where [`crate::integrate`] gives no density).
/// Memory `8 N²` bytes or more: for small lattices only (checks, benchmarks).
pub fn dense_uncertainty(
    nodes: &[Node],
    cfg: &IntegrationConfig,
) -> Result<Vec<Option<f64>>, DensityError> {
    let lat = Lattice::new(nodes)?;
    let sys = System::build(&lat, nodes, cfg.method);
    let isl = islands(nodes.len(), &sys.links, nodes);
    let mut unknown = vec![usize::MAX; nodes.len()];
    let mut n = 0;
    for (p, node) in nodes.iter().enumerate() {
        if isl.islands[isl.of_node[p]].status == IslandStatus::Solved && !node.dirichlet {
            unknown[p] = n;
            n += 1;
        }
    }
    let (trip, rhs, _) = normal_equations(&sys, &unknown);
    let mut a = Mat::<f64>::zeros(n, n);
    for t in &trip {
        a[(t.row, t.col)] += t.val;
        if t.row != t.col {
            a[(t.col, t.row)] += t.val;
        }
    }
    let inv = a
        .llt(Side::Lower)
        .map_err(|e| DensityError::Factorization(format!("{e:?}")))?
        .inverse();
    let var: Vec<f64> = match cfg.method {
        Method::Wls => (0..n).map(|i| inv[(i, i)]).collect(),
        Method::Poisson => {
            // b = J g: the edge equations' right-hand sides from the dots' gradients; the
            // estimate is A⁻¹ Dᵀ b, so Cov = (A⁻¹ Dᵀ J) Σ_g (A⁻¹ Dᵀ J)ᵀ
            let mut k = Mat::<f64>::zeros(n, 2 * nodes.len()); // Dᵀ J (dense)
            for (g, src) in sys.groups.iter().zip(&sys.edge_sources) {
                for &(p, coef) in &g.rows[0] {
                    let kp = unknown[p];
                    if kp == usize::MAX {
                        continue;
                    }
                    for &(dot, v) in src {
                        k[(kp, 2 * dot)] += coef * v[0];
                        k[(kp, 2 * dot + 1)] += coef * v[1];
                    }
                }
            }
            let m = &inv * &k;
            (0..n)
                .map(|i| {
                    (0..nodes.len())
                        .map(|dot| {
                            let u = nodes[dot].u_gradient;
                            (m[(i, 2 * dot)] * u[0]).powi(2) + (m[(i, 2 * dot + 1)] * u[1]).powi(2)
                        })
                        .sum()
                })
                .collect()
        }
    };
    // the estimated truncation error's effect, δ = A⁻¹ Gᵀ W τ̂(x), x = A⁻¹ rhs
    let apply = |v: &[f64]| -> Vec<f64> {
        (0..n)
            .map(|i| (0..n).map(|j| inv[(i, j)] * v[j]).sum())
            .collect()
    };
    let x = apply(&rhs);
    let delta = apply(&project(
        &sys,
        &unknown,
        n,
        &row_truncation(&sys, &unknown, &x, nodes),
    ));
    let u0 = cfg.reference_uncertainty;
    Ok(nodes
        .iter()
        .enumerate()
        .map(|(p, node)| {
            if isl.islands[isl.of_node[p]].status != IslandStatus::Solved {
                None
            } else if node.dirichlet {
                Some(u0)
            } else {
                Some((u0 * u0 + var[unknown[p]] + delta[unknown[p]].powi(2)).sqrt())
            }
        })
        .collect())
}
