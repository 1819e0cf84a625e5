//! Error against run time: every estimator and model on synthetic scenes with known truth.
//!
//! Each scene is an image of many cells; a cell holds one dot (or a touching pair, or a 3×3
//! block of an 8 px lattice) at random sub-pixel positions, rendered pixel-integrated
//! (`bostrack_model::add_dot`) with Gaussian read noise. Seeds are the true centres rounded to
//! the nearest pixel (what detection delivers), windows `Window::centred(seed, half)`. Every
//! method fits the whole image with [`crate::fit_dots`] in a one-thread rayon pool, so the time
//! per dot is single-core and includes window extraction, the start and both passes of the
//! neighbour subtraction. The bound of each scored dot is the exact Cramér-Rao bound of the
//! 7-parameter pixel-integrated model over its window (`bostrack_model::crlb`, the dot alone,
//! saturated pixels left out) for the scenes of one dot, and the joint bound with the other dots
//! of its cell (their parameters unknown too; `crate::joint`, the fit's `crlb_x`) for the
//! `touching` and `lattice_8px` scenes, so `rms_over_bound` compares every method with the same
//! bound.

use crate::config::{Estimator, FitConfig, FitSampling, Neighbours, Solver};
use crate::{FitError, fit_dots};
use bostrack_core::{Gaussian2D, GridIndex, Image, ImageMeta, NoiseModel, Seed, Window};
use bostrack_model::{ModelKind, Sampling, add_dot, crlb_masked};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::time::Instant;

/// Size of the study.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StudyConfig {
    /// Cells (noise realisations) per scene (default 1000; a CI run can use ~50).
    pub realisations: usize,
    /// Seed of the random positions and noise (default 1).
    pub seed: u64,
    /// Scene names to run (default: empty = all, see [`study_scenes`]).
    pub scenes: Vec<String>,
}

impl Default for StudyConfig {
    fn default() -> Self {
        StudyConfig {
            realisations: 1000,
            seed: 1,
            scenes: Vec::new(),
        }
    }
}

/// One line of the study: one scene, one method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudyRow {
    pub scene: String,
    /// `estimator/solver/model/sampling/neighbours` for the least-squares fit (neighbours
    /// `none` or `subtract<passes>`), the estimator's name otherwise.
    pub method: String,
    pub estimator: String,
    pub model: String,
    pub sampling: String,
    pub solver: String,
    pub neighbours: String,
    /// Scored dots.
    pub dots: usize,
    /// Fits with a failure status or a position error above 1 px.
    pub failures: usize,
    pub failure_rate: f64,
    /// RMS position error of the successful fits (px).
    pub rms_x: f64,
    pub rms_y: f64,
    /// sqrt(mean((error / bound)²)).
    pub rms_over_bound_x: f64,
    pub rms_over_bound_y: f64,
    /// Mean position error (px) and its standard error.
    pub bias_x: f64,
    pub bias_y: f64,
    pub bias_err_x: f64,
    pub bias_err_y: f64,
    /// Mean exact bound (px).
    pub bound_x: f64,
    pub bound_y: f64,
    /// Mean relative error of σx (fitted / true - 1).
    pub sigma_x_rel_bias: f64,
    /// Single-core time per dot (µs), all dots of the image, the fastest of 3 runs.
    pub us_per_dot: f64,
}

/// Column names of [`write_study_csv`].
pub const STUDY_CSV_COLUMNS: &str = "scene,method,estimator,model,sampling,solver,neighbours,dots,failures,failure_rate,rms_x,rms_y,rms_over_bound_x,rms_over_bound_y,bias_x,bias_y,bias_err_x,bias_err_y,bound_x,bound_y,sigma_x_rel_bias,us_per_dot";

