//! The pair pipeline over files: a small synthetic campaign on disk, its outputs, determinism,
//! "compute only what is asked for", and bad inputs (each a clear error, nothing written).

use bostrack_core::{DotFlags, Image, ImageMeta};
use bostrack_displacement::COLUMNS;
use bostrack_pipeline::{
    ConfigError, PipelineError, Plan, ReferenceContext, frame_is_complete, process_frame,
    process_image, write_frame,
};
use bostrack_synth::{DisplacementField, FlowConfig, Scene, SceneConfig, stack};
use std::fs;
use std::path::{Path, PathBuf};

const SHIFT: [f64; 2] = [0.3, -0.2];

fn scene() -> SceneConfig {
    SceneConfig {
        width: 160,
        height: 144,
        seed: 5,
        ..Default::default()
    }
}

/// `root/camp/{reference.tif, gradient/frame_1.tif, stack/s1..s3.tif}` and
/// `root/pipeline.toml` (with `extra` appended).
fn campaign(extra: &str) -> (tempfile::TempDir, PathBuf) {
    let root = tempfile::tempdir().unwrap();
    let camp = root.path().join("camp");
    fs::create_dir_all(camp.join("gradient")).unwrap();
    fs::create_dir_all(camp.join("stack")).unwrap();
    let sc = scene();
    let flow = FlowConfig {
        displacement: DisplacementField::Uniform {
            dx: SHIFT[0],
            dy: SHIFT[1],
        },
        ..Default::default()
    };
    let w = |p: &Path, img: &Image| bostrack_io::write_tiff_u16(p, img).unwrap();
    w(
        &camp.join("reference.tif"),
        &Scene::reference(&sc).unwrap().image,
    );
    w(
        &camp.join("gradient/frame_1.tif"),
        &Scene::gradient(&sc, &flow).unwrap().image,
    );
    for (k, img) in stack(&sc, 3).unwrap().iter().enumerate() {
        w(&camp.join(format!("stack/s{}.tif", k + 1)), img);
    }
    let cfg = root.path().join("pipeline.toml");
    fs::write(
        &cfg,
        format!(
            "[input]\ndir = \"camp\"\nstack_glob = \"s*.tif\"\n{extra}\n[detect]\nspacing = 8.0\n"
        ),
    )
    .unwrap();
    (root, cfg)
}

fn csv_of(dir: &Path, stem: &str) -> String {
    fs::read_to_string(dir.join(stem).join("dots.csv")).unwrap()
}

