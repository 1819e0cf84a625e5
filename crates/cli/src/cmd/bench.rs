//! `bostrack bench`: whole-tool benchmarks whose results are kept as CSV + figure + summary,
//! each with a record of the machine it ran on.
//!
//! - default mode: the error-against-time study of `bostrack_fit::study` (every estimator and
//!   model on synthetic scenes with known truth) → `error-vs-time.csv`, `.png`, `.svg`;
//! - `--real`: stage timings on the real sample (decode, noise, detection, fits with the fast
//!   solver and with the levenberg-marquardt crate, 1 thread against N threads) →
//!   `real-sample.csv`, `real-sample.md`;
//! - `--paper`: the paper's Monte Carlo (`bostrack_paper::run_study`, Fig. 5) at a chosen size
//!   → `paper-mc-<study>.csv`, `.png`, `.svg`, `paper-mc.md`.

use crate::Outcome;
use crate::jobs::{JobsArg, positive_up_to};
use anyhow::{Context as _, bail};
use bostrack_core::{DotFit, FitStatus};
use bostrack_figures::{AxisScale, Figure, RefLine, SeriesStyle, XyPlot, XySeries, xy_panels};
use bostrack_fit::study::{StudyConfig, StudyRow, error_vs_time, study_scenes, write_study_csv};
use bostrack_fit::{FitConfig, Solver, estimate_noise, fit_dots};
use clap::Args;
use std::fmt::Write as _;
use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::time::Instant;

const BENCH_LONG_ABOUT: &str = "\
Whole-tool benchmarks. Each mode prints a Markdown report that starts with a record of the
machine (CPU model, CPUs available, /proc/loadavg at the start and the end) and the date, and
writes its tables and figures into --out (created; files of the same name are replaced).

Default mode: the error-against-time study (bostrack_fit::study::error_vs_time). For every
scene (clean round dots of three sizes, a blurred elliptical dot, an undersampled dot, low SNR,
saturated dots, touching neighbours, the real sample's 8 px lattice) and every method (the
least-squares Gaussian with each solver, model, sampling and neighbour treatment; the
intensity-weighted centroid; the three-point Gaussian) it measures, over --realisations noise
realisations at random sub-pixel positions: the RMS position error, RMS / exact Cramér-Rao
bound, the bias with its standard error, the failure rate (a failed fit or an error above 1 px)
and the single-thread time per dot (fastest of 3 runs). Writes error-vs-time.csv (one row per
scene and method) and error-vs-time.png / .svg (RMS/bound against µs per dot, one panel per
scene). The study always times one thread; --jobs does not apply.

--real: timings on the real sample (bostrack_io::bos_sample_dir(), or --sample DIR): decoding
the 16-bit and 12-bit images and the mask, the noise estimate, detection (1 thread; µs per dot
and ms per megapixel), and the fits of all dots with the fast solver and with the
levenberg-marquardt crate in the same run (their ratio), and with the fast solver on --jobs
threads (default 2; its speed-up over 1 thread). Runs are interleaved and the best of --runs is
kept. Writes real-sample.csv and real-sample.md.

--paper: the paper's Monte Carlo (Rajendran, Bane & Vlachos 2020, Sec. 3, Fig. 5) through
bostrack_paper::run_study: --draws random setups, each dot ray-traced and fitted --realisations
times (default 1000 x 1000; a quick look needs ~30 x 200), for the volumetric and the BOS
configuration, on --jobs threads. Writes paper-mc-<study>.csv / .png / .svg and paper-mc.md.";

/// Whole-tool benchmarks with a record of the machine.
#[derive(Debug, Args)]
#[command(
    about = "Benchmarks: error against time per dot (default), real-sample timings (--real), the paper's Monte Carlo (--paper)",
    long_about = BENCH_LONG_ABOUT
)]
pub(crate) struct BenchArgs {
    /// Output folder (created; files of the same name are replaced).
    #[arg(
        short = 'o',
        long = "out",
        value_name = "DIR",
        default_value = "docs/benchmarks"
    )]
    out: PathBuf,
    /// Noise realisations: cells per scene of the error-vs-time study [default: 1000], or fits
    /// per draw with --paper [default: 1000].
    #[arg(long, value_name = "N", value_parser = positive_up_to::<1_000_000>)]
    realisations: Option<NonZeroUsize>,
    /// Seed of the random positions and noise.
    #[arg(long, value_name = "N", default_value_t = 1)]
    seed: u64,
    /// Scenes of the error-vs-time study, comma-separated [default: all; see --list-scenes].
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    scenes: Vec<String>,
    /// Print the scenes of the error-vs-time study and exit.
    #[arg(long)]
    list_scenes: bool,
    /// Time the stages on the real sample instead of running the study.
    #[arg(long, conflicts_with_all = ["paper", "scenes", "realisations"])]
    real: bool,
    /// Folder of the real sample (with pair/reference.tif, ref-stack/, mask.tif) [default:
    /// BOSTRACK_SAMPLE_DIR, else bostrack_io::bos_sample_dir()].
    #[arg(long, value_name = "DIR", requires = "real")]
    sample: Option<PathBuf>,
    /// With --real: timed runs of each stage; the best is kept.
    #[arg(long, value_name = "N", default_value = "3", requires = "real", value_parser = positive_up_to::<100>)]
    runs: NonZeroUsize,
    /// Run the paper's Monte Carlo (bostrack-paper) instead of the study.
    #[arg(long, conflicts_with = "scenes")]
    paper: bool,
    /// With --paper: random setups per study.
    #[arg(long, value_name = "N", default_value = "1000", requires = "paper", value_parser = positive_up_to::<1_000_000>)]
    draws: NonZeroUsize,
    #[command(flatten)]
    jobs: JobsArg,
}