/// Writes the rows as CSV (header [`STUDY_CSV_COLUMNS`]).
pub fn write_study_csv(mut out: impl Write, rows: &[StudyRow]) -> std::io::Result<()> {
    // an unknown value (NaN: nothing scored) is the empty field, as in every table
    let f = |v: f64, decimals: usize| {
        if v.is_finite() {
            format!("{v:.decimals$}")
        } else {
            String::new()
        }
    };
    writeln!(out, "{STUDY_CSV_COLUMNS}")?;
    for r in rows {
        writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.scene,
            r.method,
            r.estimator,
            r.model,
            r.sampling,
            r.solver,
            r.neighbours,
            r.dots,
            r.failures,
            f(r.failure_rate, 4),
            f(r.rms_x, 6),
            f(r.rms_y, 6),
            f(r.rms_over_bound_x, 4),
            f(r.rms_over_bound_y, 4),
            f(r.bias_x, 6),
            f(r.bias_y, 6),
            f(r.bias_err_x, 6),
            f(r.bias_err_y, 6),
            f(r.bound_x, 6),
            f(r.bound_y, 6),
            f(r.sigma_x_rel_bias, 5),
            f(r.us_per_dot, 3),
        )?;
    }
    Ok(())
}

/// A scene of the study.
#[derive(Clone, Debug, PartialEq)]
pub struct StudyScene {
    pub name: &'static str,
    pub description: &'static str,
    sigma_x: f64,
    sigma_y: f64,
    rho: f64,
    amplitude: f64,
    background: f64,
    noise: f64,
    half: usize,
    layout: Layout,
    clip_12bit: bool,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Layout {
    Single,
    /// A second dot at this distance along x (not scored).
    Pair(f64),
    /// 3×3 dots at this pitch; the centre one is scored.
    Lattice(f64),
}

/// The scenes of the study.
pub fn study_scenes() -> Vec<StudyScene> {
    let base = StudyScene {
        name: "",
        description: "",
        sigma_x: 1.6,
        sigma_y: 1.6,
        rho: 0.0,
        amplitude: 1000.0,
        background: 100.0,
        noise: 20.0,
        half: 4,
        layout: Layout::Single,
        clip_12bit: false,
    };
    vec![
        StudyScene {
            name: "clean_s0.8",
            description: "round dot, sigma 0.8 px, peak SNR 50, 9x9",
            sigma_x: 0.8,
            sigma_y: 0.8,
            ..base.clone()
        },
        StudyScene {
            name: "clean_s1.6",
            description: "round dot, sigma 1.6 px, peak SNR 50, 9x9",
            ..base.clone()
        },
        StudyScene {
            name: "clean_s3.0",
            description: "round dot, sigma 3 px, peak SNR 50, 17x17",
            sigma_x: 3.0,
            sigma_y: 3.0,
            half: 8,
            ..base.clone()
        },
        StudyScene {
            name: "blurred_elliptical",
            description: "sigma 2.2 x 1.3 px, rho 0.6, peak SNR 40, 13x13",
            sigma_x: 2.2,
            sigma_y: 1.3,
            rho: 0.6,
            amplitude: 800.0,
            half: 6,
            ..base.clone()
        },
        StudyScene {
            name: "undersampled_s0.5",
            description: "round dot, sigma 0.5 px, peak SNR 50, 9x9",
            sigma_x: 0.5,
            sigma_y: 0.5,
            ..base.clone()
        },
        StudyScene {
            name: "low_snr",
            description: "round dot, sigma 1.6 px, peak SNR 5, 9x9",
            amplitude: 100.0,
            ..base.clone()
        },
        StudyScene {
            name: "saturated",
            description: "sigma 1.6 px, peak 6000 clipped at 4095 (12 bit), 9x9",
            amplitude: 6000.0,
            clip_12bit: true,
            ..base.clone()
        },
        StudyScene {
            name: "touching",
            description: "sigma 1.6 px with an equal neighbour 6.4 px (4 sigma) away in x, 9x9",
            layout: Layout::Pair(6.4),
            ..base.clone()
        },
        StudyScene {
            name: "lattice_8px",
            description: "3x3 dots at 8 px pitch, sigma 1.6 px, centre dot scored, 9x9 (the real sample's geometry)",
            layout: Layout::Lattice(8.0),
            ..base
        },
    ]
}

/// A method of the study.
#[derive(Clone, Debug)]
struct Method {
    cfg: FitConfig,
}

impl Method {
    fn name(&self) -> String {
        let c = &self.cfg;
        match c.estimator {
            Estimator::Lsg => format!(
                "lsg/{}/{}/{}/{}",
                c.solver.as_str(),
                c.model.as_str(),
                c.sampling.as_str(),
                neighbours_label(c)
            ),
            e => e.as_str().to_string(),
        }
    }
}

fn neighbours_name(n: Neighbours) -> &'static str {
    match n {
        Neighbours::None => "none",
        Neighbours::Subtract => "subtract",
    }
}

