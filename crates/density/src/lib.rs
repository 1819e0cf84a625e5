//! The density field from its measured gradient on the dot lattice, with the exact 1σ
//! uncertainty of every node.
//!
//! The dots of a BOS target carry grid indices `(i, j)`, so their density gradients already lie
//! on a structured lattice (with holes where a dot is invalid). [`integrate`] solves for the
//! density ρ at every node ([`Node`]) of that lattice, relative to a known reference density on
//! the Dirichlet nodes (by default the outer ring of the valid nodes, [`outer_ring`]); Neumann
//! (nothing imposed) everywhere else, holes included. Two methods ([`Method`]):
//!
//! - **`Wls`** (default): the generalised least-squares solution of the per-dot observation
//!   equations `(∂ρ/∂t)_p = ∇ρ_p · (∂X/∂t)_p` along both lattice directions `t`, each derivative
//!   taken by the same one-sided fourth-order stencil (BDF4, `[25, −48, 36, −16, 3]/12`; lower
//!   orders where holes or the edge leave no room) applied to the node densities and to the
//!   node positions, weighted by the inverse covariance of each dot's
//!   two observations (from the per-axis gradient uncertainties). Every dot's gradient enters once,
//!   so the observations are independent and the covariance of the solution is *exactly* the
//!   inverse of the normal matrix `A = Gᵀ W G`; its diagonal comes from the sparse Cholesky
//!   factor by selected inversion (Takahashi recurrences), in about the time of the
//!   factorisation, without any dense matrix.
//! - **`Poisson`**: the discrete Poisson equation `∇²ρ = ∇·g` as the unweighted least squares of
//!   the edge equations `ρ_q − ρ_p = (g_p + g_q)/2 · (X_q − X_p)` (the trapezoid rule along each
//!   lattice step; Neumann at every boundary and hole by construction). Neighbouring edge
//!   equations share a dot, so its covariance is the sandwich `A⁻¹ (Dᵀ Σ_b D) A⁻¹`; its diagonal
//!   is computed exactly by supernodal solves of blocks of unit columns (the forward solve only
//!   where a block's columns reach, in parallel over the blocks: `O(N nnz(L))`).
//!
//! Why one-sided stencils for WLS: a symmetric (central) node stencil does not see the
//! alternating mode `(−1)^t` (odd–even decoupling); the trapezoid edge form sees it but couples
//! neighbouring observations, whose exact covariance is a sandwich that selected inversion
//! cannot give. A one-sided stencil has neither problem; its truncation error (BDF4:
//! `h⁴ρ⁽⁵⁾/5`; the trapezoid's `h³ρ'''/12`) is deterministic and not in the noise's covariance,
//! so u_ρ also holds an estimate of it, from the data: each row's truncation estimated by the
//! difference of its stencil and the next order's (`∓∇⁵/5` on the solution; the trapezoid:
//! `−Δ³/12`), propagated through the same solve, `δ = A⁻¹ Gᵀ W τ̂` (one more solve with the
//! factor), and added in quadrature: `u_ρ² = u_ref² + diag(Cov) + δ²`
//! ([`NodeResult::u_truncation`] is `|δ|`). docs/theory.md has the derivation and the
//! measurements.
//!
//! The reference density's own uncertainty is an offset common to every node: since every
//! stencil sums to zero, the solution with Dirichlet value `ρ_ref` is `ρ_ref` plus the solution
//! with zero (its part of u_ρ is `u_ref`).
//!
//! Islands (parts of the lattice not joined by any stencil or edge) are solved together but each
//! needs a Dirichlet node: one without gets [`IslandStatus::NoReference`] and its nodes no
//! density. A lattice without any Dirichlet node is an error.
//!
//! Pure arithmetic: no filesystem, no image. Units are the caller's (SI in the pipeline:
//! positions in m, gradients in kg/m⁴, densities in kg/m³).
//!
//! ```
//! use bostrack_density::{IntegrationConfig, Method, Node, integrate, outer_ring};
//! // ρ = 1.2 + 3 x − 2 y on a 6 × 5 lattice with 1 mm steps: both methods are exact for it
//! let mut nodes = Vec::new();
//! for i in 0..5 {
//!     for j in 0..6 {
//!         nodes.push(Node {
//!             index: [i, j],
//!             position: [j as f64 * 1e-3, i as f64 * 1e-3],
//!             gradient: [3.0, -2.0],
//!             u_gradient: [0.1, 0.1],
//!             dirichlet: false,
//!         });
//!     }
//! }
//! let ring = outer_ring(&nodes.iter().map(|n| n.index).collect::<Vec<_>>());
//! for (n, r) in nodes.iter_mut().zip(&ring) {
//!     n.dirichlet = *r && n.index == [0, 0]; // one reference node is enough
//! }
//! for method in [Method::Wls, Method::Poisson] {
//!     let cfg = IntegrationConfig { method, reference_density: 1.2, ..IntegrationConfig::default() };
//!     let f = integrate(&nodes, &cfg).unwrap();
//!     for (n, r) in nodes.iter().zip(&f.nodes) {
//!         let truth = 1.2 + 3.0 * n.position[0] - 2.0 * n.position[1];
//!         assert!((r.rho.unwrap() - truth).abs() < 1e-12);
//!         // the uncertainty grows away from the reference node
//!         assert!(r.u_rho.unwrap() >= 0.0);
//!     }
//! }
//! ```

