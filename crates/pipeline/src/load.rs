//! Reading `pipeline.toml` into a [`PipelineConfig`], with errors that name the file, the line and
//! the key, and suggest the key that was probably meant.

use crate::config::PipelineConfig;
use crate::error::ConfigError;
use crate::suggest::did_you_mean;
use serde::de::DeserializeOwned;
use std::path::Path;

/// Reads and parses a configuration file (first level: the file as written; no path is checked).
pub fn load_config(path: &Path) -> Result<PipelineConfig, ConfigError> {
    parse_config(&read_config_text(path)?, path)
}

/// Parses configuration text; `path` is only used to name the file in errors.
pub fn parse_config(text: &str, path: &Path) -> Result<PipelineConfig, ConfigError> {
    let cfg = parse_toml(text, path)?;
    crate::density::check_required_keys(text, path)?;
    Ok(cfg)
}

/// Reads any TOML file into `T` with the errors of [`load_config`] (file, line, unknown key with
/// a suggestion); for the stage crates' own files, e.g. a synthetic scene.
pub fn load_toml<T: DeserializeOwned>(path: &Path) -> Result<T, ConfigError> {
    let text = read_config_text(path)?;
    parse_toml(&text, path)
}

/// Largest configuration file read, 1 MiB (a `pipeline.toml` is a few KiB).
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// Reads a configuration file as text, in bounded time and memory: only a regular file (a FIFO
/// would block, `/dev/zero` never ends) of at most [`MAX_CONFIG_BYTES`].
pub fn read_config_text(path: &Path) -> Result<String, ConfigError> {
    use std::io::Read;
    let err = |source| ConfigError::Read {
        path: path.to_path_buf(),
        source,
    };
    let other = |m: &str| err(std::io::Error::new(std::io::ErrorKind::InvalidInput, m));
    let meta = std::fs::metadata(path).map_err(err)?;
    if !meta.is_file() {
        return Err(other("not a regular file"));
    }
    let mut text = String::new();
    std::fs::File::open(path)
        .map_err(err)?
        .take(MAX_CONFIG_BYTES + 1)
        .read_to_string(&mut text)
        .map_err(err)?;
    if text.len() as u64 > MAX_CONFIG_BYTES {
        return Err(other(
            "larger than 1 MiB, the limit for a configuration file (a few KiB)",
        ));
    }
    Ok(text)
}

/// Parses TOML text into `T`; `path` is only used to name the file in errors.
pub fn parse_toml<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, ConfigError> {
    toml::from_str::<T>(text).map_err(|e| translate(&e, text, path))
}

fn translate(e: &toml::de::Error, text: &str, path: &Path) -> ConfigError {
    let offset = e.span().map(|s| s.start).unwrap_or(0).min(text.len());
    let (line, column) = line_column(text, offset);
    let message = e.message().trim().to_string();
    let path = path.to_path_buf();
    if let Some((word, valid)) = parse_unknown(&message, "unknown field `") {
        let candidates: Vec<&str> = valid.iter().map(String::as_str).collect();
        let suggestion = did_you_mean(&word, &candidates).map(Box::from);
        return ConfigError::UnknownKey {
            path,
            line,
            column,
            section: section_at(text, offset),
            key: word,
            suggestion,
            valid: valid.into_boxed_slice(),
        };
    }
    if let Some((word, valid)) = parse_unknown(&message, "unknown variant `") {
        let candidates: Vec<&str> = valid.iter().map(String::as_str).collect();
        let suggestion = did_you_mean(&word, &candidates).map(Box::from);
        return ConfigError::UnknownValue {
            path,
            line,
            column,
            value: word,
            suggestion,
            valid: valid.into_boxed_slice(),
        };
    }
    ConfigError::Parse {
        path,
        line,
        column,
        message: message.replace('\n', " "),
    }
}

/// Splits serde's "unknown field `x`, expected one of `a`, `b`" (or "expected `a` or `b`",
/// "expected `a`", "there are no fields") into the word and the valid words.
fn parse_unknown(message: &str, prefix: &str) -> Option<(String, Vec<String>)> {
    let rest = message.strip_prefix(prefix)?;
    let end = rest.find('`')?;
    let word = rest[..end].to_string();
    let tail = &rest[end + 1..];
    let valid = tail
        .split('`')
        .skip(1)
        .step_by(2)
        .map(str::to_owned)
        .collect();
    Some((word, valid))
}

/// 1-based line and column (in characters) of a byte offset.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..floor_char_boundary(text, offset)];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, before[line_start..].chars().count() + 1)
}

fn floor_char_boundary(text: &str, mut offset: usize) -> usize {
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    offset
}

/// The table that holds the key at `offset`, as `[name]`, or `the top level`. When the offset is
/// on a table header itself (an unknown section), the table that contains that header.
fn section_at(text: &str, offset: usize) -> String {
    let offset = floor_char_boundary(text, offset);
    let line_start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[offset..].find('\n').map_or(text.len(), |i| offset + i);
    let current = header_name(&text[line_start..line_end]);
    let name = match current {
        // The unknown key is the last part of this header: its parent holds it.
        Some(h) => h.rsplit_once('.').map(|(parent, _)| parent.to_string()),
        None => text[..line_start].lines().rev().find_map(header_name),
    };
    match name {
        Some(n) if !n.is_empty() => format!("[{n}]"),
        _ => "the top level".to_string(),
    }
}

