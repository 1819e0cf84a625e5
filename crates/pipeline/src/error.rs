//! The errors of reading a configuration and building a plan. Each names the file, and where it
//! can the line and the key.

use std::fmt;
use std::path::PathBuf;

/// What was wrong with a configuration file or with the files it points at.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The configuration file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },

    /// TOML syntax error, or a value of the wrong type.
    #[error("{}:{line}:{column}: {message}", path.display())]
    Parse {
        path: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },

    /// A key (or a section) that the schema does not have.
    #[error(
        "{}:{line}:{column}: unknown key `{key}` in {section}{}",
        path.display(),
        Hint { suggestion: suggestion.as_deref(), valid, what: "keys" }
    )]
    UnknownKey {
        path: PathBuf,
        line: usize,
        column: usize,
        /// `[section]` (or `the top level`).
        section: String,
        key: String,
        /// The valid key closest to `key`, if one is close.
        suggestion: Option<Box<str>>,
        /// Every valid key of the section.
        valid: Box<[String]>,
    },

    /// A value outside the allowed set of words (e.g. `ar_variant = "publishd"`).
    #[error(
        "{}:{line}:{column}: unknown value `{value}`{}",
        path.display(),
        Hint { suggestion: suggestion.as_deref(), valid, what: "values" }
    )]
    UnknownValue {
        path: PathBuf,
        line: usize,
        column: usize,
        value: String,
        suggestion: Option<Box<str>>,
        valid: Box<[String]>,
    },

    /// A value that parses but is not allowed (out of range, contradicts another key).
    #[error("{}: {key}: {message}", path.display())]
    Invalid {
        path: PathBuf,
        key: String,
        message: String,
    },

    /// A file or folder named by the configuration does not exist.
    #[error("{}: {key}: {} not found", path.display(), file.display())]
    NotFound {
        path: PathBuf,
        key: String,
        file: PathBuf,
    },

    /// A path named by the configuration (or matched by one of its patterns) exists but is not
    /// what the key needs, or cannot be examined: a folder where a file is needed, a file
    /// where a folder is needed, a broken symbolic link or a link loop.
    #[error("{}: {key}: {}: {problem}", path.display(), file.display())]
    BadPath {
        path: PathBuf,
        key: String,
        file: PathBuf,
        /// What is wrong ("is a folder, not a file", "cannot be examined: ...").
        problem: String,
    },

    /// A folder named by the configuration could not be listed.
    #[error("{}: {key}: cannot list {}: {source}", path.display(), dir.display())]
    ListDir {
        path: PathBuf,
        key: String,
        dir: PathBuf,
        source: std::io::Error,
    },

    /// A file-name pattern matched no file.
    #[error("{}: {key}: no file in {} matches `{pattern}`", path.display(), dir.display())]
    NoMatch {
        path: PathBuf,
        key: String,
        dir: PathBuf,
        pattern: String,
    },
}

/// "; did you mean `x`? (valid keys: a, b)" or " (valid keys: a, b)".
struct Hint<'a> {
    suggestion: Option<&'a str>,
    valid: &'a [String],
    what: &'a str,
}

impl fmt::Display for Hint<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(s) = self.suggestion {
            write!(f, "; did you mean `{s}`?")?;
        }
        if self.valid.is_empty() {
            write!(f, " (no {} allowed here)", self.what)
        } else {
            write!(f, " (valid {}: {})", self.what, self.valid.join(", "))
        }
    }
}

/// What can stop the pair pipeline (reference context or one frame). Each names the file and
/// the problem. Per-dot problems are flags in the results, never errors.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The configuration or the files it names.
    #[error(transparent)]
    Config(#[from] ConfigError),

    /// An image or mask could not be read.
    #[error(transparent)]
    Io(#[from] bostrack_io::IoError),

    /// Detection (or tracking) failed on a whole image.
    #[error("{}: detection failed: {source}", path.display())]
    Detect {
        path: PathBuf,
        source: bostrack_detect::DetectError,
    },

    /// The fit stage rejected its inputs.
    #[error("{}: fit failed: {source}", path.display())]
    Fit {
        path: PathBuf,
        source: bostrack_fit::FitError,
    },

    /// Matching or validation rejected its inputs.
    #[error("{}: matching failed: {message}", path.display())]
    Match { path: PathBuf, message: String },

    /// The no-flow stack statistics rejected their inputs.
    #[error("{}: stack statistics failed: {message}", path.display())]
    Stack { path: PathBuf, message: String },

    /// An image whose size (or kind) differs from the reference.
    #[error("{}: {what}: expected {expected}, got {got}", path.display())]
    SizeMismatch {
        path: PathBuf,
        /// What differs ("image size", "bit depth", ...).
        what: String,
        expected: String,
        got: String,
    },

    /// No dot could be found (reference) or matched (gradient) in an image.
    #[error("{}: {message}", path.display())]
    NoDots { path: PathBuf, message: String },

    /// The density field of a frame could not be integrated (no Dirichlet node, ...).
    #[error("{}: density: {message}", path.display())]
    Density { path: PathBuf, message: String },

    /// A failure of the reference side (noise model, detection, fits) or of a frame (detection,
    /// fits) while a mask limits the
    /// usable pixels: the message names the mask too, since it may be the cause.
    #[error("{source} (the mask {} keeps {kept} of its {total} pixels)", mask.display())]
    Masked {
        mask: PathBuf,
        kept: usize,
        total: usize,
        source: Box<PipelineError>,
    },

    /// The outputs could not be written.
    #[error("{}: cannot write: {source}", path.display())]
    Output {
        path: PathBuf,
        source: std::io::Error,
    },
}
