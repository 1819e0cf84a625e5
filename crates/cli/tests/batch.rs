//! `bostrack run` and `bostrack merge` on small synthetic campaigns, driving the real binary in
//! temporary folders: failures recorded, determinism across thread counts, resuming after a
//! kill, shards merged equal to one run, refusal of a folder of another configuration.

mod common;
use common::*;

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const FRAMES: usize = 20;

const ALL_FIGURES: &str = "[\"displacement\", \"uncertainty\", \"amplification\", \"histograms\", \"campaign\", \"detections\"]";

/// A synthetic campaign of `frames` 128 x 128 px frames (a Gaussian bump flow, 3 no-flow
/// images) in `root/camp`, and `root/p.toml` describing it with every figure.
fn campaign(root: &Path, frames: usize) {
    let n = frames.to_string();
    let o = bostrack(
        &[
            "synth",
            "-o",
            "camp",
            "--width",
            "128",
            "--height",
            "128",
            "--bits",
            "16",
            "--field",
            "bump:30,16",
            "--blur",
            "20",
            "--frames",
            &n,
            "--stack",
            "3",
            "--seed",
            "11",
        ],
        root,
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    write_config(root, "p.toml", "");
}

fn write_config(root: &Path, name: &str, extra: &str) {
    let text = format!(
        "[input]\ndir = \"camp\"\nreference = \"reference.tif\"\nstack_dir = \"stack\"\n\
         gradient_dir = \"gradient\"\n{extra}\n[output]\ndir = \"out\"\nfigures = {ALL_FIGURES}\n"
    );
    std::fs::write(root.join(name), text).unwrap();
}

/// Every file under `dir` (relative path → bytes), hidden names included.
fn tree(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(base: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(base, &p, out);
            } else {
                out.insert(
                    p.strip_prefix(base).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// Removes every key naming a wall time from a JSON value.
fn drop_times(v: &mut Value) {
    match v {
        Value::Object(o) => {
            o.retain(|k, _| !(k.contains("time") || k.contains("seconds")));
            o.values_mut().for_each(drop_times);
        }
        Value::Array(a) => a.iter_mut().for_each(drop_times),
        _ => {}
    }
}

/// campaign.csv without the timing columns that campaign.json names.
fn campaign_csv_without_times(out: &Path) -> String {
    let json: Value =
        serde_json::from_slice(&std::fs::read(out.join("campaign.json")).unwrap()).unwrap();
    let timing: Vec<&str> = json["timing_columns"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(timing.iter().any(|c| c.starts_with("times.")), "{timing:?}");
    let text = std::fs::read_to_string(out.join("campaign.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let keep: Vec<usize> = (0..header.len())
        .filter(|&k| !timing.contains(&header[k]))
        .collect();
    let mut out = String::new();
    for line in std::iter::once(header.join(",")).chain(lines.map(str::to_owned)) {
        // No cell of these campaigns holds a comma (reasons are not compared this way).
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), header.len(), "{line}");
        out += &keep.iter().map(|&k| cells[k]).collect::<Vec<_>>().join(",");
        out.push('\n');
    }
    out
}

/// The outputs of a run that do not depend on wall times or on the output folder's name:
/// every frame file (summary.json without its times) and the campaign files.
fn comparable(out: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut t = tree(out);
    t.retain(|p, _| !(p.starts_with("shards") || p == Path::new("run.toml")));
    for (p, bytes) in t.iter_mut() {
        let name = p.file_name().unwrap().to_str().unwrap();
        if name == "summary.json" || name == "campaign.json" {
            let mut v: Value = serde_json::from_slice(bytes).unwrap();
            drop_times(&mut v);
            *bytes = serde_json::to_vec(&v).unwrap();
        }
    }
    t.insert(
        PathBuf::from("campaign.csv"),
        campaign_csv_without_times(out).into_bytes(),
    );
    t
}

fn assert_same(a: &BTreeMap<PathBuf, Vec<u8>>, b: &BTreeMap<PathBuf, Vec<u8>>) {
    let ka: Vec<_> = a.keys().collect();
    let kb: Vec<_> = b.keys().collect();
    assert_eq!(ka, kb, "different files");
    for (p, bytes) in a {
        assert!(bytes == &b[p], "{} differs", p.display());
    }
}

fn complete_frames(out: &Path) -> usize {
    (1..=FRAMES * 2)
        .filter(|n| out.join(format!("frame_{n:02}/summary.json")).is_file())
        .count()
}

#[test]
fn a_corrupt_frame_is_recorded_the_others_finish_and_outputs_do_not_depend_on_jobs() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    campaign(root, FRAMES);
    let bad = root.join("camp/gradient/frame_07.tif");
    std::fs::write(&bad, b"II*\0 this is not a TIFF any more").unwrap();

    let o = bostrack(&["run", "p.toml", "--jobs", "2"], root);
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("failed: frame 7") && err.contains("frame_07.tif"),
        "{err}"
    );
    let out = root.join("out");
    assert_eq!(complete_frames(&out), FRAMES - 1);
    assert!(!out.join("frame_07").exists());

    let failures: Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    assert_eq!(failures["failed"], 1);
    let f = &failures["failures"][0];
    assert_eq!(
        (f["frame"].as_u64(), f["stem"].as_str()),
        (Some(7), Some("frame_07"))
    );
    assert!(f["file"].as_str().unwrap().ends_with("frame_07.tif"), "{f}");
    assert!(
        f["reason"].as_str().unwrap().contains("frame_07.tif"),
        "{f}"
    );

    // The campaign table: one row per frame in order, frame 7 failed, medians plausible
    // (the bump moves dots by up to 30 e^-1/2 / 16 = 1.14 px).
    let campaign: Value =
        serde_json::from_slice(&std::fs::read(out.join("campaign.json")).unwrap()).unwrap();
    let rows = campaign["rows"].as_array().unwrap();
    assert_eq!(rows.len(), FRAMES);
    for (k, r) in rows.iter().enumerate() {
        assert_eq!(r["frame"].as_u64(), Some(k as u64 + 1));
        if k == 6 {
            assert_eq!(r["status"], "failed");
        } else {
            assert_eq!(r["status"], "ok", "{r}");
            let d = r["medians.abs_d"].as_f64().unwrap();
            assert!(d > 0.01 && d < 1.2, "{d}");
            assert!(r["timings"]["times.fit"].as_f64().unwrap() >= 0.0);
        }
    }
    let csv = std::fs::read_to_string(out.join("campaign.csv")).unwrap();
    assert_eq!(csv.lines().count(), FRAMES + 1);
    assert!(csv.lines().nth(7).unwrap().contains(",failed,"), "{csv}");

    // Every requested figure exists, PNG, per frame and per campaign.
    for n in [1, 20] {
        for name in [
            "displacement",
            "uncertainty",
            "amplification",
            "uncertainty-histogram",
            "ar-histogram",
        ] {
            let png = std::fs::read(out.join(format!("frame_{n:02}/{name}.png"))).unwrap();
            assert_eq!(&png[1..4], b"PNG", "{name}");
        }
    }
    for name in ["campaign.png", "detections.png"] {
        assert_eq!(&std::fs::read(out.join(name)).unwrap()[1..4], b"PNG");
    }
    let record = std::fs::read_to_string(out.join("run.toml")).unwrap();
    assert!(record.contains("bostrack_version") && record.contains("[config.fit]"));

    // One thread gives byte-identical per-dot outputs and figures.
    let o = bostrack(
        &["run", "p.toml", "--jobs", "1", "--out", "out1", "-q"],
        root,
    );
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert_same(&comparable(&out), &comparable(&root.join("out1")));

    // A rerun skips every complete frame and retries the failed one; outputs unchanged.
    let before = tree(&out);
    let o = bostrack(&["run", "p.toml", "--jobs", "2"], root);
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("19 frames complete already"),
        "{}",
        stderr(&o)
    );
    let after = tree(&out);
    for (p, bytes) in &before {
        let name = p.to_str().unwrap();
        if name.starts_with("frame_") {
            assert!(after[p] == *bytes, "{name} changed on a rerun");
        }
    }
}

#[test]
fn a_killed_run_resumes_to_the_outputs_of_an_uninterrupted_one() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    campaign(root, FRAMES);
    let o = bostrack(&["run", "p.toml", "--out", "whole", "-q"], root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));

    // Kill a one-thread run once a few frames are done (retry with an earlier kill if it
    // finished first on a fast machine).
    let out = root.join("out");
    let mut killed_partway = false;
    for wanted in [4, 2, 1] {
        let _ = std::fs::remove_dir_all(&out);
        let mut child = Command::new(env!("CARGO_BIN_EXE_bostrack"))
            .args(["run", "p.toml", "--jobs", "1", "-q"])
            .current_dir(root)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        while complete_frames(&out) < wanted && t0.elapsed() < Duration::from_secs(120) {
            if child.try_wait().unwrap().is_some() {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        child.kill().ok();
        child.wait().unwrap();
        let done = complete_frames(&out);
        if done < FRAMES {
            killed_partway = true;
            break;
        }
    }
    assert!(
        killed_partway,
        "every run finished before it could be killed"
    );
    // Complete frames: data and figures; a frame killed while drawing has only its data.
    let done = (1..=FRAMES)
        .filter(|n| out.join(format!("frame_{n:02}/figures.json")).is_file())
        .count();
    assert!(
        !out.join("campaign.csv").exists(),
        "a killed run wrote campaign files"
    );

    let o = bostrack(&["run", "p.toml", "--jobs", "2"], root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    if done > 0 {
        assert!(
            stderr(&o).contains(&format!("{done} frames complete already")),
            "{done}: {}",
            stderr(&o)
        );
    }
    // Nothing hidden or temporary is left, and everything equals the uninterrupted run.
    for p in tree(&out).keys() {
        assert!(
            !p.components()
                .any(|c| c.as_os_str().to_string_lossy().starts_with('.')),
            "left over: {}",
            p.display()
        );
    }
    assert_same(&comparable(&root.join("whole")), &comparable(&out));
}

#[test]
fn merged_shards_equal_one_run_and_a_changed_configuration_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    campaign(root, FRAMES);
    // Frame 5 (shard 2/3) is unreadable: its failure must merge like the rest.
    std::fs::write(root.join("camp/gradient/frame_05.tif"), b"not an image").unwrap();
    let o = bostrack(&["run", "p.toml", "--out", "whole", "-q"], root);
    assert_eq!(code(&o), 2, "{}", stderr(&o));

    // Two of three shards, then merge: the missing shard's frames are reported.
    for k in ["1/3", "3/3"] {
        let o = bostrack(&["run", "p.toml", "--shard", k, "--jobs", "1"], root);
        assert_eq!(code(&o), 0, "{k}: {}", stderr(&o));
        assert!(stderr(&o).contains("bostrack merge"), "{}", stderr(&o));
    }
    let out = root.join("out");
    assert!(!out.join("campaign.csv").exists() && !out.join("run.toml").exists());
    assert!(out.join("shards/shard-1-of-3.toml").is_file());
    let shard1: Vec<usize> = (1..=FRAMES)
        .filter(|n| out.join(format!("frame_{n:02}")).exists())
        .collect();
    let expected: Vec<usize> = (1..=FRAMES).filter(|n| (n - 1) % 3 != 1).collect();
    assert_eq!(
        shard1, expected,
        "shards 1/3 and 3/3 take frames n with (n-1) mod 3 = 0, 2"
    );
    let o = bostrack(&["merge", "out"], root);
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert!(stderr(&o).contains("not processed"), "{}", stderr(&o));
    let failures: Value =
        serde_json::from_slice(&std::fs::read(out.join("failures.json")).unwrap()).unwrap();
    let missing = (1..=FRAMES).filter(|n| (n - 1) % 3 == 1).count();
    assert_eq!(failures["failed"].as_u64(), Some(missing as u64));

    // The last shard, then merge: identical to the unsharded run, frame 5's failure included.
    let o = bostrack(&["run", "p.toml", "--shard", "2/3"], root);
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    let o = bostrack(&["merge", "out"], root);
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("failed: frame 5") && !stderr(&o).contains("not processed"),
        "{}",
        stderr(&o)
    );
    assert_same(&comparable(&root.join("whole")), &comparable(&out));
    let record = std::fs::read_to_string(out.join("run.toml")).unwrap();
    assert!(record.contains("kind = \"merge\""), "{record}");

    // Another fit setting into the same folder is refused; --force recomputes.
    write_config(root, "p.toml", "[fit]\nmax_iterations = 30\n");
    let o = bostrack(&["run", "p.toml"], root);
    assert_eq!(code(&o), 1, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("another configuration") && stderr(&o).contains("config.fit"),
        "{}",
        stderr(&o)
    );
    let o = bostrack(&["run", "p.toml", "--out", "whole", "--force", "-q"], root);
    assert_eq!(code(&o), 2, "{}", stderr(&o));

    // Usage errors.
    for bad in ["0/3", "4/3", "x"] {
        let o = bostrack(&["run", "p.toml", "--shard", bad], root);
        assert_eq!(code(&o), 1, "{bad}");
    }
    let o = bostrack(&["merge", "camp"], root);
    assert_eq!(code(&o), 1);
    assert!(stderr(&o).contains("no run record"), "{}", stderr(&o));
}

#[test]
fn the_real_sample_produces_every_figure() {
    let Some(_) = bostrack_io::bos_sample_dir() else {
        eprintln!("skipped: the real sample data (../shared/data/bos-sample) is absent");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../testdata/bos-sample.toml");
    let o = bostrack(
        &["run", config.to_str().unwrap(), "--out", "out", "-q"],
        dir.path(),
    );
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let out = dir.path().join("out");
    for name in [
        "gradient/displacement.png",
        "gradient/uncertainty.png",
        "gradient/amplification.png",
        "gradient/uncertainty-histogram.png",
        "gradient/ar-histogram.png",
        "campaign.png",
        "detections.png",
    ] {
        let png = std::fs::read(out.join(name)).unwrap();
        assert_eq!(&png[1..4], b"PNG", "{name}");
    }
    let figures: Value =
        serde_json::from_slice(&std::fs::read(out.join("gradient/figures.json")).unwrap()).unwrap();
    assert_eq!(figures["skipped"].as_array().unwrap().len(), 0, "{figures}");
    let campaign = std::fs::read_to_string(out.join("campaign.csv")).unwrap();
    assert_eq!(campaign.lines().count(), 2);
    assert!(
        campaign
            .lines()
            .nth(1)
            .unwrap()
            .starts_with("1,gradient,gradient.tif,ok,")
    );
}