#[test]
fn a_campaign_runs_and_its_frame_is_written_atomically() {
    let (root, cfg) = campaign("");
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    assert_eq!(ctx.image_size(), (160, 144));
    assert_eq!(ctx.noise().1, "stack");
    assert_eq!(ctx.stack_summary().unwrap().images, 3);
    let stages: Vec<&str> = ctx
        .timings()
        .stages
        .iter()
        .map(|(n, _)| n.as_str())
        .collect();
    assert_eq!(
        stages,
        [
            "stack_decode",
            "decode",
            "noise",
            "detect",
            "fit",
            "stack_fit",
            "stack_scatter"
        ]
    );
    let r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
    assert_eq!(r.stem, "frame_1");
    assert_eq!(r.dots.len(), ctx.fits().len());
    let s = &r.summary;
    assert!(s.counts.valid > 250, "{:?}", s.counts);
    assert_eq!(s.counts.matched, s.counts.reference_fitted);
    for a in 0..2 {
        let d = s.medians.d[a].unwrap();
        assert!((d - SHIFT[a]).abs() < 0.01, "axis {a}: median d {d}");
        assert!(s.medians.u_d[a].unwrap() > 0.0);
    }
    let names: Vec<&str> = s.times.stages.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["decode", "detect", "fit", "match", "validate", "pair"]
    );

    let out = root.path().join("out");
    write_frame(&out, &r).unwrap();
    assert!(frame_is_complete(&out, "frame_1"));
    assert!(!frame_is_complete(&out, "frame_2"));
    let csv = csv_of(&out, "frame_1");
    let mut lines = csv.lines();
    assert_eq!(lines.next().unwrap(), COLUMNS.join(","));
    assert_eq!(lines.count(), r.dots.len());
    let json: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(out.join("frame_1/summary.json")).unwrap())
            .unwrap();
    assert_eq!(json["counts"]["valid"], s.counts.valid);
    assert_eq!(json["version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(json["noise"]["source"], "stack");
    assert_eq!(json["stack"]["images"], 3);
    assert!(json["times"]["fit"].as_f64().unwrap() >= 0.0);
    assert!(json["stack_note"].is_null());

    // writing again replaces the folder; no temporary folder is left behind
    write_frame(&out, &r).unwrap();
    let entries: Vec<String> = fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(entries, ["frame_1"]);
}

#[test]
fn outputs_do_not_depend_on_the_thread_count() {
    let (root, cfg) = campaign("");
    let plan = Plan::load(&cfg).unwrap();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let ctx = ReferenceContext::prepare(&plan).unwrap();
            let r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
            let out = root.path().join(format!("out{threads}"));
            write_frame(&out, &r).unwrap();
            csv_of(&out, "frame_1")
        })
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn only_what_is_asked_for_is_computed() {
    // displacement only: no stack fits (the stack still gives the noise model), no AR, no u
    let (_root, cfg) = campaign("[output]\nquantities = \"displacement\"\n");
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    assert!(ctx.stack_summary().is_none());
    assert!(
        ctx.stack_note()
            .unwrap()
            .contains("quantities = \"displacement\"")
    );
    assert!(ctx.timings().get("stack_fit").is_none());
    assert_eq!(ctx.noise().1, "stack");
    let r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
    let valid: Vec<_> = r.dots.iter().filter(|d| d.valid).collect();
    assert!(!valid.is_empty());
    assert!(valid.iter().all(|d| d.displacement.is_some()
        && d.ar.is_none()
        && d.u_ref.is_none()
        && d.reference.unwrap().crlb_x > 0.0));
    assert!(r.summary.stack_note.is_some());

    // amplification: AR, but still no stack fits
    let (_root, cfg) = campaign("[output]\nquantities = \"amplification\"\n");
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    assert!(ctx.stack_summary().is_none());
    let r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
    assert!(
        r.dots
            .iter()
            .filter(|d| d.valid)
            .all(|d| d.ar.is_some() && d.u_d.is_none())
    );

    // no stack: the noise model from the reference image, the summary says why u is empty,
    // the per-dot bound is still there
    let (_root, cfg) = campaign("stack_dir = \"\"\n");
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    assert_eq!(ctx.noise().1, "reference image");
    let r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
    assert!(
        r.summary
            .stack_note
            .as_deref()
            .unwrap()
            .contains("no no-flow stack")
    );
    assert!(r.summary.medians.u_d[0].is_none());
    assert!(r.summary.medians.crlb_ref[0].unwrap() > 0.0);
    assert!(r.summary.medians.ar[0].is_some());
}

#[test]
fn the_stack_mean_can_be_the_reference() {
    let (_root, cfg) = campaign(
        "reference_from = \"stack-mean\"\n[uncertainty]\nreference_position = \"stack-mean\"\n",
    );
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    let s = ctx.summary();
    // the reference fits are weighted with the noise of a mean of 3 images
    let ratio = s["reference_noise"]["read_variance"].as_f64().unwrap()
        / s["noise"]["read_variance"].as_f64().unwrap();
    assert!((ratio - 1.0 / 3.0).abs() < 1e-12);
    let r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
    for a in 0..2 {
        assert!((r.summary.medians.d[a].unwrap() - SHIFT[a]).abs() < 0.01);
    }
    // u_d = sqrt(u_ref²/K + u_grad²) with K = 3
    let d = r.dots.iter().find(|d| d.valid && d.u_d.is_some()).unwrap();
    let (u, g, ud) = (d.u_ref.unwrap()[0], d.u_grad.unwrap()[0], d.u_d.unwrap()[0]);
    assert!((ud - (u * u / 3.0 + g * g).sqrt()).abs() < 1e-12);
}

fn assert_nothing_written(root: &Path) {
    assert!(!root.join("out").exists());
}

#[test]
fn a_gradient_of_another_size_is_an_error() {
    let (root, cfg) = campaign("");
    let small = Image::new(96, 96, vec![100.0; 96 * 96], ImageMeta::synthetic(12)).unwrap();
    let path = root.path().join("camp/gradient/frame_1.tif");
    bostrack_io::write_tiff_u16(&path, &small).unwrap();
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    let e = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap_err();
    assert!(matches!(e, PipelineError::SizeMismatch { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("frame_1.tif") && msg.contains("expected 160x144 px, got 96x96 px"),
        "{msg}"
    );
    assert_nothing_written(root.path());
}

#[test]
fn a_stack_image_of_another_size_is_an_error() {
    let (root, cfg) = campaign("");
    let small = Image::new(160, 96, vec![100.0; 160 * 96], ImageMeta::synthetic(12)).unwrap();
    bostrack_io::write_tiff_u16(&root.path().join("camp/stack/s2.tif"), &small).unwrap();
    let plan = Plan::load(&cfg).unwrap();
    let e = ReferenceContext::prepare(&plan).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, PipelineError::SizeMismatch { .. }), "{msg}");
    assert!(
        msg.contains("s2.tif") && msg.contains("got 160x96 px"),
        "{msg}"
    );
    assert_nothing_written(root.path());
}

