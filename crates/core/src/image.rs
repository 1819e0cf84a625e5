use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::PathBuf;

/// How the stored samples are to be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleFormat {
    /// Unsigned integers of `bits_per_sample` bits.
    Unsigned,
    /// IEEE floating point.
    Float,
}

/// TIFF PhotometricInterpretation of the source file. Samples in an [`Image`] are always stored
/// so that larger means brighter on display: WhiteIsZero data is inverted on reading
/// (`max - raw`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Photometric {
    BlackIsZero,
    WhiteIsZero,
}

impl fmt::Display for Photometric {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Photometric::BlackIsZero => "BlackIsZero",
            Photometric::WhiteIsZero => "WhiteIsZero",
        })
    }
}

/// What is known about where the samples of an image came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageMeta {
    /// Bits per sample of the source (8, 12, 16, 32, 64).
    pub bits_per_sample: u16,
    pub sample_format: SampleFormat,
    /// Largest representable sample value (2^bits - 1 for integers): a pixel at this value is
    /// taken as saturated (clipped). `None` for float data.
    pub saturation: Option<f64>,
    /// Compression of the source file, e.g. `"none"`, `"packbits"`, `"lzw"`, `"deflate"`.
    pub compression: String,
    pub photometric: Photometric,
    /// File the image was read from, if any.
    pub source: Option<PathBuf>,
    /// Page index in a multi-page source (0 for single images).
    pub page: usize,
}

impl ImageMeta {
    /// Metadata for an image made in memory with integer samples of `bits` bits.
    pub fn synthetic(bits: u16) -> Self {
        let (sample_format, saturation) = if bits >= 32 {
            (SampleFormat::Float, None)
        } else {
            (SampleFormat::Unsigned, Some(((1u64 << bits) - 1) as f64))
        };
        ImageMeta {
            bits_per_sample: bits,
            sample_format,
            saturation,
            compression: "none".into(),
            photometric: Photometric::BlackIsZero,
            source: None,
            page: 0,
        }
    }
}

impl Default for ImageMeta {
    fn default() -> Self {
        ImageMeta::synthetic(64)
    }
}

/// The data length does not match width x height, or a size is zero.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShapeError {
    pub width: usize,
    pub height: usize,
    pub len: usize,
}

impl fmt::Display for ShapeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "image of {}x{} pixels needs {} samples, got {}",
            self.width,
            self.height,
            self.width * self.height,
            self.len
        )
    }
}

impl std::error::Error for ShapeError {}

/// A single-channel image with f64 samples in row-major order (`data[y * width + x]`).
///
/// f64 represents every 8/12/16-bit and 32-bit float sample exactly.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    width: usize,
    height: usize,
    data: Vec<f64>,
    pub meta: ImageMeta,
}

impl Image {
    /// An image from row-major samples. Errors if a size is zero or the length does not match.
    pub fn new(
        width: usize,
        height: usize,
        data: Vec<f64>,
        meta: ImageMeta,
    ) -> Result<Self, ShapeError> {
        if width == 0 || height == 0 || data.len() != width * height {
            return Err(ShapeError {
                width,
                height,
                len: data.len(),
            });
        }
        Ok(Image {
            width,
            height,
            data,
            meta,
        })
    }

