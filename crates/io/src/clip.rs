//! The clip (saturation) level of camera data, which is often below its container's maximum:
//! most scientific cameras write 12-bit (or 10/14-bit) samples into 16-bit files, so a pixel
//! clipped at 4095 is not at the container's 65535 and would be fitted as a valid sample.
//!
//! [`Saturation`] is what the user asks for (`[input] saturation`, `locate --saturation`):
//! `"auto"` or a level in counts. [`find_clip_level`] finds the level from the data and says
//! where it came from ([`ClipLevel`]); [`apply_saturation`] sets it as the image's
//! `meta.saturation`, which every stage reads (pixels at or above it are left out of the fits and
//! flag their dot `saturated`).
//!
//! `auto`, for unsigned integer images, in this order (the first that applies):
//! 1. the TIFF tag **MaxSampleValue** (281), when present and below the container's maximum;
//! 2. a **pile-up** at the largest sample value `M`: at least [`PILE_MIN`] samples at `M`, at
//!    least [`PILE_RATIO`] times as many as at any of the [`PILE_BELOW`] sample values just below
//!    it (in steps of the samples' common power of two), and at most half of the samples;
//! 3. the **significant bits** of the samples: `2^b - 1` for the smallest camera depth `b` (8,
//!    10, 12, 14 bit, below the container's) that holds every sample; else, when the low `t`
//!    bits are zero in every sample (left-justified data), the container's maximum with them
//!    cleared, `2^bits - 2^t`. No sample lies above it, so it changes only samples exactly at it
//!    (a 12-bit camera's 4095, left out of the fits as clipped);
//! 4. the container's maximum `2^bits - 1`.
//!
//! Float images have no clip level unless one is given.

use crate::error::{IoError, IoErrorKind};
use bostrack_core::{Image, SampleFormat};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;
use std::str::FromStr;

/// Fewest samples at the largest value that make a pile-up.
pub const PILE_MIN: usize = 3;
/// A pile-up holds at least this many times the samples of any value just below it.
pub const PILE_RATIO: usize = 4;
/// Sample values below the largest one compared with it.
pub const PILE_BELOW: u64 = 8;

/// Samples per rayon task of the clip level's passes over the image (a 1-MP image: 16 tasks).
const CLIP_CHUNK: usize = 1 << 16;

/// Camera bit depths that the significant-bits rule recognises below a 16-bit container.
const CAMERA_BITS: [u32; 4] = [8, 10, 12, 14];

/// The clip level asked for: found from the data (`"auto"`) or given in counts.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Saturation {
    /// Found by [`find_clip_level`].
    #[default]
    Auto,
    /// This level, counts (finite, > 0): samples at or above it are clipped.
    Counts(f64),
}

impl Saturation {
    /// `Err` with the reason when a given level is not a finite number > 0.
    pub fn validate(self) -> Result<(), String> {
        match self {
            Saturation::Counts(c) if !(c.is_finite() && c > 0.0) => Err(format!(
                "must be \"auto\" or a level in counts > 0, got {c}"
            )),
            _ => Ok(()),
        }
    }
}

impl fmt::Display for Saturation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Saturation::Auto => f.write_str("auto"),
            Saturation::Counts(c) => write!(f, "{c}"),
        }
    }
}

impl FromStr for Saturation {
    type Err = String;
    /// `"auto"` or a number of counts > 0.
    fn from_str(s: &str) -> Result<Self, String> {
        if s.trim() == "auto" {
            return Ok(Saturation::Auto);
        }
        let v = s
            .trim()
            .parse::<f64>()
            .map_err(|_| format!("expected \"auto\" or a level in counts, got `{s}`"))?;
        let sat = Saturation::Counts(v);
        sat.validate()?;
        Ok(sat)
    }
}

impl Serialize for Saturation {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Saturation::Auto => s.serialize_str("auto"),
            // whole levels as integers (`4095`, not `4095.0`)
            Saturation::Counts(c) if c.fract() == 0.0 && c.abs() < 9.0e15 => {
                s.serialize_i64(*c as i64)
            }
            Saturation::Counts(c) => s.serialize_f64(*c),
        }
    }
}