fn neighbours_label(c: &FitConfig) -> String {
    match c.neighbours {
        Neighbours::Subtract => format!("subtract{}", c.neighbour_passes),
        n => neighbours_name(n).to_string(),
    }
}

fn methods() -> Vec<Method> {
    let base = FitConfig {
        bound: false,
        ..FitConfig::default()
    };
    let mut m = vec![
        Method { cfg: base.clone() },
        Method {
            cfg: FitConfig {
                neighbours: Neighbours::None,
                ..base.clone()
            },
        },
        Method {
            cfg: FitConfig {
                sampling: FitSampling::Integrated,
                ..base.clone()
            },
        },
        Method {
            cfg: FitConfig {
                sampling: FitSampling::Point,
                ..base.clone()
            },
        },
        Method {
            cfg: FitConfig {
                model: ModelKind::AxisAligned,
                ..base.clone()
            },
        },
        Method {
            cfg: FitConfig {
                model: ModelKind::Circular,
                ..base.clone()
            },
        },
        Method {
            cfg: FitConfig {
                solver: Solver::LmCrate,
                ..base.clone()
            },
        },
        // the earlier default: two fixed neighbour passes
        Method {
            cfg: FitConfig {
                neighbour_passes: 2,
                ..base.clone()
            },
        },
    ];
    for e in [Estimator::Iwc, Estimator::Tpg] {
        m.push(Method {
            cfg: FitConfig {
                estimator: e,
                neighbours: Neighbours::None,
                ..base.clone()
            },
        });
    }
    m
}

/// A rendered scene: the image, the seeds, and for each scored dot (seed index, truth, bound).
struct Rendered {
    image: Image,
    seeds: Vec<Seed>,
    scored: Vec<(usize, Gaussian2D, [f64; 2])>,
}