    /// An image whose sample at `(x, y)` is `f(x, y)`; metadata default (float, no saturation).
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> f64) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Image {
            width,
            height,
            data,
            meta: ImageMeta::default(),
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    /// Row-major samples.
    pub fn data(&self) -> &[f64] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [f64] {
        &mut self.data
    }
    pub fn into_data(self) -> Vec<f64> {
        self.data
    }
    /// Sample at column `x`, row `y`. Panics when out of bounds (like slice indexing).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> f64 {
        self.data[y * self.width + x]
    }
    /// Row `y` as a slice.
    #[inline]
    pub fn row(&self, y: usize) -> &[f64] {
        &self.data[y * self.width..(y + 1) * self.width]
    }
    /// Whether the sample is at or above the saturation level of its source.
    #[inline]
    pub fn is_saturated(&self, v: f64) -> bool {
        self.meta.saturation.is_some_and(|s| v >= s)
    }
    /// (min, max, mean) over all finite samples; `None` if there is none.
    pub fn stats(&self) -> Option<(f64, f64, f64)> {
        let mut n = 0usize;
        let (mut lo, mut hi, mut sum) = (f64::INFINITY, f64::NEG_INFINITY, 0.0);
        for &v in self.data.iter().filter(|v| v.is_finite()) {
            lo = lo.min(v);
            hi = hi.max(v);
            sum += v;
            n += 1;
        }
        (n > 0).then(|| (lo, hi, sum / n as f64))
    }
}

/// Region of interest: `true` = keep. "Keep" is what displays white in the mask file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mask {
    width: usize,
    height: usize,
    keep: Vec<bool>,
}

impl Mask {
    pub fn new(width: usize, height: usize, keep: Vec<bool>) -> Result<Self, ShapeError> {
        if width == 0 || height == 0 || keep.len() != width * height {
            return Err(ShapeError {
                width,
                height,
                len: keep.len(),
            });
        }
        Ok(Mask {
            width,
            height,
            keep,
        })
    }
    /// A mask that keeps every pixel.
    pub fn all(width: usize, height: usize) -> Self {
        Mask {
            width,
            height,
            keep: vec![true; width * height],
        }
    }
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> bool) -> Self {
        let mut keep = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                keep.push(f(x, y));
            }
        }
        Mask {
            width,
            height,
            keep,
        }
    }
    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    #[inline]
    pub fn keeps(&self, x: usize, y: usize) -> bool {
        self.keep[y * self.width + x]
    }
    pub fn as_slice(&self) -> &[bool] {
        &self.keep
    }
    /// Whether the point `(x, y)` (px, pixel centres at integers) is kept: the pixel it rounds
    /// to is kept. A point outside the image, or not finite, is not kept.
    pub fn keeps_point(&self, x: f64, y: f64) -> bool {
        let (cx, cy) = (x.round(), y.round());
        // NaN fails every comparison
        if !(cx >= 0.0 && cy >= 0.0 && cx < self.width as f64 && cy < self.height as f64) {
            return false;
        }
        self.keeps(cx as usize, cy as usize)
    }
    /// Number of kept pixels.
    pub fn count_kept(&self) -> usize {
        self.keep.iter().filter(|&&k| k).count()
    }
    /// Whether the mask has the same size as `img`.
    pub fn matches(&self, img: &Image) -> bool {
        self.width == img.width() && self.height == img.height()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shape_is_checked() {
        assert!(Image::new(2, 2, vec![0.0; 3], ImageMeta::default()).is_err());
        assert!(Image::new(0, 2, vec![], ImageMeta::default()).is_err());
        let img = Image::new(
            2,
            2,
            vec![1.0, 2.0, 3.0, f64::NAN],
            ImageMeta::synthetic(12),
        )
        .unwrap();
        assert_eq!(img.stats(), Some((1.0, 3.0, 2.0)));
        assert!(img.is_saturated(4095.0) && !img.is_saturated(4094.0));
    }

    #[test]
    fn mask_counts() {
        let m = Mask::from_fn(4, 3, |x, _| x < 2);
        assert_eq!(m.count_kept(), 6);
        assert!(m.keeps(1, 2) && !m.keeps(2, 0));
        assert!(m.keeps_point(1.49, 2.4) && !m.keeps_point(1.5, 0.0));
        assert!(!m.keeps_point(-0.6, 0.0) && !m.keeps_point(0.0, 2.5));
        assert!(m.keeps_point(-0.4, 0.0) && !m.keeps_point(f64::NAN, 0.0));
    }
}
