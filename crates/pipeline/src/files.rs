//! File-name patterns and natural sorting of the frames of a campaign.

use std::cmp::Ordering;
use std::path::{Path, PathBuf};

/// Whether `name` matches the file-name pattern `pattern`.
///
/// `*` matches any run of characters (also none), `?` exactly one character, `[abc]` one of the
/// listed characters, `[a-z]` one in the range and `[!a-z]` one outside it. Everything else matches
/// itself (case-sensitively). Patterns apply to file names only, never to folders.
pub fn glob_match(pattern: &str, name: &str) -> bool {
    let p: Vec<char> = pattern.chars().collect();
    let n: Vec<char> = name.chars().collect();
    // Iterative matcher with backtracking to the last `*` (linear in practice).
    let (mut pi, mut ni) = (0usize, 0usize);
    let mut star: Option<(usize, usize)> = None;
    while ni < n.len() {
        if pi < p.len() {
            match p[pi] {
                '*' => {
                    star = Some((pi, ni));
                    pi += 1;
                    continue;
                }
                '?' => {
                    pi += 1;
                    ni += 1;
                    continue;
                }
                '[' => {
                    if let Some((matched, next)) = class_match(&p, pi, n[ni]) {
                        if matched {
                            pi = next;
                            ni += 1;
                            continue;
                        }
                    } else if n[ni] == '[' {
                        // An unclosed `[` is a literal.
                        pi += 1;
                        ni += 1;
                        continue;
                    }
                }
                c if c == n[ni] => {
                    pi += 1;
                    ni += 1;
                    continue;
                }
                _ => {}
            }
        }
        match star {
            Some((sp, sn)) => {
                pi = sp + 1;
                ni = sn + 1;
                star = Some((sp, sn + 1));
            }
            None => return false,
        }
    }
    p[pi..].iter().all(|&c| c == '*')
}

/// Matches the character class starting at `p[start] == '['` against `c`: `Some((matched, index
/// after the class))`, or `None` if the class is not closed.
fn class_match(p: &[char], start: usize, c: char) -> Option<(bool, usize)> {
    let mut i = start + 1;
    let negate = matches!(p.get(i), Some('!') | Some('^'));
    if negate {
        i += 1;
    }
    let mut matched = false;
    let mut first = true;
    while i < p.len() {
        if p[i] == ']' && !first {
            return Some((matched != negate, i + 1));
        }
        first = false;
        if i + 2 < p.len() && p[i + 1] == '-' && p[i + 2] != ']' {
            if p[i] <= c && c <= p[i + 2] {
                matched = true;
            }
            i += 3;
        } else {
            if p[i] == c {
                matched = true;
            }
            i += 1;
        }
    }
    None
}

/// Natural order of two strings: runs of ASCII digits compare by their numeric value, so
/// `frame2` sorts before `frame10`; ties (e.g. `frame01` vs `frame1`) fall back to plain order.
pub fn natural_cmp(a: &str, b: &str) -> Ordering {
    let (ab, bb) = (a.as_bytes(), b.as_bytes());
    let (mut i, mut j) = (0usize, 0usize);
    while i < ab.len() && j < bb.len() {
        if ab[i].is_ascii_digit() && bb[j].is_ascii_digit() {
            let si = i;
            while i < ab.len() && ab[i].is_ascii_digit() {
                i += 1;
            }
            let sj = j;
            while j < bb.len() && bb[j].is_ascii_digit() {
                j += 1;
            }
            let na = strip_zeros(&ab[si..i]);
            let nb = strip_zeros(&bb[sj..j]);
            let ord = na.len().cmp(&nb.len()).then_with(|| na.cmp(nb));
            if ord != Ordering::Equal {
                return ord;
            }
        } else {
            // Compare one character (UTF-8 bytes compare like code points).
            if ab[i] != bb[j] {
                return ab[i].cmp(&bb[j]);
            }
            i += 1;
            j += 1;
        }
    }
    (ab.len() - i).cmp(&(bb.len() - j)).then_with(|| a.cmp(b))
}

fn strip_zeros(d: &[u8]) -> &[u8] {
    let k = d.iter().position(|&c| c != b'0').unwrap_or(d.len());
    &d[k..]
}

/// The files (not folders) of `dir` whose names match `pattern`, in natural order of their names.
/// Names that are not valid UTF-8 are skipped, and so is every match that is not a file (see
/// `Plan::load` for the errors and warnings they give there).
pub fn list_matching(dir: &Path, pattern: &str) -> std::io::Result<Vec<PathBuf>> {
    Ok(list_inputs(dir, pattern)?.files)
}

