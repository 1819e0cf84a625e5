//! Where the real sample data lives, for tests and benchmarks.

use std::path::PathBuf;

/// `../shared/data/bos-sample` relative to the workspace root (overridable with the environment
/// variable `BOSTRACK_SAMPLE_DIR`).
///
/// Returns `None` when the folder is missing, so a test can skip with a message; **when the
/// environment variable `CI` is `true` a missing folder panics instead**, so that CI fails rather
/// than silently skipping the real-data tests.
pub fn bos_sample_dir() -> Option<PathBuf> {
    let dir = match std::env::var_os("BOSTRACK_SAMPLE_DIR") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bos-sample"),
    };
    if dir.join("pair/reference.tif").is_file() {
        return Some(dir.canonicalize().unwrap_or(dir));
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "real sample data not found at {} (CI=true: tests that need it must fail, not skip)",
            dir.display()
        );
    }
    eprintln!("skipping: real sample data not found at {}", dir.display());
    None
}
