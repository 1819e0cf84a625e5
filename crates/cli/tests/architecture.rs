//! Architecture invariants of docs/ARCHITECTURE.md, checked as ordinary tests.

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

fn crates_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Internal (bostrack-*) crates a crate depends on in `[dependencies]` (not dev-dependencies).
fn internal_deps(krate: &str) -> BTreeSet<String> {
    let text = fs::read_to_string(crates_dir().join(krate).join("Cargo.toml")).unwrap();
    let manifest: toml::Table = toml::from_str(&text).unwrap();
    manifest
        .get("dependencies")
        .and_then(|d| d.as_table())
        .map(|t| {
            t.keys()
                .filter(|k| k.starts_with("bostrack-"))
                .cloned()
                .collect()
        })
        .unwrap_or_default()
}

fn all_crates() -> Vec<String> {
    let mut names: Vec<String> = fs::read_dir(crates_dir())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().join("Cargo.toml").is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn stage_crates_never_depend_on_each_other() {
    let allowed: BTreeSet<String> = ["bostrack-core", "bostrack-model"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for stage in [
        "detect",
        "fit",
        "match",
        "displacement",
        "uncertainty",
        "density",
    ] {
        let deps = internal_deps(stage);
        let extra: Vec<_> = deps.difference(&allowed).collect();
        assert!(
            extra.is_empty(),
            "stage crate `{stage}` depends on {extra:?}; stage crates may use only core and model"
        );
    }
    assert!(
        internal_deps("core").is_empty(),
        "core depends on nothing internal"
    );
    let model: Vec<_> = internal_deps("model").into_iter().collect();
    assert_eq!(model, ["bostrack-core"], "model depends only on core");
}

#[test]
fn only_io_pipeline_and_cli_touch_the_filesystem() {
    let allowed = ["io", "pipeline", "cli"];
    let mut offenders = Vec::new();
    for krate in all_crates()
        .into_iter()
        .filter(|k| !allowed.contains(&k.as_str()))
    {
        let mut stack = vec![crates_dir().join(&krate).join("src")];
        while let Some(dir) = stack.pop() {
            for entry in fs::read_dir(&dir).unwrap().filter_map(|e| e.ok()) {
                let path = entry.path();
                if path.is_dir() {
                    stack.push(path);
                } else if path.extension().is_some_and(|e| e == "rs") {
                    let text = fs::read_to_string(&path).unwrap();
                    // test modules may read fixtures; library code may not touch files
                    let lib_part = text.split("#[cfg(test)]").next().unwrap_or("");
                    if ["std::fs", "fs::", "File::open", "File::create"]
                        .iter()
                        .any(|p| lib_part.contains(p))
                    {
                        offenders.push(path.display().to_string());
                    }
                }
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "library code outside io/pipeline/cli touches the filesystem: {offenders:?}"
    );
}
