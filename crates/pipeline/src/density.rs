//! Physical units and the density field (issue 15): the optical setup of `pipeline.toml`
//! (`[optics]`, `[geometry]`, `[constants]`: the keys of `bostrack crlb`'s setup file, parsed by
//! `bostrack_theory`), the per-dot density gradient in SI units appended to `dots.csv`, and the
//! density field integrated on the lattice (`bostrack_density`) in `density.csv`. Nothing here
//! runs without an `[optics]` section. Physics and sign conventions: docs/theory.md, "From
//! displacements to density".

use crate::config::PipelineConfig;
use crate::error::{ConfigError, PipelineError};
use bostrack_core::Mask;
use bostrack_density::{IntegrationConfig, Method, Node, NodeStatus};
use bostrack_displacement::PairDot;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// `[density]`: integrating the density gradient on the lattice (used only with `[optics]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DensitySection {
    /// `"wls"` (uncertainty-weighted least squares) or `"poisson"`.
    pub method: Method,
    /// Density of the quiescent gas on the Dirichlet nodes (kg/m³).
    pub reference_density_kg_m3: f64,
    /// Its 1σ uncertainty (kg/m³), common to every node.
    pub reference_density_uncertainty_kg_m3: f64,
    /// Mask image of the quiescent gas (kept pixels), relative to `input.dir`: the valid dots
    /// inside it are the Dirichlet nodes. Empty: the outer ring of the valid dots.
    pub reference_mask: PathBuf,
}

impl Default for DensitySection {
    fn default() -> Self {
        DensitySection {
            method: Method::Wls,
            reference_density_kg_m3: 1.204,
            reference_density_uncertainty_kg_m3: 0.0,
            reference_mask: PathBuf::new(),
        }
    }
}

/// The validated optical setup and density settings of a plan.
#[derive(Clone, Debug, PartialEq)]
pub struct DensityPlan {
    /// Pixel pitch on the sensor (m).
    pub pitch_m: f64,
    /// Magnification of the dot target, M (Eq. 5, or `optics.magnification`).
    pub magnification: f64,
    /// Magnification of the plane of the density field, `M_A = f / (Z_B − Z_D − f)`, or M when
    /// only `optics.magnification` is given.
    pub magnification_density: f64,
    /// `S = M K Z_D Δz / n0`: metres on the sensor per kg/m⁴ (`theory::bos_sensitivity`).
    pub sensitivity_m: f64,
    pub method: Method,
    pub reference_density: f64,
    pub reference_uncertainty: f64,
    /// The quiescent-gas mask (resolved, checked to exist); `None`: the outer ring.
    pub reference_mask: Option<PathBuf>,
}

/// The keys the measurement needs written out (the prediction's defaults would silently set
/// the scale of every density): `optics.pixel_pitch_um`, `optics.magnification` or both
/// `optics.focal_length_mm` and `optics.target_distance_m`, `geometry.z_d_m` and
/// `geometry.delta_z_m`. Checked on the text, where a left-out key is still visible.
pub(crate) fn check_required_keys(text: &str, path: &Path) -> Result<(), ConfigError> {
    let Ok(table) = text.parse::<toml::Table>() else {
        return Ok(()); // the typed parse reports it
    };
    let section = |name: &str| table.get(name).and_then(|v| v.as_table());
    let has = |s: &str, k: &str| section(s).is_some_and(|t| t.contains_key(k));
    let invalid = |key: &str, message: String| ConfigError::Invalid {
        path: path.to_path_buf(),
        key: key.into(),
        message,
    };
    let any = ["optics", "geometry", "constants", "density"]
        .iter()
        .any(|s| table.contains_key(*s));
    if !any {
        return Ok(());
    }
    if section("optics").is_none() {
        return Err(invalid(
            "optics",
            "densities need the optical setup: an [optics] section with pixel_pitch_um and \
             magnification (or focal_length_mm and target_distance_m), and [geometry] with \
             z_d_m and delta_z_m"
                .into(),
        ));
    }
    if !has("optics", "pixel_pitch_um") {
        return Err(invalid(
            "optics.pixel_pitch_um",
            "missing: the pixel pitch sets every length in metres".into(),
        ));
    }
    let lens = has("optics", "focal_length_mm") && has("optics", "target_distance_m");
    if !(has("optics", "magnification") || lens) {
        return Err(invalid(
            "optics.magnification",
            "missing: give magnification, or focal_length_mm and target_distance_m".into(),
        ));
    }
    for key in ["z_d_m", "delta_z_m"] {
        if !has("geometry", key) {
            return Err(invalid(
                &format!("geometry.{key}"),
                "missing: the BOS geometry ([geometry] kind = \"bos\", z_d_m, delta_z_m) sets \
                 the sensitivity"
                    .into(),
            ));
        }
    }
    Ok(())
}

