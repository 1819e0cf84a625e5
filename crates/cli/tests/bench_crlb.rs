//! `bostrack bench` and `bostrack crlb`, driving the real binary in temporary folders.

mod common;
use common::*;

use bostrack_fit::study::{STUDY_CSV_COLUMNS, study_scenes};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Output;

fn example_setup() -> PathBuf {
    repo_root().join("testdata/crlb-setup.toml")
}

/// A one-line error, exit code 1, containing every needle.
fn assert_fails_with(o: &Output, needles: &[&str]) {
    let err = stderr(o);
    assert_eq!(code(o), 1, "stderr: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in: {err}");
    }
}

fn decodes_as_png(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&bytes[1..4], b"PNG", "{}", path.display());
    let img = image::load_from_memory(&bytes).unwrap();
    (img.width(), img.height())
}

fn is_svg(path: &Path) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.starts_with("<svg") && text.trim_end().ends_with("</svg>"));
}

/// Parses a CSV without quoted fields into header and rows of named values.
fn read_csv(path: &Path) -> (Vec<String>, Vec<BTreeMap<String, String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            assert_eq!(v.len(), header.len(), "{l}");
            header
                .iter()
                .cloned()
                .zip(v.iter().map(|s| s.to_string()))
                .collect()
        })
        .collect();
    (header, rows)
}

fn num(row: &BTreeMap<String, String>, key: &str) -> f64 {
    row[key]
        .parse()
        .unwrap_or_else(|_| panic!("{key} = {:?} is not a number", row[key]))
}