pub(crate) fn run(args: BenchArgs) -> anyhow::Result<Outcome> {
    if args.list_scenes {
        for s in study_scenes() {
            println!("{:20} {}", s.name, s.description);
        }
        return Ok(Outcome::Done);
    }
    if args.real {
        run_real(&args)
    } else if args.paper {
        run_paper(&args)
    } else {
        run_study(&args)
    }
}

// ---------------------------------------------------------------------------------------------
// The machine record

/// The machine a benchmark ran on, and when.
#[derive(Debug)]
struct Machine {
    cpu: String,
    /// CPUs available to this process (affinity / cgroup quota).
    available: usize,
    /// `processor` lines of /proc/cpuinfo.
    online: usize,
    load_start: String,
    started: std::time::SystemTime,
    t0: Instant,
}

impl Machine {
    fn now() -> Machine {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let cpu = cpuinfo
            .lines()
            .find_map(|l| {
                let (k, v) = l.split_once(':')?;
                (k.trim() == "model name").then(|| v.trim().to_string())
            })
            .unwrap_or_else(|| "unknown CPU".to_string());
        let online = cpuinfo
            .lines()
            .filter(|l| l.split(':').next().is_some_and(|k| k.trim() == "processor"))
            .count();
        Machine {
            cpu,
            available: std::thread::available_parallelism().map_or(0, NonZeroUsize::get),
            online,
            load_start: loadavg(),
            started: std::time::SystemTime::now(),
            t0: Instant::now(),
        }
    }

    /// Markdown lines: date, version, command, machine, load at the start and now.
    fn record(&self) -> String {
        let command = std::env::args()
            .skip(1)
            .fold(String::from("bostrack"), |mut s, a| {
                s.push(' ');
                s.push_str(&a);
                s
            });
        format!(
            "- date: {} (UTC); bostrack {}\n- command: `{command}`\n- machine: {}, {} CPUs available to the process ({} in /proc/cpuinfo)\n- load average (/proc/loadavg 1, 5, 15 min): {} at the start, {} at the end; wall time {:.1} s\n",
            utc_string(self.started),
            env!("CARGO_PKG_VERSION"),
            self.cpu,
            self.available,
            self.online,
            self.load_start,
            loadavg(),
            self.t0.elapsed().as_secs_f64()
        )
    }
}

/// The three load averages of /proc/loadavg, or "unavailable".
fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unavailable".to_string())
}

/// `YYYY-MM-DD HH:MM` in UTC (civil date from days since 1970-01-01, proleptic Gregorian).
fn utc_string(t: std::time::SystemTime) -> String {
    let secs = t
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let (days, rem) = ((secs / 86_400) as i64, secs % 86_400);
    let (y, m, d) = civil_from_days(days);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}",
        rem / 3600,
        (rem % 3600) / 60
    )
}

/// Year, month, day of the day `z` days after 1970-01-01: the day count is shifted to start on
/// 0000-03-01 so that leap days fall at the end of a 400-year era of 146 097 days.
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468; // days from 0000-03-01 to 1970-01-01
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097); // day of the era, 0..146096
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365; // year of the era
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100); // day of the year from March 1
    let mp = (5 * doy + 2) / 153; // month from March = 0
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

fn create_dir(dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))
}

fn write_file(path: &Path, bytes: impl AsRef<[u8]>) -> anyhow::Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}

// ---------------------------------------------------------------------------------------------
// Error against time

