//! The parts of the pair pipeline on the real sample, each timed alone (best of `--runs`,
//! default 5) on the rayon pool of `RAYON_NUM_THREADS`: where the time of `pair/fast` goes and
//! what the alternatives cost; plus two diagnostics of the fits.
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p bostrack-pipeline --example pair_parts -- [--runs N] [--only PART]`
//!
//! `--no-mask` runs every stage without the sample's region of interest. PART (default: all): `noise`, `fit0`..`fit3` (`fit_dots` of the reference with 0..3
//! neighbour passes; 0 = no neighbour model), `iwc`, `refit` (the gradient fitted in one pass
//! from the reference fits moved by each dot's tracked displacement, as the no-flow stack is),
//! `fitgrad` (`fit_dots` of the gradient), and the diagnostics `passes` (reference positions
//! after the default 2 neighbour passes against 4, in units of the bound, inside and outside
//! the flow region, and the 12 dots that differ most) and `start` (the moment estimates against
//! the least-squares fits: how far the first pass starts from its solution). Decoding,
//! detection and tracking are always timed. For instruction counts run one part under
//! `valgrind --tool=callgrind` with `--runs 1`.

use bostrack_core::Image;
use bostrack_fit::{FitConfig, Neighbours, estimate_noise, fit_dots, refit_dots};
use bostrack_io::{bos_sample_dir, read_image, read_mask_for};
use std::time::Instant;

fn best<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut t_best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs {
        let t = Instant::now();
        let v = f();
        t_best = t_best.min(t.elapsed().as_secs_f64());
        out = Some(v);
    }
    (t_best * 1e3, out.expect("runs >= 1"))
}

fn stats(name: &str, a: &[bostrack_core::DotFit], b: &[bostrack_core::DotFit], flow: bool) {
    let mut d: Vec<f64> = a
        .iter()
        .zip(b)
        .filter(|(x, y)| x.status.is_ok() && y.status.is_ok())
        .filter(|(x, _)| {
            let inside =
                (700.0..=860.0).contains(&x.params.y0) && (380.0..=640.0).contains(&x.params.x0);
            inside == flow
        })
        .map(|(x, y)| {
            ((x.params.x0 - y.params.x0) / y.crlb_x)
                .abs()
                .max(((x.params.y0 - y.params.y0) / y.crlb_y).abs())
        })
        .collect();
    d.sort_by(f64::total_cmp);
    let q = |p: f64| d[((d.len() - 1) as f64 * p) as usize];
    println!(
        "{name:32} {} n {:6}  |d|/bound median {:.4} p90 {:.4} p99 {:.4} max {:.4}",
        if flow { "flow" } else { "rest" },
        d.len(),
        q(0.5),
        q(0.9),
        q(0.99),
        q(1.0)
    );
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Some(dir) = bos_sample_dir() else {
        eprintln!("no ../shared/data/bos-sample");
        return Ok(());
    };
    let runs = std::env::args()
        .skip_while(|a| a != "--runs")
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(5);
    let only: Option<String> = std::env::args().skip_while(|a| a != "--only").nth(1);
    let want = |name: &str| only.as_deref().is_none_or(|o| o == name);
    println!("rayon threads {}", rayon::current_num_threads());
    let (t, reference) = best(runs, || read_image(&dir.join("pair/reference.tif")));
    let reference: Image = reference?;
    println!("decode reference      {t:7.2} ms");
    let (w, h) = (reference.width(), reference.height());
    let (t, mask) = best(runs, || read_mask_for(&dir.join("mask.tif"), w, h));
    let mask = mask?;
    // `--no-mask`: every stage without the region of interest
    let no_mask = std::env::args().any(|a| a == "--no-mask");
    let roi = (!no_mask).then_some(&mask);
    println!("decode mask           {t:7.2} ms");
    let (t, gradient) = best(runs, || read_image(&dir.join("pair/gradient.tif")));
    let gradient = gradient?;
    println!("decode gradient       {t:7.2} ms");
    let (t, noise) = best(if want("noise") { runs } else { 1 }, || {
        estimate_noise(&reference, roi)
    });
    let noise = noise?;
    println!("noise (one image)     {t:7.2} ms");
    let dcfg = bostrack_detect::DetectConfig {
        spacing: Some(8.0),
        diameter: Some(6.5),
        ..Default::default()
    };
    let (t, det) = best(runs, || bostrack_detect::detect(&reference, roi, &dcfg));
    let det = det?;
    println!("detect                {t:7.2} ms");
    let (t, tracked) = best(runs, || bostrack_detect::track(&gradient, roi, &det, &dcfg));
    let tracked = tracked?;
    println!("track                 {t:7.2} ms");
    let n = det.seeds.len() as f64;
    let cfg = FitConfig::default();
    for passes in [0u32, 1, 2, 3] {
        if !want(&format!("fit{passes}")) {
            continue;
        }
        let c = FitConfig {
            neighbour_passes: passes,
            neighbours: if passes == 0 {
                Neighbours::None
            } else {
                Neighbours::Subtract
            },
            ..cfg.clone()
        };
        let (t, fits) = best(runs, || fit_dots(&reference, roi, &det.seeds, &c, &noise));
        let fits = fits?;
        println!(
            "fit_dots passes {passes}     {t:7.2} ms  {:.2} us/dot, {:.2} iterations/dot (last pass)",
            t * 1e3 / n,
            fits.iter().map(|f| f.iterations as f64).sum::<f64>() / n
        );
    }
    let iwc = FitConfig {
        estimator: bostrack_fit::Estimator::Iwc,
        bound: false,
        ..cfg.clone()
    };
    if want("iwc") {
        let (t, fits) = best(runs, || fit_dots(&reference, roi, &det.seeds, &iwc, &noise));
        // a digest of the estimates (Debug prints each f64 so that it reads back to the same
        // bits): to check that a change leaves them alone
        let mut hasher = std::hash::DefaultHasher::new();
        for f in fits? {
            std::hash::Hash::hash(&format!("{:?}", f.params), &mut hasher);
        }
        let digest = std::hash::Hasher::finish(&hasher);
        println!(
            "iwc                   {t:7.2} ms  {:.2} us/dot, digest {digest:016x}",
            t * 1e3 / n
        );
    }
    if !(want("refit")
        || want("stack")
        || want("fitgrad")
        || want("start")
        || want("passes")
        || want("sequence")
        || want("tolerance"))
    {
        return Ok(());
    }
    let ref_fits = fit_dots(&reference, roi, &det.seeds, &cfg, &noise)?;
    // the gradient from the reference fits, each moved by its own tracked displacement
    let prior: Vec<_> = ref_fits
        .iter()
        .zip(det.seeds.iter().zip(&tracked.seeds))
        .map(|(f, (r, g))| {
            let mut p = *f;
            p.params.x0 += g.centre[0] - r.centre[0];
            p.params.y0 += g.centre[1] - r.centre[1];
            p
        })
        .collect();
    if want("refit") {
        let (t, _) = best(runs, || {
            refit_dots(&gradient, roi, &tracked.seeds, &cfg, &noise, &prior, None)
        });
        println!(
            "refit gradient        {t:7.2} ms  {:.2} us/dot",
            t * 1e3 / n
        );
        let (refit, report) = bostrack_fit::refit_dots_report(
            &gradient,
            roi,
            &tracked.seeds,
            &cfg,
            &noise,
            &prior,
            None,
        )?;
        println!(
            "  passes {} refits {:?} converged {} unconverged {}",
            report.passes, report.refits, report.converged, report.unconverged
        );
        let direct = fit_dots(&gradient, roi, &tracked.seeds, &cfg, &noise)?;
        let deep = fit_dots(
            &gradient,
            roi,
            &tracked.seeds,
            &FitConfig {
                tolerance: 0.005,
                neighbour_tolerance: 0.01,
                ..cfg.clone()
            },
            &noise,
        )?;
        for flow in [false, true] {
            stats("refit vs fit_dots (gradient)", &refit, &direct, flow);
            stats("refit vs deep (gradient)", &refit, &deep, flow);
            stats("fit_dots vs deep (gradient)", &direct, &deep, flow);
        }
    }
    if want("stack") {
        // one no-flow image fitted as the pipeline fits the stack: from the reference fits
        // moved by the median tracked shift, then the neighbour iteration
        let img = read_image(&dir.join("ref-stack/im_0001.tif"))?;
        let tr = bostrack_detect::track(&img, roi, &det, &dcfg)?;
        let mut dx: Vec<f64> = det
            .seeds
            .iter()
            .zip(&tr.seeds)
            .map(|(r, g)| g.centre[0] - r.centre[0])
            .collect();
        let mut dy: Vec<f64> = det
            .seeds
            .iter()
            .zip(&tr.seeds)
            .map(|(r, g)| g.centre[1] - r.centre[1])
            .collect();
        let shift = [
            bostrack_core::median(&mut dx),
            bostrack_core::median(&mut dy),
        ];
        let prior: Vec<_> = ref_fits
            .iter()
            .map(|f| {
                let mut p = *f;
                p.params.x0 += shift[0];
                p.params.y0 += shift[1];
                p
            })
            .collect();
        let (t, _) = best(runs, || {
            refit_dots(&img, roi, &tr.seeds, &cfg, &noise, &prior, None)
        });
        println!(
            "refit stack image     {t:7.2} ms  {:.2} us/dot",
            t * 1e3 / n
        );
        let (_, report) =
            bostrack_fit::refit_dots_report(&img, roi, &tr.seeds, &cfg, &noise, &prior, None)?;
        println!(
            "  passes {} refits {:?} converged {} unconverged {}",
            report.passes, report.refits, report.converged, report.unconverged
        );
    }
    if want("passes") || want("sequence") {
        // every dot refitted `passes` times
        let with = |passes: u32| {
            fit_dots(
                &reference,
                roi,
                &det.seeds,
                &FitConfig {
                    neighbour_passes: passes,
                    ..cfg.clone()
                },
                &noise,
            )
        };
        let deep = with(8)?;
        for passes in [1u32, 2, 3, 4, 6] {
            let fits = with(passes)?;
            for flow in [false, true] {
                stats(&format!("{passes} passes vs 8"), &fits, &deep, flow);
            }
            if passes == 2 {
                // without the dots next to the region of interest's edge
                let inner = |f: &[bostrack_core::DotFit]| -> Vec<bostrack_core::DotFit> {
                    f.iter()
                        .map(|d| {
                            let mut d = *d;
                            if d.flags.contains(bostrack_core::DotFlags::ROI_EDGE) {
                                d.status = bostrack_core::FitStatus::NotFitted;
                            }
                            d
                        })
                        .collect()
                };
                stats("2 passes vs 8, no roi_edge", &inner(&fits), &deep, false);
            }
        }
        if want("sequence") {
            let seq: Vec<Vec<bostrack_core::DotFit>> =
                (1..=8).map(with).collect::<Result<_, _>>()?;
            for (k, s) in det.seeds.iter().enumerate() {
                // the lattice's top row inside the region of interest (rows from 32), left part
                if (35.0..40.0).contains(&s.centre[1]) && (40.0..=80.0).contains(&s.centre[0]) {
                    let xs: Vec<String> = seq
                        .iter()
                        .map(|f| {
                            format!(
                                "{:+.3}",
                                (f[k].params.y0 - deep[k].params.y0) / deep[k].crlb_y
                            )
                        })
                        .collect();
                    let ss: Vec<String> = seq
                        .iter()
                        .map(|f| format!("{:.4}", f[k].params.sigma_y))
                        .collect();
                    println!(
                        "{:?} dy/bound {} | sigma_y {}",
                        s.index,
                        xs.join(" "),
                        ss.join(" ")
                    );
                }
            }
        }
        let mut worst: Vec<(f64, usize)> = ref_fits
            .iter()
            .zip(&deep)
            .enumerate()
            .filter(|(_, (x, y))| x.status.is_ok() && y.status.is_ok())
            .map(|(k, (x, y))| {
                (
                    ((x.params.x0 - y.params.x0) / y.crlb_x)
                        .abs()
                        .max(((x.params.y0 - y.params.y0) / y.crlb_y).abs()),
                    k,
                )
            })
            .collect();
        worst.sort_by(|a, b| b.0.total_cmp(&a.0));
        for &(d, k) in worst.iter().take(12) {
            let (a, b) = (&ref_fits[k], &deep[k]);
            println!(
                "{d:.3} {:?} x {:.2} y {:.2} sx {:.3}/{:.3} sy {:.3}/{:.3} rho {:.3}/{:.3} amp {:.0}/{:.0} flags {:?} win {:?}",
                a.index,
                a.params.x0,
                a.params.y0,
                a.params.sigma_x,
                b.params.sigma_x,
                a.params.sigma_y,
                b.params.sigma_y,
                a.params.rho,
                b.params.rho,
                a.params.amplitude,
                b.params.amplitude,
                a.flags,
                det.seeds[k].window
            );
        }
    }
    if want("tolerance") {
        let with = |tolerance: f64| {
            fit_dots(
                &reference,
                roi,
                &det.seeds,
                &FitConfig {
                    tolerance,
                    ..cfg.clone()
                },
                &noise,
            )
        };
        let tight = with(1e-3)?;
        for tol in [0.05, 0.1, 0.2, 0.3, 0.5, 1.0] {
            let (t, fits) = best(runs, || with(tol));
            let fits = fits?;
            for flow in [false, true] {
                stats(
                    &format!("tolerance {tol} vs 1e-3 ({t:.0} ms)"),
                    &fits,
                    &tight,
                    flow,
                );
            }
        }
    }
    if want("start") {
        let iwc_fits = fit_dots(&reference, roi, &det.seeds, &iwc, &noise)?;
        let mut r = [
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
        ];
        for (a, b) in iwc_fits.iter().zip(&ref_fits) {
            if !(a.status.is_ok() && b.status.is_ok()) {
                continue;
            }
            r[0].push((a.params.x0 - b.params.x0) / b.crlb_x);
            r[1].push(a.params.sigma_x / b.params.sigma_x);
            r[2].push(a.params.sigma_y / b.params.sigma_y);
            r[3].push(a.params.rho - b.params.rho);
            r[4].push(a.params.amplitude / b.params.amplitude);
            r[5].push(a.params.background - b.params.background);
        }
        for (name, mut v) in [
            "dx/bound",
            "sx ratio",
            "sy ratio",
            "drho",
            "amp ratio",
            "dbg",
        ]
        .into_iter()
        .zip(r)
        {
            v.sort_by(f64::total_cmp);
            let q = |p: f64| v[((v.len() - 1) as f64 * p) as usize];
            println!(
                "IWC vs LSG {name:10} p10 {:.4} median {:.4} p90 {:.4}",
                q(0.1),
                q(0.5),
                q(0.9)
            );
        }
    }
    if want("fitgrad") {
        let (t, _) = best(runs, || {
            fit_dots(&gradient, roi, &tracked.seeds, &cfg, &noise)
        });
        println!(
            "fit_dots gradient     {t:7.2} ms  {:.2} us/dot",
            t * 1e3 / n
        );
        let (_, report) =
            bostrack_fit::fit_dots_report(&gradient, roi, &tracked.seeds, &cfg, &noise)?;
        println!(
            "  passes {} refits {:?} converged {} unconverged {}",
            report.passes, report.refits, report.converged, report.unconverged
        );
    }
    Ok(())
}