impl<'de> Deserialize<'de> for Saturation {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Saturation;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("\"auto\" or a level in counts > 0")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Saturation, E> {
                match v {
                    "auto" => Ok(Saturation::Auto),
                    _ => Err(E::custom(format!(
                        "expected \"auto\" or a level in counts > 0, got \"{v}\""
                    ))),
                }
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Saturation, E> {
                let s = Saturation::Counts(v);
                s.validate().map_err(E::custom)?;
                Ok(s)
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Saturation, E> {
                self.visit_f64(v as f64)
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Saturation, E> {
                self.visit_f64(v as f64)
            }
        }
        d.deserialize_any(V)
    }
}

/// Where a clip level came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ClipSource {
    /// Given by the user (`[input] saturation = <counts>`, `--saturation`).
    Given,
    /// The TIFF tag MaxSampleValue.
    MaxSampleValue,
    /// A pile-up of samples at the largest value.
    PileUp,
    /// The significant bits of the samples (a camera depth below the container's).
    SignificantBits,
    /// The container's maximum, `2^bits - 1`.
    Container,
    /// Float data: no clip level.
    None,
}

impl fmt::Display for ClipSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ClipSource::Given => "given",
            ClipSource::MaxSampleValue => "max-sample-value",
            ClipSource::PileUp => "pile-up",
            ClipSource::SignificantBits => "significant-bits",
            ClipSource::Container => "container",
            ClipSource::None => "none",
        })
    }
}

/// A clip level and the evidence for it, as reported by `bostrack info` and the run record.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ClipLevel {
    /// Samples at or above this level are clipped (counts); `None`: no level (float data).
    pub level: Option<f64>,
    pub source: ClipSource,
    /// Finite samples at or above `level`.
    pub clipped_pixels: usize,
    /// The largest finite sample (`None` when none is finite).
    pub max_sample: Option<f64>,
    /// The container's maximum `2^bits - 1` (`None` for float data).
    pub container: Option<f64>,
}

impl fmt::Display for ClipLevel {
    /// `4095 (pile-up, 312 pixels)`, or `none (float data)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.level {
            Some(l) => write!(
                f,
                "{l} ({}, {} pixels at or above it)",
                self.source, self.clipped_pixels
            ),
            None => f.write_str("none (float data)"),
        }
    }
}

/// 2^52: below it, `x + 2^52` holds the integer nearest to `x ≥ 0` in its low 52 bits.
const TWO_52: f64 = 4503599627370496.0;

/// The clip level of `img` from its samples and, when known, the file's MaxSampleValue tag (see
/// the module documentation for the rules).
pub fn find_clip_level(img: &Image, max_sample_value: Option<f64>) -> ClipLevel {
    match histogram(img) {
        Some(h) => clip_from_histogram(img, &h, max_sample_value),
        None => clip_by_passes(img, max_sample_value),
    }
}