fn run_study(args: &BenchArgs) -> anyhow::Result<Outcome> {
    let all = study_scenes();
    for s in &args.scenes {
        if !all.iter().any(|a| a.name == s) {
            bail!(
                "unknown scene `{s}` (known: {})",
                all.iter().map(|a| a.name).collect::<Vec<_>>().join(", ")
            );
        }
    }
    let scenes: Vec<_> = all
        .iter()
        .filter(|s| args.scenes.is_empty() || args.scenes.iter().any(|n| n == s.name))
        .collect();
    let realisations = args.realisations.map_or(1000, NonZeroUsize::get);
    create_dir(&args.out)?;
    let machine = Machine::now();
    let mut rows: Vec<StudyRow> = Vec::new();
    for (k, s) in scenes.iter().enumerate() {
        let t0 = Instant::now();
        // one scene at a time for progress; a scene's seed depends on its place in the full
        // list, so the rows are those of a single call over all scenes
        let cfg = StudyConfig {
            realisations,
            seed: args.seed,
            scenes: vec![s.name.to_string()],
        };
        let r = error_vs_time(&cfg).with_context(|| format!("scene {}", s.name))?;
        eprintln!(
            "[{}/{}] {}: {} methods x {realisations} dots in {:.1} s",
            k + 1,
            scenes.len(),
            s.name,
            r.len(),
            t0.elapsed().as_secs_f64()
        );
        rows.extend(r);
    }

    let csv_path = args.out.join("error-vs-time.csv");
    let mut csv = Vec::new();
    write_study_csv(&mut csv, &rows).context("formatting the study table")?;
    write_file(&csv_path, csv)?;
    let descriptions: Vec<(&str, &str)> = scenes.iter().map(|s| (s.name, s.description)).collect();
    let (png, svg) = study_figure(&rows, &descriptions)?;
    write_file(&args.out.join("error-vs-time.png"), png)?;
    write_file(&args.out.join("error-vs-time.svg"), svg)?;

    let mut report = String::new();
    report.push_str("# bostrack bench: error against time per dot\n\n");
    report.push_str(&machine.record());
    let _ = writeln!(
        report,
        "- {} scenes x {realisations} realisations, seed {}; time per dot: 1 thread, fastest of 3 runs\n",
        scenes.len(),
        args.seed
    );
    report.push_str(&study_table(&rows));
    print!("{report}");
    eprintln!(
        "wrote {}, error-vs-time.png, error-vs-time.svg",
        csv_path.display()
    );
    Ok(Outcome::Done)
}

/// The study as a Markdown table (the columns of docs/benchmarks/error-vs-time.md).
fn study_table(rows: &[StudyRow]) -> String {
    let mut t = String::from(
        "| scene | method | failure rate | RMS x (px) | RMS/bound x | RMS/bound y | bias x (px) | σx rel. bias | µs/dot |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let _ = writeln!(
            t,
            "| {} | {} | {:.3} | {:.4} | {:.3} | {:.3} | {:+.4} ± {:.4} | {:+.3} | {:.1} |",
            r.scene,
            r.method,
            r.failure_rate,
            r.rms_x,
            r.rms_over_bound_x,
            r.rms_over_bound_y,
            r.bias_x,
            r.bias_err_x,
            r.sigma_x_rel_bias,
            r.us_per_dot
        );
    }
    t
}

/// A short legend label: what differs from the default least-squares fit.
fn method_label(r: &StudyRow) -> String {
    match r.estimator.as_str() {
        "lsg" => {}
        "iwc" => return "IWC (intensity-weighted centroid)".to_string(),
        "tpg" => return "TPG (three-point Gaussian)".to_string(),
        other => return other.to_uppercase(),
    }
    let d = FitConfig::default();
    let mut diffs = Vec::new();
    if r.solver != d.solver.as_str() {
        diffs.push(match r.solver.as_str() {
            "lm_crate" => "levenberg-marquardt crate".to_string(),
            s => format!("{s} solver"),
        });
    }
    if r.model != d.model.as_str() {
        diffs.push(r.model.replace('_', "-"));
    }
    if r.sampling != d.sampling.as_str() {
        diffs.push(match r.sampling.as_str() {
            "point" => "point-sampled".to_string(),
            s => format!("{s} (pixel-integrated for every dot)"),
        });
    }
    if r.neighbours != format!("subtract{}", d.neighbour_passes) {
        diffs.push(match r.neighbours.strip_prefix("subtract") {
            Some(n) => format!("{n} subtraction passes"),
            None => "no neighbour subtraction".to_string(),
        });
    }
    if diffs.is_empty() {
        "LSG default (fast, elliptical, auto sampling, converged neighbour passes)".to_string()
    } else {
        format!("LSG, {}", diffs.join(", "))
    }
}

/// The combined RMS / bound of x and y, `sqrt((rx² + ry²) / 2)`; NaN when nothing was scored.
fn combined_ratio(r: &StudyRow) -> f64 {
    if r.failures >= r.dots {
        return f64::NAN;
    }
    (0.5 * (r.rms_over_bound_x.powi(2) + r.rms_over_bound_y.powi(2))).sqrt()
}

/// Scenes per column of the error-vs-time figure, and the height of one panel (px).
const PANELS_PER_COLUMN: usize = 3;
const PANEL_HEIGHT: u32 = 470;