#[test]
fn a_stack_image_of_another_bit_depth_is_an_error() {
    let (root, cfg) = campaign("");
    let p = root.path().join("camp/stack/s3.tif");
    let img = bostrack_io::read_image(&p).unwrap();
    bostrack_io::write_tiff_f32(&p, &img).unwrap();
    let plan = Plan::load(&cfg).unwrap();
    let e = ReferenceContext::prepare(&plan).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("s3.tif") && msg.contains("bit depth") && msg.contains("got 32-bit float"),
        "{msg}"
    );
    assert_nothing_written(root.path());
}

#[test]
fn an_empty_stack_folder_is_an_error() {
    let (root, cfg) = campaign("");
    for k in 1..=3 {
        fs::remove_file(root.path().join(format!("camp/stack/s{k}.tif"))).unwrap();
    }
    let e = Plan::load(&cfg).unwrap_err();
    assert!(
        matches!(&e, ConfigError::NoMatch { key, .. } if key == "input.stack_glob"),
        "{e}"
    );
    assert!(e.to_string().contains("no file in"), "{e}");
    // through the pipeline's error type, as `bostrack run` sees it
    let e: PipelineError = e.into();
    assert!(e.to_string().contains("stack"), "{e}");
}

#[test]
fn a_gradient_without_dots_is_an_error() {
    let (root, cfg) = campaign("");
    let sc = scene();
    // the same background and noise, no dots
    let mut flat = sc.clone();
    flat.dots.amplitude = 0.0;
    let img = Scene::reference(&flat)
        .map(|s| s.image)
        .unwrap_or_else(|_| {
            Image::new(160, 144, vec![150.0; 160 * 144], ImageMeta::synthetic(12)).unwrap()
        });
    let path = root.path().join("camp/gradient/frame_1.tif");
    bostrack_io::write_tiff_u16(&path, &img).unwrap();
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    let e = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap_err();
    let msg = e.to_string();
    assert!(
        matches!(
            e,
            PipelineError::NoDots { .. } | PipelineError::Detect { .. }
        ),
        "{msg}"
    );
    assert!(msg.contains("frame_1.tif"), "{msg}");
    assert_nothing_written(root.path());
}

#[test]
fn a_bad_frame_name_is_refused_and_nothing_is_written() {
    let (root, cfg) = campaign("");
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    let mut r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
    let out = root.path().join("out");
    for stem in ["", "../escape", ".hidden", "a/b"] {
        r.stem = stem.into();
        assert!(write_frame(&out, &r).is_err(), "{stem:?}");
    }
    assert!(!out.exists() || fs::read_dir(&out).unwrap().next().is_none());
    assert!(!root.path().join("escape").exists());
}