/// The density plan of a configuration: `Ok(None)` without `[optics]`; `Err((key, message))`
/// for a setup that cannot describe the measurement.
pub(crate) fn plan(cfg: &PipelineConfig) -> Result<Option<DensityPlan>, (String, String)> {
    let Some(optics) = &cfg.optics else {
        if cfg.geometry.is_some() || cfg.constants.is_some() || cfg.density.is_some() {
            return Err((
                "optics".into(),
                "[geometry], [constants] and [density] need an [optics] section".into(),
            ));
        }
        return Ok(None);
    };
    let Some(geometry) = &cfg.geometry else {
        return Err((
            "geometry".into(),
            "densities need [geometry] (kind = \"bos\", z_d_m, delta_z_m)".into(),
        ));
    };
    let bostrack_theory::Geometry::Bos { z_d_m, delta_z_m } = *geometry else {
        return Err((
            "geometry.kind".into(),
            "densities need the BOS geometry (kind = \"bos\": a slab z_d_m in front of the \
             target); \"volumetric\" describes particles inside the field"
                .into(),
        ));
    };
    let constants = cfg.constants.clone().unwrap_or_default();
    let setup = bostrack_theory::Setup {
        optics: optics.clone(),
        geometry: geometry.clone(),
        constants: constants.clone(),
        ..Default::default()
    };
    setup.validate().map_err(|e| match e {
        bostrack_theory::TheoryError::InvalidSetup { field, problem } => (field, problem),
        other => ("optics".into(), other.to_string()),
    })?;
    let pitch_m = optics.pixel_pitch_um * 1e-6;
    let (magnification, magnification_density) = match optics.magnification {
        Some(m) => (m, m),
        None => {
            let f = optics.focal_length_mm * 1e-3;
            let z_b = optics.target_distance_m;
            if z_d_m >= z_b - f {
                return Err((
                    "geometry.z_d_m".into(),
                    format!(
                        "the density field ({z_d_m} m in front of the target) must lie between \
                         the target and the lens's focal point ({} m in front of it)",
                        z_b - f
                    ),
                ));
            }
            (
                bostrack_theory::magnification(f, z_b),
                bostrack_theory::magnification(f, z_b - z_d_m),
            )
        }
    };
    let sensitivity_m = bostrack_theory::bos_sensitivity(
        magnification,
        constants.gladstone_dale_m3_kg,
        constants.n0,
        z_d_m,
        delta_z_m,
    );
    let d = cfg.density.clone().unwrap_or_default();
    if !d.reference_density_kg_m3.is_finite() || d.reference_density_kg_m3 < 0.0 {
        return Err((
            "density.reference_density_kg_m3".into(),
            format!("must be finite and >= 0, got {}", d.reference_density_kg_m3),
        ));
    }
    let u = d.reference_density_uncertainty_kg_m3;
    if !(u.is_finite() && u >= 0.0) {
        return Err((
            "density.reference_density_uncertainty_kg_m3".into(),
            format!("must be finite and >= 0, got {u}"),
        ));
    }
    if cfg.input.stack.as_os_str().is_empty() && cfg.input.stack_dir.as_os_str().is_empty() {
        return Err((
            "input.stack_dir".into(),
            "densities need the per-dot uncertainties u_d, which need a no-flow stack \
             (input.stack or input.stack_dir; or remove [optics])"
                .into(),
        ));
    }
    if cfg.output.quantities != crate::config::Quantities::Uncertainty {
        return Err((
            "output.quantities".into(),
            "densities need the per-dot uncertainties: set quantities = \"uncertainty\" (or \
             remove [optics])"
                .into(),
        ));
    }
    Ok(Some(DensityPlan {
        pitch_m,
        magnification,
        magnification_density,
        sensitivity_m,
        method: d.method,
        reference_density: d.reference_density_kg_m3,
        reference_uncertainty: u,
        reference_mask: (!d.reference_mask.as_os_str().is_empty()).then_some(d.reference_mask),
    }))
}

