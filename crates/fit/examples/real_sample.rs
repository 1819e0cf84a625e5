//! Fit every dot of the real sample's reference image and report what comes out.
//!
//! `cargo run --release -p bostrack-fit --example real_sample`
//!
//! Seeds: the dot positions of the published package (reference-lsg.csv), rounded to a pixel,
//! with 9x9 windows (until the detect crate is wired in). Reports the noise estimates (single
//! image and the 10-image no-flow stack), status counts, median fitted sigma and rho, median
//! bound, wall time, and the effect of the neighbour subtraction (position changes, sigma) and
//! the agreement with the package's positions.

use bostrack_core::{DotFit, DotFlags, FitStatus, GridIndex, Seed, Window, median};
use bostrack_fit::{
    FitConfig, Neighbours, estimate_noise_detailed, fit_dots, noise_from_stack_detailed,
};
use bostrack_io::{bos_sample_dir, read_image, read_mask_for};
use std::time::Instant;

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        f64::NAN
    } else {
        v[((v.len() - 1) as f64 * p).round() as usize]
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Some(dir) = bos_sample_dir() else {
        return Ok(());
    };
    let img = read_image(&dir.join("pair/reference.tif"))?;
    let mask = read_mask_for(&dir.join("mask.tif"), img.width(), img.height())?;
    println!(
        "reference.tif {}x{}, saturation {:?}",
        img.width(),
        img.height(),
        img.meta.saturation
    );

    // --- noise ---
    let t = Instant::now();
    let single = estimate_noise_detailed(&img, Some(&mask))?;
    println!(
        "estimate_noise (reference, mask): {:?} ({:.0} ms)",
        single.model,
        t.elapsed().as_secs_f64() * 1e3
    );
    let mut stack = Vec::new();
    for k in 1..=10 {
        stack.push(read_image(&dir.join(format!("ref-stack/im_{k:04}.tif")))?);
    }
    let t = Instant::now();
    let from_stack = noise_from_stack_detailed(&stack, Some(&mask))?;
    println!(
        "noise_from_stack (10 frames, mask): {:?} ({:.0} ms)",
        from_stack.model,
        t.elapsed().as_secs_f64() * 1e3
    );
    println!("  mean    sd(single image)  sd(stack)   [model sd at the bin mean]");
    for (a, b) in single.bins.iter().zip(&from_stack.bins).step_by(4) {
        println!(
            "  {:6.0} {:6.1} [{:5.1}]  {:6.0} {:6.1} [{:5.1}]",
            a.mean,
            a.variance.sqrt(),
            single.model.sigma(a.mean),
            b.mean,
            b.variance.sqrt(),
            from_stack.model.sigma(b.mean)
        );
    }
    for m in [100.0, 400.0, 1000.0, 2000.0, 3000.0] {
        println!(
            "  sd at {m:5}: single {:5.1}  stack {:5.1}",
            single.model.sigma(m),
            from_stack.model.sigma(m)
        );
    }
    let noise = from_stack.model;

    // --- seeds from the package's positions ---
    let text = std::fs::read_to_string(dir.join("reference-implementation/reference-lsg.csv"))?;
    let mut pkg = Vec::new();
    for line in text.lines().skip(1) {
        let f: Vec<f64> = line
            .split(',')
            .map(|s| s.trim().parse().unwrap_or(f64::NAN))
            .collect();
        if f.len() >= 6 {
            pkg.push(f);
        }
    }
    let seeds: Vec<Seed> = pkg
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let c = [f[0].round(), f[1].round()];
            let window = Window::centred(c[0], c[1], 4)
                .clip(img.width(), img.height())
                .unwrap_or(Window::new(0, 0, 1, 1));
            Seed {
                index: GridIndex::new(k as i32, 0),
                predicted: c,
                centre: c,
                window,
                flags: DotFlags::NONE,
            }
        })
        .collect();
    println!("{} seeds from reference-lsg.csv", seeds.len());

    // --- fits ---
    let mut runs: Vec<(String, Vec<DotFit>)> = Vec::new();
    for (name, cfg) in [
        (
            "plain",
            FitConfig {
                neighbours: Neighbours::None,
                ..Default::default()
            },
        ),
        (
            "subtract x1",
            FitConfig {
                neighbour_passes: 1,
                ..Default::default()
            },
        ),
        ("subtract x2 (default)", FitConfig::default()),
        (
            "subtract x3",
            FitConfig {
                neighbour_passes: 3,
                ..Default::default()
            },
        ),
    ] {
        let t = Instant::now();
        let fits = fit_dots(&img, Some(&mask), &seeds, &cfg, &noise)?;
        let dt = t.elapsed().as_secs_f64();
        println!(
            "\n== {name}: {:.3} s wall on {} threads ({:.2} us per dot)",
            dt,
            rayon::current_num_threads(),
            dt * 1e6 / seeds.len() as f64
        );
        report(&fits, &pkg);
        runs.push((name.to_string(), fits));
    }
    // rayon scaling: best of 3 runs on 1 and 2 threads
    println!("\nrayon scaling (best of 3 wall times; the machine is shared, see uptime)");
    for (name, cfg) in [
        (
            "plain",
            FitConfig {
                neighbours: Neighbours::None,
                ..Default::default()
            },
        ),
        ("default", FitConfig::default()),
    ] {
        let mut best = [f64::INFINITY; 2];
        for (k, threads) in [1usize, 2].into_iter().enumerate() {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()?;
            for _ in 0..3 {
                let t = Instant::now();
                let _ = pool.install(|| fit_dots(&img, Some(&mask), &seeds, &cfg, &noise))?;
                best[k] = best[k].min(t.elapsed().as_secs_f64());
            }
        }
        println!(
            "  {name}: 1 thread {:.3} s ({:.2} us/dot), 2 threads {:.3} s, speed-up {:.2}",
            best[0],
            best[0] * 1e6 / seeds.len() as f64,
            best[1],
            best[0] / best[1]
        );
    }

    // --- effect of the neighbour subtraction ---
    println!(
        "\nposition change between runs (ok fits in both), px: median / 95th percentile / max"
    );
    for (a, b) in [(0, 2), (1, 2), (2, 3)] {
        let mut d = Vec::new();
        for (fa, fb) in runs[a].1.iter().zip(&runs[b].1) {
            if fa.status.is_ok() && fb.status.is_ok() {
                d.push((fa.params.x0 - fb.params.x0).hypot(fa.params.y0 - fb.params.y0));
            }
        }
        let (m, p95) = (median(&mut d.clone()), percentile(&mut d.clone(), 0.95));
        let max = d.iter().cloned().fold(0.0, f64::max);
        println!(
            "  {} -> {}: {m:.5} / {p95:.5} / {max:.4}",
            runs[a].0, runs[b].0
        );
    }
    Ok(())
}

