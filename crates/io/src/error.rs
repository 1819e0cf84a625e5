//! The one error type of the crate: which file, and what is wrong with it.

use std::path::{Path, PathBuf};

/// A file could not be read or written. `Display` names the file and the reason, e.g.
/// `data/a.tif: unsupported compression JPEG (TIFF Compression = 7); supported: none, PackBits, LZW, Deflate`.
#[derive(Debug, thiserror::Error)]
#[error("{}: {kind}", path.display())]
pub struct IoError {
    pub path: PathBuf,
    #[source]
    pub kind: IoErrorKind,
}

impl IoError {
    pub fn new(path: &Path, kind: IoErrorKind) -> Self {
        IoError {
            path: path.to_path_buf(),
            kind,
        }
    }
}

/// Why a file could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IoErrorKind {
    #[error("file not found")]
    NotFound,
    /// Any other operating-system error (permissions, a folder instead of a file, disk full).
    #[error("{0}")]
    Io(#[source] std::io::Error),
    /// Not a regular file: a folder, a FIFO (reading it could block forever), a device such as
    /// `/dev/zero` (endless), a socket. Checked before the file is opened.
    #[error("not a regular file ({0}); images are read from regular files only")]
    NotRegularFile(&'static str),
    /// The content is neither TIFF nor PNG (files are recognised by their first bytes).
    #[error("not a TIFF or PNG file (it starts with {0})")]
    UnknownFormat(String),
    /// The file ends before the data its header points to.
    #[error("truncated file: {0}")]
    Truncated(String),
    /// The structure is damaged (inconsistent tags, undecodable compressed data).
    #[error("corrupt file: {0}")]
    Corrupt(String),
    #[error(
        "unsupported compression {name} (TIFF Compression = {code}); supported: none, PackBits, LZW, Deflate"
    )]
    UnsupportedCompression { code: u16, name: &'static str },
    #[error(
        "unsupported bit depth: {bits}-bit {format} samples; supported: unsigned 8, 12, 16, 32 bit and float 32, 64 bit"
    )]
    UnsupportedBitDepth { bits: u16, format: &'static str },
    /// Something else this reader does not handle (colour, signed samples, bit order, ...).
    #[error("unsupported: {0}")]
    Unsupported(String),
    #[error("image has zero size ({width} x {height} pixels)")]
    ZeroSize { width: u64, height: u64 },
    /// An image (or one TIFF tile) larger than the reader accepts, 2^28 pixels: a guard
    /// against absurd sizes in damaged headers.
    #[error(
        "{width} x {height} pixels exceed this reader's limit of {limit} pixels per image or tile"
    )]
    TooLarge { width: u64, height: u64, limit: u64 },
    /// [`read_image`](crate::read_image) or a mask reader met a file with several pages.
    #[error("file has {pages} pages where a single image is expected (read it as a stack)")]
    MultiPage { pages: usize },
    /// Every page of a multi-page file together holds more pixels than a stack may hold
    /// (`limit`, 2^30 pixels: 8 GiB of f64 samples).
    #[error(
        "the pages hold more than {limit} pixels together (page {page} reaches {pixels}); this reader's limit for a stack"
    )]
    StackTooLarge {
        page: usize,
        pixels: u64,
        limit: u64,
    },
    /// A mask that keeps no pixel, or that has no finite sample.
    #[error("mask keeps no pixel: {0}")]
    EmptyMask(String),
    /// A mask whose size is not the image's.
    #[error("mask is {found_width} x {found_height} pixels but the image is {width} x {height}")]
    SizeMismatch {
        found_width: usize,
        found_height: usize,
        width: usize,
        height: usize,
    },
    /// An image with NaN or infinite samples cannot be stored as integers.
    #[error(
        "{count} of the samples are not finite (NaN or infinite); integer formats cannot store them"
    )]
    NonFinite { count: usize },
    /// A problem in page `page` (counted from 0) of a multi-page file.
    #[error("page {page}: {kind}")]
    InPage { page: usize, kind: Box<IoErrorKind> },
    /// An empty list of images given to a stack writer.
    #[error("no image to write")]
    NothingToWrite,
}

impl IoErrorKind {
    /// The kind itself, or for [`IoErrorKind::InPage`] the kind inside it.
    pub fn innermost(&self) -> &IoErrorKind {
        match self {
            IoErrorKind::InPage { kind, .. } => kind.innermost(),
            k => k,
        }
    }

    /// Classifies an operating-system error: missing file and end-of-file get their own kinds.
    pub(crate) fn from_io(e: std::io::Error) -> Self {
        match e.kind() {
            std::io::ErrorKind::NotFound => IoErrorKind::NotFound,
            std::io::ErrorKind::UnexpectedEof => IoErrorKind::Truncated(e.to_string()),
            _ => IoErrorKind::Io(e),
        }
    }

    /// Classifies an error of the `tiff` crate.
    pub(crate) fn from_tiff(e: tiff::TiffError) -> Self {
        use tiff::{TiffError, TiffFormatError};
        match e {
            TiffError::IoError(io) => Self::from_io(io),
            TiffError::FormatError(TiffFormatError::InvalidDimensions(w, h)) => {
                IoErrorKind::ZeroSize {
                    width: w.into(),
                    height: h.into(),
                }
            }
            TiffError::UnsupportedError(u) => IoErrorKind::Unsupported(u.to_string()),
            TiffError::LimitsExceeded => {
                IoErrorKind::Unsupported("image exceeds the TIFF decoder's memory limits".into())
            }
            other => IoErrorKind::Corrupt(other.to_string()),
        }
    }
}
