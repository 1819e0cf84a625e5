//! Where the density's coverage comes from (issue 15): the bump campaigns of
//! `tests/density.rs`, each frame's WLS integration split into its parts.
//!
//! ```text
//! cargo run --release -p bostrack-pipeline --example density_coverage [-- CAMPAIGNS [wls|poisson]]
//! ```
//!
//! Per campaign (own seed: reference, stack and frame), on the nodes the pipeline integrates
//! (`frame_nodes`: pooled u, outer ring):
//! - `measured`: the pipeline's field, `e = ρ − ρ_true`, against u_ρ (the noise's exact u and
//!   the truncation estimate |δ| in quadrature) and against the noise's part alone, u_noise;
//! - `truth`: the exact gradient at each node's (fitted) reference position, no noise: the
//!   discretisation (truncation) error alone, deterministic;
//! - `truth+N(u)`: the exact gradient plus Gaussian noise of exactly the nodes' u, against its
//!   own u_ρ: what the estimator promises, with the truncation error included;
//! - `measured − truth`: the measured error less the truncation error (the part the noise
//!   makes);
//! - the displacement errors standardised by the pooled u (per axis), and their mean over the
//!   campaigns per lattice site (a coherent bias), integrated alone.
//!
//! Coverage is `|e| ≤ u` over the solved nodes; the standard error is the spread between
//! campaigns over √campaigns (neighbouring nodes are correlated, campaigns are independent).
//!
//! With 36 campaigns (coverage ± standard error / RMS z): measured 0.675 ± 0.010 / 1.022
//! (against u_noise: 0.666 / 1.043); truth 1.000 / 0.103 (the truncation error of the
//! fourth-order stencils, RMS 0.10 u_noise, at most 0.75; |δ| from the exact gradients misses
//! it by 0.035 u_noise RMS, from the measured ones |δ| has RMS 0.20 u_noise); truth+N(u)
//! 0.694 ± 0.007 / 0.978 (u_ρ slightly conservative: δ from noisy data holds some noise);
//! measured − truth 0.668 ± 0.010 / 1.039; truth+N(u) − truth 0.688 ± 0.007 / 0.990 (the exact
//! u_noise checked). Median u_ρ 0.171 % of the peak (u_noise 0.168 %). Pooled u: displacement
//! RMS z 1.002 (own u_d: 1.131, Student's t₉). The mean gradient error over the campaigns,
//! integrated alone, is 0.267 u_noise RMS where the noise alone would leave 0.173 (the noise
//! part's RMS z / √36): a coherent fit bias of 0.204 u_noise RMS, expected coverage loss
//! `0.242 b²` = 0.010 (`P(|b + z| ≤ 1) ≈ 0.683 − 0.242 b²`), the radial
//! displacement error −1.4e-3 to −2.7e-3 px (± 0.5e-3) at r = 96 to 132 px, +1.8e-3 ± 0.6e-3
//! at 48 to 60 px, −3.4e-4 ± 1e-4 beyond 132 px. The same campaigns with the
//! third-order stencils and no truncation term (commit 8f45cc4): measured 0.652 ± 0.008 /
//! 1.080, truncation RMS 0.34 u_ρ, at most 1.95, median u_ρ 0.165 %. Poisson (`-- 36 poisson`):
//! measured 0.668 ± 0.010 / 1.033 (against u_noise 0.651); the trapezoid's truncation RMS 0.33
//! u_noise, at most 2.3, |δ| misses it by 0.009; noise part 0.665 ± 0.010; coherent bias 0.28
//! u_noise RMS (loss 0.019: unweighted, it leans more on the biased dots).

use bostrack_density::{IntegrationConfig, Method, Node, NodeStatus, integrate};
use bostrack_pipeline::{Plan, frame_nodes};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};
use std::collections::HashMap;
use std::path::Path;

#[path = "../tests/common/bump.rs"]
mod bump;
use bump::{AMPLITUDE, CENTRE, config};

/// Coverage, RMS z and count of one error vector against its u.
#[derive(Default, Clone, Copy)]
struct Tally {
    covered: usize,
    z2: f64,
    n: usize,
}