/// What a folder holds under a file-name pattern ([`list_inputs`]); every list in natural
/// order of the names.
#[derive(Debug, Default)]
pub(crate) struct Listing {
    /// Regular files (symbolic links followed).
    pub files: Vec<PathBuf>,
    /// Folders whose names match (never inputs).
    pub folders: Vec<PathBuf>,
    /// Matches that are neither: a broken symbolic link, a link loop, a FIFO..., with the
    /// problem ([`PathKind::problem`]).
    pub unusable: Vec<(PathBuf, String)>,
}

/// The entries of `dir` whose names match `pattern`, sorted into files, folders and unusable
/// entries. Names that are not valid UTF-8 are skipped.
pub(crate) fn list_inputs(dir: &Path, pattern: &str) -> std::io::Result<Listing> {
    let mut found: Vec<(String, PathBuf)> = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let Some(name) = entry.file_name().to_str().map(str::to_owned) else {
            continue;
        };
        if glob_match(pattern, &name) {
            found.push((name, entry.path()));
        }
    }
    found.sort_by(|a, b| natural_cmp(&a.0, &b.0));
    let mut out = Listing::default();
    for (_, path) in found {
        match PathKind::of(&path) {
            PathKind::File => out.files.push(path),
            PathKind::Dir => out.folders.push(path),
            // Removed while listing: not there.
            PathKind::Missing => {}
            kind => {
                let problem = kind.problem(Want::File).unwrap_or_default();
                out.unusable.push((path, problem));
            }
        }
    }
    Ok(out)
}

/// What a path is, symbolic links followed.
#[derive(Debug)]
pub(crate) enum PathKind {
    File,
    Dir,
    /// Neither a file nor a folder (a FIFO, a socket, a device).
    Special,
    /// Nothing at that path.
    Missing,
    /// A symbolic link whose target does not exist.
    DanglingLink,
    /// The path cannot be examined (a symbolic link loop, a file used as a folder, no
    /// permission): the system's reason.
    Unreadable(std::io::Error),
}

/// What a path is needed as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Want {
    File,
    Dir,
}

impl PathKind {
    pub fn of(p: &Path) -> PathKind {
        match std::fs::metadata(p) {
            Ok(m) if m.is_file() => PathKind::File,
            Ok(m) if m.is_dir() => PathKind::Dir,
            Ok(_) => PathKind::Special,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                if std::fs::symlink_metadata(p).is_ok() {
                    PathKind::DanglingLink
                } else {
                    PathKind::Missing
                }
            }
            Err(e) => PathKind::Unreadable(e),
        }
    }

    /// Why the path cannot serve as `want` (`None`: it can, or it does not exist).
    pub fn problem(&self, want: Want) -> Option<String> {
        Some(match (self, want) {
            (PathKind::Missing, _) | (PathKind::File, Want::File) | (PathKind::Dir, Want::Dir) => {
                return None;
            }
            (PathKind::Dir, Want::File) => "is a folder, not a file".into(),
            (PathKind::File, Want::Dir) => "is a file, not a folder".into(),
            (PathKind::Special, Want::File) => {
                "is not a regular file (a FIFO, socket or device)".into()
            }
            (PathKind::Special, Want::Dir) => "is not a folder (a FIFO, socket or device)".into(),
            (PathKind::DanglingLink, _) => "is a symbolic link whose target does not exist".into(),
            (PathKind::Unreadable(e), _) => format!("cannot be examined: {e}"),
        })
    }
}

