//! Recognising files by their first bytes, and names of TIFF codes.

use crate::error::IoErrorKind;
use serde::Serialize;
use std::fmt;

/// Container format of an image file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FileFormat {
    /// TIFF, classic or BigTIFF.
    Tiff,
    Png,
}

impl fmt::Display for FileFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FileFormat::Tiff => "TIFF",
            FileFormat::Png => "PNG",
        })
    }
}

/// Byte order of multi-byte samples in the file (PNG is always big-endian).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ByteOrder {
    LittleEndian,
    BigEndian,
}

impl fmt::Display for ByteOrder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ByteOrder::LittleEndian => "little-endian",
            ByteOrder::BigEndian => "big-endian",
        })
    }
}

const TIFF_MAGICS: [&[u8]; 4] = [b"II*\0", b"MM\0*", b"II+\0", b"MM\0+"];
const PNG_MAGIC: &[u8] = b"\x89PNG\r\n\x1a\n";

/// The format of a file from its first bytes (the extension is not looked at).
pub(crate) fn detect(bytes: &[u8]) -> Result<FileFormat, IoErrorKind> {
    if TIFF_MAGICS.iter().any(|m| bytes.starts_with(m)) {
        return Ok(FileFormat::Tiff);
    }
    if bytes.starts_with(PNG_MAGIC) {
        return Ok(FileFormat::Png);
    }
    if bytes.is_empty() {
        return Err(IoErrorKind::Truncated("the file is empty".into()));
    }
    let is_prefix_of = |m: &[u8]| bytes.len() < m.len() && m.starts_with(bytes);
    if TIFF_MAGICS.iter().any(|m| is_prefix_of(m)) || is_prefix_of(PNG_MAGIC) {
        return Err(IoErrorKind::Truncated(format!(
            "only {} bytes, shorter than a TIFF or PNG signature",
            bytes.len()
        )));
    }
    let shown: String = bytes
        .iter()
        .take(8)
        .map(|&b| match b {
            b' '..=b'~' => (b as char).to_string(),
            _ => format!("\\x{b:02x}"),
        })
        .collect();
    Err(IoErrorKind::UnknownFormat(format!("\"{shown}\"")))
}

/// Name of a TIFF Compression code (`"none"`, `"packbits"`, ...).
pub(crate) fn compression_name(code: u16) -> &'static str {
    match code {
        1 => "none",
        2 => "CCITT RLE",
        3 => "CCITT Group 3 fax",
        4 => "CCITT Group 4 fax",
        5 => "lzw",
        6 => "old-style JPEG",
        7 => "JPEG",
        8 | 32946 => "deflate",
        32773 => "packbits",
        34712 => "JPEG 2000",
        34925 => "LZMA",
        50000 => "Zstandard",
        50001 => "WebP",
        50002 => "JPEG XL",
        _ => "unknown",
    }
}

/// Name of a TIFF PhotometricInterpretation code.
pub(crate) fn photometric_name(code: u16) -> &'static str {
    match code {
        0 => "WhiteIsZero",
        1 => "BlackIsZero",
        2 => "RGB",
        3 => "palette colour",
        4 => "transparency mask",
        5 => "CMYK",
        6 => "YCbCr",
        8 => "CIELab",
        _ => "unknown",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magic_bytes_decide() {
        assert_eq!(detect(b"II*\0\x08\0\0\0").unwrap(), FileFormat::Tiff);
        assert_eq!(detect(b"MM\0*\0\0\0\x08").unwrap(), FileFormat::Tiff);
        assert_eq!(detect(b"\x89PNG\r\n\x1a\n....").unwrap(), FileFormat::Png);
        assert!(matches!(detect(b""), Err(IoErrorKind::Truncated(_))));
        assert!(matches!(detect(b"II*"), Err(IoErrorKind::Truncated(_))));
        match detect(b"GIF89a\x01\x02\x03") {
            Err(IoErrorKind::UnknownFormat(s)) => assert_eq!(s, "\"GIF89a\\x01\\x02\""),
            other => panic!("{other:?}"),
        }
    }
}