/// The error-vs-time figure: one panel per scene (RMS/bound against µs per dot, x log, y log
/// where the ratios span more than a factor 4, one marker per method), panels in columns of three placed side by side. Returns PNG bytes
/// and an SVG document.
fn study_figure(rows: &[StudyRow], scenes: &[(&str, &str)]) -> anyhow::Result<(Vec<u8>, String)> {
    let mut panels = Vec::new();
    for (name, description) in scenes {
        let series: Vec<XySeries> = rows
            .iter()
            .filter(|r| r.scene == *name)
            .map(|r| {
                let mut label = method_label(r);
                if r.failure_rate >= 0.005 {
                    let _ = write!(label, " (fails {:.1} %)", 100.0 * r.failure_rate);
                }
                XySeries {
                    label,
                    points: vec![(r.us_per_dot, combined_ratio(r))],
                    style: SeriesStyle::Points,
                }
            })
            .collect();
        if series.is_empty() {
            continue;
        }
        // log y only where the ratios span a wide range (a narrow log range gets one tick)
        let ys = series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.1))
            .filter(|y| y.is_finite() && *y > 0.0);
        let (lo, hi) = ys.fold((f64::INFINITY, 0.0f64), |(a, b), y| (a.min(y), b.max(y)));
        let y_scale = if hi > 4.0 * lo {
            AxisScale::Log10
        } else {
            AxisScale::Linear
        };
        panels.push(XyPlot {
            title: format!("{name}: {description}"),
            x_label: "time per dot, 1 thread (µs)".to_string(),
            y_label: "RMS error / exact bound (x, y combined)".to_string(),
            x_scale: AxisScale::Log10,
            y_scale,
            series,
            ref_lines: vec![RefLine {
                y: 1.0,
                label: "Cramér-Rao bound".to_string(),
            }],
        });
    }
    if panels.is_empty() {
        bail!("the study produced no rows to plot");
    }
    let columns: Vec<&[XyPlot]> = panels.chunks(PANELS_PER_COLUMN).collect();
    let n = columns.len();
    let mut figures = Vec::new();
    for (k, col) in columns.iter().enumerate() {
        let title = if n == 1 {
            "Position error against time per dot".to_string()
        } else {
            format!("Position error against time per dot ({}/{n})", k + 1)
        };
        // every column as tall as a full one, so the panels line up
        let rows_here = if n == 1 { col.len() } else { PANELS_PER_COLUMN };
        let fig = xy_panels(&title, col)
            .with_context(|| format!("drawing {title}"))?
            .with_size(900, 80 + PANEL_HEIGHT * rows_here as u32)
            .with_context(|| format!("sizing {title}"))?;
        figures.push(fig);
    }
    side_by_side(&figures)
}

/// Renders the figures and places them side by side (top-aligned, white behind): one PNG and
/// one SVG (each figure's SVG nested at its offset).
fn side_by_side(figures: &[Figure]) -> anyhow::Result<(Vec<u8>, String)> {
    let width: u32 = figures.iter().map(|f| f.size().0).sum();
    let height: u32 = figures.iter().map(|f| f.size().1).max().unwrap_or(1);
    let mut canvas = image::RgbImage::from_pixel(width, height, image::Rgb([255, 255, 255]));
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width}\" height=\"{height}\" viewBox=\"0 0 {width} {height}\">\n<rect width=\"{width}\" height=\"{height}\" fill=\"white\"/>\n"
    );
    let mut x = 0u32;
    for f in figures {
        let png = f
            .to_png()
            .with_context(|| format!("rendering {}", f.title()))?;
        let img = image::load_from_memory(&png)
            .with_context(|| format!("decoding the PNG of {}", f.title()))?
            .to_rgb8();
        image::imageops::replace(&mut canvas, &img, i64::from(x), 0);
        let one = f
            .to_svg()
            .with_context(|| format!("rendering {}", f.title()))?;
        let start = one
            .find("<svg")
            .with_context(|| format!("no <svg> element in the SVG of {}", f.title()))?;
        svg.push_str(&format!("<svg x=\"{x}\" y=\"0\""));
        svg.push_str(&one[start + 4..]);
        svg.push('\n');
        x += f.size().0;
    }
    svg.push_str("</svg>\n");
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(
            canvas.as_raw(),
            width,
            height,
            image::ExtendedColorType::Rgb8,
        )
        .context("encoding the PNG")?;
    Ok((png, svg))
}

use image::ImageEncoder as _;

// ---------------------------------------------------------------------------------------------
// Real sample

/// Where the real sample is: --sample, else BOSTRACK_SAMPLE_DIR, else the project's default
/// (`bostrack_io::bos_sample_dir`, which is not asked when CI=true because it panics there).
fn sample_dir(given: Option<&Path>) -> anyhow::Result<PathBuf> {
    let dir = match given {
        Some(d) => d.to_path_buf(),
        None => match std::env::var_os("BOSTRACK_SAMPLE_DIR") {
            Some(d) => PathBuf::from(d),
            None if std::env::var("CI").is_ok_and(|v| v == "true") => {
                bail!("no real sample: give --sample DIR or set BOSTRACK_SAMPLE_DIR")
            }
            None => bostrack_io::bos_sample_dir().context(
                "the real sample was not found (give --sample DIR or set BOSTRACK_SAMPLE_DIR)",
            )?,
        },
    };
    for f in ["pair/reference.tif", "ref-stack/im_0001.tif", "mask.tif"] {
        if !dir.join(f).is_file() {
            bail!("{} is not the real sample: {f} is missing", dir.display());
        }
    }
    Ok(dir)
}