/// The per-dot physical quantities (`dots.csv`'s last six columns).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhysicalDot {
    /// Position in the plane of the density field (m), origin on the optical axis (the image
    /// centre), x right, y down as in the image.
    pub position_m: Option<[f64; 2]>,
    /// `∇ρ = −d · pitch / S` (kg/m⁴), path-averaged over the slab.
    pub gradient: Option<[f64; 2]>,
    /// `u_∇ρ = u_d · pitch / S` (kg/m⁴).
    pub u_gradient: Option<[f64; 2]>,
}

/// The columns appended to `dots.csv` with `[optics]`.
pub const PHYSICAL_COLUMNS: [&str; 6] = [
    "x_m",
    "y_m",
    "grad_rho_x",
    "grad_rho_y",
    "u_grad_rho_x",
    "u_grad_rho_y",
];

/// The columns of `density.csv`.
pub const DENSITY_COLUMNS: [&str; 8] = ["i", "j", "x_m", "y_m", "rho", "u_rho", "valid", "status"];

impl DensityPlan {
    /// The physical quantities of every dot of an image of `size` (px).
    pub fn physical(&self, dots: &[PairDot], size: (usize, usize)) -> Vec<PhysicalDot> {
        let centre = [(size.0 as f64 - 1.0) / 2.0, (size.1 as f64 - 1.0) / 2.0];
        let plane = self.pitch_m / self.magnification_density;
        let grad = self.pitch_m / self.sensitivity_m;
        dots.iter()
            .map(|d| PhysicalDot {
                position_m: d
                    .reference_position
                    .map(|p| [(p[0] - centre[0]) * plane, (p[1] - centre[1]) * plane]),
                gradient: d.displacement.map(|v| [-v[0] * grad, -v[1] * grad]),
                u_gradient: d.u_d.map(|u| [u[0] * grad, u[1] * grad]),
            })
            .collect()
    }
}

/// One frame's density field.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameDensity {
    /// One per dot (the rows of `dots.csv`): `(ρ, u_ρ, status)`; status `None` where the dot
    /// is not a node (not valid).
    pub nodes: Vec<(Option<f64>, Option<f64>, Option<NodeStatus>)>,
    pub summary: DensitySummary,
}

/// `summary.json`'s `density` (also the campaign table's `density.*` columns).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct DensitySummary {
    /// "wls" or "poisson".
    pub method: String,
    /// Lattice nodes (valid dots), Dirichlet nodes among them, and nodes with a density.
    pub nodes: usize,
    pub reference_nodes: usize,
    pub solved: usize,
    /// Islands (connected parts of the lattice) and those without a Dirichlet node (no
    /// density there).
    pub islands: usize,
    pub islands_without_reference: usize,
    /// Median 1σ uncertainty of ρ over the nodes solved (kg/m³).
    pub median_u_rho: Option<f64>,
    /// Range of ρ (kg/m³).
    pub rho_min: Option<f64>,
    pub rho_max: Option<f64>,
    /// RMS of the whitened residuals of the observation equations (WLS: ≈ 1 when the
    /// uncertainties hold).
    pub residual_rms: Option<f64>,
    /// Stored entries of the sparse Cholesky factor.
    pub factor_nnz: usize,
    /// The scale used: kg/m⁴ of density gradient per px of displacement, and metres in the
    /// density plane per px.
    pub gradient_per_px: f64,
    pub metres_per_px: f64,
}

