//! Fingerprints of the input files, so that a rerun notices changed inputs: each file's size,
//! modification time and content hash (XXH3-128), recorded in the run record for the
//! reference side (reference image, mask, no-flow images) and the gradient frames, and per
//! frame in `DIR/<stem>/inputs.json` next to the outputs it produced.
//!
//! A file whose size and modification time (ns) equal the recorded ones is taken as unchanged
//! without being read (as make and rsync do); otherwise its content is hashed, so a file that
//! was only touched is not recomputed.

use super::BatchError;
use super::fsx::write_atomic;
use serde::{Deserialize, Serialize};
use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

/// Per-frame input record: `DIR/<stem>/inputs.json`.
pub(crate) const FRAME_INPUTS: &str = "inputs.json";

/// What identifies the content of one input file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct Fingerprint {
    /// The file, absolute (as in the run record).
    pub path: PathBuf,
    /// Size in bytes.
    pub size: u64,
    /// Modification time, ns since the Unix epoch (absent where the system has none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modified_ns: Option<i64>,
    /// XXH3-128 of the content, 32 hex digits.
    pub xxh3_128: String,
}

impl Fingerprint {
    /// The fingerprint of `path`. The content is read and hashed unless `known` names the same
    /// path, size and modification time, whose hash is then taken over.
    pub fn of(path: &Path, known: Option<&Fingerprint>) -> std::io::Result<Fingerprint> {
        let meta = std::fs::metadata(path)?;
        let modified_ns = meta
            .modified()
            .ok()
            .and_then(|t| match t.duration_since(UNIX_EPOCH) {
                Ok(d) => i64::try_from(d.as_nanos()).ok(),
                Err(e) => i64::try_from(e.duration().as_nanos()).ok().map(|n| -n),
            });
        if let Some(k) = known
            && k.path == path
            && k.size == meta.len()
            && k.modified_ns.is_some()
            && k.modified_ns == modified_ns
        {
            return Ok(k.clone());
        }
        let mut file = std::fs::File::open(path)?;
        let mut hasher = xxhash_rust::xxh3::Xxh3::new();
        let mut buf = vec![0u8; 1 << 20];
        let mut size = 0u64;
        loop {
            let n = file.read(&mut buf)?;
            if n == 0 {
                break;
            }
            hasher.update(&buf[..n]);
            size += n as u64;
        }
        Ok(Fingerprint {
            path: path.to_path_buf(),
            size,
            modified_ns,
            xxh3_128: format!("{:032x}", hasher.digest128()),
        })
    }

    /// Whether `self` and `other` describe the same content of the same file.
    pub fn same_content(&self, other: &Fingerprint) -> bool {
        self.path == other.path && self.size == other.size && self.xxh3_128 == other.xxh3_128
    }

    /// `"PATH (content changed: size A -> B bytes, modified later)"`: how `self` differs from the
    /// `old` fingerprint of the same file.
    pub fn change_from(&self, old: &Fingerprint) -> String {
        let mut parts = vec!["content changed".to_string()];
        if self.size != old.size {
            parts.push(format!("size {} -> {} bytes", old.size, self.size));
        }
        match (old.modified_ns, self.modified_ns) {
            (Some(a), Some(b)) if b > a => parts.push("modified later".into()),
            (Some(a), Some(b)) if b < a => parts.push("an older modification time".into()),
            _ => {}
        }
        format!("{} ({})", self.path.display(), parts.join(", "))
    }
}

/// What the outputs of one frame were computed from: `DIR/<stem>/inputs.json`, written once
/// the frame's outputs are.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct FrameInputs {
    /// The gradient image.
    pub frame: Fingerprint,
    /// Digest of everything on the reference side that decides the frame's results: the
    /// result-deciding configuration and the fingerprints of the reference image, mask and
    /// no-flow images ([`super::record::RunRecord::reference_side_key`]).
    pub reference_side: String,
}

impl FrameInputs {
    /// The record of frame folder `dir` (`None`: absent or unreadable).
    pub fn read(dir: &Path) -> Option<FrameInputs> {
        let bytes = std::fs::read(dir.join(FRAME_INPUTS)).ok()?;
        serde_json::from_slice(&bytes).ok()
    }

    pub fn write(&self, dir: &Path) -> Result<(), BatchError> {
        let path = dir.join(FRAME_INPUTS);
        let mut bytes = serde_json::to_vec_pretty(self).map_err(|e| BatchError::Corrupt {
            path: path.clone(),
            message: e.to_string(),
        })?;
        bytes.push(b'\n');
        write_atomic(&path, &bytes)
    }
}