fn render_scene(s: &StudyScene, n: usize, seed: u64) -> Rendered {
    let mut rng = StdRng::seed_from_u64(seed);
    let reach = (6.0 * s.sigma_x.max(s.sigma_y)).ceil() as usize;
    let extent = match s.layout {
        Layout::Single => 0.0,
        Layout::Pair(d) => d,
        Layout::Lattice(p) => 2.0 * p,
    };
    let cell = 2 * (s.half.max(reach)) + extent.ceil() as usize + 4;
    let cols = (n as f64).sqrt().ceil() as usize;
    let rows = n.div_ceil(cols);
    let (w, h) = (cols * cell, rows * cell);
    let mut data = vec![s.background; w * h];
    let mut seeds = Vec::new();
    let mut scored = Vec::new();
    // every dot of every cell (truth without background, window, first seed of its cell)
    let mut cell_dots: Vec<(Gaussian2D, Window, usize)> = Vec::new();
    let whole = Window::new(0, 0, w, h);
    for c in 0..n {
        let (cx, cy) = ((c % cols) * cell, (c / cols) * cell);
        let origin = (
            cx as f64 + 0.5 * (cell as f64 - extent),
            cy as f64 + 0.5 * cell as f64,
        );
        let mut dots = Vec::new();
        let first = seeds.len();
        match s.layout {
            Layout::Single => dots.push((0.0, 0.0, true)),
            Layout::Pair(d) => {
                dots.push((0.0, 0.0, true));
                dots.push((d, 0.0, false));
            }
            Layout::Lattice(p) => {
                for j in 0..3 {
                    for i in 0..3 {
                        dots.push((i as f64 * p, (j as f64 - 1.0) * p, i == 1 && j == 1));
                    }
                }
            }
        }
        for (dx, dy, score) in dots {
            let g = Gaussian2D {
                x0: origin.0 + dx + rng.random_range(-0.5..0.5),
                y0: origin.1 + dy + rng.random_range(-0.5..0.5),
                amplitude: s.amplitude,
                sigma_x: s.sigma_x,
                sigma_y: s.sigma_y,
                rho: s.rho,
                background: 0.0,
            };
            // draw only near the dot (6 sigma holds all but 1.5e-8 of it)
            let wnd = Window::centred(g.x0, g.y0, reach)
                .clip(w, h)
                .unwrap_or(whole);
            let mut patch = vec![0.0; wnd.len()];
            add_dot(&g, wnd, Sampling::Integrated, &mut patch);
            for j in 0..wnd.height {
                for i in 0..wnd.width {
                    data[(wnd.y as usize + j) * w + wnd.x as usize + i] += patch[j * wnd.width + i];
                }
            }
            let window = Window::centred(g.x0, g.y0, s.half);
            let centre = [g.x0.round(), g.y0.round()];
            cell_dots.push((g, window, first));
            if score {
                scored.push((
                    seeds.len(),
                    Gaussian2D {
                        background: s.background,
                        ..g
                    },
                    [0.0; 2],
                ));
            }
            seeds.push(Seed {
                index: GridIndex::new(seeds.len() as i32, 0),
                predicted: centre,
                centre,
                window,
                flags: bostrack_core::DotFlags::NONE,
            });
        }
    }
    for v in data.iter_mut() {
        let z: f64 = rng.sample(StandardNormal);
        *v += s.noise * z;
        if s.clip_12bit {
            *v = v.round().clamp(0.0, 4095.0);
        }
    }
    let meta = ImageMeta::synthetic(if s.clip_12bit { 12 } else { 64 });
    let image = Image::new(w, h, data, meta).expect("sizes match");
    // exact bound of each scored dot alone over its window, saturated pixels left out
    let noise = NoiseModel::read(s.noise);
    for (k, g, bound) in scored.iter_mut() {
        let win = seeds[*k].window;
        let img = &image;
        let keep = |x: i64, y: i64| {
            x >= 0
                && y >= 0
                && (x as usize) < w
                && (y as usize) < h
                && !img.is_saturated(img.get(x as usize, y as usize))
        };
        // the other dots of the cell: the joint bound of crate::joint (their parameters unknown
        // too), the dot alone otherwise
        let cell = cell_dots[*k].2;
        let others: Vec<crate::joint::JointDot> = cell_dots
            .iter()
            .enumerate()
            .filter(|(j, d)| *j != *k && d.2 == cell)
            .filter_map(|(_, (o, ow, _))| {
                let ow = ow.clip(w, h)?;
                crate::joint::JointDot::from_params(
                    &Gaussian2D {
                        background: s.background,
                        ..*o
                    },
                    ow,
                    crate::eval::Kind::Elliptical,
                )
            })
            .collect();
        let joint = (!others.is_empty())
            .then(|| {
                let dot = crate::joint::JointDot::from_params(
                    g,
                    win.clip(w, h)?,
                    crate::eval::Kind::Elliptical,
                )?;
                crate::joint::joint_bound(
                    crate::eval::Kind::Elliptical,
                    &dot,
                    &others,
                    &noise,
                    &keep,
                )
            })
            .flatten();
        *bound = joint.unwrap_or_else(|| {
            crlb_masked(
                g,
                win,
                &noise,
                Sampling::Integrated,
                ModelKind::Elliptical,
                &keep,
            )
            .map(|b| [b.std[0], b.std[1]])
            .unwrap_or([f64::NAN; 2])
        });
    }
    Rendered {
        image,
        seeds,
        scored,
    }
}

