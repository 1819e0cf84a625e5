//! Changed inputs and odd paths, driving the real binary on a small synthetic campaign: a
//! rerun recomputes exactly the frames whose image changed and refuses a changed reference
//! side (issue #14, "stale results"); folders, files and link loops are named for what they
//! are, and patterns that also match the reference are warned about ("paths and plans").

mod common;
use common::*;

use serde_json::Value;
use std::path::Path;

/// A synthetic campaign of `frames` 96 x 96 px frames (uniform shift field, 3 no-flow images)
/// in `root/camp`, and `root/p.toml` describing it without figures.
fn small_campaign(root: &Path, frames: usize) {
    let frames = frames.to_string();
    let args = [
        "synth", "-o", "camp", "--width", "96", "--height", "96", "--bits", "16", "--frames",
        &frames, "--stack", "3", "--seed", "5",
    ];
    let o = bostrack(&args, root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    config(
        root,
        "reference = \"reference.tif\"\ngradient_dir = \"gradient\"\n",
    );
}

fn config(root: &Path, input: &str) {
    let text = format!(
        "[input]\ndir = \"camp\"\nstack_dir = \"stack\"\n{input}\n[output]\ndir = \"out\"\nfigures = []\n"
    );
    std::fs::write(root.join("p.toml"), text).unwrap();
}

fn read(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn frame_inputs(out: &Path, stem: &str) -> Value {
    serde_json::from_slice(&read(&out.join(stem).join("inputs.json"))).unwrap()
}

#[test]
fn a_changed_frame_is_recomputed_and_a_changed_reference_side_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    small_campaign(root, 4);
    let camp = root.join("camp");
    let out = root.join("out");
    let o = bostrack(&["run", "p.toml", "--jobs", "2"], root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let record = std::fs::read_to_string(out.join("run.toml")).unwrap();
    for part in [
        "[[inputs.reference_side]]",
        "[[inputs.frames]]",
        "xxh3_128 = ",
        "modified_ns = ",
    ] {
        assert!(record.contains(part), "{part}: {record}");
    }
    let f2 = frame_inputs(&out, "frame_02");
    assert!(
        f2["frame"]["path"]
            .as_str()
            .unwrap()
            .ends_with("frame_02.tif")
    );
    assert_eq!(
        f2["frame"]["size"].as_u64(),
        Some(
            std::fs::metadata(camp.join("gradient/frame_02.tif"))
                .unwrap()
                .len()
        )
    );
    let before: Vec<Vec<u8>> = (1..=4)
        .map(|n| read(&out.join(format!("frame_{n:02}/dots.csv"))))
        .collect();
    assert_ne!(before[1], before[2], "frames 2 and 3 differ");

    // Nothing changed: nothing is computed.
    let o = bostrack(&["run", "p.toml"], root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("4 frames complete already") && !stderr(&o).contains("note:"),
        "{}",
        stderr(&o)
    );

    // Frame 2 replaced by frame 3's image: exactly frame 2 is recomputed, and its results are
    // now those of frame 3 (same image, same reference), byte for byte.
    std::fs::copy(
        camp.join("gradient/frame_03.tif"),
        camp.join("gradient/frame_02.tif"),
    )
    .unwrap();
    let o = bostrack(&["run", "p.toml"], root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("note: frame 2: ")
            && err.contains("frame_02.tif (content changed")
            && err.contains("recomputed")
            && err.contains("1 computed (1 of them again, as their inputs changed)")
            && err.contains("3 frames complete already"),
        "{err}"
    );
    assert_eq!(read(&out.join("frame_02/dots.csv")), before[2]);
    for n in [1, 3, 4] {
        assert_eq!(
            read(&out.join(format!("frame_{n:02}/dots.csv"))),
            before[n - 1]
        );
    }
    assert_ne!(frame_inputs(&out, "frame_02")["frame"], f2["frame"]);

    // Touched, not changed: not recomputed, and the new time is recorded.
    let f1 = frame_inputs(&out, "frame_01");
    let file = std::fs::File::options()
        .append(true)
        .open(camp.join("gradient/frame_01.tif"))
        .unwrap();
    file.set_modified(std::time::SystemTime::now() + std::time::Duration::from_secs(60))
        .unwrap();
    drop(file);
    let o = bostrack(&["run", "p.toml"], root);
    assert!(
        code(&o) == 0 && stderr(&o).contains("4 frames complete already"),
        "{}",
        stderr(&o)
    );
    let f1_now = frame_inputs(&out, "frame_01");
    assert_eq!(f1_now["frame"]["xxh3_128"], f1["frame"]["xxh3_128"]);
    assert_ne!(f1_now["frame"]["modified_ns"], f1["frame"]["modified_ns"]);

    // A frame whose input record is missing, or was computed with another reference side (a
    // killed --force run): recomputed, each with its reason.
    std::fs::remove_file(out.join("frame_03/inputs.json")).unwrap();
    let mut f4 = frame_inputs(&out, "frame_04");
    f4["reference_side"] = Value::String("0".repeat(32));
    std::fs::write(out.join("frame_04/inputs.json"), f4.to_string()).unwrap();
    let o = bostrack(&["run", "p.toml"], root);
    let err = stderr(&o);
    assert!(
        code(&o) == 0
            && err.contains("frame 3: ")
            && err.contains("no input record")
            && err.contains("frame 4: ")
            && err.contains("another reference side")
            && err.contains("2 computed (2 of them again"),
        "{err}"
    );
    assert_eq!(read(&out.join("frame_04/dots.csv")), before[3]);

    // A new reference image: every frame depends on it, so the run is refused with the file
    // named, the outputs untouched; --force recomputes, and the record describes the new file.
    let mut stack: Vec<_> = std::fs::read_dir(camp.join("stack"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    stack.sort();
    assert_eq!(stack.len(), 3);
    let reference = camp.join("reference.tif");
    std::fs::copy(&stack[0], &reference).unwrap();
    let o = bostrack(&["run", "p.toml"], root);
    let err = stderr(&o);
    assert_eq!(code(&o), 1, "{err}");
    assert!(
        err.contains("run.toml: the results in this folder were computed from other versions of a reference-side file")
            && err.contains("reference.tif (content changed")
            && err.contains("--force"),
        "{err}"
    );
    assert_eq!(read(&out.join("frame_01/dots.csv")), before[0]);
    let o = bostrack(&["run", "p.toml", "--force", "-q"], root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let record: toml::Table =
        toml::from_str(&std::fs::read_to_string(out.join("run.toml")).unwrap()).unwrap();
    let side = record["inputs"]["reference_side"].as_array().unwrap();
    assert!(side[0]["path"].as_str().unwrap().ends_with("reference.tif"));
    assert_eq!(
        side[0]["size"].as_integer(),
        Some(std::fs::metadata(&reference).unwrap().len() as i64)
    );
    let o = bostrack(&["run", "p.toml"], root);
    assert!(
        code(&o) == 0 && stderr(&o).contains("4 frames complete already"),
        "{}",
        stderr(&o)
    );

    // A changed no-flow image is refused the same way.
    std::fs::copy(&stack[0], &stack[1]).unwrap();
    let o = bostrack(&["run", "p.toml"], root);
    let name = stack[1].file_name().unwrap().to_str().unwrap();
    assert!(
        code(&o) == 1 && stderr(&o).contains(&format!("{name} (content changed")),
        "{}",
        stderr(&o)
    );
}

#[test]
fn paths_are_named_for_what_they_are_and_overlapping_patterns_are_warned_about() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    small_campaign(root, 2);
    let camp = root.join("camp");

    // A folder where a file is needed: not "not found".
    std::fs::create_dir(camp.join("folder.tif")).unwrap();
    config(
        root,
        "reference = \"folder.tif\"\ngradient_dir = \"gradient\"\n",
    );
    let o = bostrack(&["check", "p.toml"], root);
    assert_eq!(code(&o), 1);
    assert!(
        stderr(&o).contains("input.reference: ")
            && stderr(&o).contains("folder.tif: is a folder, not a file")
            && !stderr(&o).contains("not found"),
        "{}",
        stderr(&o)
    );

    // An output folder that is an existing file: refused by check and by run --out.
    config(
        root,
        "reference = \"reference.tif\"\ngradient_dir = \"gradient\"\n",
    );
    std::fs::write(root.join("taken"), b"x").unwrap();
    let text = std::fs::read_to_string(root.join("p.toml")).unwrap();
    std::fs::write(
        root.join("q.toml"),
        text.replace("dir = \"out\"", "dir = \"taken\""),
    )
    .unwrap();
    let o = bostrack(&["check", "q.toml"], root);
    assert_eq!(code(&o), 1);
    assert!(
        stderr(&o).contains("q.toml: output.dir: ")
            && stderr(&o).contains("taken: is a file, not a folder"),
        "{}",
        stderr(&o)
    );
    let o = bostrack(&["run", "p.toml", "--out", "taken", "-q"], root);
    assert_eq!(code(&o), 1);
    assert!(
        stderr(&o).contains("taken: cannot be the output folder: is a file, not a folder"),
        "{}",
        stderr(&o)
    );
    assert_eq!(read(&root.join("taken")), b"x");

    // The reference beside the frames under `*.tif`: warned by check and run (also quiet),
    // and processed as a frame as configured; a folder named like a frame is skipped, warned.
    std::fs::copy(
        camp.join("reference.tif"),
        camp.join("gradient/reference.tif"),
    )
    .unwrap();
    std::fs::create_dir(camp.join("gradient/old.tif")).unwrap();
    config(
        root,
        "reference = \"gradient/reference.tif\"\ngradient_dir = \"gradient\"\n",
    );
    let o = bostrack(&["check", "p.toml"], root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    let plan: Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(plan["gradients"].as_array().unwrap().len(), 3);
    assert_eq!(plan["warnings"].as_array().unwrap().len(), 2, "{plan}");
    let err = stderr(&o);
    assert!(
        err.contains("warning: ")
            && err.contains("input.gradient_glob: `*.tif` also matches the reference image")
            && err.contains("gradient/reference.tif")
            && err.contains("matches the folder")
            && err.contains("old.tif, which is skipped"),
        "{err}"
    );
    let o = bostrack(&["run", "p.toml", "-q"], root);
    assert_eq!(code(&o), 0, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("also matches the reference image"),
        "{}",
        stderr(&o)
    );
    assert!(root.join("out/reference/dots.csv").is_file());

    // A link loop matching the pattern is an error that names it (not skipped).
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink("loop.tif", camp.join("gradient/loop.tif")).unwrap();
        let o = bostrack(&["check", "p.toml"], root);
        assert_eq!(code(&o), 1);
        assert!(
            stderr(&o).contains("input.gradient_glob: ")
                && stderr(&o).contains("loop.tif: matches `*.tif` but cannot be examined"),
            "{}",
            stderr(&o)
        );
    }
}