/// [`find_clip_level`] by passes over the samples as floats (any format and values).
fn clip_by_passes(img: &Image, max_sample_value: Option<f64>) -> ClipLevel {
    let chunks = || img.data().par_chunks(CLIP_CHUNK);
    // One pass for the largest finite sample, the OR of the samples (their common power of
    // two) and the count of finite ones; the pile-up test one more, which also counts the
    // samples at the largest value, so that the clipped pixels need a pass of their own only
    // for a level below the largest sample (a tag or a given level). Unsigned images of up to
    // 16 bits take the histogram instead (`histogram`: these passes took 53 M instructions per
    // 1-MP image, 3 × its decoding). Each pass runs over blocks of rows on the current rayon
    // pool: the maximum, the OR and the counts do not depend on the order, so neither does the
    // result.
    let (max, or, finite) = chunks()
        .map(|c| {
            let (mut max, mut or, mut n) = (f64::NEG_INFINITY, 0u64, 0usize);
            for &v in c.iter().filter(|v| v.is_finite()) {
                max = max.max(v);
                or |= v.max(0.0) as u64;
                n += 1;
            }
            (max, or, n)
        })
        .reduce(
            || (f64::NEG_INFINITY, 0u64, 0usize),
            |a, b| (a.0.max(b.0), a.1 | b.1, a.2 + b.2),
        );
    let max_sample = max.is_finite().then_some(max);
    let meta = &img.meta;
    let container = match meta.sample_format {
        SampleFormat::Unsigned if meta.bits_per_sample < 64 => {
            Some(((1u64 << meta.bits_per_sample) - 1) as f64)
        }
        _ => None,
    };
    // `at_max`: the finite samples equal to the largest one, where counted
    let with = |level: Option<f64>, source, at_max: Option<usize>| ClipLevel {
        level,
        source,
        clipped_pixels: level.map_or(0, |l| match (max_sample, at_max) {
            (Some(m), _) if l > m => 0,
            (Some(m), Some(at)) if l == m => at,
            (None, _) => 0,
            _ => chunks()
                .map(|c| c.iter().filter(|&&v| v.is_finite() && v >= l).count())
                .sum(),
        }),
        max_sample,
        container,
    };
    let Some(cmax) = container else {
        return with(None, ClipSource::None, None);
    };
    if let Some(t) = max_sample_value.filter(|&t| t > 0.0 && t < cmax) {
        return with(Some(t), ClipSource::MaxSampleValue, None);
    }
    let Some(m) = max_sample.filter(|&m| m > 0.0) else {
        return with(Some(cmax), ClipSource::Container, None);
    };
    // the samples' common power of two (left-justified data step by 2^t)
    let t = or.trailing_zeros().min(63);
    let step = (1u64 << t) as f64;
    let (pile_up, at) = pile_up(img, m, step, finite);
    if pile_up {
        return with(Some(m), ClipSource::PileUp, Some(at));
    }
    let bits: u32 = meta.bits_per_sample.into();
    // right-justified data of a shallower camera, else left-justified data (low bits zero)
    let level = match CAMERA_BITS
        .into_iter()
        .find(|&b| b < bits && m < (1u64 << b) as f64)
    {
        Some(b) => Some(((1u64 << b) - 1) as f64),
        None => (t >= 1 && t < bits).then(|| ((1u64 << bits) - (1u64 << t)) as f64),
    };
    if let Some(level) = level.filter(|&l| l < cmax) {
        return with(Some(level), ClipSource::SignificantBits, Some(at));
    }
    with(Some(cmax), ClipSource::Container, Some(at))
}

/// Deepest container (bits) whose samples [`find_clip_level`] counts in a histogram.
const HISTOGRAM_BITS: u16 = 16;

/// Samples per rayon task of the histogram.
const HISTOGRAM_CHUNK: usize = 1 << 18;

/// The histogram of an unsigned-integer image of at most [`HISTOGRAM_BITS`] bits (one bin per
/// sample value; `None` when a sample is not an integer in the container's range, or for other
/// formats): one pass of ~17 instructions per pixel from which every rule of
/// [`find_clip_level`] is read, instead of two passes over the samples as floats.
fn histogram(img: &Image) -> Option<Vec<u32>> {
    let meta = &img.meta;
    if meta.sample_format != SampleFormat::Unsigned || meta.bits_per_sample > HISTOGRAM_BITS {
        return None;
    }
    let bins = 1usize << meta.bits_per_sample;
    // (blocks of 2^18 samples: a 1-MP image makes 4 histograms of up to 256 KiB to merge)
    img.data()
        .par_chunks(HISTOGRAM_CHUNK)
        .try_fold(
            || vec![0u32; bins],
            |mut h, c| {
                for &v in c {
                    // the integer nearest to v in the low bits of v + 2^52 (2 instructions where
                    // `as usize` takes 16); a sample that is not that integer (a fraction, a
                    // negative, NaN, ∞) fails the comparison
                    let k = ((v + TWO_52).to_bits() & ((1u64 << 52) - 1)) as i64;
                    match h.get_mut(k as usize) {
                        Some(n) if k as f64 == v => *n += 1,
                        _ => return None,
                    }
                }
                Some(h)
            },
        )
        .try_reduce(
            || vec![0u32; bins],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(&b) {
                    *x += y;
                }
                Some(a)
            },
        )
}