fn report(fits: &[DotFit], pkg: &[Vec<f64>]) {
    let mut counts = std::collections::BTreeMap::new();
    for f in fits {
        *counts.entry(f.status.as_str()).or_insert(0usize) += 1;
    }
    let n_flag = |fl: DotFlags| fits.iter().filter(|f| f.flags.contains(fl)).count();
    println!(
        "status {:?}; flags: border {}, masked {}, saturated {}, at_bound {}",
        counts,
        n_flag(DotFlags::BORDER),
        n_flag(DotFlags::MASKED),
        n_flag(DotFlags::SATURATED),
        n_flag(DotFlags::AT_BOUND)
    );
    let ok: Vec<&DotFit> = fits.iter().filter(|f| f.status.is_ok()).collect();
    let col = |g: &dyn Fn(&DotFit) -> f64| -> Vec<f64> { ok.iter().map(|f| g(f)).collect() };
    println!(
        "median sigma_x {:.3}, sigma_y {:.3}, rho {:.3}, amplitude {:.0}, background {:.0}, rms {:.1}, crlb_x {:.4}, crlb_y {:.4}, iterations {}",
        median(&mut col(&|f| f.params.sigma_x)),
        median(&mut col(&|f| f.params.sigma_y)),
        median(&mut col(&|f| f.params.rho)),
        median(&mut col(&|f| f.params.amplitude)),
        median(&mut col(&|f| f.params.background)),
        median(&mut col(&|f| f.rms)),
        median(&mut col(&|f| f.crlb_x)),
        median(&mut col(&|f| f.crlb_y)),
        median(&mut col(&|f| f.iterations as f64)),
    );
    // against the package (same order as the seeds)
    let mut d = Vec::new();
    let (mut dxs, mut dys, mut ds) = (Vec::new(), Vec::new(), Vec::new());
    for (f, p) in fits.iter().zip(pkg) {
        if f.status.is_ok() && f.status == FitStatus::Converged {
            let (dx, dy) = (f.params.x0 - p[0], f.params.y0 - p[1]);
            d.push(dx.hypot(dy));
            dxs.push(dx);
            dys.push(dy);
            // the package's diameters are clipped at its window; compare unclipped ones only
            if p[2] < 7.9 && p[3] < 7.9 {
                ds.push(f.params.sigma_x / (p[2] / 4.0));
            }
        }
    }
    println!(
        "vs package: |dpos| median {:.4} px, 95th pct {:.4} px; median dx {:+.4}, dy {:+.4}; median sigma_x / package (unclipped) {:.3}",
        median(&mut d.clone()),
        percentile(&mut d, 0.95),
        median(&mut dxs),
        median(&mut dys),
        median(&mut ds)
    );
}