mod lattice;
mod reference;
mod solve;
mod system;

pub use lattice::outer_ring;
pub use reference::dense_uncertainty;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// One valid lattice node: a dot with a measured density gradient.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    /// Lattice index `[i, j]` (docs/CONVENTIONS.md), unique.
    pub index: [i32; 2],
    /// Position in the plane of the density field (m in the pipeline).
    pub position: [f64; 2],
    /// Measured gradient `[∂ρ/∂x, ∂ρ/∂y]` (kg/m⁴).
    pub gradient: [f64; 2],
    /// 1σ uncertainty of each gradient component (independent axes), > 0.
    pub u_gradient: [f64; 2],
    /// The density is known here (the reference density).
    pub dirichlet: bool,
}

/// The integration method.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Generalised (uncertainty-weighted) least squares of the per-dot observations.
    #[default]
    Wls,
    /// The discrete Poisson equation (unweighted least squares of the edge equations).
    Poisson,
}

impl Method {
    /// The name used in configuration files and summaries.
    pub fn name(self) -> &'static str {
        match self {
            Method::Wls => "wls",
            Method::Poisson => "poisson",
        }
    }
}

/// What [`integrate`] computes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntegrationConfig {
    pub method: Method,
    /// Density on the Dirichlet nodes (kg/m³) \[1.204, air at 20 °C\].
    pub reference_density: f64,
    /// Its 1σ uncertainty (kg/m³) \[0\]: common to every node.
    pub reference_uncertainty: f64,
    /// Compute the per-node uncertainty \[true\].
    pub uncertainty: bool,
}

impl Default for IntegrationConfig {
    fn default() -> Self {
        IntegrationConfig {
            method: Method::Wls,
            reference_density: 1.204,
            reference_uncertainty: 0.0,
            uncertainty: true,
        }
    }
}

/// What became of a node.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NodeStatus {
    /// Solved.
    Solved,
    /// A Dirichlet node: ρ is the reference density.
    Reference,
    /// Its island has no Dirichlet node: no density.
    NoReference,
}

impl NodeStatus {
    pub fn name(self) -> &'static str {
        match self {
            NodeStatus::Solved => "solved",
            NodeStatus::Reference => "reference",
            NodeStatus::NoReference => "no_reference",
        }
    }
}

/// The result at one node (same order as the input).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodeResult {
    /// Density; `None` when its island has no Dirichlet node.
    pub rho: Option<f64>,
    /// 1σ uncertainty of `rho`: the noise's (exact) and the estimated discretisation error
    /// `u_truncation` in quadrature; `None` when not requested or no density.
    pub u_rho: Option<f64>,
    /// The estimated discretisation (truncation) error of `rho`, `|δ|` (included in `u_rho`);
    /// `None` when not requested or no density, 0 on the Dirichlet nodes.
    pub u_truncation: Option<f64>,
    /// Island (connected part of the lattice) of the node, from 0 in order of first node.
    pub island: usize,
    pub status: NodeStatus,
}

/// Whether an island could be solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum IslandStatus {
    Solved,
    /// No Dirichlet node on it: its density is unknown up to a constant, so none is given.
    NoReference,
}

/// One connected part of the lattice.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Island {
    pub nodes: usize,
    pub reference_nodes: usize,
    pub status: IslandStatus,
}

/// The integrated field.
#[derive(Clone, Debug, PartialEq)]
pub struct DensityField {
    /// One per input node, in input order.
    pub nodes: Vec<NodeResult>,
    pub islands: Vec<Island>,
    /// Unknowns of the linear system (nodes solved that are not Dirichlet nodes).
    pub unknowns: usize,
    /// Stored entries of the Cholesky factor (memory is `O(nnz)`, never `O(N²)`).
    pub factor_nnz: usize,
    /// RMS of the weighted residuals of the observation equations (WLS: about 1 when the
    /// gradient uncertainties are right and the field is smooth on the lattice; Poisson: in the
    /// units of ρ). `None` without unknowns.
    pub residual_rms: Option<f64>,
}

