//! Small filesystem helpers of the batch runner: atomic writes and stale temporaries.

use super::BatchError;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Marker in the names of this module's temporary files: `.NAME.batch-tmp-PID-N`.
const TMP_MARK: &str = ".batch-tmp-";

/// Writes `bytes` to `path` through a hidden temporary file in the same folder and a rename, so
/// a reader (or a rerun after a kill) never sees half a file.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), BatchError> {
    let tmp = temporary_name(path);
    let result = std::fs::File::create(&tmp)
        .and_then(|mut f| f.write_all(bytes).and_then(|()| f.flush()))
        .and_then(|()| std::fs::rename(&tmp, path));
    if let Err(source) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(BatchError::Write {
            path: path.to_path_buf(),
            source,
        });
    }
    Ok(())
}

/// A file written under a hidden temporary name and renamed into place by
/// [`AtomicFile::commit`]; dropped without a commit, the temporary is removed.
pub(crate) struct AtomicFile {
    path: PathBuf,
    tmp: PathBuf,
    writer: Option<std::io::BufWriter<std::fs::File>>,
}

impl AtomicFile {
    pub(crate) fn create(path: &Path) -> Result<AtomicFile, BatchError> {
        let tmp = temporary_name(path);
        let file = std::fs::File::create(&tmp).map_err(|source| BatchError::Write {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(AtomicFile {
            path: path.to_path_buf(),
            tmp,
            writer: Some(std::io::BufWriter::new(file)),
        })
    }

    pub(crate) fn writer(&mut self) -> &mut std::io::BufWriter<std::fs::File> {
        self.writer.as_mut().expect("not committed")
    }

    pub(crate) fn commit(mut self) -> Result<(), BatchError> {
        let w = self.writer.take().expect("not committed");
        let result = w
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)
            .and_then(|_| std::fs::rename(&self.tmp, &self.path));
        result.map_err(|source| BatchError::Write {
            path: self.path.clone(),
            source,
        })
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.tmp.exists() {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

fn temporary_name(path: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    dir.join(format!(".{name}{TMP_MARK}{}-{n}", std::process::id()))
}

/// Creates `dir` and its parents.
pub(crate) fn create_dir(dir: &Path) -> Result<(), BatchError> {
    std::fs::create_dir_all(dir).map_err(|source| BatchError::Write {
        path: dir.to_path_buf(),
        source,
    })
}

/// Removes what a killed run left of frame `stem`: the pair pipeline's temporary folders
/// `DIR/.STEM.tmp-*` and this module's temporary files inside `DIR/STEM/`. Only this frame's
/// names are touched, so shards working in the same folder never remove each other's files.
pub(crate) fn remove_stale_temporaries(out_dir: &Path, stem: &str) {
    let prefix = format!(".{stem}.tmp-");
    if let Ok(entries) = std::fs::read_dir(out_dir) {
        for e in entries.flatten() {
            let name = e.file_name();
            let name = name.to_string_lossy();
            if name.starts_with(&prefix) {
                let p = e.path();
                let _ = if p.is_dir() {
                    std::fs::remove_dir_all(&p)
                } else {
                    std::fs::remove_file(&p)
                };
            }
        }
    }
    remove_stale_files(&out_dir.join(stem));
}

/// Removes this module's temporary files (`.*.batch-tmp-*`) directly inside `dir`.
pub(crate) fn remove_stale_files(dir: &Path) {
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let name = e.file_name();
            let name = name.to_string_lossy();
            if name.starts_with('.') && name.contains(TMP_MARK) && e.path().is_file() {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// Reads a whole file, naming it in the error.
pub(crate) fn read(path: &Path) -> Result<Vec<u8>, BatchError> {
    std::fs::read(path).map_err(|source| BatchError::Read {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["a.txt"]);
        let e = write_atomic(&dir.path().join("no/such/dir.txt"), b"x").unwrap_err();
        assert!(e.to_string().contains("dir.txt"), "{e}");

        let mut f = AtomicFile::create(&p).unwrap();
        f.writer().write_all(b"three").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two", "not yet committed");
        f.commit().unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"three");
        let mut f = AtomicFile::create(&p).unwrap();
        f.writer().write_all(b"four").unwrap();
        drop(f);
        assert_eq!(
            std::fs::read(&p).unwrap(),
            b"three",
            "dropped, not committed"
        );
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn stale_temporaries_of_one_frame_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir_all(d.join(".f1.tmp-123/x")).unwrap();
        std::fs::create_dir_all(d.join(".f10.tmp-123")).unwrap();
        std::fs::create_dir_all(d.join("f1")).unwrap();
        std::fs::write(d.join("f1/.a.png.batch-tmp-9-0"), b"x").unwrap();
        std::fs::write(d.join("f1/keep.png"), b"x").unwrap();
        remove_stale_temporaries(d, "f1");
        assert!(!d.join(".f1.tmp-123").exists());
        assert!(d.join(".f10.tmp-123").exists(), "another frame's temporary");
        assert!(!d.join("f1/.a.png.batch-tmp-9-0").exists());
        assert!(d.join("f1/keep.png").exists());
    }
}