/// Runs the study: every scene of `cfg.scenes` (all if empty) with every method.
pub fn error_vs_time(cfg: &StudyConfig) -> Result<Vec<StudyRow>, FitError> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| FitError::InvalidConfig(format!("cannot build a one-thread pool: {e}")))?;
    let n = cfg.realisations.max(1);
    let mut rows = Vec::new();
    for (si, scene) in study_scenes().iter().enumerate() {
        if !cfg.scenes.is_empty() && !cfg.scenes.iter().any(|s| s == scene.name) {
            continue;
        }
        let r = render_scene(
            scene,
            n,
            cfg.seed.wrapping_mul(1000).wrapping_add(si as u64),
        );
        let noise = NoiseModel::read(scene.noise);
        for m in methods() {
            // the fastest of 3 runs (the machine may be shared)
            let mut best = f64::INFINITY;
            let mut fits = Vec::new();
            for _ in 0..3 {
                let t0 = Instant::now();
                fits = pool.install(|| fit_dots(&r.image, None, &r.seeds, &m.cfg, &noise))?;
                best = best.min(t0.elapsed().as_secs_f64());
            }
            let us = best * 1e6 / r.seeds.len() as f64;
            rows.push(score(scene, &m, &r, &fits, us));
        }
    }
    Ok(rows)
}

fn score(
    scene: &StudyScene,
    m: &Method,
    r: &Rendered,
    fits: &[bostrack_core::DotFit],
    us: f64,
) -> StudyRow {
    let mut failures = 0usize;
    let (mut ex, mut ey, mut ex2, mut ey2, mut nx2, mut ny2, mut bx, mut by, mut sig) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut ok = 0usize;
    for (k, g, bound) in &r.scored {
        let f = &fits[*k];
        let (dx, dy) = (f.params.x0 - g.x0, f.params.y0 - g.y0);
        if !(f.status.is_ok() && dx.abs() <= 1.0 && dy.abs() <= 1.0) {
            failures += 1;
            continue;
        }
        ok += 1;
        ex += dx;
        ey += dy;
        ex2 += dx * dx;
        ey2 += dy * dy;
        nx2 += (dx / bound[0]).powi(2);
        ny2 += (dy / bound[1]).powi(2);
        bx += bound[0];
        by += bound[1];
        sig += f.params.sigma_x / g.sigma_x - 1.0;
    }
    let nf = ok.max(1) as f64;
    let (mx, my) = (ex / nf, ey / nf);
    let sdx = (ex2 / nf - mx * mx).max(0.0).sqrt();
    let sdy = (ey2 / nf - my * my).max(0.0).sqrt();
    let c = &m.cfg;
    let lsg = c.estimator == Estimator::Lsg;
    StudyRow {
        scene: scene.name.to_string(),
        method: m.name(),
        estimator: c.estimator.as_str().to_string(),
        model: if lsg { c.model.as_str() } else { "-" }.to_string(),
        sampling: c.sampling.as_str().to_string(),
        solver: if lsg { c.solver.as_str() } else { "-" }.to_string(),
        neighbours: neighbours_label(c),
        dots: r.scored.len(),
        failures,
        failure_rate: failures as f64 / r.scored.len().max(1) as f64,
        rms_x: (ex2 / nf).sqrt(),
        rms_y: (ey2 / nf).sqrt(),
        rms_over_bound_x: (nx2 / nf).sqrt(),
        rms_over_bound_y: (ny2 / nf).sqrt(),
        bias_x: mx,
        bias_y: my,
        bias_err_x: sdx / nf.sqrt(),
        bias_err_y: sdy / nf.sqrt(),
        bound_x: bx / nf,
        bound_y: by / nf,
        sigma_x_rel_bias: sig / nf,
        us_per_dot: us,
    }
}

/// One accuracy case: a single dot at random sub-pixel positions in its window, with Gaussian
/// read noise, fitted with `fit`.
#[derive(Clone, Debug, PartialEq)]
pub struct AccuracyCase {
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
    /// Peak height above background (counts); background 100.
    pub amplitude: f64,
    /// Read-noise standard deviation (counts).
    pub noise: f64,
    /// Window half size (window 2·half+1 square).
    pub half: usize,
    /// How the data are rendered.
    pub render: Sampling,
    pub fit: FitConfig,
}