/// Input that cannot be integrated.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DensityError {
    /// A node value is not usable; `what` says which and why.
    #[error("node {index:?}: {what}")]
    InvalidNode { index: [i32; 2], what: String },
    /// Two nodes share a lattice index.
    #[error("two nodes have the lattice index {0:?}")]
    DuplicateIndex([i32; 2]),
    /// A configuration value is not usable.
    #[error("{0}")]
    InvalidConfig(String),
    /// No node is a Dirichlet node: the density is only known up to a constant.
    #[error(
        "no Dirichlet node: none of the {nodes} valid nodes has the reference density, so the density is only known up to a constant (set the reference region)"
    )]
    NoReference { nodes: usize },
    /// The factorisation failed (a normal matrix that is not positive definite).
    #[error("the sparse Cholesky factorisation failed: {0}")]
    Factorization(String),
}

/// Integrates the gradients of `nodes` (see the crate documentation).
pub fn integrate(nodes: &[Node], cfg: &IntegrationConfig) -> Result<DensityField, DensityError> {
    check(nodes, cfg)?;
    let lat = lattice::Lattice::new(nodes)?;
    let sys = system::System::build(&lat, nodes, cfg.method);
    let islands = lattice::islands(nodes.len(), &sys.links, nodes);
    if !nodes.iter().any(|n| n.dirichlet) {
        return Err(DensityError::NoReference { nodes: nodes.len() });
    }
    // unknowns: nodes of islands with a reference that are not themselves Dirichlet nodes
    let solvable: Vec<bool> = islands
        .of_node
        .iter()
        .map(|&k| islands.islands[k].status == IslandStatus::Solved)
        .collect();
    let mut unknown = vec![usize::MAX; nodes.len()];
    let mut n_unknowns = 0;
    for (p, n) in nodes.iter().enumerate() {
        if solvable[p] && !n.dirichlet {
            unknown[p] = n_unknowns;
            n_unknowns += 1;
        }
    }
    let sol = solve::solve(&sys, &unknown, n_unknowns, nodes, cfg)?;
    let results = nodes
        .iter()
        .enumerate()
        .map(|(p, n)| {
            let island = islands.of_node[p];
            if !solvable[p] {
                NodeResult {
                    rho: None,
                    u_rho: None,
                    u_truncation: None,
                    island,
                    status: NodeStatus::NoReference,
                }
            } else if n.dirichlet {
                NodeResult {
                    rho: Some(cfg.reference_density),
                    u_rho: cfg.uncertainty.then_some(cfg.reference_uncertainty),
                    u_truncation: cfg.uncertainty.then_some(0.0),
                    island,
                    status: NodeStatus::Reference,
                }
            } else {
                let k = unknown[p];
                NodeResult {
                    rho: Some(cfg.reference_density + sol.x[k]),
                    u_rho: sol
                        .variance
                        .as_ref()
                        .zip(sol.truncation.as_ref())
                        .map(|(v, t)| {
                            (cfg.reference_uncertainty.powi(2) + v[k] + t[k] * t[k]).sqrt()
                        }),
                    u_truncation: sol.truncation.as_ref().map(|t| t[k].abs()),
                    island,
                    status: NodeStatus::Solved,
                }
            }
        })
        .collect();
    Ok(DensityField {
        nodes: results,
        islands: islands.islands,
        unknowns: n_unknowns,
        factor_nnz: sol.factor_nnz,
        residual_rms: sol.residual_rms,
    })
}

fn check(nodes: &[Node], cfg: &IntegrationConfig) -> Result<(), DensityError> {
    if !cfg.reference_density.is_finite() {
        return Err(DensityError::InvalidConfig(format!(
            "the reference density must be finite, got {}",
            cfg.reference_density
        )));
    }
    if !(cfg.reference_uncertainty.is_finite() && cfg.reference_uncertainty >= 0.0) {
        return Err(DensityError::InvalidConfig(format!(
            "the reference density's uncertainty must be finite and >= 0, got {}",
            cfg.reference_uncertainty
        )));
    }
    for n in nodes {
        let bad = |what: String| DensityError::InvalidNode {
            index: n.index,
            what,
        };
        if !n.position.iter().all(|v| v.is_finite()) {
            return Err(bad(format!("position {:?} is not finite", n.position)));
        }
        if !n.gradient.iter().all(|v| v.is_finite()) {
            return Err(bad(format!("gradient {:?} is not finite", n.gradient)));
        }
        if (cfg.method == Method::Wls || cfg.uncertainty)
            && !n.u_gradient.iter().all(|v| v.is_finite() && *v > 0.0)
        {
            return Err(bad(format!(
                "gradient uncertainty {:?} is not finite and > 0",
                n.u_gradient
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