impl Tally {
    fn add(&mut self, e: f64, u: f64) {
        self.covered += usize::from(e.abs() <= u);
        self.z2 += (e / u).powi(2);
        self.n += 1;
    }
    fn coverage(&self) -> f64 {
        self.covered as f64 / self.n as f64
    }
    fn z(&self) -> f64 {
        (self.z2 / self.n as f64).sqrt()
    }
}

fn main() {
    let campaigns: u64 = std::env::args()
        .nth(1)
        .map(|a| a.parse().expect("CAMPAIGNS: a number"))
        .unwrap_or(12);
    let dir = tempfile::tempdir().unwrap();
    for d in ["gradient", "stack"] {
        std::fs::create_dir_all(dir.path().join(d)).unwrap();
    }
    for f in ["reference.tif", "gradient/g.tif", "stack/s.tif"] {
        std::fs::write(dir.path().join(f), b"").unwrap();
    }
    let mut cfg = config();
    cfg.input.dir = ".".into();
    let plan = Plan::from_config(cfg, &dir.path().join("pipeline.toml")).unwrap();
    let dp = plan.density.clone().unwrap();
    let plane = dp.pitch_m / dp.magnification_density;
    let grad_per_px = dp.pitch_m / dp.sensitivity_m;
    let peak = AMPLITUDE * grad_per_px * plane;
    let truth_rho = |p: [f64; 2]| bump::density_deficit(p, peak);
    let truth_d = bump::displacement;
    let method = match std::env::args().nth(2).as_deref() {
        None | Some("wls") => Method::Wls,
        Some("poisson") => Method::Poisson,
        Some(m) => panic!("METHOD: wls or poisson, not {m}"),
    };
    let icfg = IntegrationConfig {
        method,
        reference_density: 0.0,
        ..IntegrationConfig::default()
    };
    let names = [
        "measured",
        "measured, u_noise",
        "truth (truncation), u_noise",
        "truth+N(u)",
        "measured - truth, u_noise",
        "truth+N(u) - truth, u_noise",
    ];
    let mut pooled = [Tally::default(); 6];
    let mut per_campaign: Vec<[f64; 6]> = Vec::new();
    let mut trunc_over_u = (0.0, 0usize, 0.0f64);
    // the truncation estimate: rms of δ (measured data) and of |δ| − |error| (exact data), in
    // units of u_noise
    let (mut delta2, mut delta_miss2) = (0.0, 0.0);
    // displacement errors in units of the pooled u and of the unpooled u_d
    let (mut dz2_pool, mut dz2_own, mut dn) = (0.0, 0.0, 0usize);
    // per lattice site: sum of the gradient error (kg/m⁴), count; and the nodes of the last
    // campaign (for integrating the mean error)
    let mut site_err: HashMap<[i32; 2], ([f64; 2], usize)> = HashMap::new();
    let mut last_nodes: Vec<Node> = Vec::new();
    let mut last_u: Vec<f64> = Vec::new();
    let mut radial = [(0.0f64, 0.0f64, 0usize); 12];
    let normal = Normal::new(0.0, 1.0).unwrap();
    let mut median_u = Vec::new();
    for seed in 0..campaigns {
        let res = bump::run(&plan, seed);
        let physical = res.physical.as_ref().unwrap();
        let (nodes, node_of) = frame_nodes(&res.dots, physical, None, Path::new("g.tif")).unwrap();
        let mut pos_px = vec![[0.0; 2]; nodes.len()];
        let mut u_own = vec![[0.0; 2]; nodes.len()];
        for (k, d) in res.dots.iter().enumerate() {
            if node_of[k] != usize::MAX {
                pos_px[node_of[k]] = d.reference_position.unwrap();
                let u = d.u_d.unwrap();
                u_own[node_of[k]] = [u[0] * grad_per_px, u[1] * grad_per_px];
            }
        }
        let truth_g: Vec<[f64; 2]> = pos_px
            .iter()
            .map(|&p| {
                let d = truth_d(p);
                [-d[0] * grad_per_px, -d[1] * grad_per_px]
            })
            .collect();
        for (k, n) in nodes.iter().enumerate() {
            for a in 0..2 {
                let e = n.gradient[a] - truth_g[k][a];
                dz2_pool += (e / n.u_gradient[a]).powi(2);
                dz2_own += (e / u_own[k][a]).powi(2);
                dn += 1;
            }
            let s = site_err.entry(n.index).or_insert(([0.0; 2], 0));
            s.0[0] += n.gradient[0] - truth_g[k][0];
            s.0[1] += n.gradient[1] - truth_g[k][1];
            s.1 += 1;
            // radial component of the displacement error (px) against radius
            let (x, y) = (pos_px[k][0] - CENTRE[0], pos_px[k][1] - CENTRE[1]);
            let r = x.hypot(y);
            let bin = ((r / 12.0) as usize).min(radial.len() - 1);
            if r > 0.0 {
                let ed = [
                    -(n.gradient[0] - truth_g[k][0]) / grad_per_px,
                    -(n.gradient[1] - truth_g[k][1]) / grad_per_px,
                ];
                let e = (ed[0] * x + ed[1] * y) / r;
                radial[bin].0 += e;
                radial[bin].1 += e * e;
                radial[bin].2 += 1;
            }
        }
        let mut rng = StdRng::seed_from_u64(7 + seed);
        let with = |g: &dyn Fn(usize) -> [f64; 2]| -> Vec<Node> {
            nodes
                .iter()
                .enumerate()
                .map(|(k, n)| Node {
                    gradient: g(k),
                    ..*n
                })
                .collect()
        };
        let noisy: Vec<[f64; 2]> = (0..nodes.len())
            .map(|k| {
                [
                    truth_g[k][0] + nodes[k].u_gradient[0] * normal.sample(&mut rng),
                    truth_g[k][1] + nodes[k].u_gradient[1] * normal.sample(&mut rng),
                ]
            })
            .collect();
        let fields = [
            integrate(&nodes, &icfg).unwrap(),
            integrate(&with(&|k| truth_g[k]), &icfg).unwrap(),
            integrate(&with(&|k| noisy[k]), &icfg).unwrap(),
        ];
        let mut us: Vec<f64> = fields[0]
            .nodes
            .iter()
            .filter(|r| r.status == NodeStatus::Solved)
            .map(|r| r.u_rho.unwrap())
            .collect();
        let mut un: Vec<f64> = fields[0]
            .nodes
            .iter()
            .filter(|r| r.status == NodeStatus::Solved)
            .map(|r| (r.u_rho.unwrap().powi(2) - r.u_truncation.unwrap().powi(2)).sqrt())
            .collect();
        median_u.push([
            bostrack_core::median(&mut us) / peak,
            bostrack_core::median(&mut un) / peak,
        ]);
        let mut t = [Tally::default(); 6];
        for k in 0..nodes.len() {
            if fields[0].nodes[k].status != NodeStatus::Solved {
                continue;
            }
            let tr = truth_rho(pos_px[k]);
            let r = &fields[0].nodes[k];
            let (ut, dm) = (r.u_rho.unwrap(), r.u_truncation.unwrap());
            // the noise's u: the same for every field of these nodes and weights
            let u = (ut * ut - dm * dm).sqrt();
            let e: Vec<f64> = fields
                .iter()
                .map(|f| f.nodes[k].rho.unwrap() - tr)
                .collect();
            t[0].add(e[0], ut);
            t[1].add(e[0], u);
            t[2].add(e[1], u);
            t[3].add(e[2], fields[2].nodes[k].u_rho.unwrap());
            t[4].add(e[0] - e[1], u);
            t[5].add(e[2] - e[1], u);
            delta2 += (dm / u).powi(2);
            delta_miss2 += ((fields[1].nodes[k].u_truncation.unwrap() - e[1].abs()) / u).powi(2);
            trunc_over_u.0 += (e[1] / u).powi(2);
            trunc_over_u.1 += 1;
            trunc_over_u.2 = trunc_over_u.2.max((e[1] / u).abs());
        }
        eprintln!(
            "campaign {seed}: {}",
            names
                .iter()
                .zip(&t)
                .map(|(n, t)| format!("{n} {:.3}/{:.3}", t.coverage(), t.z()))
                .collect::<Vec<_>>()
                .join(", ")
        );
        for (a, b) in pooled.iter_mut().zip(&t) {
            a.covered += b.covered;
            a.z2 += b.z2;
            a.n += b.n;
        }
        per_campaign.push(std::array::from_fn(|m| t[m].coverage()));
        if seed + 1 == campaigns {
            last_u = fields[0]
                .nodes
                .iter()
                .map(|r| {
                    (r.u_rho.unwrap_or(0.0).powi(2) - r.u_truncation.unwrap_or(0.0).powi(2)).sqrt()
                })
                .collect();
            last_nodes = nodes;
        }
    }
    let c = campaigns as f64;
    println!(
        "{campaigns} campaigns: coverage / rms z (standard error of the coverage between campaigns)"
    );
    for (m, name) in names.iter().enumerate() {
        let mean = per_campaign.iter().map(|p| p[m]).sum::<f64>() / c;
        let sd = (per_campaign
            .iter()
            .map(|p| (p[m] - mean).powi(2))
            .sum::<f64>()
            / (c - 1.0))
            .sqrt();
        println!(
            "  {name:<30} {:.3} / {:.3} ({:.3})",
            pooled[m].coverage(),
            pooled[m].z(),
            sd / c.sqrt()
        );
    }
    println!(
        "median u_rho / peak: {:.4} % (u_noise: {:.4} %)",
        100.0 * median_u.iter().map(|m| m[0]).sum::<f64>() / c,
        100.0 * median_u.iter().map(|m| m[1]).sum::<f64>() / c
    );
    let nt = trunc_over_u.1 as f64;
    println!(
        "truncation error / u_noise: rms {:.3}, max {:.3}; its estimate |delta| (in u_rho) from the measured data: rms {:.3} u_noise; from the exact data: rms of |delta| - |truncation error| {:.3} u_noise",
        (trunc_over_u.0 / nt).sqrt(),
        trunc_over_u.2,
        (delta2 / nt).sqrt(),
        (delta_miss2 / nt).sqrt()
    );
    println!(
        "displacement rms z: pooled u {:.3}, own u_d {:.3}",
        (dz2_pool / dn as f64).sqrt(),
        (dz2_own / dn as f64).sqrt()
    );
    println!(
        "mean radial displacement error (px) by radius (12 px bins), ± its standard error (dots taken as independent), dots:"
    );
    for (b, &(s, s2, n)) in radial.iter().enumerate() {
        if n > 1 {
            let m = s / n as f64;
            let se = ((s2 - n as f64 * m * m) / (n - 1) as f64 / n as f64).sqrt();
            println!(
                "  r {:>3}-{:<3} {m:+.2e} ± {se:.1e} ({n})",
                b * 12,
                b * 12 + 12
            );
        }
    }
    // the mean gradient error per site (a bias the campaigns share), integrated alone
    let bias: Vec<Node> = last_nodes
        .iter()
        .map(|n| {
            let (s, k) = site_err.get(&n.index).copied().unwrap_or(([0.0; 2], 1));
            Node {
                gradient: [s[0] / k as f64, s[1] / k as f64],
                ..*n
            }
        })
        .collect();
    let f = integrate(&bias, &icfg).unwrap();
    let (mut b2, mut n, mut bmax) = (0.0, 0usize, 0.0f64);
    for (r, u) in f.nodes.iter().zip(&last_u) {
        if r.status == NodeStatus::Solved {
            let z = r.rho.unwrap() / u;
            b2 += z * z;
            n += 1;
            bmax = bmax.max(z.abs());
        }
    }
    // what the noise leaves in a mean of `campaigns` errors: the noise part's rms z / √c
    let (b_rms, noise_rms) = ((b2 / n as f64).sqrt(), pooled[4].z() / c.sqrt());
    let coherent = (b_rms * b_rms - noise_rms * noise_rms).max(0.0).sqrt();
    println!(
        "mean gradient error over the campaigns, integrated: rms {b_rms:.3} u_noise, max {bmax:.3} u_noise; the noise alone would leave {noise_rms:.3}: a coherent bias of rms {coherent:.3} u_noise, whose expected coverage loss is 0.242 b^2 = {:.4}",
        0.242 * coherent * coherent
    );
}