/// A smooth field whose displacement reaches 6 px (three quarters of the 8 px spacing) in the
/// middle and vanishes at the edges (a BOS-like bump): tracking grows from the small
/// displacements outward, so every dot keeps its grid index and every displacement is right,
/// flagged or not. The match stage's independent kd-tree cross-check cannot follow the core of
/// the bump (the nearest dot there is a neighbour, consistently over a whole region, so its
/// local-median predictor locks onto the alias) nor its flanks, where the lattice is also
/// compressed by 30 %: it flags `GRID_MISMATCH` there (measured: 97 of 1024 dots, all with
/// |d| > 2.4 px = 0.3 spacing), which makes those dots invalid. (A *uniform* shift of more
/// than half the spacing is ambiguous even to tracking.)
#[test]
fn a_displacement_larger_than_half_the_spacing_is_followed() {
    let (_root, cfg) = campaign("");
    let plan = Plan::load(&cfg).unwrap();
    let sc = SceneConfig {
        width: 256,
        height: 256,
        ..scene()
    };
    let flow = FlowConfig {
        displacement: DisplacementField::GaussianBump {
            centre: [128.0, 128.0],
            amplitude: 317.0,
            width: 32.0,
        },
        ..Default::default()
    };
    let reference = Scene::reference(&sc).unwrap();
    let gradient = Scene::gradient(&sc, &flow).unwrap();
    let ctx =
        ReferenceContext::from_images(&plan, reference.image.clone(), None, stack(&sc, 3).unwrap())
            .unwrap();
    let r = bostrack_pipeline::process_image(&ctx, &plan, &gradient.image, Path::new("bump.tif"))
        .unwrap();
    let c = &r.summary.counts;
    assert_eq!(c.matched, c.reference_fitted, "{c:?}");
    // truth by site: the synthetic lattice has site (0, 0) at (128, 128), spacing 8
    let site = |p: [f64; 2]| {
        (
            ((p[0] - 128.0) / 8.0).round() as i64,
            ((p[1] - 128.0) / 8.0).round() as i64,
        )
    };
    let truth: std::collections::HashMap<_, _> = reference
        .truth
        .iter()
        .zip(&gradient.truth)
        .map(|(t, g)| {
            (
                site([t.params.x0, t.params.y0]),
                [g.params.x0 - t.params.x0, g.params.y0 - t.params.y0],
            )
        })
        .collect();
    let (mut largest, mut worst, mut flagged): (f64, f64, usize) = (0.0, 0.0, 0);
    for d in r.dots.iter().filter(|d| d.displacement.is_some()) {
        let (p, disp) = (d.reference_position.unwrap(), d.displacement.unwrap());
        let t = truth[&site(p)];
        let size = t[0].hypot(t[1]);
        largest = largest.max(size);
        if !d.flags.contains(bostrack_core::DotFlags::BORDER) {
            // dots cut by the image edge have bounds of ~0.1 px
            worst = worst.max((disp[0] - t[0]).hypot(disp[1] - t[1]));
        }
        if d.flags.contains(bostrack_core::DotFlags::GRID_MISMATCH) {
            flagged += 1;
            assert!(size > 0.25 * 8.0, "flagged at |d| = {size}");
        }
    }
    assert!(largest > 5.5, "largest true displacement {largest}");
    // every dot paired with its own partner: a wrong index would be off by ~a spacing. (The
    // largest error, 0.30 px, is a fit bias where the bump compresses the lattice to ~5.5 px and
    // neighbours overlap; most errors are at the bound, ~0.015 px.)
    assert!(worst < 0.5, "largest error {worst} px");
    assert_eq!(flagged, c.grid_mismatches);
    assert!(flagged < 150, "{flagged} flagged");
}

/// `camp/mask.png` keeping `keep(x, y)`, stored as a numpy/MATLAB logical would be: 0 and 1.
fn write_logical_mask(root: &Path, keep: impl Fn(usize, usize) -> bool) -> PathBuf {
    let sc = scene();
    let mut img = Image::from_fn(sc.width, sc.height, |x, y| f64::from(u8::from(keep(x, y))));
    img.meta = ImageMeta::synthetic(8);
    let p = root.join("camp/mask.png");
    bostrack_io::write_png_u8(&p, &img).unwrap();
    p
}

#[test]
fn a_zero_one_mask_keeps_its_ones_and_no_dot_outside_it_is_valid() {
    let (root, cfg) = campaign("mask = \"mask.png\"\n");
    // keep the left 85 columns, less the centre pixel of every 7th dot there (found without
    // a mask): those dots' centres lie outside the region of interest
    write_logical_mask(root.path(), |_, _| true);
    let plan = Plan::load(&cfg).unwrap();
    let holes: Vec<(usize, usize)> = ReferenceContext::prepare(&plan)
        .unwrap()
        .fits()
        .iter()
        .filter(|d| d.params.x0 > 10.0 && d.params.x0 < 80.0 && d.params.y0 > 10.0)
        .step_by(7)
        .map(|d| (d.params.x0.round() as usize, d.params.y0.round() as usize))
        .collect();
    assert!(holes.len() >= 5, "{}", holes.len());
    write_logical_mask(root.path(), |x, y| x < 85 && !holes.contains(&(x, y)));
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    let mask = ctx.mask().unwrap();
    assert_eq!(mask.count_kept(), 85 * 144 - holes.len());
    let r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
    let outside = |p: Option<[f64; 2]>| p.is_some_and(|p| !mask.keeps_point(p[0], p[1]));
    let mut flagged = 0;
    for d in &r.dots {
        let out = outside(d.reference_position)
            || outside(d.gradient.map(|g| [g.params.x0, g.params.y0]));
        assert_eq!(
            d.flags.contains(DotFlags::OUTSIDE_MASK),
            out,
            "{:?}",
            d.index
        );
        assert!(
            !(out && d.valid),
            "a dot outside the mask is valid: {:?}",
            d.index
        );
        flagged += usize::from(out);
    }
    let valid = r.dots.iter().filter(|d| d.valid).count();
    eprintln!("valid {valid}, outside the mask {flagged}");
    assert!(valid > 100, "{valid}");
    assert!(
        flagged >= holes.len() - 1,
        "{flagged} of {} holes",
        holes.len()
    );
    for a in 0..2 {
        assert!((r.summary.medians.d[a].unwrap() - SHIFT[a]).abs() < 0.01);
    }
}