/// CPU time consumed so far by every thread of this process (s): the sum of the first field
/// (ns on the CPU) of /proc/self/task/*/schedstat; NaN where unavailable.
fn cpu_seconds() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return f64::NAN;
    };
    let mut ns = 0u64;
    for t in tasks.flatten() {
        let Ok(text) = std::fs::read_to_string(t.path().join("schedstat")) else {
            return f64::NAN;
        };
        match text
            .split_whitespace()
            .next()
            .and_then(|v| v.parse::<u64>().ok())
        {
            Some(v) => ns += v,
            None => return f64::NAN,
        }
    }
    ns as f64 * 1e-9
}

/// One timed run: wall time and the process's CPU time over it (s).
#[derive(Debug, Clone, Copy)]
struct Run {
    wall: f64,
    cpu: f64,
}

impl Run {
    /// Times `f`.
    fn of<T>(f: impl FnOnce() -> T) -> (T, Run) {
        let (c0, t0) = (cpu_seconds(), Instant::now());
        let v = f();
        let wall = t0.elapsed().as_secs_f64();
        (
            v,
            Run {
                wall,
                cpu: cpu_seconds() - c0,
            },
        )
    }
}

/// Repeated runs of one stage.
#[derive(Debug, Default, Clone)]
struct Times(Vec<Run>);

impl Times {
    /// The run with the shortest wall time.
    fn best_run(&self) -> Run {
        self.0
            .iter()
            .copied()
            .min_by(|a, b| a.wall.total_cmp(&b.wall))
            .unwrap_or(Run {
                wall: f64::NAN,
                cpu: f64::NAN,
            })
    }
    fn best(&self) -> f64 {
        self.best_run().wall
    }
    fn median(&self) -> f64 {
        bostrack_core::median(&mut self.0.iter().map(|r| r.wall).collect::<Vec<f64>>())
    }
}

/// Runs `f` `runs` times; the last result and the times.
fn timed<T>(runs: usize, mut f: impl FnMut() -> anyhow::Result<T>) -> anyhow::Result<(T, Times)> {
    let mut times = Times::default();
    let mut last = None;
    for _ in 0..runs.max(1) {
        let (v, r) = Run::of(&mut f);
        last = Some(v?);
        times.0.push(r);
    }
    Ok((last.context("no run")?, times))
}

/// One row of real-sample.csv.
#[derive(Debug)]
struct Stage {
    stage: &'static str,
    detail: String,
    threads: usize,
    times: Times,
    /// Dots the stage handled (detection: dots found; fits: dots fitted).
    dots: Option<usize>,
    megapixels: f64,
    /// Best time relative to the 1-thread fit with the fast solver.
    ratio: Option<f64>,
}

const REAL_COLUMNS: &str = "stage,detail,threads,runs,dots,megapixels,best_ms,median_ms,cpu_ms,us_per_dot,ms_per_megapixel,ratio_to_fast_1_thread";

impl Stage {
    /// CPU time of the best run (ms), for runs of at least 100 ms: the kernel's accounting
    /// can be as coarse as a scheduler tick (4 ms).
    fn cpu_ms(&self) -> Option<f64> {
        let r = self.times.best_run();
        (r.wall >= 0.1 && r.cpu.is_finite()).then_some(1e3 * r.cpu)
    }
    fn us_per_dot(&self) -> Option<f64> {
        self.dots
            .filter(|&n| n > 0)
            .map(|n| self.times.best() * 1e6 / n as f64)
    }
    /// One CSV line (the detail never holds a comma; any would be replaced by `;`).
    fn csv(&self) -> String {
        let opt = |v: Option<f64>, p: usize| v.map_or(String::new(), |v| format!("{v:.p$}"));
        format!(
            "{},{},{},{},{},{:.6},{:.3},{:.3},{},{},{:.3},{}",
            self.stage,
            self.detail.replace(',', ";"),
            self.threads,
            self.times.0.len(),
            self.dots.map_or(String::new(), |d| d.to_string()),
            self.megapixels,
            1e3 * self.times.best(),
            1e3 * self.times.median(),
            opt(self.cpu_ms(), 3),
            opt(self.us_per_dot(), 3),
            1e3 * self.times.best() / self.megapixels,
            opt(self.ratio, 4)
        )
    }
    fn markdown(&self) -> String {
        let opt = |v: Option<f64>, p: usize| v.map_or("–".to_string(), |v| format!("{v:.p$}"));
        format!(
            "| {} | {} | {} | {} | {:.2} | {:.2} | {} | {} | {:.2} | {} |",
            self.stage,
            self.detail,
            self.threads,
            self.dots.map_or("–".to_string(), |d| d.to_string()),
            1e3 * self.times.best(),
            1e3 * self.times.median(),
            opt(self.cpu_ms(), 2),
            opt(self.us_per_dot(), 2),
            1e3 * self.times.best() / self.megapixels,
            opt(self.ratio, 3)
        )
    }
}

