//! The observation equations of both methods, as sparse rows over the nodes.

use crate::lattice::Lattice;
use crate::{Method, Node};

/// One dot's observations: one or two rows (the two lattice directions) sharing the dot's
/// gradient, so with a 2 × 2 covariance (WLS); or one edge equation (Poisson).
#[derive(Clone, Debug)]
pub(crate) struct Group {
    /// The dot whose gradient the rows observe (Poisson: the edge's first end).
    pub dot: usize,
    /// Rows: `(node, coefficient)` terms.
    pub rows: Vec<Vec<(usize, f64)>>,
    /// Observed value of each row.
    pub obs: Vec<f64>,
    /// Weight matrix (inverse covariance) of the rows, row-major `rows.len()²` (WLS); unit
    /// weights for Poisson.
    pub weight: Vec<f64>,
    /// Per row, the estimate of its truncation error as `(node, coefficient)` terms `d`, so
    /// that `G ρ ≈ obs + τ̂` with `τ̂ = Σ d_k (ρ_k − g · X_k)` (`g` the dot's gradient; empty
    /// where the lattice line has no room; WLS: the difference of the row's stencil and the
    /// next order's, Poisson: the trapezoid's `−Δ³/12`).
    pub truncation: Vec<Vec<(usize, f64)>>,
}

/// The equations of one method.
pub(crate) struct System {
    pub groups: Vec<Group>,
    /// Pairs of nodes that appear in one equation (for the islands).
    pub links: Vec<(usize, usize)>,
    /// Poisson only: for each edge row, the dots whose gradients enter it and the vectors
    /// multiplying them: `b = Σ v · g_dot` (for the exact covariance of the edge equations).
    pub edge_sources: Vec<[(usize, [f64; 2]); 2]>,
}

/// The lattice steps in index space: along j (columns) and along i (rows).
const AXES: [[i32; 2]; 2] = [[0, 1], [1, 0]];

/// One-sided and symmetric stencils in the lattice index t, most preferred first: the offsets
/// and the coefficients of `dρ/dt` at offset 0 (`Σ_j ∇^j/j`, j ≤ order: the backward
/// differentiation formulas). The fourth-order ones first (backward, then forward); where holes
/// or the edge of the lattice leave no room, lower orders.
const STENCILS: [(&[i32], &[f64]); 9] = [
    (
        &[0, -1, -2, -3, -4],
        &[25.0 / 12.0, -4.0, 3.0, -4.0 / 3.0, 0.25],
    ),
    (
        &[0, 1, 2, 3, 4],
        &[-25.0 / 12.0, 4.0, -3.0, 4.0 / 3.0, -0.25],
    ),
    (&[0, -1, -2, -3], &[11.0 / 6.0, -3.0, 1.5, -1.0 / 3.0]),
    (&[0, 1, 2, 3], &[-11.0 / 6.0, 3.0, -1.5, 1.0 / 3.0]),
    (&[0, -1, -2], &[1.5, -2.0, 0.5]),
    (&[0, 1, 2], &[-1.5, 2.0, -0.5]),
    (&[-1, 1], &[-0.5, 0.5]),
    (&[0, 1], &[-1.0, 1.0]),
    (&[0, -1], &[1.0, -1.0]),
];

/// The truncation-error estimate of a one-sided stencil of order `k` in direction `dir` (its
/// offsets `0, dir, …, k dir`): `G_k − G_{k+1}` on the offsets `0, dir, …, (k+1) dir`, i.e.
/// `−∇^{k+1}/(k+1)` backward and `+∇^{k+1}/(k+1)` forward: the coefficient of offset `i dir` is
/// `dir (−1)^i C(k+1, i)/(k+1)`. `None` for a symmetric stencil.
fn next_order(offs: &[i32]) -> Option<(i32, Vec<f64>)> {
    let k = offs.len() as i32 - 1;
    let dir = *offs.get(1)?;
    if offs[0] != 0 || offs.iter().zip(0..).any(|(&o, i)| o != i * dir) {
        return None;
    }
    let m = k + 1;
    let mut binom = 1.0; // C(m, i)
    let coefs = (0..=m)
        .map(|i| {
            if i > 0 {
                binom = binom * f64::from(m - i + 1) / f64::from(i);
            }
            f64::from(dir) * if i % 2 == 0 { 1.0 } else { -1.0 } * binom / f64::from(m)
        })
        .collect();
    Some((dir, coefs))
}

impl System {
    pub(crate) fn build(lat: &Lattice, nodes: &[Node], method: Method) -> System {
        match method {
            Method::Wls => wls(lat, nodes),
            Method::Poisson => poisson(lat, nodes),
        }
    }
}

