//! Public readers: one image, a stack, a mask, and header-only probing.

use crate::error::{IoError, IoErrorKind};
use crate::format::{ByteOrder, FileFormat, compression_name, detect};
use crate::info::ImageInfo;
use crate::png_read::{png_header, read_png};
use crate::tiff_read::{Chunks, PageHeader, TiffFile};
use bostrack_core::{Image, ImageMeta, Mask, Photometric, SampleFormat};
use std::fs::{File, FileType};
use std::io::{BufReader, Read, Seek};
use std::path::Path;

/// Most pixels [`read_stack`] reads from one file, all pages together: 2^30 (8 GiB of f64
/// samples). A few kilobytes of compressed data can claim that much, so it is checked before
/// each page is decoded.
pub(crate) const MAX_STACK_PIXELS: u64 = 1 << 30;

/// An image file opened for reading: a buffered reader at its start, its length, its format.
struct Opened {
    reader: BufReader<File>,
    len: u64,
    format: FileFormat,
}

/// What a file that is not a regular file is, for the error message.
fn kind_of(t: FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() { "a folder" } else { "not a file" }
}

/// Opens an image file after checking that it is a regular file (a FIFO would block, a device
/// such as `/dev/zero` never ends), and recognises its format from its first bytes. Nothing
/// else is read: the readers then read only what the image structure needs.
fn open(path: &Path) -> Result<Opened, IoError> {
    let err = |k| IoError::new(path, k);
    let io = |e| err(IoErrorKind::from_io(e));
    let meta = std::fs::metadata(path).map_err(io)?;
    if !meta.is_file() {
        return Err(err(IoErrorKind::NotRegularFile(kind_of(meta.file_type()))));
    }
    let mut reader = BufReader::new(File::open(path).map_err(io)?);
    let mut head = Vec::with_capacity(8);
    reader.by_ref().take(8).read_to_end(&mut head).map_err(io)?;
    let format = detect(&head).map_err(err)?;
    reader.rewind().map_err(io)?;
    Ok(Opened {
        reader,
        len: meta.len(),
        format,
    })
}

fn meta_of(h: &PageHeader, path: &Path, page: usize) -> ImageMeta {
    ImageMeta {
        bits_per_sample: h.bits,
        sample_format: h.format,
        saturation: match h.format {
            SampleFormat::Unsigned => Some(((1u64 << h.bits) - 1) as f64),
            SampleFormat::Float => None,
        },
        compression: compression_name(h.compression).into(),
        photometric: h.photometric,
        source: Some(path.to_path_buf()),
        page,
    }
}

fn current_page<R: Read + Seek>(tif: &mut TiffFile<R>, path: &Path) -> Result<Image, IoErrorKind> {
    let h = tif.header()?;
    let data = tif.decode(&h)?;
    let meta = meta_of(&h, path, tif.page());
    Image::new(h.width, h.height, data, meta).map_err(|e| IoErrorKind::Corrupt(e.to_string()))
}

/// Reads a single-page image file (TIFF or PNG, recognised by content).
///
/// Samples are in camera counts, larger = brighter on display (WhiteIsZero data is inverted,
/// `max - raw`; see `docs/CONVENTIONS.md`). Supported: TIFF with 8, 12 (packed), 16, 32-bit
/// unsigned or 32, 64-bit float single-channel samples, uncompressed, PackBits, LZW or Deflate
/// (12-bit too), either byte order, strips or tiles, BlackIsZero or WhiteIsZero; grayscale PNG of
/// 8 or 16 bits. A multi-page TIFF is an error ([`IoErrorKind::MultiPage`]); use [`read_stack`].
///
/// Only regular files are read ([`IoErrorKind::NotRegularFile`] otherwise), and of those only
/// the bytes the image structure points to: trailing or unreferenced data are never read.
pub fn read_image(path: &Path) -> Result<Image, IoError> {
    let f = open(path)?;
    let err = |k| IoError::new(path, k);
    match f.format {
        FileFormat::Png => {
            let (w, h, data, mut meta) = read_png(f.reader).map_err(err)?;
            meta.source = Some(path.to_path_buf());
            Image::new(w, h, data, meta).map_err(|e| err(IoErrorKind::Corrupt(e.to_string())))
        }
        FileFormat::Tiff => {
            let mut tif = TiffFile::open(f.reader, f.len).map_err(err)?;
            if tif.has_more_pages() {
                let pages = tif.count_remaining_pages();
                return Err(err(IoErrorKind::MultiPage { pages }));
            }
            current_page(&mut tif, path).map_err(err)
        }
    }
}

