//! Frames per second per core of a campaign run, and the CPU time of one gradient frame of the
//! real sample (issue 17: "per gradient frame of the real sample (tracking, fits, matching,
//! validation, uncertainty; figures off) ≤ 60 ms of CPU, reported as frames per second per core
//! on a campaign of synthetic 1-MP frames").
//!
//! `cargo run --release -p bostrack-pipeline --example campaign_rate -- [--frames N] [--jobs 1,2] [--runs R] [--size PX] [--frame-map true|false]`
//!
//! (`--frame-map`: the real frame with `[fit] frame_map` set so, instead of the sample's
//! configuration's)
//!
//! 1. Writes a synthetic campaign into a temporary folder with `bostrack-synth`: a
//!    `--size`² reference (default 1024², 8 px square lattice, σ 1.25 px: 16,384 dots), a
//!    3-image no-flow stack and `--frames` gradient frames (default 16) of a vortex (largest
//!    displacement ~2 px), 16-bit TIFF.
//! 2. For each `--jobs` count: `run_batch` of the whole campaign (quantities "uncertainty",
//!    no figures, every frame recomputed), less the reference side (`ReferenceContext::prepare`
//!    timed alone on the same pool). Prints wall frames/s, CPU ms per frame (the process's
//!    user + system time from `/proc/self/stat`, what `getrusage(RUSAGE_SELF)` reports) and
//!    frames/s per core = 1000 / (CPU ms per frame). Best of `--runs` (default 2).
//! 3. With the real sample beside the repository (`testdata/bos-sample.toml`, its no-flow stack,
//!    figures off): one gradient frame (`process_frame` + `write_frame`) on a 1-thread pool,
//!    its CPU time (the pool thread's own run time from `/proc/thread-self/schedstat`,
//!    nanoseconds) and its stage times, best of `--runs`; the fit stage's share and the
//!    writing's own CPU apart; then the CPU of the stages the issue lists alone
//!    (`process_image` of the frame decoded beforehand, nothing written), best of `--runs`.
//!
//! CPU times do not grow with the machine's load the way wall times do (they still grow a
//! little with cache contention): on the shared 2-core machine read the CPU columns.

use bostrack_pipeline::{
    BatchOptions, Plan, ReferenceContext, Silent, load_config, process_frame, process_image,
    run_batch, write_frame,
};
use bostrack_synth::{DisplacementField, FlowConfig, Scene, SceneConfig, stack};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

type Res<T> = Result<T, Box<dyn std::error::Error + Send + Sync>>;

/// One run of the real frame: its CPU seconds, its stages' wall seconds, its writing's CPU.
type FrameRun = (f64, Vec<(String, f64)>, f64);

fn arg(name: &str) -> Option<String> {
    std::env::args().skip_while(|a| a != name).nth(1)
}

/// User + system CPU seconds of the whole process (all threads, finished ones included).
fn process_cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // fields after the command name in parentheses: state is field 3; utime 14, stime 15
    let rest = s.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // USER_HZ is 100 on every Linux (the unit of /proc's clock ticks)
    (ticks(11) + ticks(12)) / 100.0
}

/// CPU seconds of the calling thread (nanoseconds in /proc/thread-self/schedstat).
fn thread_cpu() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(f64::NAN, |ns| ns * 1e-9)
}

fn write_campaign(dir: &Path, size: usize, frames: usize) -> Res<PathBuf> {
    let mut scene = SceneConfig {
        width: size,
        height: size,
        ..SceneConfig::default()
    };
    scene.lattice.spacing = 8.0;
    scene.dots.sigma_x = 1.25;
    scene.dots.sigma_y = 1.25;
    scene.validate()?;
    let c = (size as f64 - 1.0) / 2.0;
    let flow = FlowConfig {
        displacement: DisplacementField::Vortex {
            centre: [c, c],
            strength: 20.0,
            core: 60.0,
        },
        ..FlowConfig::default()
    };
    flow.validate()?;
    std::fs::create_dir_all(dir.join("stack"))?;
    std::fs::create_dir_all(dir.join("gradient"))?;
    bostrack_io::write_tiff_u16(&dir.join("reference.tif"), &Scene::reference(&scene)?.image)?;
    for (k, img) in stack(&scene, 3)?.iter().enumerate() {
        bostrack_io::write_tiff_u16(&dir.join(format!("stack/noflow_{k:02}.tif")), img)?;
    }
    (1..=frames).into_par_iter().try_for_each(|n| -> Res<()> {
        let s = Scene::frame(&scene, &flow, n)?;
        bostrack_io::write_tiff_u16(&dir.join(format!("gradient/frame_{n:03}.tif")), &s.image)?;
        Ok(())
    })?;
    let cfg = dir.join("pipeline.toml");
    std::fs::write(
        &cfg,
        "[input]\ndir = \".\"\nreference = \"reference.tif\"\nstack_dir = \"stack\"\n\
         gradient_dir = \"gradient\"\n[detect]\nspacing = 8.0\n[output]\ndir = \"out\"\n\
         quantities = \"uncertainty\"\nfigures = []\noverwrite = true\n",
    )?;
    Ok(cfg)
}