#[test]
fn bench_writes_the_study_table_and_figure() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = std::time::Instant::now();
    let o = bostrack(
        &["bench", "--realisations", "20", "--out", "out"],
        dir.path(),
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    eprintln!(
        "bench --realisations 20: {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    let out = dir.path().join("out");

    let (header, rows) = read_csv(&out.join("error-vs-time.csv"));
    assert_eq!(header.join(","), STUDY_CSV_COLUMNS);
    for c in [
        "scene",
        "method",
        "estimator",
        "model",
        "failure_rate",
        "rms_x",
        "rms_over_bound_x",
        "rms_over_bound_y",
        "bias_x",
        "bias_err_x",
        "us_per_dot",
    ] {
        assert!(header.iter().any(|h| h == c), "no column {c}");
    }
    // every scene, each with the same set of methods, which holds every estimator, both
    // solvers and every model
    let mut by_scene: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for r in &rows {
        by_scene
            .entry(r["scene"].clone())
            .or_default()
            .insert(r["method"].clone());
    }
    let scenes: BTreeSet<String> = study_scenes().iter().map(|s| s.name.to_string()).collect();
    assert_eq!(by_scene.keys().cloned().collect::<BTreeSet<_>>(), scenes);
    let methods = by_scene.values().next().unwrap().clone();
    assert!(by_scene.values().all(|m| *m == methods));
    assert_eq!(rows.len(), scenes.len() * methods.len(), "one row per pair");
    for m in [
        "lsg/fast/elliptical/auto/subtract40",
        "lsg/lm_crate/elliptical/auto/subtract40",
        "lsg/fast/axis_aligned/auto/subtract40",
        "lsg/fast/circular/auto/subtract40",
        "lsg/fast/elliptical/integrated/subtract40",
        "lsg/fast/elliptical/point/subtract40",
        "iwc",
        "tpg",
    ] {
        assert!(methods.contains(m), "{m} missing from {methods:?}");
    }
    for r in &rows {
        assert_eq!(num(r, "dots"), 20.0, "{r:?}");
        let f = num(r, "failure_rate");
        assert!((0.0..=1.0).contains(&f));
        assert!(num(r, "us_per_dot") > 0.0);
        // on a clean dot the default least-squares fit is near the bound (20 dots: a ratio
        // has a relative scatter of ~1/sqrt(40) = 16 %)
        if r["scene"] == "clean_s1.6" && r["method"] == "lsg/fast/elliptical/auto/subtract40" {
            assert_eq!(f, 0.0);
            let q = num(r, "rms_over_bound_x");
            assert!(q > 0.5 && q < 1.6, "RMS/bound {q}");
        }
    }
    // the figure: three columns of three panels
    let (w, h) = decodes_as_png(&out.join("error-vs-time.png"));
    assert_eq!(w, 3 * 900);
    assert!(h > 1000, "{h}");
    is_svg(&out.join("error-vs-time.svg"));
    // the printed report starts with the machine record and holds the table
    let text = stdout(&o);
    assert!(
        text.contains("- machine: ") && text.contains("load average"),
        "{text}"
    );
    assert!(text.contains("| clean_s1.6 | lsg/fast/elliptical/auto/subtract40 |"));
}

#[test]
fn bench_rejects_unknown_scenes_and_missing_samples() {
    let dir = tempfile::tempdir().unwrap();
    let o = bostrack(
        &["bench", "--scenes", "clean_s1.6,nope", "--out", "o"],
        dir.path(),
    );
    assert_fails_with(&o, &["unknown scene `nope`", "clean_s1.6"]);
    let o = bostrack(
        &[
            "bench",
            "--real",
            "--sample",
            "no-such-folder",
            "--out",
            "o",
        ],
        dir.path(),
    );
    assert_fails_with(&o, &["no-such-folder", "pair/reference.tif"]);
    // one scene only
    let o = bostrack(
        &[
            "bench",
            "--scenes",
            "touching",
            "--realisations",
            "5",
            "--out",
            "o",
        ],
        dir.path(),
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let (_, rows) = read_csv(&dir.path().join("o/error-vs-time.csv"));
    assert!(!rows.is_empty() && rows.iter().all(|r| r["scene"] == "touching"));
    let (w, _) = decodes_as_png(&dir.path().join("o/error-vs-time.png"));
    assert_eq!(w, 900, "one column");
}

#[test]
fn bench_paper_runs_the_papers_monte_carlo() {
    let dir = tempfile::tempdir().unwrap();
    let o = bostrack(
        &[
            "bench",
            "--paper",
            "--draws",
            "2",
            "--realisations",
            "20",
            "--jobs",
            "1",
            "--out",
            "p",
        ],
        dir.path(),
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let out = dir.path().join("p");
    for study in ["volumetric", "bos"] {
        let text = std::fs::read_to_string(out.join(format!("paper-mc-{study}.csv"))).unwrap();
        assert_eq!(text.lines().count(), 3, "header + 2 draws: {text}");
        decodes_as_png(&out.join(format!("paper-mc-{study}.png")));
        is_svg(&out.join(format!("paper-mc-{study}.svg")));
    }
    let md = std::fs::read_to_string(out.join("paper-mc.md")).unwrap();
    assert!(md.contains("- machine: ") && md.contains("2 draws x 20 realisations"));
    assert_eq!(md, stdout(&o), "the printed report is the file");
}

/// The fields every consumer relies on, compared with the library on the same file.
#[test]
fn crlb_json_agrees_with_the_theory_crate() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_setup();
    let o = bostrack(&["crlb", path.to_str().unwrap(), "--json"], dir.path());
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let text = stdout(&o);
    assert_eq!(text.lines().count(), 1, "one JSON object: {text}");
    let v: Value = serde_json::from_str(&text).unwrap();

    let setup =
        bostrack_theory::Setup::from_toml(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let p = bostrack_theory::predict(&setup).unwrap();
    let expect = [
        ("shift_x", p.shift_x),
        ("shift_y", p.shift_y),
        ("sigma_x", p.sigma_x),
        ("sigma_y", p.sigma_y),
        ("rho", p.rho),
        ("diameter_x", p.diameter_x),
        ("diameter_y", p.diameter_y),
        ("crlb_x", p.crlb_x),
        ("crlb_y", p.crlb_y),
        ("crlb_ref_x", p.crlb_ref_x),
        ("crlb_ref_y", p.crlb_ref_y),
        ("eq35_x", p.eq35_x),
        ("ar_x", p.ar_x),
        ("ar_y", p.ar_y),
        ("ar_exact_x", p.ar_exact_x),
        ("sensitivity_px", p.sensitivity_px),
        ("magnification", p.magnification),
        ("u_d_x", p.crlb_ref_x.hypot(p.crlb_x)),
    ];
    for (k, want) in expect {
        let got = v[k]
            .as_f64()
            .unwrap_or_else(|| panic!("{k} missing or not a number in {text}"));
        assert!(
            (got - want).abs() <= 1e-12 * want.abs().max(1e-300),
            "{k}: {got} vs {want}"
        );
    }
    assert_eq!(v["flags"], p.flags.to_string());
    // independent sanity of the example (docs/theory.md): the dot moves against the gradient,
    // is blurred along x more than y, and its bound is amplified
    assert!(p.shift_x < 0.0 && p.shift_y < 0.0);
    assert!(v["ar_x"].as_f64().unwrap() > 1.0);
    assert!(v["crlb_x"].as_f64().unwrap() > v["crlb_ref_x"].as_f64().unwrap());

    // the text form names the same numbers
    let o = bostrack(&["crlb", path.to_str().unwrap()], dir.path());
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let t = stdout(&o);
    assert!(
        t.contains(&format!("{:+.4}, {:+.4} px", p.shift_x, p.shift_y)),
        "{t}"
    );
    assert!(
        t.contains(&format!("{:.5}, {:.5} px (exact", p.crlb_x, p.crlb_y)),
        "{t}"
    );
}

#[test]
fn crlb_without_density_derivatives_is_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    // the example setup with the [flow] table zeroed
    let text = std::fs::read_to_string(example_setup()).unwrap();
    let still: String = text
        .lines()
        .map(|l| {
            if l.starts_with("gradient_kg_m4") {
                "gradient_kg_m4 = [0.0, 0.0, 0.0]".to_string()
            } else if l.starts_with("hessian_kg_m5") {
                "hessian_kg_m5 = { xx = 0.0, xy = 0.0, yy = 0.0 }".to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    assert_ne!(still, text);
    std::fs::write(dir.path().join("still.toml"), still).unwrap();
    let o = bostrack(&["crlb", "still.toml", "--json"], dir.path());
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let v: Value = serde_json::from_str(&stdout(&o)).unwrap();
    let f = |k: &str| v[k].as_f64().unwrap();
    assert_eq!(f("shift_x"), 0.0);
    assert_eq!(f("shift_y"), 0.0);
    assert_eq!(f("ar_x"), 1.0);
    assert_eq!(f("ar_y"), 1.0);
    assert_eq!(f("rho"), 0.0);
    assert_eq!(f("sigma_x"), f("sigma_y"));
    assert!((f("crlb_x") / f("crlb_ref_x") - 1.0).abs() < 1e-12);
    assert!((f("ar_exact_x") - 1.0).abs() < 1e-12);
    assert_eq!(v["flags"], "");
}

#[test]
fn crlb_bad_setups_exit_1_naming_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("neg.toml"), "[optics]\nf_number = -2.0\n").unwrap();
    let o = bostrack(&["crlb", "neg.toml"], dir.path());
    assert_fails_with(&o, &["neg.toml", "optics.f_number"]);

    std::fs::write(dir.path().join("typo.toml"), "[optics]\nf_numbr = 8.0\n").unwrap();
    let o = bostrack(&["crlb", "typo.toml", "--json"], dir.path());
    assert_fails_with(&o, &["typo.toml", "f_numbr"]);
    assert!(stdout(&o).is_empty());

    // the slab beyond the lens
    std::fs::write(
        dir.path().join("far.toml"),
        "[geometry]\nkind = \"bos\"\nz_d_m = 2.0\ndelta_z_m = 0.05\n",
    )
    .unwrap();
    let o = bostrack(&["crlb", "far.toml"], dir.path());
    assert_fails_with(&o, &["far.toml", "geometry.z_d_m"]);

    let o = bostrack(&["crlb", "missing.toml"], dir.path());
    assert_fails_with(&o, &["missing.toml"]);
    // a sweep needs a folder
    let o = bostrack(&["crlb", "neg.toml", "--sweep"], dir.path());
    assert_eq!(code(&o), 1);
    // a bad sweep value fails before anything is printed
    let example = example_setup();
    let o = bostrack(
        &[
            "crlb",
            example.to_str().unwrap(),
            "--sweep",
            "--out",
            "s",
            "--f-numbers",
            "8,-1",
        ],
        dir.path(),
    );
    assert_fails_with(&o, &["crlb-setup.toml", "f_number", "-1"]);
    assert!(stdout(&o).is_empty());
}

#[test]
fn crlb_sweep_writes_tables_and_figures() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_setup();
    let o = bostrack(
        &["crlb", path.to_str().unwrap(), "--sweep", "--out", "sweep"],
        dir.path(),
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let out = dir.path().join("sweep");
    for name in ["crlb-vs-f-number", "crlb-vs-z_d"] {
        decodes_as_png(&out.join(format!("{name}.png")));
        is_svg(&out.join(format!("{name}.svg")));
    }
    let setup =
        bostrack_theory::Setup::from_toml(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let p = bostrack_theory::predict(&setup).unwrap();

    // f-number: both exposure scalings; at the setup's own f-number... the rows are the
    // library's, and at fixed exposure the exposure does not change
    let (header, rows) = read_csv(&out.join("crlb-vs-f-number.csv"));
    assert_eq!(header[0], "exposure");
    for c in ["f_number", "crlb_x", "crlb_y", "ar_x", "sigma_x", "flags"] {
        assert!(header.iter().any(|h| h == c), "no column {c}");
    }
    let fixed: Vec<_> = rows.iter().filter(|r| r["exposure"] == "fixed").collect();
    let lit: Vec<_> = rows
        .iter()
        .filter(|r| r["exposure"] == "aperture")
        .collect();
    assert_eq!(fixed.len(), 22);
    assert_eq!(lit.len(), 22);
    let e0 = num(fixed[0], "exposure_counts");
    assert!(fixed.iter().all(|r| num(r, "exposure_counts") == e0));
    // at fixed illumination the exposure falls with the f-number
    assert!(num(lit[0], "exposure_counts") > num(lit[21], "exposure_counts"));
    let lib = bostrack_theory::sweep_f_number(
        &setup,
        &[num(fixed[5], "f_number")],
        bostrack_theory::ExposureScaling::Fixed,
    )
    .unwrap();
    assert!((num(fixed[5], "crlb_x") / lib[0].crlb_x - 1.0).abs() < 1e-12);

    // Z_D: the shift stays that of the setup at fixed sensitivity, grows ∝ Z_D at fixed M
    let (header, rows) = read_csv(&out.join("crlb-vs-z_d.csv"));
    assert_eq!(header[0], "hold");
    let sens: Vec<_> = rows.iter().filter(|r| r["hold"] == "sensitivity").collect();
    let mag: Vec<_> = rows
        .iter()
        .filter(|r| r["hold"] == "magnification")
        .collect();
    assert_eq!(sens.len(), 25);
    assert_eq!(mag.len(), 25);
    for r in &sens {
        assert!((num(r, "shift_x") / p.shift_x - 1.0).abs() < 1e-9, "{r:?}");
    }
    let z_d0 = 0.5;
    for r in &mag {
        let want = p.shift_x * num(r, "z_d_m") / z_d0;
        assert!((num(r, "shift_x") / want - 1.0).abs() < 1e-9, "{r:?}");
    }
}

#[test]
fn new_commands_have_help() {
    let dir = tempfile::tempdir().unwrap();
    let o = bostrack(&["--help"], dir.path());
    let help = stdout(&o);
    for sub in ["bench", "crlb"] {
        assert!(help.contains(&format!("\n  {sub} ")), "{help}");
        let o = bostrack(&[sub, "--help"], dir.path());
        assert_eq!(code(&o), 0);
        let text = stdout(&o);
        let lines: Vec<&str> = text.lines().collect();
        let start = lines
            .iter()
            .position(|l| *l == "Arguments:" || *l == "Options:")
            .unwrap();
        for (k, l) in lines.iter().enumerate().skip(start) {
            if l.starts_with("  ") && !l.starts_with("   ") {
                let next = lines.get(k + 1).copied().unwrap_or("");
                assert!(
                    next.starts_with("    ") && !next.trim().is_empty(),
                    "{sub}: no help for {l}"
                );
            }
        }
    }
}

/// One file describes an experiment for both commands (issue #15): the example setup with the
/// pipeline's sections added is still a setup for `crlb` (same prediction), and a
/// `pipeline.toml` for `run` (whose plan holds the setup's optics).
#[test]
fn crlb_reads_the_optical_setup_of_a_pipeline_toml() {
    let dir = tempfile::tempdir().unwrap();
    let setup = std::fs::read_to_string(example_setup()).unwrap();
    let both = format!(
        "[input]\ndir = \".\"\nstack_dir = \"\"\n[output]\ndir = \"out\"\n[density]\n\
         method = \"poisson\"\n{setup}"
    );
    std::fs::write(dir.path().join("setup.toml"), &setup).unwrap();
    std::fs::write(dir.path().join("pipeline.toml"), &both).unwrap();
    let a = bostrack(&["crlb", "setup.toml", "--json"], dir.path());
    let b = bostrack(&["crlb", "pipeline.toml", "--json"], dir.path());
    assert_eq!(code(&b), 0, "{}", stderr(&b));
    // the same prediction; only the file named differs
    assert_eq!(
        stdout(&a).replace("setup.toml", "F"),
        stdout(&b).replace("pipeline.toml", "F")
    );
    let cfg = bostrack_pipeline::parse_config(&both, &dir.path().join("pipeline.toml")).unwrap();
    assert_eq!(cfg.optics.unwrap().focal_length_mm, 105.0);
}