/// [`find_clip_level`] read from the image's [`histogram`]: the same rules, the same result.
fn clip_from_histogram(img: &Image, h: &[u32], max_sample_value: Option<f64>) -> ClipLevel {
    let meta = &img.meta;
    let cmax = ((1u64 << meta.bits_per_sample) - 1) as f64;
    let top = h.iter().rposition(|&n| n > 0);
    let max_sample = top.map(|m| m as f64);
    let finite: usize = img.data().len();
    let at_or_above = |l: f64| -> usize {
        let from = l.ceil().max(0.0);
        if from >= h.len() as f64 {
            return 0;
        }
        h[from as usize..].iter().map(|&n| n as usize).sum()
    };
    let with = |level: f64, source| ClipLevel {
        level: Some(level),
        source,
        clipped_pixels: at_or_above(level),
        max_sample,
        container: Some(cmax),
    };
    if let Some(t) = max_sample_value.filter(|&t| t > 0.0 && t < cmax) {
        return with(t, ClipSource::MaxSampleValue);
    }
    let Some(m) = top.filter(|&m| m > 0) else {
        return with(cmax, ClipSource::Container);
    };
    let or = h
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .fold(0usize, |o, (k, _)| o | k);
    let t = or.trailing_zeros().min(63);
    let step = 1usize << t;
    let at = h[m] as usize;
    let most_below = (1..=PILE_BELOW as usize)
        .filter_map(|k| m.checked_sub(k * step))
        .map(|v| h[v] as usize)
        .max()
        .unwrap_or(0);
    if at >= PILE_MIN && at >= PILE_RATIO * most_below && 2 * at <= finite {
        return with(m as f64, ClipSource::PileUp);
    }
    let bits: u32 = meta.bits_per_sample.into();
    let level = match CAMERA_BITS
        .into_iter()
        .find(|&b| b < bits && m < 1usize << b)
    {
        Some(b) => Some(((1u64 << b) - 1) as f64),
        None => (t >= 1 && t < bits).then(|| ((1u64 << bits) - (1u64 << t)) as f64),
    };
    if let Some(level) = level.filter(|&l| l < cmax) {
        return with(level, ClipSource::SignificantBits);
    }
    with(cmax, ClipSource::Container)
}

/// Whether the largest sample `m` holds a pile-up (module documentation, rule 2), of `finite`
/// finite samples; and how many samples equal `m`.
fn pile_up(img: &Image, m: f64, step: f64, finite: usize) -> (bool, usize) {
    type Counts = (usize, [usize; PILE_BELOW as usize]);
    let lo = m - PILE_BELOW as f64 * step;
    let (at, below) = img
        .data()
        .par_chunks(CLIP_CHUNK)
        .map(|c| {
            let (mut at, mut below): Counts = (0, [0; PILE_BELOW as usize]);
            for &v in c {
                at += usize::from(v == m);
                // (rare: the few values just below the largest; NaN compares false)
                if v >= lo && v < m {
                    let k = ((m - v) / step).round() as usize;
                    if (1..=below.len()).contains(&k) && (m - v) == k as f64 * step {
                        below[k - 1] += 1;
                    }
                }
            }
            (at, below)
        })
        .reduce(
            || (0, [0; PILE_BELOW as usize]),
            |a: Counts, b: Counts| {
                let mut below = a.1;
                for (x, y) in below.iter_mut().zip(b.1) {
                    *x += y;
                }
                (a.0 + b.0, below)
            },
        );
    let most_below = below.into_iter().max().unwrap_or(0);
    (
        at >= PILE_MIN && at >= PILE_RATIO * most_below && 2 * at <= finite,
        at,
    )
}

/// The TIFF tag MaxSampleValue (281) of the first page of `path`, `None` when absent or for a
/// PNG file. Reads only the file's header and first directory.
pub fn max_sample_value(path: &Path) -> Result<Option<f64>, IoError> {
    let err = |k| IoError::new(path, k);
    let file = std::fs::File::open(path).map_err(|e| err(IoErrorKind::from_io(e)))?;
    let mut reader = std::io::BufReader::new(file);
    let mut magic = [0u8; 4];
    {
        use std::io::{Read as _, Seek as _};
        let n = reader
            .read(&mut magic)
            .map_err(|e| err(IoErrorKind::from_io(e)))?;
        reader.rewind().map_err(|e| err(IoErrorKind::from_io(e)))?;
        if crate::format::detect(&magic[..n]).ok() != Some(crate::FileFormat::Tiff) {
            return Ok(None);
        }
    }
    let mut dec =
        tiff::decoder::Decoder::new(reader).map_err(|e| err(IoErrorKind::from_tiff(e)))?;
    let v = dec
        .find_tag_unsigned::<u64>(tiff::tags::Tag::MaxSampleValue)
        .map_err(|e| err(IoErrorKind::from_tiff(e)))?;
    Ok(v.map(|v| v as f64))
}

