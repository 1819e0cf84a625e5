//! One run of the pair pipeline on a campaign, with its stage wall times: for profiling and
//! instruction counts (`valgrind --tool=callgrind`), where a criterion loop would be too long.
//!
//! `cargo run --release -p bostrack-pipeline --example pair_once -- [CONFIG] [fast|lm_crate] [pair|stack]`
//!
//! CONFIG defaults to `testdata/bos-sample.toml`. `pair`: no stack, displacement and AR only
//! (the reference side and one frame); `stack`: the configuration as written (with the no-flow
//! stack and the uncertainties).
//!
//! With `PAIR_ONCE_NO_FRAME` set it stops after the reference side: the instructions of one frame
//! are those of a run without it less those of a run with it (`valgrind --tool=callgrind`, one
//! thread), a count the machine's load does not disturb. With `PAIR_ONCE_FRAMES=N` the frame is
//! processed N times (a profile then shows mostly the frame's work; the best and the median of
//! the frames' CPU times are printed). With `PAIR_ONCE_POOL=N`
//! everything runs inside a rayon pool of N threads (`install`), as `run` does: no parallel
//! loop is then handed over from the main thread (whose wake-ups a profile of one thread
//! would otherwise show).

use bostrack_fit::Solver;
use bostrack_pipeline::{Plan, Quantities, ReferenceContext, load_config, process_frame};
use std::path::PathBuf;
use std::time::Instant;

type Res = Result<(), Box<dyn std::error::Error + Send + Sync>>;

fn main() -> Res {
    match std::env::var("PAIR_ONCE_POOL")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()?
            .install(run),
        None => run(),
    }
}

fn run() -> Res {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config = args.first().map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/bos-sample.toml")
    });
    let solver = match args.get(1).map(String::as_str) {
        None | Some("fast") => Solver::Fast,
        Some("lm_crate") => Solver::LmCrate,
        Some(s) => return Err(format!("unknown solver `{s}` (fast | lm_crate)").into()),
    };
    let with_stack = match args.get(2).map(String::as_str) {
        None | Some("pair") => false,
        Some("stack") => true,
        Some(s) => return Err(format!("unknown mode `{s}` (pair | stack)").into()),
    };
    let mut cfg = load_config(&config)?;
    cfg.fit.solver = solver;
    if !with_stack {
        cfg.input.stack_dir = "".into();
        cfg.output.quantities = Quantities::Amplification;
    }
    let plan = Plan::from_config(cfg, &config)?;
    let t = Instant::now();
    let ctx = ReferenceContext::prepare(&plan)?;
    if std::env::var_os("PAIR_ONCE_NO_FRAME").is_some() {
        return Ok(());
    }
    // (`PAIR_ONCE_FRAMES=N`: the frame N times, for a profile of the frame's work)
    let repeats: usize = std::env::var("PAIR_ONCE_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    // each frame's CPU time (of the calling thread: all of it with `PAIR_ONCE_POOL=1`)
    // (and its wall time: the thread CPU clock ticks in 4 ms steps on some machines)
    let (mut cpu, mut wall) = (Vec::with_capacity(repeats), Vec::with_capacity(repeats));
    for _ in 1..repeats {
        let (c, t0) = (thread_cpu(), Instant::now());
        process_frame(&ctx, &plan, &plan.gradients[0])?;
        wall.push(t0.elapsed().as_secs_f64());
        cpu.push(thread_cpu() - c);
    }
    let (c, t0) = (thread_cpu(), Instant::now());
    let r = process_frame(&ctx, &plan, &plan.gradients[0])?;
    wall.push(t0.elapsed().as_secs_f64());
    cpu.push(thread_cpu() - c);
    cpu.sort_by(f64::total_cmp);
    wall.sort_by(f64::total_cmp);
    println!(
        "total {:.3} s wall, {} threads",
        t.elapsed().as_secs_f64(),
        rayon::current_num_threads()
    );
    println!("reference stages: {:?}", ctx.timings().stages);
    println!("frame stages: {:?}", r.summary.times.stages);
    println!("counts: {:?}", r.summary.counts);
    println!(
        "frame CPU of the calling thread (ms): best {:.2}, median {:.2}; wall best {:.2}, \
         median {:.2} (of {})",
        1e3 * cpu[0],
        1e3 * cpu[cpu.len() / 2],
        1e3 * wall[0],
        1e3 * wall[wall.len() / 2],
        cpu.len()
    );
    Ok(())
}

/// CPU seconds of the calling thread (nanoseconds in /proc/thread-self/schedstat).
fn thread_cpu() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(f64::NAN, |ns| ns * 1e-9)
}
