//! What `probe` reports about a file, and summary statistics of a decoded image.

use crate::format::{ByteOrder, FileFormat};
use bostrack_core::{Image, Photometric, SampleFormat};
use serde::Serialize;
use std::fmt;
use std::path::PathBuf;

/// Facts about an image file read from its headers (no pixel is decoded), as printed by
/// `bostrack info IMAGE`. Width, height and sample description are those of the first page.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageInfo {
    pub path: PathBuf,
    pub format: FileFormat,
    pub width: usize,
    pub height: usize,
    /// Bits per sample as stored (a 1/2/4-bit PNG reports 8, the depth it is decoded to).
    pub bits_per_sample: u16,
    pub sample_format: SampleFormat,
    /// Compression name: `"none"`, `"packbits"`, `"lzw"`, `"deflate"` (PNG: `"deflate"`).
    pub compression: String,
    pub photometric: Photometric,
    /// Number of pages (images) in the file; PNG: 1.
    pub pages: usize,
    /// Byte order of multi-byte samples; PNG: big-endian.
    pub endianness: ByteOrder,
    /// Whether the samples are stored in tiles rather than strips (TIFF).
    pub tiled: bool,
}

impl fmt::Display for ImageInfo {
    /// One `key: value` line per field.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let sf = match self.sample_format {
            SampleFormat::Unsigned => "unsigned",
            SampleFormat::Float => "float",
        };
        writeln!(f, "file: {}", self.path.display())?;
        writeln!(f, "format: {}", self.format)?;
        writeln!(f, "size: {} x {} px", self.width, self.height)?;
        writeln!(f, "samples: {}-bit {sf}", self.bits_per_sample)?;
        writeln!(f, "compression: {}", self.compression)?;
        writeln!(f, "photometric: {}", self.photometric)?;
        writeln!(f, "pages: {}", self.pages)?;
        writeln!(f, "byte order: {}", self.endianness)?;
        write!(f, "layout: {}", if self.tiled { "tiles" } else { "strips" })
    }
}

/// Summary of the samples of an image.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ImageStats {
    /// Minimum, maximum and mean over the finite samples.
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    /// Samples at or above the saturation level of the source (`ImageMeta::saturation`); 0 for
    /// float data.
    pub saturated_pixels: usize,
    /// NaN or infinite samples (left out of min/max/mean).
    pub non_finite_pixels: usize,
}

/// Statistics of `img`; `None` when no sample is finite.
pub fn image_stats(img: &Image) -> Option<ImageStats> {
    let (min, max, mean) = img.stats()?;
    let saturated_pixels = img.data().iter().filter(|&&v| img.is_saturated(v)).count();
    let non_finite_pixels = img.data().iter().filter(|v| !v.is_finite()).count();
    Some(ImageStats {
        min,
        max,
        mean,
        saturated_pixels,
        non_finite_pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use bostrack_core::ImageMeta;

    #[test]
    fn stats_count_saturation_and_non_finite() {
        let data = vec![0.0, 4095.0, 4095.0, 100.0, f64::NAN, 5.0];
        let img = Image::new(3, 2, data, ImageMeta::synthetic(12)).unwrap();
        let s = image_stats(&img).unwrap();
        assert_eq!((s.min, s.max, s.mean), (0.0, 4095.0, 8295.0 / 5.0));
        assert_eq!((s.saturated_pixels, s.non_finite_pixels), (2, 1));
        let nan = Image::new(1, 1, vec![f64::NAN], ImageMeta::synthetic(16)).unwrap();
        assert_eq!(image_stats(&nan), None);
    }
}