/// Half-width (lattice steps) of the neighbourhood over which [`pool_uncertainties`] pools.
const POOL_HALF: i32 = 2;

/// Replaces each node's gradient uncertainty by a pooled one: the shape of the dot's own exact
/// bounds, `b = sqrt(crlb_ref² + crlb_grad²)` per axis, times the root-mean-square of
/// `u_d / b` over the valid dots of its `(2·POOL_HALF + 1)²` lattice neighbourhood.
///
/// Why: u_d is estimated from the no-flow stack (ν = K − 1 degrees of freedom per dot, 9 for
/// 10 images), so the weights `1/u_d²` of the integration are noisy; the dots whose u_d came
/// out small get too much weight, and the covariance `(AᵀWA)⁻¹` under-states the variance of
/// the weighted solution (on the bump campaign of `tests/density.rs`: coverage 0.61 instead of
/// 0.68). With the default `ar_variant = "bounds"`, `u_d / b = u_ref / crlb_ref` for every dot,
/// so pooling that ratio over ~25 dots (~225 degrees of freedom) keeps its spatial variation
/// and the stack's measurement while removing the noise. A node without finite bounds keeps its
/// own u_d.
fn pool_uncertainties(nodes: &mut [Node], node_of: &[usize], dots: &[PairDot]) {
    let mut bound = vec![[f64::NAN; 2]; nodes.len()];
    for (k, d) in dots.iter().enumerate() {
        let n = node_of[k];
        if n == usize::MAX {
            continue;
        }
        let (Some(r), Some(g), Some(u_d)) = (d.reference, d.gradient, d.u_d) else {
            continue;
        };
        // the node's uncertainty in its own units per px of u_d
        let scale = [
            nodes[n].u_gradient[0] / u_d[0],
            nodes[n].u_gradient[1] / u_d[1],
        ];
        let b = [
            r.crlb_x.hypot(g.crlb_x) * scale[0],
            r.crlb_y.hypot(g.crlb_y) * scale[1],
        ];
        if b.iter().all(|v| v.is_finite() && *v > 0.0) {
            bound[n] = b;
        }
    }
    let at: std::collections::HashMap<[i32; 2], usize> = nodes
        .iter()
        .enumerate()
        .map(|(n, x)| (x.index, n))
        .collect();
    let pooled: Vec<Option<[f64; 2]>> = (0..nodes.len())
        .map(|n| {
            if !bound[n][0].is_finite() {
                return None;
            }
            let [i, j] = nodes[n].index;
            let (mut sum, mut count) = ([0.0f64; 2], 0usize);
            for di in -POOL_HALF..=POOL_HALF {
                for dj in -POOL_HALF..=POOL_HALF {
                    let Some(&m) = at.get(&[i + di, j + dj]) else {
                        continue;
                    };
                    if !bound[m][0].is_finite() {
                        continue;
                    }
                    for a in 0..2 {
                        sum[a] += (nodes[m].u_gradient[a] / bound[m][a]).powi(2);
                    }
                    count += 1;
                }
            }
            (count > 0).then(|| {
                [
                    bound[n][0] * (sum[0] / count as f64).sqrt(),
                    bound[n][1] * (sum[1] / count as f64).sqrt(),
                ]
            })
        })
        .collect();
    for (node, p) in nodes.iter_mut().zip(pooled) {
        if let Some(u) = p {
            node.u_gradient = u;
        }
    }
}

