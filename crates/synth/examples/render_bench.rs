//! Rendering speed of a 1024×1024 scene with ~16k dots (8 px pitch), in release:
//!
//! `cargo run --release -p bostrack-synth --example render_bench`
//!
//! Prints, for the noise-free render, noise + quantisation, the per-dot bounds and a whole
//! reference scene, the best wall time of 5 runs and the mean process CPU time per run (user +
//! system, from /proc/self/stat on Linux: a machine shared with other work inflates wall time
//! but not much the CPU time), for an axis-aligned (ρ = 0, separable erf differences) and a
//! rotated (ρ = 0.3, quadrature) dot. Set `RAYON_NUM_THREADS` to choose the thread count.

use bostrack_synth::{
    Scene, SceneConfig, add_noise, compute_bounds, layout, render_mean, scene_mask,
};
use std::time::Instant;

/// Process CPU time (user + system) in seconds, or NaN where /proc is not available.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // fields after the command name (which is in parentheses): utime is field 14, stime 15
    let Some(rest) = stat.rsplit(')').next() else {
        return f64::NAN;
    };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| {
        f.get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    (ticks(11) + ticks(12)) / 100.0 // USER_HZ = 100 on Linux
}

/// (best wall time, mean CPU time) in ms over 5 runs, and the last result.
fn best<T>(mut f: impl FnMut() -> T) -> ((f64, f64), T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    let c0 = cpu_seconds();
    for _ in 0..5 {
        let t = Instant::now();
        let v = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(v);
    }
    let cpu = (cpu_seconds() - c0) / 5.0;
    ((best * 1e3, cpu * 1e3), out.unwrap())
}

fn main() {
    println!("threads: {}", rayon::current_num_threads());
    for rho in [0.0, 0.3] {
        let mut cfg = SceneConfig {
            width: 1024,
            height: 1024,
            ..SceneConfig::default()
        };
        cfg.dots.rho = rho;
        cfg.lattice.angle_deg = 3.0;
        let truth = layout(&cfg).unwrap();
        let (t_mean, mean) = best(|| render_mean(&cfg, &truth).unwrap());
        let (t_noise, _) = best(|| add_noise(&cfg, &mean, 1).unwrap());
        let mask = scene_mask(&cfg);
        let (t_bounds, _) = best(|| {
            let mut tr = truth.clone();
            compute_bounds(&cfg, &mut tr, &mean, mask.as_ref());
            tr
        });
        let (t_scene, s) = best(|| Scene::reference(&cfg).unwrap());
        let inside = s
            .truth
            .iter()
            .filter(|t| t.centre_inside(1024, 1024))
            .count();
        println!(
            "rho {rho}: {} dots ({inside} centred inside); wall ms (best of 5) / CPU ms (mean)",
            truth.len()
        );
        for (name, (wall, cpu)) in [
            ("render_mean", t_mean),
            ("add_noise", t_noise),
            ("compute_bounds", t_bounds),
            ("Scene::reference", t_scene),
        ] {
            println!("  {name:18} {wall:8.1} / {cpu:8.1}");
        }
    }
}