/// Sets `img.meta.saturation` from `setting` (given, or [`find_clip_level`] with the file's
/// MaxSampleValue tag when `path` is the file the image was read from) and returns the level
/// with its evidence.
pub fn apply_saturation(
    img: &mut Image,
    setting: Saturation,
    path: Option<&Path>,
) -> Result<ClipLevel, IoError> {
    let found = match setting {
        Saturation::Counts(c) => {
            let mut f = find_clip_level(img, None);
            f.level = Some(c);
            f.source = ClipSource::Given;
            f.clipped_pixels = img
                .data()
                .iter()
                .filter(|v| v.is_finite() && **v >= c)
                .count();
            f
        }
        Saturation::Auto => {
            let tag = match path {
                Some(p) => max_sample_value(p)?,
                None => None,
            };
            find_clip_level(img, tag)
        }
    };
    img.meta.saturation = found.level;
    Ok(found)
}

/// [`read_image`](crate::read_image), then [`apply_saturation`] with the file's tag.
pub fn read_image_clipped(path: &Path, setting: Saturation) -> Result<(Image, ClipLevel), IoError> {
    let mut img = crate::read_image(path)?;
    let clip = apply_saturation(&mut img, setting, Some(path))?;
    Ok((img, clip))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bostrack_core::ImageMeta;

    fn image(bits: u16, data: Vec<f64>) -> Image {
        let n = data.len();
        Image::new(n, 1, data, ImageMeta::synthetic(bits)).unwrap()
    }

    /// The histogram of integer images gives what the passes over the samples give, for every
    /// rule: pile-ups, shallower cameras, left-justified data, the tag, empty and full images.
    #[test]
    fn the_histogram_and_the_passes_agree() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        for case in 0..60 {
            let bits: u16 = [8, 12, 16][case % 3];
            let n = 1 + (case * 9_973) % 300_000;
            let top: u64 = match case % 5 {
                0 => (1 << bits) - 1,
                1 => 4095.min((1 << bits) - 1),
                2 => 1023,
                3 => 0,
                _ => rng.random_range(1..(1u64 << bits)),
            }
            .min((1 << bits) - 1);
            let shift = if case % 7 == 0 {
                4.min(bits as u32 - 1)
            } else {
                0
            };
            let mut d: Vec<f64> = (0..n)
                .map(|_| ((rng.random_range(0..=top) >> shift) << shift) as f64)
                .collect();
            if case % 4 == 1 {
                // a pile-up at the largest value
                let m = d.iter().cloned().fold(0.0, f64::max);
                for v in d.iter_mut().take(n / 10) {
                    *v = m;
                }
            }
            let img = image(bits, d);
            for tag in [None, Some(1000.0), Some(0.5 * ((1u64 << bits) - 1) as f64)] {
                let h = histogram(&img).expect("integer samples");
                assert_eq!(
                    clip_from_histogram(&img, &h, tag),
                    clip_by_passes(&img, tag),
                    "case {case}, bits {bits}, tag {tag:?}"
                );
            }
        }
        // not integers, NaN, negative, beyond the container: the passes
        for d in [
            vec![1.5, 2.0],
            vec![f64::NAN, 3.0],
            vec![-1.0, 3.0],
            vec![70000.0, 1.0],
        ] {
            assert!(histogram(&image(16, d)).is_none());
        }
    }

    #[test]
    fn pile_up_at_the_maximum_is_the_level() {
        // a smooth top (1 sample per value) and 40 samples piled at 3000
        let mut d: Vec<f64> = (0..3000).map(f64::from).collect();
        d.extend(std::iter::repeat_n(3000.0, 40));
        let c = find_clip_level(&image(16, d), None);
        assert_eq!(
            (c.level, c.source, c.clipped_pixels),
            (Some(3000.0), ClipSource::PileUp, 40)
        );
    }

    #[test]
    fn no_pile_up_falls_back_to_the_significant_bits() {
        let d: Vec<f64> = (0..3000).map(f64::from).collect();
        let c = find_clip_level(&image(16, d), None);
        assert_eq!(
            (c.level, c.source, c.clipped_pixels),
            (Some(4095.0), ClipSource::SignificantBits, 0)
        );
        // 10-bit data
        let c = find_clip_level(
            &image(16, vec![3.0, 1000.0, 1000.0, 1000.0, 999.0, 999.0]),
            None,
        );
        assert_eq!(c.source, ClipSource::SignificantBits, "{c:?}");
        assert_eq!(c.level, Some(1023.0));
        // left-justified 12-bit data: multiples of 16, clipped at 65520
        let mut d: Vec<f64> = (0..2000).map(|v| f64::from(v * 16)).collect();
        d.extend(std::iter::repeat_n(65520.0, 10));
        let c = find_clip_level(&image(16, d), None);
        assert_eq!((c.level, c.source), (Some(65520.0), ClipSource::PileUp));
        let d: Vec<f64> = (0..2000).map(|v| f64::from(v * 16)).collect();
        let c = find_clip_level(&image(16, d), None);
        assert_eq!(
            (c.level, c.source),
            (Some(65520.0), ClipSource::SignificantBits)
        );
    }

    #[test]
    fn the_tag_wins_and_full_depth_data_keep_the_container() {
        let d: Vec<f64> = (0..3000).map(f64::from).collect();
        let c = find_clip_level(&image(16, d.clone()), Some(4000.0));
        assert_eq!(
            (c.level, c.source),
            (Some(4000.0), ClipSource::MaxSampleValue)
        );
        // a tag at the container's maximum says nothing
        let c = find_clip_level(&image(16, d), Some(65535.0));
        assert_eq!(c.source, ClipSource::SignificantBits);
        let c = find_clip_level(&image(16, vec![1.0, 60000.0, 17.0]), None);
        assert_eq!((c.level, c.source), (Some(65535.0), ClipSource::Container));
        let c = find_clip_level(&image(8, vec![1.0, 200.0, 17.0]), None);
        assert_eq!((c.level, c.source), (Some(255.0), ClipSource::Container));
        // nothing to go on: all zero, or a constant image (a pile-up of everything)
        let c = find_clip_level(&image(16, vec![0.0; 10]), None);
        assert_eq!(c.source, ClipSource::Container);
        let c = find_clip_level(&image(16, vec![700.0; 10]), None);
        assert_eq!(
            (c.level, c.source),
            (Some(1023.0), ClipSource::SignificantBits)
        );
        let c = find_clip_level(&image(64, vec![0.5, f64::NAN]), None);
        assert_eq!(
            (c.level, c.source, c.max_sample),
            (None, ClipSource::None, Some(0.5))
        );
    }

    #[test]
    fn settings_parse_and_serialise() {
        assert_eq!("auto".parse::<Saturation>(), Ok(Saturation::Auto));
        assert_eq!("4095".parse::<Saturation>(), Ok(Saturation::Counts(4095.0)));
        assert!("-3".parse::<Saturation>().unwrap_err().contains("> 0"));
        assert!("full".parse::<Saturation>().unwrap_err().contains("full"));
        #[derive(Debug, Serialize, Deserialize, PartialEq)]
        struct T {
            s: Saturation,
        }
        for (text, s) in [
            ("s = \"auto\"\n", Saturation::Auto),
            ("s = 4095\n", Saturation::Counts(4095.0)),
            ("s = 4095.5\n", Saturation::Counts(4095.5)),
        ] {
            let t: T = toml::from_str(text).unwrap();
            assert_eq!(t.s, s);
            assert_eq!(toml::to_string(&t).unwrap(), text);
        }
        for bad in ["s = \"max\"\n", "s = 0\n", "s = -1.5\n", "s = true\n"] {
            let e = toml::from_str::<T>(bad).unwrap_err().to_string();
            assert!(e.contains("\"auto\" or a level in counts"), "{bad}: {e}");
        }
    }

    #[test]
    fn applying_sets_the_meta() {
        let mut img = image(16, (0..3000).map(f64::from).collect());
        let c = apply_saturation(&mut img, Saturation::Counts(2000.0), None).unwrap();
        assert_eq!(
            (c.level, c.source, c.clipped_pixels),
            (Some(2000.0), ClipSource::Given, 1000)
        );
        assert_eq!(img.meta.saturation, Some(2000.0));
        let c = apply_saturation(&mut img, Saturation::Auto, None).unwrap();
        assert_eq!(img.meta.saturation, Some(4095.0));
        assert_eq!(
            c.to_string(),
            "4095 (significant-bits, 0 pixels at or above it)"
        );
    }
}