/// The lattice nodes [`integrate_frame`] integrates: the valid dots with a gradient and its
/// uncertainty (pooled over each dot's 5 × 5 lattice neighbourhood), the Dirichlet nodes
/// marked (inside `quiet`, or the outer ring of the valid dots); and for each dot its node
/// (`usize::MAX`: none). For studies of the integration (`examples/density_coverage.rs`).
pub fn frame_nodes(
    dots: &[PairDot],
    physical: &[PhysicalDot],
    quiet: Option<&Mask>,
    frame: &Path,
) -> Result<(Vec<Node>, Vec<usize>), PipelineError> {
    let mut node_of = vec![usize::MAX; dots.len()];
    let mut nodes = Vec::new();
    for (k, (d, p)) in dots.iter().zip(physical).enumerate() {
        let (true, Some(position), Some(gradient), Some(u)) =
            (d.valid, p.position_m, p.gradient, p.u_gradient)
        else {
            continue;
        };
        if !(u[0] > 0.0 && u[1] > 0.0) {
            continue;
        }
        let dirichlet = match (quiet, d.reference_position) {
            (Some(m), Some(r)) => m.keeps_point(r[0], r[1]),
            _ => false,
        };
        node_of[k] = nodes.len();
        nodes.push(Node {
            index: [d.index.i, d.index.j],
            position,
            gradient,
            u_gradient: u,
            dirichlet,
        });
    }
    if nodes.is_empty() {
        return Err(PipelineError::Density {
            path: frame.to_path_buf(),
            message: "no valid dot has a displacement uncertainty u_d (it needs a no-flow stack \
                      of at least 3 images in which the dots are fitted)"
                .into(),
        });
    }
    pool_uncertainties(&mut nodes, &node_of, dots);
    if quiet.is_none() {
        let ring = bostrack_density::outer_ring(&nodes.iter().map(|n| n.index).collect::<Vec<_>>());
        for (n, r) in nodes.iter_mut().zip(ring) {
            n.dirichlet = r;
        }
    }
    Ok((nodes, node_of))
}

/// Integrates one frame's gradients (the nodes of [`frame_nodes`]). `quiet` is the
/// quiescent-gas mask (`None`: the outer ring of the valid dots).
pub fn integrate_frame(
    plan: &DensityPlan,
    dots: &[PairDot],
    physical: &[PhysicalDot],
    quiet: Option<&Mask>,
    frame: &Path,
) -> Result<FrameDensity, PipelineError> {
    let (nodes, node_of) = frame_nodes(dots, physical, quiet, frame)?;
    let cfg = IntegrationConfig {
        method: plan.method,
        reference_density: plan.reference_density,
        reference_uncertainty: plan.reference_uncertainty,
        uncertainty: true,
    };
    let field = bostrack_density::integrate(&nodes, &cfg).map_err(|e| PipelineError::Density {
        path: frame.to_path_buf(),
        message: match (&e, &plan.reference_mask) {
            (bostrack_density::DensityError::NoReference { .. }, Some(m)) => format!(
                "{e}: the reference mask {} keeps none of the frame's valid dots",
                m.display()
            ),
            _ => e.to_string(),
        },
    })?;
    let per_dot = node_of
        .iter()
        .map(|&k| {
            if k == usize::MAX {
                (None, None, None)
            } else {
                let r = &field.nodes[k];
                (r.rho, r.u_rho, Some(r.status))
            }
        })
        .collect();
    let solved: Vec<&bostrack_density::NodeResult> =
        field.nodes.iter().filter(|r| r.rho.is_some()).collect();
    let finite = |v: Option<f64>| v.filter(|x| x.is_finite());
    let mut u_solved: Vec<f64> = solved
        .iter()
        .filter(|r| r.status == NodeStatus::Solved)
        .filter_map(|r| r.u_rho)
        .collect();
    let summary = DensitySummary {
        method: plan.method.name().into(),
        nodes: nodes.len(),
        reference_nodes: nodes.iter().filter(|n| n.dirichlet).count(),
        solved: solved.len(),
        islands: field.islands.len(),
        islands_without_reference: field
            .islands
            .iter()
            .filter(|i| i.status == bostrack_density::IslandStatus::NoReference)
            .count(),
        median_u_rho: finite(Some(bostrack_core::median(&mut u_solved))),
        rho_min: solved.iter().filter_map(|r| r.rho).reduce(f64::min),
        rho_max: solved.iter().filter_map(|r| r.rho).reduce(f64::max),
        residual_rms: field.residual_rms,
        factor_nnz: field.factor_nnz,
        gradient_per_px: plan.pitch_m / plan.sensitivity_m,
        metres_per_px: plan.pitch_m / plan.magnification_density,
    };
    Ok(FrameDensity {
        nodes: per_dot,
        summary,
    })
}
