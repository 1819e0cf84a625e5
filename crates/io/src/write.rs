//! Writers: 16-bit and 32-bit float TIFF (tiff crate), 8 and 16-bit PNG (image crate).
//! Every writer is atomic: the file is written under a temporary name in the same folder and
//! renamed over `path` only when complete, so a reader never sees half a file and a failed write
//! leaves an existing file untouched (this does not `fsync`, so it is not proof against power loss).

use crate::error::{IoError, IoErrorKind};
use bostrack_core::Image;
use image::{DynamicImage, ImageBuffer, ImageFormat, Luma};
use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use tiff::encoder::{TiffEncoder, colortype};

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let err = |e: std::io::Error| IoError::new(path, IoErrorKind::Io(e));
    let name = path.file_name().ok_or_else(|| {
        IoError::new(
            path,
            IoErrorKind::Io(std::io::Error::other("the path does not name a file")),
        )
    })?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(
        ".{}.{}-{n}.tmp",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = std::fs::File::create(&tmp)
        .and_then(|mut f| f.write_all(bytes).and_then(|()| f.flush()))
        .and_then(|()| std::fs::rename(&tmp, path));
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(err(e));
    }
    Ok(())
}

/// Samples rounded (half away from zero) and clamped to `0..=max`; non-finite samples are an error.
fn to_ints<'a>(
    path: &Path,
    img: &'a Image,
    max: f64,
) -> Result<impl Iterator<Item = f64> + 'a, IoError> {
    let count = img.data().iter().filter(|v| !v.is_finite()).count();
    if count > 0 {
        return Err(IoError::new(path, IoErrorKind::NonFinite { count }));
    }
    Ok(img.data().iter().map(move |v| v.round().clamp(0.0, max)))
}

fn dims(path: &Path, img: &Image) -> Result<(u32, u32), IoError> {
    match (u32::try_from(img.width()), u32::try_from(img.height())) {
        (Ok(w), Ok(h)) => Ok((w, h)),
        _ => Err(IoError::new(
            path,
            IoErrorKind::Unsupported(format!(
                "an image of {} x {} pixels has a side too long for TIFF and PNG (2^32 - 1)",
                img.width(),
                img.height()
            )),
        )),
    }
}

fn tiff_err(path: &Path) -> impl Fn(tiff::TiffError) -> IoError + '_ {
    move |e| IoError::new(path, IoErrorKind::from_tiff(e))
}

/// Writes 16-bit unsigned, uncompressed, little-endian TIFF pages (one per image; BlackIsZero).
/// Samples are rounded and clamped to `0..=65535`; NaN or infinite samples are an error.
pub fn write_tiff_stack_u16(path: &Path, images: &[Image]) -> Result<(), IoError> {
    if images.is_empty() {
        return Err(IoError::new(path, IoErrorKind::NothingToWrite));
    }
    let mut buf = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut buf).map_err(tiff_err(path))?;
    for img in images {
        let (w, h) = dims(path, img)?;
        let data: Vec<u16> = to_ints(path, img, 65535.0)?.map(|v| v as u16).collect();
        enc.write_image::<colortype::Gray16>(w, h, &data)
            .map_err(tiff_err(path))?;
    }
    write_atomic(path, buf.get_ref())
}

/// Writes a 16-bit unsigned, uncompressed, little-endian TIFF (BlackIsZero). Samples are rounded
/// and clamped to `0..=65535`; NaN or infinite samples are an error.
pub fn write_tiff_u16(path: &Path, img: &Image) -> Result<(), IoError> {
    write_tiff_stack_u16(path, std::slice::from_ref(img))
}

/// Writes a 32-bit float, uncompressed, little-endian TIFF (BlackIsZero, SampleFormat IEEEFP).
/// Samples are rounded to the nearest f32 (values beyond ±3.4e38 become infinite; NaN is kept).
pub fn write_tiff_f32(path: &Path, img: &Image) -> Result<(), IoError> {
    let (w, h) = dims(path, img)?;
    let data: Vec<f32> = img.data().iter().map(|&v| v as f32).collect();
    let mut buf = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut buf).map_err(tiff_err(path))?;
    enc.write_image::<colortype::Gray32Float>(w, h, &data)
        .map_err(tiff_err(path))?;
    write_atomic(path, buf.get_ref())
}

fn write_png(path: &Path, img: DynamicImage) -> Result<(), IoError> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, ImageFormat::Png)
        .map_err(|e| IoError::new(path, IoErrorKind::Io(std::io::Error::other(e))))?;
    write_atomic(path, out.get_ref())
}

/// Writes a 16-bit grayscale PNG; samples rounded and clamped to `0..=65535`, non-finite is an error.
pub fn write_png_u16(path: &Path, img: &Image) -> Result<(), IoError> {
    let (w, h) = dims(path, img)?;
    let data: Vec<u16> = to_ints(path, img, 65535.0)?.map(|v| v as u16).collect();
    let buf = ImageBuffer::<Luma<u16>, _>::from_raw(w, h, data)
        .ok_or_else(|| IoError::new(path, IoErrorKind::Corrupt("image buffer size".into())))?;
    write_png(path, DynamicImage::ImageLuma16(buf))
}

/// Writes an 8-bit grayscale PNG; samples rounded and clamped to `0..=255`, non-finite is an error.
pub fn write_png_u8(path: &Path, img: &Image) -> Result<(), IoError> {
    let (w, h) = dims(path, img)?;
    let data: Vec<u8> = to_ints(path, img, 255.0)?.map(|v| v as u8).collect();
    let buf = ImageBuffer::<Luma<u8>, _>::from_raw(w, h, data)
        .ok_or_else(|| IoError::new(path, IoErrorKind::Corrupt("image buffer size".into())))?;
    write_png(path, DynamicImage::ImageLuma8(buf))
}
