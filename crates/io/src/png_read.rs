//! PNG: 8 and 16-bit grayscale through the `image` crate.

use crate::error::IoErrorKind;
use crate::tiff_read::MAX_PIXELS;
use bostrack_core::{ImageMeta, Photometric, SampleFormat};
use image::codecs::png::PngDecoder;
use image::{ColorType, DynamicImage, ExtendedColorType, ImageDecoder, ImageError};
use std::io::{BufRead, Seek};

/// Header facts of a PNG file: (width, height, bits per decoded sample).
pub(crate) fn png_header<R: BufRead + Seek>(r: R) -> Result<(usize, usize, u16), IoErrorKind> {
    let dec = PngDecoder::new(r).map_err(from_image)?;
    header_of(&dec)
}

fn header_of<R: BufRead + Seek>(dec: &PngDecoder<R>) -> Result<(usize, usize, u16), IoErrorKind> {
    let (w, h) = dec.dimensions();
    if w == 0 || h == 0 {
        return Err(IoErrorKind::ZeroSize {
            width: w.into(),
            height: h.into(),
        });
    }
    if u64::from(w) * u64::from(h) > MAX_PIXELS {
        return Err(IoErrorKind::TooLarge {
            width: w.into(),
            height: h.into(),
            limit: MAX_PIXELS,
        });
    }
    let bits = match dec.color_type() {
        // 1, 2 and 4-bit grayscale arrive expanded (and scaled) to 8 bits
        ColorType::L8 => 8,
        ColorType::L16 => 16,
        _ => {
            return Err(IoErrorKind::Unsupported(format!(
                "PNG colour type {}; only grayscale without alpha (8 or 16 bit) is read",
                color_name(dec.original_color_type())
            )));
        }
    };
    Ok((w as usize, h as usize, bits))
}

/// Decodes a grayscale PNG: (width, height, samples, metadata without source path). The stream
/// is read up to the end of the image data only.
#[allow(clippy::type_complexity)]
pub(crate) fn read_png<R: BufRead + Seek>(
    r: R,
) -> Result<(usize, usize, Vec<f64>, ImageMeta), IoErrorKind> {
    let dec = PngDecoder::new(r).map_err(from_image)?;
    let (w, h, bits) = header_of(&dec)?;
    let data: Vec<f64> = match DynamicImage::from_decoder(dec).map_err(from_image)? {
        DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(f64::from).collect(),
        DynamicImage::ImageLuma16(b) => b.into_raw().into_iter().map(f64::from).collect(),
        other => {
            return Err(IoErrorKind::Unsupported(format!(
                "PNG decoded as {:?}",
                other.color()
            )));
        }
    };
    let meta = ImageMeta {
        bits_per_sample: bits,
        sample_format: SampleFormat::Unsigned,
        saturation: Some(f64::from((1u32 << bits) - 1)),
        compression: "deflate".into(),
        photometric: Photometric::BlackIsZero,
        source: None,
        page: 0,
    };
    Ok((w, h, data, meta))
}

fn color_name(c: ExtendedColorType) -> String {
    match c {
        ExtendedColorType::Unknown(bits) => format!("indexed ({bits}-bit palette)"),
        other => format!("{other:?}"),
    }
}

fn from_image(e: ImageError) -> IoErrorKind {
    match e {
        ImageError::IoError(io) => IoErrorKind::from_io(io),
        ImageError::Unsupported(u) => IoErrorKind::Unsupported(u.to_string()),
        ImageError::Limits(l) => IoErrorKind::Unsupported(l.to_string()),
        ImageError::Decoding(d) => {
            let msg = d.to_string();
            if msg.to_ascii_lowercase().contains("eof") || msg.contains("end of") {
                IoErrorKind::Truncated(msg)
            } else {
                IoErrorKind::Corrupt(msg)
            }
        }
        other => IoErrorKind::Corrupt(other.to_string()),
    }
}