#[test]
fn a_mask_that_leaves_too_little_names_itself_in_the_error() {
    let (root, cfg) = campaign("mask = \"mask.png\"\n");
    let mask = write_logical_mask(root.path(), |x, y| x < 6 && y < 6);
    let plan = Plan::load(&cfg).unwrap();
    let e = ReferenceContext::prepare(&plan).unwrap_err();
    assert!(matches!(e, PipelineError::Masked { kept: 36, .. }), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.contains(&format!(
            "the mask {} keeps 36 of its 23040 pixels",
            mask.display()
        )),
        "{msg}"
    );

    // a mask that keeps nothing is refused when it is read, naming it
    write_logical_mask(root.path(), |_, _| false);
    let e = ReferenceContext::prepare(&plan).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.starts_with(&format!("{}: mask keeps no pixel", mask.display())),
        "{msg}"
    );
}

/// A gradient frame that fails under a mask names the mask too (as the reference side does).
#[test]
fn a_frame_that_fails_under_a_mask_names_the_mask() {
    let (root, cfg) = campaign("mask = \"mask.png\"\n");
    let mask = write_logical_mask(root.path(), |x, _| x >= 4);
    let plan = Plan::load(&cfg).unwrap();
    let ctx = ReferenceContext::prepare(&plan).unwrap();
    // a frame without dots: its detection fails
    let (w, h) = ctx.image_size();
    let blank = Image::new(w, h, vec![100.0; w * h], ImageMeta::default()).unwrap();
    let e = process_image(&ctx, &plan, &blank, Path::new("blank.tif")).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, PipelineError::Masked { .. }), "{e:?}");
    assert!(msg.starts_with("blank.tif"), "{msg}");
    assert!(
        msg.contains(&format!("the mask {}", mask.display())),
        "{msg}"
    );
}

#[test]
fn a_multi_page_tiff_is_a_stack_and_gives_what_its_pages_give_as_files() {
    let (root, cfg) = campaign("");
    let camp = root.path().join("camp");
    // the same three no-flow images as one multi-page file
    let pages: Vec<Image> = (1..=3)
        .map(|k| bostrack_io::read_image(&camp.join(format!("stack/s{k}.tif"))).unwrap())
        .collect();
    bostrack_io::write_tiff_stack_u16(&camp.join("stack.tif"), &pages).unwrap();
    let file_cfg = root.path().join("file.toml");
    fs::write(
        &file_cfg,
        "[input]\ndir = \"camp\"\nstack = \"stack.tif\"\nstack_dir = \"nowhere\"\n[detect]\nspacing = 8.0\n",
    )
    .unwrap();

    let run = |cfg: &Path, out: &str| {
        let plan = Plan::load(cfg).unwrap();
        let ctx = ReferenceContext::prepare(&plan).unwrap();
        assert_eq!(ctx.stack_summary().unwrap().images, 3);
        assert_eq!(ctx.noise().1, "stack");
        let r = process_frame(&ctx, &plan, &plan.gradients[0]).unwrap();
        write_frame(&root.path().join(out), &r).unwrap();
        (plan, csv_of(&root.path().join(out), "frame_1"))
    };
    let (plan, from_file) = run(&file_cfg, "out-file");
    assert_eq!(plan.stack, vec![camp.join("stack.tif")]);
    let (_, from_folder) = run(&cfg, "out-folder");
    assert!(
        from_file == from_folder,
        "the stack file gives other results"
    );
    // u_ref_x (column 22) comes from the stack
    assert!(
        from_file
            .lines()
            .skip(1)
            .any(|l| l.split(',').nth(22).is_some_and(|u| !u.is_empty()))
    );

    // a stack file that is missing is a configuration error naming the key
    fs::write(
        &file_cfg,
        "[input]\ndir = \"camp\"\nstack = \"none.tif\"\n[detect]\nspacing = 8.0\n",
    )
    .unwrap();
    let e = Plan::load(&file_cfg).unwrap_err();
    assert!(
        matches!(&e, ConfigError::NotFound { key, .. } if key == "input.stack"),
        "{e:?}"
    );
}