/// Why `dir` cannot be created or used as an output folder: it, or the nearest ancestor that
/// exists, is not a folder (`None`: it is a folder, or can be created under one).
pub(crate) fn output_dir_problem(dir: &Path) -> Option<String> {
    let mut p = dir;
    loop {
        let kind = PathKind::of(p);
        if let PathKind::Missing = kind {
            match p.parent() {
                Some(q) if !q.as_os_str().is_empty() => p = q,
                _ => return None,
            }
            continue;
        }
        let problem = kind.problem(Want::Dir)?;
        return Some(if p == dir {
            problem
        } else {
            format!("cannot be created: {} {problem}", p.display())
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glob_basics() {
        assert!(glob_match("*.tif", "frame10.tif"));
        assert!(glob_match("*.tif", ".tif"));
        assert!(!glob_match("*.tif", "frame10.tiff"));
        assert!(glob_match("*.tif*", "frame10.tiff"));
        assert!(glob_match("im_????.tif", "im_0001.tif"));
        assert!(!glob_match("im_????.tif", "im_001.tif"));
        assert!(glob_match("im_[0-9]*", "im_7x"));
        assert!(!glob_match("im_[!0-9]*", "im_7x"));
        assert!(glob_match("im_[!0-9]*", "im_ax"));
        assert!(glob_match("a*b*c", "aXXbYYbZc"));
        assert!(!glob_match("a*b*c", "aXXbYYbZ"));
        assert!(glob_match("gradient.tif", "gradient.tif"));
        assert!(!glob_match("gradient.tif", "gradient.tiff"));
        assert!(glob_match("[x", "[x"));
        assert!(glob_match("*", ""));
        assert!(!glob_match("?", ""));
    }

    #[test]
    fn natural_order() {
        let mut v = vec![
            "frame10.tif",
            "frame2.tif",
            "frame1.tif",
            "frame02.tif",
            "a.tif",
            "frame.tif",
        ];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            v,
            [
                "a.tif",
                "frame.tif",
                "frame1.tif",
                "frame02.tif",
                "frame2.tif",
                "frame10.tif"
            ]
        );
        assert_eq!(
            natural_cmp("x99999999999999999999999", "x100000000000000000000000"),
            Ordering::Less
        );
        assert_eq!(natural_cmp("im_0010", "im_0009"), Ordering::Greater);
        assert_eq!(natural_cmp("same", "same"), Ordering::Equal);
    }

    #[test]
    fn lists_only_matching_files_naturally() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["f10.tif", "f2.tif", "f1.tif", "notes.txt"] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        std::fs::create_dir(dir.path().join("f3.tif")).unwrap(); // a folder, not a file
        let names: Vec<String> = list_matching(dir.path(), "*.tif")
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["f1.tif", "f2.tif", "f10.tif"]);
    }

    #[cfg(unix)]
    #[test]
    fn folders_links_and_loops_are_told_apart() {
        use std::os::unix::fs::symlink;
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("f1.tif"), b"x").unwrap();
        std::fs::create_dir(d.join("f2.tif")).unwrap();
        symlink("f1.tif", d.join("f3.tif")).unwrap(); // a link to a file: a file
        symlink("absent.tif", d.join("f4.tif")).unwrap();
        symlink("f5.tif", d.join("f5.tif")).unwrap(); // a loop
        let l = list_inputs(d, "*.tif").unwrap();
        let name = |p: &PathBuf| p.file_name().unwrap().to_str().unwrap().to_owned();
        assert_eq!(
            l.files.iter().map(name).collect::<Vec<_>>(),
            ["f1.tif", "f3.tif"]
        );
        assert_eq!(l.folders.iter().map(name).collect::<Vec<_>>(), ["f2.tif"]);
        assert_eq!(l.unusable.len(), 2);
        assert_eq!(name(&l.unusable[0].0), "f4.tif");
        assert!(
            l.unusable[0].1.contains("target does not exist"),
            "{:?}",
            l.unusable
        );
        assert_eq!(name(&l.unusable[1].0), "f5.tif");
        assert!(
            l.unusable[1].1.contains("symbolic links"),
            "a loop is named by the system's reason: {:?}",
            l.unusable
        );
        assert_eq!(list_matching(d, "*.tif").unwrap().len(), 2);

        assert_eq!(PathKind::of(&d.join("f2.tif")).problem(Want::Dir), None);
        assert_eq!(
            PathKind::of(&d.join("f2.tif"))
                .problem(Want::File)
                .as_deref(),
            Some("is a folder, not a file")
        );
        assert_eq!(PathKind::of(&d.join("nope")).problem(Want::File), None);

        assert_eq!(output_dir_problem(&d.join("new/deeper")), None);
        assert_eq!(output_dir_problem(&d.join("f2.tif")), None);
        assert_eq!(
            output_dir_problem(&d.join("f1.tif")).as_deref(),
            Some("is a file, not a folder")
        );
        let under_file = output_dir_problem(&d.join("f1.tif/out")).unwrap();
        assert!(under_file.contains("cannot be examined"), "{under_file}");
        let under_missing_file = output_dir_problem(&d.join("f4.tif")).unwrap();
        assert!(
            under_missing_file.contains("target does not exist"),
            "{under_missing_file}"
        );
        assert!(output_dir_problem(&d.join("f5.tif")).is_some());
    }
}