fn wls(lat: &Lattice, nodes: &[Node]) -> System {
    let mut groups = Vec::with_capacity(nodes.len());
    let mut links = Vec::new();
    for (p, n) in nodes.iter().enumerate() {
        let mut truncation = Vec::with_capacity(2);
        let mut rows = Vec::with_capacity(2);
        let mut vecs: Vec<[f64; 2]> = Vec::with_capacity(2);
        for axis in AXES {
            let at = |t: i32| lat.get([n.index[0] + t * axis[0], n.index[1] + t * axis[1]]);
            let Some((offs, coefs)) = STENCILS
                .iter()
                .find(|(o, _)| o.iter().all(|&t| at(t).is_some()))
            else {
                continue;
            };
            // the truncation-error estimate, where the line has room for the next order
            let corr: Option<Vec<(usize, f64)>> = next_order(offs).and_then(|(dir, c)| {
                (0..)
                    .zip(c)
                    .map(|(i, c)| at(i * dir).map(|q| (q, c)))
                    .collect()
            });
            truncation.push(corr.unwrap_or_default());
            let mut row = Vec::with_capacity(offs.len());
            let mut v = [0.0; 2];
            for (&t, &c) in offs.iter().zip(coefs.iter()) {
                let q = at(t).expect("checked");
                row.push((q, c));
                v[0] += c * nodes[q].position[0];
                v[1] += c * nodes[q].position[1];
                if q != p {
                    links.push((p, q));
                }
            }
            rows.push(row);
            vecs.push(v);
        }
        if rows.is_empty() {
            continue;
        }
        // covariance of the observations g·v_a: v_aᵀ Σ v_b, Σ = diag(u_x², u_y²)
        let s = [n.u_gradient[0].powi(2), n.u_gradient[1].powi(2)];
        let cov = |a: &[f64; 2], b: &[f64; 2]| a[0] * b[0] * s[0] + a[1] * b[1] * s[1];
        let obs: Vec<f64> = vecs
            .iter()
            .map(|v| n.gradient[0] * v[0] + n.gradient[1] * v[1])
            .collect();
        if rows.len() == 2 {
            let (c00, c01, c11) = (
                cov(&vecs[0], &vecs[0]),
                cov(&vecs[0], &vecs[1]),
                cov(&vecs[1], &vecs[1]),
            );
            let det = c00 * c11 - c01 * c01;
            if det > 1e-12 * c00 * c11 {
                groups.push(Group {
                    dot: p,
                    rows,
                    obs,
                    weight: vec![c11 / det, -c01 / det, -c01 / det, c00 / det],
                    truncation,
                });
                continue;
            }
            // the two steps are parallel here (a degenerate lattice): keep one
            rows.truncate(1);
            truncation.truncate(1);
        }
        let c = cov(&vecs[0], &vecs[0]);
        groups.push(Group {
            dot: p,
            rows,
            obs: vec![obs[0]],
            weight: vec![1.0 / c],
            truncation,
        });
    }
    System {
        groups,
        links,
        edge_sources: Vec::new(),
    }
}

fn poisson(lat: &Lattice, nodes: &[Node]) -> System {
    let mut groups = Vec::with_capacity(2 * nodes.len());
    let mut links = Vec::new();
    let mut edge_sources = Vec::new();
    for (p, n) in nodes.iter().enumerate() {
        for axis in AXES {
            let Some(q) = lat.get([n.index[0] + axis[0], n.index[1] + axis[1]]) else {
                continue;
            };
            let m = &nodes[q];
            // the trapezoid's truncation `−h³ρ'''/12`: `−Δ³/12` on the offsets −1, 0, 1, 2
            let trapezoid: Option<Vec<(usize, f64)>> = [(-1, 1.0), (0, -3.0), (1, 3.0), (2, -1.0)]
                .into_iter()
                .map(|(t, c)| {
                    lat.get([n.index[0] + t * axis[0], n.index[1] + t * axis[1]])
                        .map(|r| (r, c / 12.0))
                })
                .collect();
            let step = [m.position[0] - n.position[0], m.position[1] - n.position[1]];
            let half = [0.5 * step[0], 0.5 * step[1]];
            let b = (n.gradient[0] + m.gradient[0]) * half[0]
                + (n.gradient[1] + m.gradient[1]) * half[1];
            groups.push(Group {
                dot: p,
                rows: vec![vec![(q, 1.0), (p, -1.0)]],
                obs: vec![b],
                weight: vec![1.0],
                truncation: vec![trapezoid.unwrap_or_default()],
            });
            edge_sources.push([(p, half), (q, half)]);
            links.push((p, q));
        }
    }
    System {
        groups,
        links,
        edge_sources,
    }
}