/// What [`accuracy`] measures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AccuracyResult {
    pub realisations: usize,
    pub failures: usize,
    pub rms_x: f64,
    pub rms_y: f64,
    /// sqrt(mean((error / exact bound)²)); its statistical standard error is about
    /// `value / sqrt(2 n)`.
    pub rms_over_bound_x: f64,
    pub rms_over_bound_y: f64,
    pub bias_x: f64,
    pub bias_y: f64,
    /// Standard errors of the biases.
    pub bias_err_x: f64,
    pub bias_err_y: f64,
    pub mean_iterations: f64,
}

/// Monte Carlo of one [`AccuracyCase`]: `n` noise realisations, each at a new uniformly random
/// sub-pixel position; the bound is the exact 7-parameter bound of the rendered model
/// (`bostrack_model::crlb`, sampling `case.render`) over the window at the truth. Fits start
/// from the window centre (the seed rounded to a pixel).
pub fn accuracy(case: &AccuracyCase, n: usize, seed: u64) -> AccuracyResult {
    let mut rng = StdRng::seed_from_u64(seed);
    let side = 2 * case.half + 1;
    let w = Window::new(0, 0, side, side);
    let noise = NoiseModel::read(case.noise);
    let mut fitter = crate::Fitter::new(&case.fit);
    let c = case.half as f64;
    let (mut ex, mut ey, mut ex2, mut ey2, mut nx, mut ny, mut it) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut failures = 0;
    let mut values = vec![0.0; w.len()];
    for _ in 0..n {
        let g = Gaussian2D {
            x0: c + rng.random_range(-0.5..0.5),
            y0: c + rng.random_range(-0.5..0.5),
            amplitude: case.amplitude,
            sigma_x: case.sigma_x,
            sigma_y: case.sigma_y,
            rho: case.rho,
            background: 100.0,
        };
        values.iter_mut().for_each(|v| *v = g.background);
        add_dot(&g, w, case.render, &mut values);
        for v in values.iter_mut() {
            let z: f64 = rng.sample(StandardNormal);
            *v += case.noise * z;
        }
        let b = bostrack_model::crlb(&g, w, &noise, case.render, ModelKind::Elliptical)
            .map(|b| [b.std[0], b.std[1]])
            .unwrap_or([f64::NAN; 2]);
        let s = crate::WindowSamples {
            window: w,
            values: &values,
            keep: None,
            saturation: None,
        };
        let f = fitter.fit_samples(&s, [c, c], None, &noise);
        let (dx, dy) = (f.params.x0 - g.x0, f.params.y0 - g.y0);
        if !(f.status.is_ok() && dx.abs() < 1.0 && dy.abs() < 1.0) {
            failures += 1;
            continue;
        }
        ex += dx;
        ey += dy;
        ex2 += dx * dx;
        ey2 += dy * dy;
        nx += (dx / b[0]).powi(2);
        ny += (dy / b[1]).powi(2);
        it += f.iterations as f64;
    }
    let k = (n - failures).max(1) as f64;
    let (mx, my) = (ex / k, ey / k);
    AccuracyResult {
        realisations: n,
        failures,
        rms_x: (ex2 / k).sqrt(),
        rms_y: (ey2 / k).sqrt(),
        rms_over_bound_x: (nx / k).sqrt(),
        rms_over_bound_y: (ny / k).sqrt(),
        bias_x: mx,
        bias_y: my,
        bias_err_x: ((ex2 / k - mx * mx).max(0.0) / k).sqrt(),
        bias_err_y: ((ey2 / k - my * my).max(0.0) / k).sqrt(),
        mean_iterations: it / k,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_names_are_unique_and_csv_has_all_columns() {
        let s = study_scenes();
        let mut names: Vec<_> = s.iter().map(|s| s.name).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), s.len());
        let rows = error_vs_time(&StudyConfig {
            realisations: 4,
            seed: 3,
            scenes: vec!["clean_s1.6".into()],
        })
        .unwrap();
        assert_eq!(rows.len(), methods().len());
        let mut out = Vec::new();
        write_study_csv(&mut out, &rows).unwrap();
        let text = String::from_utf8(out).unwrap();
        let n_cols = STUDY_CSV_COLUMNS.split(',').count();
        for line in text.lines() {
            assert_eq!(line.split(',').count(), n_cols, "{line}");
        }
    }
}