fn main() -> Res<()> {
    let frames: usize = arg("--frames")
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(16);
    let size: usize = arg("--size")
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(1024);
    let runs: usize = arg("--runs").map(|s| s.parse()).transpose()?.unwrap_or(2);
    let jobs: Vec<usize> = arg("--jobs")
        .unwrap_or_else(|| "1,2".into())
        .split(',')
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let load = || {
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    };
    println!("load at the start: {}", load());

    let tmp = tempfile::tempdir()?;
    let t = Instant::now();
    let cfg = write_campaign(tmp.path(), size, frames)?;
    println!(
        "synthetic campaign: {size}x{size} px, 8 px lattice, sigma 1.25 px, 3 stack images, \
         {frames} frames of a vortex (written in {:.1} s)",
        t.elapsed().as_secs_f64()
    );
    let plan = Plan::load(&cfg)?;
    println!(
        "| jobs | frames/s (wall) | CPU ms per frame | frames/s per core (1000 / CPU ms) | reference side CPU s |"
    );
    println!("|---|---|---|---|---|");
    for &n in &jobs {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build()?;
        let (mut best_wall, mut best_cpu, mut best_ref) = (f64::INFINITY, f64::INFINITY, 0.0);
        for _ in 0..runs {
            let (wall, cpu, ref_cpu) = pool.install(|| -> Res<(f64, f64, f64)> {
                let c0 = process_cpu();
                let t0 = Instant::now();
                let ctx = ReferenceContext::prepare(&plan)?;
                let ref_wall = t0.elapsed().as_secs_f64();
                let ref_cpu = process_cpu() - c0;
                drop(ctx);
                let c1 = process_cpu();
                let t1 = Instant::now();
                let report = run_batch(
                    &plan,
                    &BatchOptions {
                        force: true,
                        ..BatchOptions::default()
                    },
                    &Silent,
                )?;
                let wall = t1.elapsed().as_secs_f64() - ref_wall;
                let cpu = process_cpu() - c1 - ref_cpu;
                if report.computed != frames {
                    return Err(format!(
                        "{} of {frames} frames computed ({} failed)",
                        report.computed,
                        report.failures.len()
                    )
                    .into());
                }
                Ok((wall, cpu, ref_cpu))
            })?;
            if cpu < best_cpu {
                (best_cpu, best_ref) = (cpu, ref_cpu);
            }
            best_wall = best_wall.min(wall);
        }
        let ms = 1e3 * best_cpu / frames as f64;
        println!(
            "| {n} | {:.2} | {ms:.0} | {:.2} | {best_ref:.2} |",
            frames as f64 / best_wall,
            1e3 / ms
        );
    }

    let sample_cfg =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/bos-sample.toml");
    if bostrack_io::bos_sample_dir().is_some() {
        let mut cfg = load_config(&sample_cfg)?;
        cfg.output.figures.clear();
        if let Some(v) = arg("--frame-map") {
            cfg.fit.frame_map = v.parse()?;
        }
        let plan = Plan::from_config(cfg, &sample_cfg)?;
        let out = tmp.path().join("real");
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
        let ctx = pool.install(|| ReferenceContext::prepare(&plan))?;
        let mut best: Option<FrameRun> = None;
        for _ in 0..runs.max(2) {
            let (cpu, stages, write_cpu) = pool.install(|| -> Res<FrameRun> {
                let c0 = thread_cpu();
                let t0 = Instant::now();
                let r = process_frame(&ctx, &plan, &plan.gradients[0])?;
                let t_frame = t0.elapsed().as_secs_f64();
                let (t1, c1) = (Instant::now(), thread_cpu());
                write_frame(&out, &r)?;
                let write_cpu = thread_cpu() - c1;
                let mut stages = r.summary.times.stages.clone();
                stages.push(("write".into(), t1.elapsed().as_secs_f64()));
                stages.push(("total".into(), t_frame + t1.elapsed().as_secs_f64()));
                Ok((thread_cpu() - c0, stages, write_cpu))
            })?;
            if best.as_ref().is_none_or(|b| cpu < b.0) {
                best = Some((cpu, stages, write_cpu));
            }
        }
        let (cpu, stages, write_cpu) = best.expect("at least one run");
        // the stages the issue lists alone (tracking, fits, matching, validation, uncertainty):
        // `process_image` of the frame decoded beforehand, nothing written
        let frame = &plan.gradients[0];
        let (img, _) = bostrack_io::read_image_clipped(frame, plan.config.input.saturation)?;
        let mut compute = f64::INFINITY;
        for _ in 0..runs.max(2) {
            let c = pool.install(|| -> Res<f64> {
                let c0 = thread_cpu();
                process_image(&ctx, &plan, &img, frame)?;
                Ok(thread_cpu() - c0)
            })?;
            compute = compute.min(c);
        }
        let wall = |k: &str| stages.iter().find(|s| s.0 == k).map_or(0.0, |s| s.1);
        let fit_share = wall("fit") / wall("total");
        println!(
            "\nreal sample, one gradient frame with its uncertainties (testdata/bos-sample.toml, \
             figures off), 1 thread, best of {}: CPU {:.0} ms (target 60 ms); fit stage {:.0} % \
             of the frame's wall time, so ~{:.0} ms CPU outside the fits",
            runs.max(2),
            1e3 * cpu,
            100.0 * fit_share,
            1e3 * cpu * (1.0 - fit_share)
        );
        let line: Vec<String> = stages
            .iter()
            .map(|(k, v)| format!("{k} {:.1}", 1e3 * v))
            .collect();
        println!(
            "the stages the issue lists alone (tracking, fits, matching, validation, uncertainty: \
             `process_image` of the decoded frame, nothing written), best of {}: CPU {:.0} ms",
            runs.max(2),
            1e3 * compute
        );
        println!("stage wall times (ms): {}", line.join(", "));
        println!(
            "writing the frame's files: {:.1} ms CPU of the frame's {:.0} (the rest of its wall \
             time waits for the disk)",
            1e3 * write_cpu,
            1e3 * cpu
        );
    }
    println!("load at the end: {}", load());
    Ok(())
}