fn pool(threads: usize) -> anyhow::Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("bostrack-bench-{i}"))
        .build()
        .with_context(|| format!("cannot start {threads} worker threads"))
}

fn run_real(args: &BenchArgs) -> anyhow::Result<Outcome> {
    let dir = sample_dir(args.sample.as_deref())?;
    let runs = args.runs.get();
    let threads = args.jobs.threads(2);
    create_dir(&args.out)?;
    let machine = Machine::now();
    let reference = dir.join("pair/reference.tif");
    let stack_image = dir.join("ref-stack/im_0001.tif");
    let mask_path = dir.join("mask.tif");
    let mut stages = Vec::new();

    // every 1-thread stage runs in a 1-thread pool (a library may use rayon inside)
    let one = pool(1)?;
    let many = pool(threads)?;
    let (image, t) = one.install(|| timed(runs, || Ok(bostrack_io::read_image(&reference)?)))?;
    let mp = (image.width() * image.height()) as f64 / 1e6;
    stages.push(Stage {
        stage: "decode",
        detail: "pair/reference.tif (16-bit PackBits)".into(),
        threads: 1,
        times: t,
        dots: None,
        megapixels: mp,
        ratio: None,
    });
    let (stack, t) = one.install(|| timed(runs, || Ok(bostrack_io::read_image(&stack_image)?)))?;
    stages.push(Stage {
        stage: "decode",
        detail: "ref-stack/im_0001.tif (12-bit packed)".into(),
        threads: 1,
        times: t,
        dots: None,
        megapixels: (stack.width() * stack.height()) as f64 / 1e6,
        ratio: None,
    });
    let (mask, t) = one.install(|| {
        timed(runs, || {
            Ok(bostrack_io::read_mask_for(
                &mask_path,
                image.width(),
                image.height(),
            )?)
        })
    })?;
    stages.push(Stage {
        stage: "decode",
        detail: "mask.tif (8-bit WhiteIsZero)".into(),
        threads: 1,
        times: t,
        dots: None,
        megapixels: mp,
        ratio: None,
    });

    let (noise, t) = one.install(|| {
        timed(runs, || {
            estimate_noise(&image, Some(&mask)).context("estimating the noise of the reference")
        })
    })?;
    stages.push(Stage {
        stage: "noise",
        detail: "estimate_noise (read + shot)".into(),
        threads: 1,
        times: t,
        dots: None,
        megapixels: mp,
        ratio: None,
    });
    let detect_cfg = bostrack_detect::DetectConfig::default();
    let (det, t) = one.install(|| {
        timed(runs, || {
            bostrack_detect::detect(&image, Some(&mask), &detect_cfg)
                .context("detecting the dots of the reference")
        })
    })?;
    let found = det.stats.found;
    stages.push(Stage {
        stage: "detect",
        detail: format!("detect ({} sites; {found} with a dot)", det.seeds.len()),
        threads: 1,
        times: t,
        dots: Some(found),
        megapixels: mp,
        ratio: None,
    });

    // fits: fast (1 thread), lm crate (1 thread), fast (N threads), interleaved so that a
    // change of load hits all three alike
    let fast = FitConfig::default();
    let lm = FitConfig {
        solver: Solver::LmCrate,
        ..FitConfig::default()
    };
    let fit = |cfg: &FitConfig, p: &rayon::ThreadPool| -> anyhow::Result<(Vec<DotFit>, Run)> {
        let (f, run) =
            Run::of(|| p.install(|| fit_dots(&image, Some(&mask), &det.seeds, cfg, &noise)));
        Ok((f.context("fitting the dots of the reference")?, run))
    };
    let (mut t_fast, mut t_lm, mut t_many) = (Times::default(), Times::default(), Times::default());
    let (mut fits_fast, mut fits_lm) = (Vec::new(), Vec::new());
    for k in 0..runs {
        eprintln!("fits: run {}/{runs}", k + 1);
        let (f, t) = fit(&fast, &one)?;
        fits_fast = f;
        t_fast.0.push(t);
        let (f, t) = fit(&lm, &one)?;
        fits_lm = f;
        t_lm.0.push(t);
        let (_, t) = fit(&fast, &many)?;
        t_many.0.push(t);
    }
    let fitted = fits_fast
        .iter()
        .filter(|f| f.status != FitStatus::NotFitted)
        .count();
    let base = t_fast.best();
    let (lm_ratio, many_ratio) = (t_lm.best() / base, t_many.best() / base);
    for (detail, th, times, ratio) in [
        ("fit_dots with the fast solver", 1, t_fast, 1.0),
        (
            "fit_dots with the levenberg-marquardt crate",
            1,
            t_lm,
            lm_ratio,
        ),
        ("fit_dots with the fast solver", threads, t_many, many_ratio),
    ] {
        stages.push(Stage {
            stage: "fit",
            detail: detail.into(),
            threads: th,
            times,
            dots: Some(fitted),
            megapixels: mp,
            ratio: Some(ratio),
        });
    }

    // agreement of the two solvers on the dots both fitted
    let (mut both, mut max_dx, mut max_rel_crlb) = (0usize, 0.0f64, 0.0f64);
    for (a, b) in fits_fast.iter().zip(&fits_lm) {
        if a.status.is_ok() && b.status.is_ok() {
            both += 1;
            let d = (a.params.x0 - b.params.x0)
                .abs()
                .max((a.params.y0 - b.params.y0).abs());
            max_dx = max_dx.max(d);
            if a.crlb_x > 0.0 {
                max_rel_crlb = max_rel_crlb.max(d / a.crlb_x);
            }
        }
    }
    let ok_fast = fits_fast.iter().filter(|f| f.status.is_ok()).count();
    let ok_lm = fits_lm.iter().filter(|f| f.status.is_ok()).count();

    let mut csv = String::from(REAL_COLUMNS);
    csv.push('\n');
    for s in &stages {
        csv.push_str(&s.csv());
        csv.push('\n');
    }
    let csv_path = args.out.join("real-sample.csv");
    write_file(&csv_path, &csv)?;

    let mut report = String::from("# bostrack bench --real: stage timings on the real sample\n\n");
    report.push_str(&machine.record());
    let _ = writeln!(
        report,
        "- sample: {} ({}x{} px, {:.3} MP); best and median of {runs} runs; fits interleaved (fast, lm crate, fast on {threads} threads) in each run\n",
        dir.display(),
        image.width(),
        image.height(),
        mp
    );
    report.push_str("| stage | detail | threads | dots | best (ms) | median (ms) | CPU of the best run (ms) | µs/dot | ms/MP | time / fast 1-thread fit |\n|---|---|---|---|---|---|---|---|---|---|\n");
    for s in &stages {
        report.push_str(&s.markdown());
        report.push('\n');
    }
    let single = stages
        .iter()
        .filter(|s| s.stage != "fit" || (s.threads == 1 && s.detail.ends_with("fast solver")))
        .filter(|s| !s.detail.starts_with("ref-stack"))
        .map(|s| s.times.best())
        .sum::<f64>();
    let cpu_of = |k: usize| {
        stages
            .iter()
            .filter(|s| s.stage == "fit")
            .nth(k)
            .map_or(f64::NAN, |s| s.times.best_run().cpu)
    };
    let _ = writeln!(
        report,
        "\n- levenberg-marquardt crate / fast solver, same run, 1 thread: **{lm_ratio:.2}x** the wall time, {:.2}x the CPU time",
        cpu_of(1) / cpu_of(0)
    );
    let best_many = stages
        .iter()
        .rfind(|s| s.stage == "fit")
        .map(|s| s.times.best_run());
    let _ = writeln!(
        report,
        "- fast solver on {threads} threads: speed-up **{:.2}x** over 1 thread (wall); its best run kept {:.2} CPUs busy on average (CPU time / wall time)",
        1.0 / many_ratio,
        best_many.map_or(f64::NAN, |r| r.cpu / r.wall)
    );
    if let Some(r) = best_many
        && threads > 1
        && r.cpu / r.wall < 0.8 * threads as f64
    {
        let _ = writeln!(
            report,
            "- **the machine did not give this process {threads} CPUs** (other load: see the load average): the speed-up above measures the load, not the code; compare the CPU times instead: 1 thread {:.0} ms, {threads} threads {:.0} ms (their difference is the cost of running in parallel)",
            1e3 * cpu_of(0),
            1e3 * r.cpu
        );
    }
    let _ = writeln!(
        report,
        "- usable fits: fast {ok_fast}, lm crate {ok_lm} of {fitted} fitted dots; on the {both} both fitted, the positions differ by at most {max_dx:.2e} px ({max_rel_crlb:.2e} of the dot's bound)"
    );
    let _ = writeln!(
        report,
        "- one image end to end on 1 thread (decode reference + mask, noise, detect, fast fits): {:.0} ms",
        1e3 * single
    );
    let _ = writeln!(
        report,
        "- noise model: read {:.2} counts, gain {:.4} counts per count above {:.1}",
        noise.read_variance.sqrt(),
        noise.gain,
        noise.offset
    );
    report.push_str(&format!(
        "\nColumns of real-sample.csv: {REAL_COLUMNS} (times of the best run; cpu_ms: CPU time of all the process's threads during that run, for runs of 100 ms or more; µs/dot over the dots found (detect) or fitted (fit); the last column is the best time over that of the 1-thread fast fit).\n"
    ));
    write_file(&args.out.join("real-sample.md"), &report)?;
    print!("{report}");
    eprintln!("wrote {} and real-sample.md", csv_path.display());
    Ok(Outcome::Done)
}

