//! Public readers: one image, a stack, a mask, and header-only probing.

use crate::error::{IoError, IoErrorKind};
use crate::format::{ByteOrder, FileFormat, compression_name, detect};
use crate::info::ImageInfo;
use crate::png_read::{png_header, read_png};
use crate::tiff_read::{Chunks, PageHeader, TiffFile};
use bostrack_core::{Image, ImageMeta, Mask, Photometric, SampleFormat};
use std::path::Path;

fn load(path: &Path) -> Result<(Vec<u8>, FileFormat), IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::new(path, IoErrorKind::from_io(e)))?;
    let format = detect(&bytes).map_err(|k| IoError::new(path, k))?;
    Ok((bytes, format))
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

fn current_page(tif: &mut TiffFile<'_>, path: &Path) -> Result<Image, IoErrorKind> {
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
pub fn read_image(path: &Path) -> Result<Image, IoError> {
    let (bytes, format) = load(path)?;
    let err = |k| IoError::new(path, k);
    match format {
        FileFormat::Png => {
            let (w, h, data, mut meta) = read_png(&bytes).map_err(err)?;
            meta.source = Some(path.to_path_buf());
            Image::new(w, h, data, meta).map_err(|e| err(IoErrorKind::Corrupt(e.to_string())))
        }
        FileFormat::Tiff => {
            let mut tif = TiffFile::open(&bytes).map_err(err)?;
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
/// Pages may differ in size and sample type; each image's `meta.page` is its index.
pub fn read_stack(path: &Path) -> Result<Vec<Image>, IoError> {
    let (bytes, format) = load(path)?;
    let err = |k| IoError::new(path, k);
    if format == FileFormat::Png {
        return read_image(path).map(|img| vec![img]);
    }
    let mut tif = TiffFile::open(&bytes).map_err(err)?;
    let mut out = vec![current_page(&mut tif, path).map_err(err)?];
    while tif.next_page().map_err(err)? {
        out.push(current_page(&mut tif, path).map_err(err)?);
    }
    Ok(out)
}

/// Reads a region-of-interest mask: a pixel is kept when it **displays white**, i.e. its
/// sample (after the photometric inversion of WhiteIsZero files) is above half the maximum:
/// `v > saturation / 2` for integer files, `v > 0.5` for float files.
pub fn read_mask(path: &Path) -> Result<Mask, IoError> {
    let img = read_image(path)?;
    let threshold = img.meta.saturation.map_or(0.5, |s| s / 2.0);
    let keep = img.data().iter().map(|&v| v > threshold).collect();
    Mask::new(img.width(), img.height(), keep)
        .map_err(|e| IoError::new(path, IoErrorKind::Corrupt(e.to_string())))
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
    let (bytes, format) = load(path)?;
    let err = |k| IoError::new(path, k);
    match format {
        FileFormat::Png => {
            let (width, height, bits) = png_header(&bytes).map_err(err)?;
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
            let mut tif = TiffFile::open(&bytes).map_err(err)?;
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