/// `Some("a.b")` for a `[a.b]` or `[[a.b]]` header line (whitespace and comments allowed).
fn header_name(line: &str) -> Option<String> {
    let t = line.trim();
    let inner = t
        .strip_prefix("[[")
        .map(|r| (r, "]]"))
        .or_else(|| t.strip_prefix('[').map(|r| (r, "]")));
    let (rest, close) = inner?;
    let end = rest.find(close)?;
    let after = rest[end + close.len()..].trim();
    if !(after.is_empty() || after.starts_with('#')) {
        return None;
    }
    Some(
        rest[..end]
            .split('.')
            .map(|p| p.trim().trim_matches('"'))
            .collect::<Vec<_>>()
            .join("."),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> ConfigError {
        parse_config(text, Path::new("camp/pipeline.toml")).unwrap_err()
    }

    #[test]
    fn empty_file_is_the_default() {
        assert_eq!(
            parse_config("", Path::new("x.toml")).unwrap(),
            PipelineConfig::default()
        );
    }

    #[test]
    fn unknown_key_names_file_line_section_and_suggests() {
        let e =
            err("[input]\ndir = \".\"\n\n[match]\nsearch_radius = 0.3\nmedian_treshold = 3.0\n");
        match &e {
            ConfigError::UnknownKey {
                line,
                column,
                section,
                key,
                suggestion,
                valid,
                ..
            } => {
                assert_eq!((*line, *column), (6, 1));
                assert_eq!(section, "[match]");
                assert_eq!(key, "median_treshold");
                assert_eq!(suggestion.as_deref(), Some("median_threshold"));
                assert_eq!(
                    **valid,
                    [
                        "search_radius",
                        "median_epsilon",
                        "median_threshold",
                        "max_displacement",
                        "min_matched_fraction",
                        "keep_flagged"
                    ]
                );
            }
            other => panic!("wrong error: {other:?}"),
        }
        let msg = e.to_string();
        assert!(
            msg.starts_with("camp/pipeline.toml:6:1: unknown key `median_treshold` in [match]"),
            "{msg}"
        );
        assert!(msg.contains("did you mean `median_threshold`?"), "{msg}");
        assert!(!msg.contains('\n'));
    }

    #[test]
    fn unknown_section_is_reported_at_the_top_level() {
        let e = err("[input]\n\n[mach]\nsearch_radius = 0.3\n");
        match &e {
            ConfigError::UnknownKey {
                line,
                section,
                key,
                suggestion,
                ..
            } => {
                assert_eq!(*line, 3);
                assert_eq!(section, "the top level");
                assert_eq!(key, "mach");
                assert_eq!(suggestion.as_deref(), Some("match"));
            }
            other => panic!("wrong error: {other:?}"),
        }
    }

    #[test]
    fn unknown_key_without_a_near_miss_lists_the_valid_keys() {
        let e = err("[run]\ncolour = true\n");
        let msg = e.to_string();
        assert!(
            msg.contains("unknown key `colour` in [run] (valid keys: jobs, frames_in_flight)"),
            "{msg}"
        );
    }

    #[test]
    fn unknown_value_suggests() {
        let e = err("[uncertainty]\nar_variant = \"publishd\"\n");
        match &e {
            ConfigError::UnknownValue {
                line,
                value,
                suggestion,
                valid,
                ..
            } => {
                assert_eq!(*line, 2);
                assert_eq!(value, "publishd");
                assert_eq!(suggestion.as_deref(), Some("published"));
                assert_eq!(**valid, ["notes", "bounds", "published"]);
            }
            other => panic!("wrong error: {other:?}"),
        }
    }

    #[test]
    fn wrong_type_names_the_line() {
        let e = err("[match]\nsearch_radius = \"wide\"\n");
        match &e {
            ConfigError::Parse { line, message, .. } => {
                assert_eq!(*line, 2);
                assert!(message.contains("invalid type"), "{message}");
            }
            other => panic!("wrong error: {other:?}"),
        }
        let e = err("[match\n");
        assert!(matches!(e, ConfigError::Parse { line: 1, .. }), "{e:?}");
    }

    #[test]
    fn only_small_regular_files_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let e = load_config(dir.path()).unwrap_err().to_string();
        assert!(e.ends_with(": not a regular file"), "{e}");
        if Path::new("/dev/zero").exists() {
            let e = load_config(Path::new("/dev/zero")).unwrap_err().to_string();
            assert_eq!(e, "cannot read /dev/zero: not a regular file");
        }
        let big = dir.path().join("big.toml");
        std::fs::write(&big, "#".repeat(MAX_CONFIG_BYTES as usize + 1)).unwrap();
        let e = load_config(&big).unwrap_err().to_string();
        assert!(e.contains("larger than 1 MiB"), "{e}");
        std::fs::write(&big, "#".repeat(MAX_CONFIG_BYTES as usize)).unwrap();
        assert_eq!(load_config(&big).unwrap(), PipelineConfig::default());
    }

    #[test]
    fn header_names() {
        assert_eq!(header_name("[a.b]  # c").as_deref(), Some("a.b"));
        assert_eq!(header_name(" [[ \"x\" . y ]]").as_deref(), Some("x.y"));
        assert_eq!(header_name("a = [1]"), None);
        assert_eq!(line_column("ab\ncé\nx", 6), (2, 3));
    }
}
