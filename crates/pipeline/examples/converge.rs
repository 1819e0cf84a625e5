//! The neighbour iteration on the real sample: how many passes and refits it takes, what it
//! costs against the two fixed passes of earlier versions, how far positions moved, and how
//! far dots still move between the last two passes (inside and outside the flow region).
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p bostrack-pipeline --example converge -- [--runs N]`
//! (`BT_TOL=0.05` sets `[fit] neighbour_tolerance` for the converged runs; `--stack-only`: the
//! no-flow stack's linearised iteration against the pixel iteration, then stop; `--frame-only`:
//! the gradient frame's iteration with the reference's linear coupling map for its no-flow part
//! against the pixel iteration alone and a deep one, then stop).

use bostrack_core::{DotFit, DotFlags, Image, Mask, NoiseModel, Seed};
use bostrack_fit::{
    FitConfig, FitMemory, NeighbourTails, PassReport, estimate_noise, fit_dots_remembered,
    fit_dots_report, refit_dots_remembered, refit_dots_report,
};
use bostrack_io::{bos_sample_dir, read_image, read_mask_for};
use std::time::Instant;

/// One stack image's fits by the linear map and by the pixel iteration.
type Paths = (Vec<DotFit>, Vec<DotFit>);

fn in_flow(f: &DotFit) -> bool {
    (700.0..=860.0).contains(&f.params.y0) && (380.0..=640.0).contains(&f.params.x0)
}

/// |a − b| in units of b's bound (the larger axis), per dot with both fits usable.
fn moves(a: &[DotFit], b: &[DotFit], keep: impl Fn(&DotFit) -> bool) -> Vec<f64> {
    let mut d: Vec<f64> = a
        .iter()
        .zip(b)
        .filter(|(x, y)| x.status.is_ok() && y.status.is_ok() && keep(y))
        .map(|(x, y)| {
            ((x.params.x0 - y.params.x0) / y.crlb_x)
                .abs()
                .max(((x.params.y0 - y.params.y0) / y.crlb_y).abs())
        })
        .collect();
    d.sort_by(f64::total_cmp);
    d
}

fn summary(name: &str, d: &[f64]) {
    if d.is_empty() {
        println!("  {name:40} n 0");
        return;
    }
    let q = |p: f64| d[((d.len() - 1) as f64 * p) as usize];
    let over = d.iter().filter(|&&v| v > 0.7).count();
    println!(
        "  {name:40} n {:6}  median {:.4} p90 {:.4} p99 {:.4} max {:.4}  > 0.7: {:.2} %",
        d.len(),
        q(0.5),
        q(0.9),
        q(0.99),
        q(1.0),
        100.0 * over as f64 / d.len() as f64
    );
}

fn timed(
    runs: usize,
    img: &Image,
    mask: Option<&Mask>,
    seeds: &[Seed],
    cfg: &FitConfig,
    noise: &NoiseModel,
) -> (f64, Vec<DotFit>, PassReport) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs {
        let t = Instant::now();
        let r = fit_dots_report(img, mask, seeds, cfg, noise).expect("fit");
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
        out = Some(r);
    }
    let (f, r) = out.expect("runs >= 1");
    (best, f, r)
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
        .unwrap_or(3);
    println!("rayon threads {}", rayon::current_num_threads());
    let reference = read_image(&dir.join("pair/reference.tif"))?;
    let (w, h) = (reference.width(), reference.height());
    let mask = read_mask_for(&dir.join("mask.tif"), w, h)?;
    let gradient = read_image(&dir.join("pair/gradient.tif"))?;
    let noise = estimate_noise(&reference, Some(&mask))?;
    let dcfg = bostrack_detect::DetectConfig {
        spacing: Some(8.0),
        diameter: Some(6.5),
        ..Default::default()
    };
    let det = bostrack_detect::detect(&reference, Some(&mask), &dcfg)?;
    let tracked = bostrack_detect::track(&gradient, Some(&mask), &det, &dcfg)?;
    let mut cfg = FitConfig::default();
    if let Ok(t) = std::env::var("BT_TOL") {
        cfg.neighbour_tolerance = t.parse()?;
    }
    let two = FitConfig {
        neighbour_passes: 2,
        ..cfg.clone()
    };
    // the no-flow stack: refits from the reference's fits, one pass (earlier versions) against
    // the converged iteration
    let (ref_fits, _) = fit_dots_report(&reference, Some(&mask), &det.seeds, &cfg, &noise)?;
    if std::env::args().any(|a| a == "--frame-only") {
        return frame_only(
            &reference, &gradient, &mask, &det, &tracked, &cfg, &noise, runs,
        );
    }
    let tails = NeighbourTails::new(&ref_fits, &det.seeds, &cfg, w, h);
    let one = FitConfig {
        neighbour_passes: 1,
        ..cfg.clone()
    };
    let mut stack = Vec::new();
    for k in 1..=10 {
        let p = dir.join(format!("ref-stack/im_{k:04}.tif"));
        if p.exists() {
            stack.push(read_image(&p)?);
        }
    }
    // the linearised iteration (the pipeline's way) against the pixel iteration and a deep one
    let t = Instant::now();
    let coupled =
        NeighbourTails::coupled(&ref_fits, &det.seeds, &cfg, &stack[0], Some(&mask), &noise);
    println!("coupling map: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
    let deep = FitConfig {
        neighbour_tolerance: 0.005,
        neighbour_passes: 60,
        ..cfg.clone()
    };
    let (mut tl, mut tp) = (0.0, 0.0);
    let (mut lin_pix, mut lin_deep, mut pix_deep) = (Vec::new(), Vec::new(), Vec::new());
    let mut one_deep = Vec::new();
    // every image's fits by both paths, for the stack scatter each gives
    let mut per_image: Vec<Paths> = Vec::new();
    let mut sweeps = Vec::new();
    // one stack image refitted from the reference's fits
    let refit = |img: &Image, cfg: &FitConfig, tails: &NeighbourTails| {
        refit_dots_report(
            img,
            Some(&mask),
            &det.seeds,
            cfg,
            &noise,
            &ref_fits,
            Some(tails),
        )
    };
    for (k, img) in stack.iter().enumerate() {
        let t = Instant::now();
        let (fl, rl) = refit(img, &cfg, &coupled)?;
        tl += t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let (fp, _) = refit(img, &cfg, &tails)?;
        tp += t.elapsed().as_secs_f64() * 1e3;
        sweeps.push((rl.linear_sweeps, rl.passes));
        lin_pix.extend(moves(&fl, &fp, |_| true));
        per_image.push((fl.clone(), fp.clone()));
        if k < 3 {
            let (fd, _) = refit(img, &deep, &tails)?;
            lin_deep.extend(moves(&fl, &fd, |_| true));
            let (f1, _) = refit(img, &one, &tails)?;
            one_deep.extend(moves(&f1, &fd, |_| true));
            pix_deep.extend(moves(&fp, &fd, |_| true));
        }
    }
    println!(
        "stack ({} images): linear map {tl:8.2} ms  pixel iteration {tp:8.2} ms  ratio {:.3}; (sweeps, passes) {sweeps:?}",
        stack.len(),
        tl / tp
    );
    for v in [&mut lin_pix, &mut lin_deep, &mut pix_deep, &mut one_deep] {
        v.sort_by(f64::total_cmp);
    }
    summary("linear vs pixel iteration", &lin_pix);
    summary("linear vs deep (3 images)", &lin_deep);
    summary("pixel iteration vs deep (3 images)", &pix_deep);
    summary("first pass vs deep (3 images)", &one_deep);
    // the per-dot scatter over the stack (sample standard deviation of x, as u_ref before the
    // common-mode correction), by both paths, against the reference's bound
    let scatter = |pick: fn(&Paths) -> &Vec<DotFit>, d: usize| {
        let xs: Vec<f64> = per_image
            .iter()
            .map(|p| &pick(p)[d])
            .filter(|f| f.status.is_ok())
            .map(|f| f.params.x0)
            .collect();
        let n = xs.len() as f64;
        if xs.len() < per_image.len() {
            return f64::NAN;
        }
        let m = xs.iter().sum::<f64>() / n;
        (xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0)).sqrt()
    };
    let (mut ratio, mut u_lin, mut u_pix, mut bound) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (d, r) in ref_fits.iter().enumerate() {
        let (a, b) = (scatter(|p| &p.0, d), scatter(|p| &p.1, d));
        if r.status.is_ok() && a.is_finite() && b.is_finite() && b > 0.0 {
            ratio.push(a / b);
            u_lin.push(a);
            u_pix.push(b);
            bound.push(r.crlb_x);
        }
    }
    let med = |v: &mut Vec<f64>| bostrack_core::median(v);
    println!(
        "stack scatter of x over {} dots: median linear / pixel iteration {:.4}; median scatter linear {:.5} px, pixel iteration {:.5} px, median reference bound {:.5} px",
        ratio.len(),
        med(&mut ratio),
        med(&mut u_lin),
        med(&mut u_pix),
        med(&mut bound)
    );
    if std::env::args().any(|a| a == "--stack-only") {
        return Ok(());
    }
    let (mut t1, mut tc) = (0.0, 0.0);
    let mut refits = Vec::new();
    for img in &stack {
        let t = Instant::now();
        refit(img, &one, &tails)?;
        t1 += t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let (_, r) = refit(img, &cfg, &tails)?;
        tc += t.elapsed().as_secs_f64() * 1e3;
        if refits.is_empty() {
            println!("stack image 1: {r:?}");
        }
        refits.push((
            r.passes,
            r.refits.iter().skip(1).sum::<usize>(),
            r.unconverged,
        ));
    }
    println!(
        "stack ({} images): one pass {t1:8.2} ms  converged {tc:8.2} ms  ratio {:.3}; (passes, refits after pass 1, unconverged) {refits:?}",
        stack.len(),
        tc / t1
    );
    for (name, img, seeds) in [
        ("reference", &reference, &det.seeds),
        ("gradient", &gradient, &tracked.seeds),
    ] {
        println!("{name}: {} seeds", seeds.len());
        // interleaved, so that drift of the machine's speed hits both alike
        let (mut t2, mut tc) = (f64::INFINITY, f64::INFINITY);
        let (mut f2, mut fc, mut rc) = (Vec::new(), Vec::new(), PassReport::default());
        for _ in 0..runs {
            let (t, f, _) = timed(1, img, Some(&mask), seeds, &two, &noise);
            (t2, f2) = (t2.min(t), f);
            let (t, f, r) = timed(1, img, Some(&mask), seeds, &cfg, &noise);
            (tc, fc, rc) = (tc.min(t), f, r);
        }
        println!(
            "  fit_dots 2 passes {t2:8.2} ms   converged {tc:8.2} ms   ratio {:.3}",
            tc / t2
        );
        println!(
            "  passes {} refits {:?} converged {} unconverged {}",
            rc.passes, rc.refits, rc.converged, rc.unconverged
        );
        // the reported (joint) bound against the bound of the dot alone at the same parameters
        let mut ratio: Vec<f64> = fc
            .iter()
            .zip(seeds.iter())
            .filter(|(f, _)| f.status.is_ok() && f.crlb_x.is_finite())
            .filter_map(|(f, s)| {
                let b = bostrack_model::crlb_masked(
                    &f.params,
                    s.window,
                    &noise,
                    bostrack_model::Sampling::Integrated,
                    bostrack_model::ModelKind::Elliptical,
                    &|x, y| {
                        x >= 0
                            && y >= 0
                            && (x as usize) < w
                            && (y as usize) < h
                            && mask.keeps(x as usize, y as usize)
                            && !img.is_saturated(img.get(x as usize, y as usize))
                    },
                )?;
                Some(f.crlb_x / b.std[0])
            })
            .collect();
        summary("joint / single-dot bound (x)", {
            ratio.sort_by(f64::total_cmp);
            &ratio
        });
        let count = |f: DotFlags| fc.iter().filter(|d| d.flags.contains(f)).count();
        println!(
            "  flags: residual {} unconverged {}  fit_failed {}",
            count(DotFlags::RESIDUAL),
            count(DotFlags::UNCONVERGED),
            count(DotFlags::FIT_FAILED)
        );
        let res: Vec<&DotFit> = fc
            .iter()
            .filter(|d| d.flags.contains(DotFlags::RESIDUAL))
            .collect();
        let with = |f: DotFlags| res.iter().filter(|d| d.flags.intersects(f)).count();
        println!(
            "  residual with: roi_edge {} border {} masked {} defect|faint {} saturated {}; in flow {}",
            with(DotFlags::ROI_EDGE),
            with(DotFlags::BORDER),
            with(DotFlags::MASKED),
            with(DotFlags::from_bits(
                DotFlags::DEFECT.bits() | DotFlags::FAINT.bits()
            )),
            with(DotFlags::SATURATED),
            res.iter().filter(|d| in_flow(d)).count()
        );
        for alpha in [1e-4, 1e-5, 1e-6, 1e-8] {
            let c = FitConfig {
                residual_false_alarm: alpha,
                ..cfg.clone()
            };
            let (_, fa, _) = timed(1, img, Some(&mask), seeds, &c, &noise);
            let n = fa
                .iter()
                .filter(|d| d.flags.contains(DotFlags::RESIDUAL))
                .count();
            println!("  residual at false-alarm rate {alpha:e}: {n}");
        }
        summary("2 passes vs converged, flow", &moves(&f2, &fc, in_flow));
        summary(
            "2 passes vs converged, rest",
            &moves(&f2, &fc, |f| !in_flow(f)),
        );
        // the last two passes of the converged iteration
        if rc.passes >= 2 {
            let prev = FitConfig {
                neighbour_passes: rc.passes - 1,
                ..cfg.clone()
            };
            let (_, fp, _) = timed(1, img, Some(&mask), seeds, &prev, &noise);
            summary("last two passes, flow", &moves(&fp, &fc, in_flow));
            summary("last two passes, rest", &moves(&fp, &fc, |f| !in_flow(f)));
            let top = fc
                .iter()
                .filter(|f| f.status.is_ok())
                .map(|f| f.index.j)
                .min()
                .unwrap_or(0);
            summary(
                "last two passes, top row",
                &moves(&fp, &fc, |f| f.index.j == top),
            );
            let top2 = FitConfig {
                neighbour_passes: 3,
                ..cfg.clone()
            };
            let (_, f3, _) = timed(1, img, Some(&mask), seeds, &top2, &noise);
            summary(
                "passes 2 and 3, top row",
                &moves(&f2, &f3, |f| f.index.j == top),
            );
            summary("passes 2 and 3, all", &moves(&f2, &f3, |_| true));
        }
    }
    Ok(())
}

/// The gradient frame from the reference's fits (as the pipeline fits it): with the reference's
/// linear coupling map for its no-flow part, by the pixel iteration alone, and by a deep pixel
/// iteration; positions compared in units of the deep fit's bound, inside and outside the flow.
#[allow(clippy::too_many_arguments)]
fn frame_only(
    reference: &Image,
    gradient: &Image,
    mask: &Mask,
    det: &bostrack_detect::Detection,
    tracked: &bostrack_detect::Detection,
    cfg: &FitConfig,
    noise: &NoiseModel,
    runs: usize,
) -> Result<(), Box<dyn std::error::Error>> {
    let (ref_fits, _, memory) = fit_dots_remembered(reference, Some(mask), &det.seeds, cfg, noise)?;
    let t = Instant::now();
    let with_map: FitMemory =
        memory
            .clone()
            .linearised(&ref_fits, &det.seeds, cfg, reference, Some(mask), noise);
    println!(
        "coupling map of the reference: {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    // the reference fits each moved by its tracked displacement (as the pipeline's prior)
    let prior: Vec<DotFit> = ref_fits
        .iter()
        .zip(det.seeds.iter().zip(&tracked.seeds))
        .map(|(f, (r, g))| {
            let mut p = *f;
            p.params.x0 += g.centre[0] - r.centre[0];
            p.params.y0 += g.centre[1] - r.centre[1];
            p
        })
        .collect();
    let fit = |c: &FitConfig, m: &FitMemory| {
        refit_dots_remembered(
            gradient,
            Some(mask),
            &tracked.seeds,
            c,
            noise,
            &prior,
            None,
            Some(m),
        )
    };
    // (`[fit] frame_map` is on by default; the passes alone with it off)
    let on = FitConfig {
        frame_map: true,
        ..cfg.clone()
    };
    let (mut th, mut tp) = (f64::INFINITY, f64::INFINITY);
    let (mut fh, mut fp) = (Vec::new(), Vec::new());
    let (mut rh, mut rp) = (PassReport::default(), PassReport::default());
    for _ in 0..runs {
        let t = Instant::now();
        (fh, rh) = fit(&on, &with_map)?;
        th = th.min(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        (fp, rp) = fit(cfg, &memory)?;
        tp = tp.min(t.elapsed().as_secs_f64() * 1e3);
    }
    let deep = FitConfig {
        neighbour_tolerance: 0.005,
        neighbour_passes: 60,
        ..cfg.clone()
    };
    let (fd, rd) = fit(&deep, &memory)?;
    println!(
        "gradient frame, best of {runs}: with the map {th:.2} ms, pixel iteration {tp:.2} ms, ratio {:.3}",
        th / tp
    );
    println!(
        "  with the map: passes {} refits {:?} sweeps {} unconverged {}",
        rh.passes, rh.refits, rh.linear_sweeps, rh.unconverged
    );
    println!(
        "  pixel iteration: passes {} refits {:?} unconverged {}",
        rp.passes, rp.refits, rp.unconverged
    );
    println!(
        "  deep: passes {} unconverged {}",
        rd.passes, rd.unconverged
    );
    summary("map vs deep, flow", &moves(&fh, &fd, in_flow));
    summary("map vs deep, rest", &moves(&fh, &fd, |f| !in_flow(f)));
    summary("pixel vs deep, flow", &moves(&fp, &fd, in_flow));
    summary("pixel vs deep, rest", &moves(&fp, &fd, |f| !in_flow(f)));
    summary("map vs pixel, all", &moves(&fh, &fp, |_| true));
    // the bounds and the flags
    let ratio: Vec<f64> = {
        let mut r: Vec<f64> = fh
            .iter()
            .zip(&fp)
            .filter(|(a, b)| a.status.is_ok() && b.status.is_ok() && b.crlb_x > 0.0)
            .map(|(a, b)| (a.crlb_x / b.crlb_x - 1.0).abs())
            .collect();
        r.sort_by(f64::total_cmp);
        r
    };
    summary("|bound x map / pixel - 1|", &ratio);
    for flag in [
        DotFlags::RESIDUAL,
        DotFlags::UNCONVERGED,
        DotFlags::FIT_FAILED,
    ] {
        let count = |f: &[DotFit]| f.iter().filter(|d| d.flags.contains(flag)).count();
        println!(
            "  {flag:?}: map {} pixel {} deep {}",
            count(&fh),
            count(&fp),
            count(&fd)
        );
    }
    Ok(())
}