// ---------------------------------------------------------------------------------------------
// The paper's Monte Carlo

fn run_paper(args: &BenchArgs) -> anyhow::Result<Outcome> {
    use bostrack_paper::{StudyConfig as PaperConfig, fig5_figure, run_study, write_draws_csv};
    let realisations = args.realisations.map_or(1000, NonZeroUsize::get);
    let draws = args.draws.get();
    let threads = args.jobs.threads(0);
    create_dir(&args.out)?;
    let machine = Machine::now();
    let p = pool(threads)?;
    let mut results = Vec::new();
    for mut cfg in [
        PaperConfig::volumetric(draws, realisations),
        PaperConfig::bos(draws, realisations),
    ] {
        cfg.seed = args.seed;
        let name = cfg.name.clone();
        let r = p
            .install(|| run_study(&cfg))
            .with_context(|| format!("the paper's {name} study"))?;
        eprintln!(
            "{name}: {draws} draws x {realisations} realisations in {:.1} s on {} threads",
            r.wall_s, r.threads
        );
        let mut csv = Vec::new();
        write_draws_csv(&r.rows, &mut csv).context("formatting the draws")?;
        write_file(&args.out.join(format!("paper-mc-{name}.csv")), csv)?;
        let fig = fig5_figure(&r).with_context(|| format!("drawing the {name} figure"))?;
        write_file(
            &args.out.join(format!("paper-mc-{name}.png")),
            fig.to_png().context("rendering the PNG")?,
        )?;
        write_file(
            &args.out.join(format!("paper-mc-{name}.svg")),
            fig.to_svg().context("rendering the SVG")?,
        )?;
        results.push(r);
    }
    let mut report = String::from("# bostrack bench --paper: the paper's Monte Carlo (Fig. 5)\n\n");
    report.push_str(&machine.record());
    let _ = writeln!(
        report,
        "- {draws} draws x {realisations} realisations per study, seed {}, {threads} threads",
        args.seed
    );
    for r in &results {
        let _ = writeln!(
            report,
            "- {}: {:.1} s wall on {} threads",
            r.config.name, r.wall_s, r.threads
        );
    }
    report.push('\n');
    let mut table = Vec::new();
    bostrack_paper::write_study_markdown(&results.iter().collect::<Vec<_>>(), &mut table)
        .context("formatting the summary")?;
    report.push_str(&String::from_utf8_lossy(&table));
    write_file(&args.out.join("paper-mc.md"), &report)?;
    print!("{report}");
    eprintln!(
        "wrote paper-mc-*.csv, .png, .svg and paper-mc.md to {}",
        args.out.display()
    );
    Ok(Outcome::Done)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn civil_dates() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(59), (1970, 3, 1));
        // 2000-02-29 (a leap day of a year divisible by 400) is day 11 016
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
        assert_eq!(civil_from_days(11_017), (2000, 3, 1));
        // 2026-11-22 is 20 779 days after the epoch
        assert_eq!(civil_from_days(20_779), (2026, 11, 22));
        assert_eq!(civil_from_days(-1), (1969, 12, 31));
    }

    #[test]
    fn times_best_and_median() {
        let runs = |w: &[f64]| {
            Times(
                w.iter()
                    .map(|&wall| Run {
                        wall,
                        cpu: 2.0 * wall,
                    })
                    .collect(),
            )
        };
        let t = runs(&[3.0, 1.0, 2.0, 10.0]);
        assert_eq!(t.best(), 1.0);
        assert_eq!(t.best_run().cpu, 2.0);
        assert_eq!(t.median(), 2.5);
        assert_eq!(runs(&[4.0, 1.0, 2.0]).median(), 2.0);
    }

    #[test]
    fn real_sample_rows_have_every_column() {
        let s = Stage {
            stage: "fit",
            detail: "a, b".into(),
            threads: 2,
            times: Times(vec![Run {
                wall: 0.5,
                cpu: 0.9,
            }]),
            dots: Some(1000),
            megapixels: 1.0,
            ratio: Some(0.6),
        };
        let line = s.csv();
        assert_eq!(
            line.split(',').count(),
            REAL_COLUMNS.split(',').count(),
            "{line}"
        );
        assert_eq!(
            line,
            "fit,a; b,2,1,1000,1.000000,500.000,500.000,900.000,500.000,500.000,0.6000"
        );
        let quick = Stage {
            times: Times(vec![Run {
                wall: 0.01,
                cpu: 0.0,
            }]),
            dots: None,
            ratio: None,
            ..s
        };
        // no CPU time for short runs (coarse accounting), no per-dot time without dots
        assert_eq!(
            quick.csv(),
            "fit,a; b,2,1,,1.000000,10.000,10.000,,,10.000,"
        );
    }

    #[test]
    fn cpu_time_counts_busy_threads() {
        let (_, r) = Run::of(|| {
            let t0 = Instant::now();
            let mut x = 0u64;
            while t0.elapsed().as_secs_f64() < 0.05 {
                x = x.wrapping_add(std::hint::black_box(1));
            }
            x
        });
        assert!(r.wall >= 0.05);
        // a busy loop is on the CPU for most of its wall time (the machine may be shared);
        // with no /proc the CPU time is NaN
        assert!(
            r.cpu.is_nan() || (r.cpu > 0.005 && r.cpu <= r.wall * 1.5),
            "{r:?}"
        );
    }
}