/// Whether the complete outputs of a frame still describe its inputs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Freshness {
    /// Same frame content, same reference side.
    Current,
    /// Same content, but the file was touched (size or time): its record is rewritten so the
    /// next run need not read it again.
    Touched,
    /// The outputs do not describe the inputs (the reason, naming the file).
    Stale(String),
}

/// Compares a frame's recorded inputs with its fingerprint now (`None`: the file cannot be
/// read, which processing will report) and the reference side's key now.
pub(crate) fn freshness(
    stored: Option<&FrameInputs>,
    now: Option<&Fingerprint>,
    reference_side: &str,
    file: &Path,
) -> Freshness {
    let Some(stored) = stored else {
        return Freshness::Stale(format!(
            "{}: its outputs carry no input record ({FRAME_INPUTS}: written by an older \
             bostrack, or the run was interrupted)",
            file.display()
        ));
    };
    let Some(now) = now else {
        return Freshness::Stale(format!("{}: cannot be read", file.display()));
    };
    if !now.same_content(&stored.frame) {
        return Freshness::Stale(if now.path == stored.frame.path {
            format!(
                "{} changed since its outputs were computed",
                now.change_from(&stored.frame)
            )
        } else {
            format!(
                "{}: its outputs were computed from {}",
                file.display(),
                stored.frame.path.display()
            )
        });
    }
    if stored.reference_side != reference_side {
        return Freshness::Stale(format!(
            "{}: its outputs were computed with another reference side or configuration (an \
             interrupted --force run)",
            file.display()
        ));
    }
    if now == &stored.frame {
        Freshness::Current
    } else {
        Freshness::Touched
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fingerprint_follows_the_content() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.tif");
        std::fs::write(&p, b"one").unwrap();
        let a = Fingerprint::of(&p, None).unwrap();
        assert_eq!((a.size, a.xxh3_128.len()), (3, 32));
        assert!(a.modified_ns.is_some());
        assert_eq!(Fingerprint::of(&p, Some(&a)).unwrap(), a);
        // The reference value of XXH3-128 (seed 0) for no bytes, as `xxhsum -H2` prints it.
        let empty = dir.path().join("empty");
        std::fs::write(&empty, b"").unwrap();
        assert_eq!(
            Fingerprint::of(&empty, None).unwrap().xxh3_128,
            "99aa06d3014798d86001c324468d497f"
        );

        // Same size, other content: another hash.
        std::fs::write(&p, b"two").unwrap();
        let b = Fingerprint::of(&p, None).unwrap();
        assert!(!b.same_content(&a));
        let why = b.change_from(&a);
        assert!(why.contains("a.tif (content changed"), "{why}");
        // Taken over only when size and time agree: a forged record with the same size and
        // time is believed (the documented limit), another time is not.
        let mut forged = a.clone();
        forged.modified_ns = b.modified_ns;
        assert_eq!(Fingerprint::of(&p, Some(&forged)).unwrap(), forged);
        let mut old_time = a.clone();
        old_time.modified_ns = Some(1);
        assert_eq!(Fingerprint::of(&p, Some(&old_time)).unwrap(), b);

        let c = {
            std::fs::write(&p, b"three").unwrap();
            Fingerprint::of(&p, Some(&b)).unwrap()
        };
        assert!(
            c.change_from(&b).contains("size 3 -> 5 bytes"),
            "{}",
            c.change_from(&b)
        );
        assert!(Fingerprint::of(&dir.path().join("absent"), None).is_err());
    }

    #[test]
    fn freshness_of_a_frame() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.tif");
        std::fs::write(&p, b"frame").unwrap();
        let fp = Fingerprint::of(&p, None).unwrap();
        let stored = FrameInputs {
            frame: fp.clone(),
            reference_side: "k".into(),
        };
        stored.write(dir.path()).unwrap();
        let back = FrameInputs::read(dir.path()).unwrap();
        assert_eq!(back, stored);
        assert_eq!(
            freshness(Some(&back), Some(&fp), "k", &p),
            Freshness::Current
        );
        let mut touched = fp.clone();
        touched.modified_ns = Some(7);
        assert_eq!(
            freshness(Some(&back), Some(&touched), "k", &p),
            Freshness::Touched
        );
        let stale = |f: Freshness| match f {
            Freshness::Stale(why) => why,
            other => panic!("{other:?}"),
        };
        assert!(
            stale(freshness(Some(&back), Some(&fp), "other", &p))
                .contains("another reference side")
        );
        assert!(stale(freshness(None, Some(&fp), "k", &p)).contains("no input record"));
        let mut changed = fp.clone();
        changed.xxh3_128 = "0".repeat(32);
        assert!(stale(freshness(Some(&back), Some(&changed), "k", &p)).contains("changed since"));
        assert!(stale(freshness(Some(&back), None, "k", &p)).contains("cannot be read"));
    }
}
