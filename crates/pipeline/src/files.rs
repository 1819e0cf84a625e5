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
/// Names that are not valid UTF-8 are skipped.
pub fn list_matching(dir: &Path, pattern: &str) -> std::io::Result<Vec<PathBuf>> {
    let mut found: Vec<(String, PathBuf)> = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        let Some(name) = entry.file_name().to_str().map(str::to_owned) else {
            continue;
        };
        if glob_match(pattern, &name) && path.is_file() {
            found.push((name, path));
        }
    }
    found.sort_by(|a, b| natural_cmp(&a.0, &b.0));
    Ok(found.into_iter().map(|(_, p)| p).collect())
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
}
