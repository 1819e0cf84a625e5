//! Benchmark of the density integration with the full per-node uncertainty (issue 15):
//!
//! ```text
//! cargo run --release -p bostrack-density --example density_bench [-- [--quick] [--no-dense] [--dense-up-to=N] [DOTS_CSV]]
//! ```
//!
//! 1. a 128 × 128 lattice (16,384 nodes; rotated, with holes, uncertainties varying by 4×):
//!    WLS and Poisson, solve + exact uncertainty, best of 3 wall times;
//! 2. the dense-inverse reference (the published code's way) against the sparse path on the
//!    lattices up to 128 × 128 (WLS; Poisson up to 64 × 64; `--quick`: 32 × 32 only;
//!    `--no-dense`: none; `--dense-up-to=64`: 32 and 64; 128 × 128 takes minutes and 6 GB), and
//!    the ratio;
//! 3. with `DOTS_CSV` (a frame's `dots.csv` from `bostrack run` with the optics sections: the
//!    real sample's lattice), the same on that lattice (its valid dots, the outer ring as the
//!    Dirichlet nodes).
//!
//! Threads: `RAYON_NUM_THREADS` (the WLS path is single-threaded; Poisson's blocked solves use
//! rayon). Timings on a shared machine vary by 1.5×: compare numbers of one run.

use bostrack_density::{IntegrationConfig, Method, Node, dense_uncertainty, integrate, outer_ring};
use std::time::Instant;

fn lattice(n: i32) -> Vec<Node> {
    let h = 1e-3;
    let (s, c) = 20f64.to_radians().sin_cos();
    let centre = [0.3 * n as f64 * h, 0.6 * n as f64 * h];
    let width = n as f64 * h / 8.0;
    let mut nodes = Vec::new();
    for i in 0..n {
        for j in 0..n {
            if (i - n / 2).abs() < 2 && (j - n / 3).abs() < 3 {
                continue; // a hole
            }
            let (a, b) = (j as f64 * h, i as f64 * h);
            let p = [c * a - s * b, s * a + c * b];
            let (x, y) = (p[0] - centre[0], p[1] - centre[1]);
            let e = -0.05 * (-(x * x + y * y) / (2.0 * width * width)).exp() / (width * width);
            let u = 1.0 + 3.0 * (-(x * x + y * y) / (2.0 * width * width)).exp();
            nodes.push(Node {
                index: [i, j],
                position: p,
                gradient: [-x * e, -y * e],
                u_gradient: [u, u],
                dirichlet: false,
            });
        }
    }
    ring(&mut nodes);
    nodes
}

fn ring(nodes: &mut [Node]) {
    let r = outer_ring(&nodes.iter().map(|n| n.index).collect::<Vec<_>>());
    for (n, r) in nodes.iter_mut().zip(r) {
        n.dirichlet = r;
    }
}

fn best_of(k: usize, mut f: impl FnMut()) -> f64 {
    (0..k)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn cfg(method: Method) -> IntegrationConfig {
    IntegrationConfig {
        method,
        ..IntegrationConfig::default()
    }
}

fn report(name: &str, nodes: &[Node]) {
    for method in [Method::Wls, Method::Poisson] {
        let f = integrate(nodes, &cfg(method)).unwrap();
        let t = best_of(3, || {
            integrate(nodes, &cfg(method)).unwrap();
        });
        let t0 = best_of(3, || {
            integrate(
                nodes,
                &IntegrationConfig {
                    uncertainty: false,
                    ..cfg(method)
                },
            )
            .unwrap();
        });
        println!(
            "{name}: {} nodes, {} unknowns, nnz(L) = {} ({:.1} MB), {:<7} solve {:.3} s, with exact u_rho {:.3} s",
            nodes.len(),
            f.unknowns,
            f.factor_nnz,
            f.factor_nnz as f64 * 16e-6,
            method.name(),
            t0,
            t
        );
    }
}

fn read_dots(path: &str) -> Vec<Node> {
    let mut rdr = csv::Reader::from_path(path).expect("a dots.csv");
    let h = rdr.headers().unwrap().clone();
    let col = |n: &str| {
        h.iter()
            .position(|c| c == n)
            .unwrap_or_else(|| panic!("no {n}"))
    };
    let c = [
        "i",
        "j",
        "x_m",
        "y_m",
        "grad_rho_x",
        "grad_rho_y",
        "u_grad_rho_x",
        "u_grad_rho_y",
        "valid",
    ]
    .map(col);
    let mut nodes = Vec::new();
    for r in rdr.records() {
        let r = r.unwrap();
        let f = |k: usize| r[c[k]].parse::<f64>().ok();
        if &r[c[8]] != "true" {
            continue;
        }
        let (Some(x), Some(y), Some(gx), Some(gy), Some(ux), Some(uy)) =
            (f(2), f(3), f(4), f(5), f(6), f(7))
        else {
            continue;
        };
        nodes.push(Node {
            index: [r[c[0]].parse().unwrap(), r[c[1]].parse().unwrap()],
            position: [x, y],
            gradient: [gx, gy],
            u_gradient: [ux, uy],
            dirichlet: false,
        });
    }
    ring(&mut nodes);
    nodes
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let quick = args.iter().any(|a| a == "--quick");
    let csv = args.iter().find(|a| !a.starts_with("--"));
    println!(
        "threads: {} (RAYON_NUM_THREADS)",
        rayon::current_num_threads()
    );
    let sizes: &[i32] = if quick { &[32] } else { &[128] };
    for &n in sizes {
        report(&format!("{n}x{n} lattice"), &lattice(n));
    }
    let dense_sizes: &[i32] = if args.iter().any(|a| a == "--no-dense") {
        &[]
    } else if quick {
        &[32]
    } else {
        &[32, 64, 90, 128]
    };
    let up_to: i32 = args
        .iter()
        .find_map(|a| a.strip_prefix("--dense-up-to="))
        .map_or(i32::MAX, |v| {
            v.parse().expect("--dense-up-to=N: a lattice size")
        });
    for &n in dense_sizes.iter().filter(|&&n| n <= up_to) {
        let nodes = lattice(n);
        // Poisson's dense reference also forms the dense N × 2N sandwich factor: 64 × 64 at most
        let methods: &[Method] = if n <= 64 {
            &[Method::Wls, Method::Poisson]
        } else {
            &[Method::Wls]
        };
        for &method in methods {
            let c = cfg(method);
            let sparse = best_of(3, || {
                integrate(&nodes, &c).unwrap();
            });
            let f = integrate(&nodes, &c).unwrap();
            let t = Instant::now();
            let dense = dense_uncertainty(&nodes, &c).unwrap();
            let td = t.elapsed().as_secs_f64();
            let worst = f
                .nodes
                .iter()
                .zip(&dense)
                .map(|(a, b)| (a.u_rho.unwrap() - b.unwrap()).abs() / b.unwrap())
                .fold(0.0, f64::max);
            println!(
                "dense reference {n}x{n} {:<7} ({} unknowns, dense matrix {:.0} MB): dense {td:.3} s, sparse {sparse:.4} s, ratio {:.0}x, max rel diff {worst:.1e}",
                method.name(),
                f.unknowns,
                (f.unknowns as f64).powi(2) * 8e-6,
                td / sparse
            );
        }
    }
    if let Some(path) = csv {
        let nodes = read_dots(path);
        report(&format!("real lattice {path}"), &nodes);
    }
}
