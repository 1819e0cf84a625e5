//! Image I/O for real camera files.
//!
//! Reads TIFF and PNG files into [`bostrack_core::Image`] (f64 samples in camera counts, larger =
//! brighter on display) with their [`ImageMeta`](bostrack_core::ImageMeta): bit depth, sample
//! format, saturation level `2^bits - 1`, compression, photometric interpretation, source path
//! and page. Files are recognised by their first bytes, not by their extension.
//!
//! | | supported |
//! |---|---|
//! | TIFF samples | unsigned 8, **12 (packed)**, 16, 32 bit; float 32, 64 bit; one channel |
//! | TIFF compression | none, PackBits, LZW, Deflate (also for 12-bit); **not** JPEG, CCITT, LZMA, Zstd, WebP |
//! | TIFF layout | little or big endian, strips or tiles, multi-page ([`read_stack`]), BigTIFF |
//! | photometric | BlackIsZero; WhiteIsZero inverted on reading (`max - raw`, `1.0 - raw` for float) |
//! | PNG | grayscale 8 or 16 bit (1/2/4-bit grayscale expanded to 8 bit) |
//! | masks ([`read_mask`]) | any of the above; kept = displays brighter than the midpoint of the mask's darkest and brightest samples ({0, 1}, {0, 255}, {0, 65535} alike) |
//! | writing | TIFF u16 and f32 (uncompressed, little-endian), PNG u8 and u16; atomic (temp file + rename) |
//! | clip level | `saturation` = `2^bits - 1` on reading; [`read_image_clipped`] / [`apply_saturation`] set the camera's level (`"auto"`: [`find_clip_level`], e.g. 4095 for 12-bit data in a 16-bit file) |
//!
//! 8/16/32-bit and float TIFF samples are decoded by the `tiff` crate. Neither it nor `image`
//! decodes 12-bit samples, so for those this crate takes the strip/tile tags from the `tiff`
//! decoder, reads the chunks itself, undoes PackBits/LZW/Deflate and unpacks two pixels from
//! three bytes, MSB first whatever the byte order (TIFF 6.0, FillOrder 1). Unsupported: FillOrder
//! 2, a predictor on 12-bit data, colour, signed integers, and bit depths other than the above.
//!
//! **Bounded reading.** Only regular files are read (a folder, a FIFO, which would block, or a
//! device such as `/dev/zero`, which never ends, is refused before it is opened:
//! [`IoErrorKind::NotRegularFile`]), and of a file only the bytes its image structure points to:
//! the headers, the directories and each page's strips or tiles, a chunk no further than its data
//! can need. Trailing or unreferenced bytes are never read, so a 256 x 256 TIFF padded to 3 GB
//! reads in a few MiB. An image or tile holds at most 2^28 pixels, a stack's pages at most 2^30
//! together.
//!
//! Every failure is an [`IoError`] naming the file and the reason; nothing panics on bad input.
//!
//! ```
//! use bostrack_core::{Image, ImageMeta};
//! use bostrack_io::{probe, read_image, write_tiff_u16};
//!
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("frame.tif");
//! let mut img = Image::from_fn(6, 4, |x, y| (100 * y + x) as f64);
//! img.meta = ImageMeta::synthetic(16);
//! write_tiff_u16(&path, &img)?;
//!
//! let info = probe(&path)?;
//! assert_eq!((info.width, info.height, info.bits_per_sample, info.pages), (6, 4, 16, 1));
//! let back = read_image(&path)?;
//! assert_eq!(back.get(5, 3), 305.0);
//! assert_eq!(back.meta.saturation, Some(65535.0));
//!
//! let err = read_image(&dir.path().join("missing.tif")).unwrap_err();
//! assert!(err.to_string().ends_with("missing.tif: file not found"));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod clip;
mod decompress;
mod error;
mod format;
mod info;
mod png_read;
mod read;
mod sample;
mod tiff_read;
mod write;

pub use clip::{
    ClipLevel, ClipSource, PILE_BELOW, PILE_MIN, PILE_RATIO, Saturation, apply_saturation,
    find_clip_level, max_sample_value, read_image_clipped,
};
pub use error::{IoError, IoErrorKind};
pub use format::{ByteOrder, FileFormat};
pub use info::{ImageInfo, ImageStats, image_stats};
pub use read::{mask_of, probe, read_image, read_mask, read_mask_for, read_stack};
pub use sample::bos_sample_dir;
pub use write::{
    write_png_u8, write_png_u16, write_tiff_f32, write_tiff_stack_u16, write_tiff_u16,
};