/// Reads every page of a file, in order (a PNG or single-page TIFF gives one image).
///
/// Pages may differ in size and sample type; each image's `meta.page` is its index. All pages
/// together may hold at most 2^30 pixels ([`IoErrorKind::StackTooLarge`], checked from each
/// page's header before it is decoded).
pub fn read_stack(path: &Path) -> Result<Vec<Image>, IoError> {
    let f = open(path)?;
    let err = |k| IoError::new(path, k);
    if f.format == FileFormat::Png {
        return read_image(path).map(|img| vec![img]);
    }
    let mut tif = TiffFile::open(f.reader, f.len).map_err(err)?;
    let mut out = Vec::new();
    let mut pixels = 0u64;
    loop {
        let h = tif.header().map_err(err)?;
        pixels += (h.width * h.height) as u64;
        if pixels > MAX_STACK_PIXELS {
            return Err(err(IoErrorKind::StackTooLarge {
                page: tif.page(),
                pixels,
                limit: MAX_STACK_PIXELS,
            }));
        }
        out.push(current_page(&mut tif, path).map_err(err)?);
        if !tif.next_page().map_err(err)? {
            return Ok(out);
        }
    }
}

/// Reads a region-of-interest mask. **A pixel is kept when it displays brighter than the
/// midpoint between the mask's darkest and brightest samples** (samples after the photometric
/// inversion of WhiteIsZero files, so "displays" is as a viewer shows the file). The rule
/// depends on no bit depth or maximum: {0, 1} (a numpy or MATLAB logical), {0, 255},
/// {0, 65535}, 8 or 16-bit, TIFF or PNG, integer or float, all keep their non-zero pixels
/// (BlackIsZero) or their zero pixels (WhiteIsZero). A mask of a single value keeps every
/// pixel if that value displays brighter than black, and is an error if it is black
/// ([`IoErrorKind::EmptyMask`]); non-finite samples are not kept. Every error names the mask
/// file.
pub fn read_mask(path: &Path) -> Result<Mask, IoError> {
    let img = read_image(path)?;
    mask_of(&img).map_err(|k| IoError::new(path, k))
}

/// The mask rule of [`read_mask`] applied to an image in memory (e.g. an array handed over by
/// the Python package).
pub fn mask_of(img: &Image) -> Result<Mask, IoErrorKind> {
    let (lo, hi, _) = img
        .stats()
        .ok_or_else(|| IoErrorKind::EmptyMask("no sample is finite".into()))?;
    // samples are larger = brighter after the WhiteIsZero inversion: 0 displays black
    let keep: Vec<bool> = if lo == hi {
        if hi <= 0.0 {
            return Err(IoErrorKind::EmptyMask(format!(
                "every sample displays black (value {hi})"
            )));
        }
        img.data().iter().map(|v| v.is_finite()).collect()
    } else {
        let mid = 0.5 * (lo + hi);
        img.data().iter().map(|&v| v > mid).collect()
    };
    Mask::new(img.width(), img.height(), keep).map_err(|e| IoErrorKind::Corrupt(e.to_string()))
}

/// [`read_mask`], with an error ([`IoErrorKind::SizeMismatch`]) when the mask is not
/// `width` x `height` pixels.
pub fn read_mask_for(path: &Path, width: usize, height: usize) -> Result<Mask, IoError> {
    let m = read_mask(path)?;
    if m.width() != width || m.height() != height {
        return Err(IoError::new(
            path,
            IoErrorKind::SizeMismatch {
                found_width: m.width(),
                found_height: m.height(),
                width,
                height,
            },
        ));
    }
    Ok(m)
}

/// Reads the headers of an image file without decoding pixels.
///
/// Fails with the same error as [`read_stack`] would for anything this crate cannot decode
/// (unsupported compression, bit depth, colour, truncated chunks), so a successful probe
/// means the file's headers are readable; a page's compressed data is only checked on reading.
pub fn probe(path: &Path) -> Result<ImageInfo, IoError> {
    let f = open(path)?;
    let err = |k| IoError::new(path, k);
    let format = f.format;
    match format {
        FileFormat::Png => {
            let (width, height, bits) = png_header(f.reader).map_err(err)?;
            Ok(ImageInfo {
                path: path.to_path_buf(),
                format,
                width,
                height,
                bits_per_sample: bits,
                sample_format: SampleFormat::Unsigned,
                compression: "deflate".into(),
                photometric: Photometric::BlackIsZero,
                pages: 1,
                endianness: ByteOrder::BigEndian,
                tiled: false,
            })
        }
        FileFormat::Tiff => {
            let mut tif = TiffFile::open(f.reader, f.len).map_err(err)?;
            let h = tif.header().map_err(err)?;
            let endianness = tif.byte_order();
            let mut pages = 1;
            while tif.next_page().map_err(err)? {
                tif.header().map_err(err)?;
                pages += 1;
            }
            Ok(ImageInfo {
                path: path.to_path_buf(),
                format,
                width: h.width,
                height: h.height,
                bits_per_sample: h.bits,
                sample_format: h.format,
                compression: compression_name(h.compression).into(),
                photometric: h.photometric,
                pages,
                endianness,
                tiled: matches!(h.chunks, Chunks::Tiles { .. }),
            })
        }
    }
}
