//! Bad input: each case gives an `IoError` whose message names the file and the reason, never a
//! panic. The bad files are crafted here by writing or patching bytes.

mod support;

use bostrack_core::{Image, ImageMeta};
use bostrack_io::{
    IoError, IoErrorKind, probe, read_image, read_mask, read_mask_for, read_stack, write_tiff_u16,
};
use std::path::{Path, PathBuf};
use support::{fixture, gray8_tiff, patch_tag_le};

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// The message starts with the file and contains `reason`.
fn assert_message(e: &IoError, path: &Path, reason: &str) {
    let msg = e.to_string();
    assert!(msg.starts_with(&format!("{}: ", path.display())), "{msg}");
    assert!(msg.contains(reason), "{msg:?} should contain {reason:?}");
}

#[test]
fn missing_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nope.tif");
    for e in [
        read_image(&path).unwrap_err(),
        read_stack(&path).unwrap_err(),
        probe(&path).unwrap_err(),
    ] {
        assert!(matches!(e.kind, IoErrorKind::NotFound), "{e:?}");
        assert_message(&e, &path, "file not found");
    }
}

#[test]
fn truncated_file() {
    let dir = tempfile::tempdir().unwrap();
    // tifffile puts the IFD first, the data after it: cutting the data leaves the tags intact
    let full = std::fs::read(fixture("be_u16_packbits.tif")).unwrap();
    let cut = write(dir.path(), "cut-data.tif", &full[..full.len() - 100]);
    let e = read_image(&cut).unwrap_err();
    assert!(matches!(e.kind, IoErrorKind::Truncated(_)), "{e:?}");
    assert_message(&e, &cut, "lies past the end of the file");
    assert!(matches!(
        probe(&cut).unwrap_err().kind,
        IoErrorKind::Truncated(_)
    ));
    // the tiff crate writes the IFD last: cutting it off loses the tags
    let enc = gray8_tiff(40, 30);
    let cut = write(dir.path(), "cut-ifd.tif", &enc[..enc.len() - 60]);
    let e = read_image(&cut).unwrap_err();
    assert!(matches!(e.kind, IoErrorKind::Truncated(_)), "{e:?}");
    assert_message(&e, &cut, "truncated file");
    // only part of the signature
    let cut = write(dir.path(), "cut-magic.tif", b"MM\0");
    assert!(matches!(
        read_image(&cut).unwrap_err().kind,
        IoErrorKind::Truncated(_)
    ));
}

#[test]
fn not_a_tiff() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "notes.tif", b"x,y\n1,2\n");
    let e = read_image(&path).unwrap_err();
    assert!(matches!(e.kind, IoErrorKind::UnknownFormat(_)), "{e:?}");
    assert_message(
        &e,
        &path,
        "not a TIFF or PNG file (it starts with \"x,y\\x0a1,2\\x0a\")",
    );
}

#[test]
fn jpeg_compression_is_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = gray8_tiff(16, 16);
    patch_tag_le(&mut bytes, 259, 7); // Compression = JPEG
    let path = write(dir.path(), "jpeg.tif", &bytes);
    let e = read_image(&path).unwrap_err();
    assert!(
        matches!(e.kind, IoErrorKind::UnsupportedCompression { code: 7, .. }),
        "{e:?}"
    );
    assert_message(
        &e,
        &path,
        "unsupported compression JPEG (TIFF Compression = 7)",
    );
    assert!(matches!(
        probe(&path).unwrap_err().kind,
        IoErrorKind::UnsupportedCompression { code: 7, .. }
    ));
}

#[test]
fn four_bit_samples_are_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = gray8_tiff(16, 16);
    patch_tag_le(&mut bytes, 258, 4); // BitsPerSample = 4 (the tiff crate itself would read it)
    let path = write(dir.path(), "4bit.tif", &bytes);
    let e = read_image(&path).unwrap_err();
    assert!(
        matches!(e.kind, IoErrorKind::UnsupportedBitDepth { bits: 4, .. }),
        "{e:?}"
    );
    assert_message(&e, &path, "unsupported bit depth: 4-bit unsigned samples");
}

#[test]
fn twenty_four_bit_samples_are_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = gray8_tiff(16, 16);
    patch_tag_le(&mut bytes, 258, 24);
    let path = write(dir.path(), "24bit.tif", &bytes);
    let e = read_image(&path).unwrap_err();
    assert!(
        matches!(e.kind, IoErrorKind::UnsupportedBitDepth { bits: 24, .. }),
        "{e:?}"
    );
    assert_message(&e, &path, "24-bit unsigned");
}

#[test]
fn signed_samples_are_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let mut buf = std::io::Cursor::new(Vec::new());
    let mut enc = tiff::encoder::TiffEncoder::new(&mut buf).unwrap();
    enc.write_image::<tiff::encoder::colortype::GrayI16>(4, 4, &[-3i16; 16])
        .unwrap();
    let path = write(dir.path(), "i16.tif", buf.get_ref());
    let e = read_image(&path).unwrap_err();
    assert_message(&e, &path, "16-bit signed integer samples");
}

#[test]
fn colour_tiff_is_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let mut buf = std::io::Cursor::new(Vec::new());
    let mut enc = tiff::encoder::TiffEncoder::new(&mut buf).unwrap();
    enc.write_image::<tiff::encoder::colortype::RGB8>(4, 4, &[9u8; 48])
        .unwrap();
    let path = write(dir.path(), "rgb.tif", buf.get_ref());
    let e = read_image(&path).unwrap_err();
    assert!(matches!(e.kind, IoErrorKind::Unsupported(_)), "{e:?}");
    assert_message(&e, &path, "3 samples per pixel");
}

#[test]
fn zero_sized_image() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = gray8_tiff(16, 16);
    patch_tag_le(&mut bytes, 256, 0); // ImageWidth = 0
    let path = write(dir.path(), "zero.tif", &bytes);
    let e = read_image(&path).unwrap_err();
    assert!(
        matches!(
            e.kind,
            IoErrorKind::ZeroSize {
                width: 0,
                height: 16
            }
        ),
        "{e:?}"
    );
    assert_message(&e, &path, "image has zero size (0 x 16 pixels)");
    assert!(matches!(
        probe(&path).unwrap_err().kind,
        IoErrorKind::ZeroSize { .. }
    ));
}

#[test]
fn multi_page_where_one_image_is_expected() {
    let path = fixture("le_u12_3pages.tif");
    let e = read_image(&path).unwrap_err();
    assert!(
        matches!(e.kind, IoErrorKind::MultiPage { pages: 3 }),
        "{e:?}"
    );
    assert_message(
        &e,
        &path,
        "file has 3 pages where a single image is expected",
    );
    assert!(matches!(
        read_mask(&path).unwrap_err().kind,
        IoErrorKind::MultiPage { pages: 3 }
    ));
    assert_eq!(read_stack(&path).unwrap().len(), 3);
}

#[test]
fn corrupt_compressed_12_bit_strip() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = std::fs::read(fixture("le_u12_deflate.tif")).unwrap();
    // one strip; its zlib stream starts right after the 8-byte header
    assert_eq!(
        &bytes[8..9],
        &[0x78],
        "zlib header where the fixture README says"
    );
    for b in &mut bytes[10..40] {
        *b = !*b;
    }
    let path = write(dir.path(), "bad-deflate.tif", &bytes);
    let e = read_image(&path).unwrap_err();
    assert!(matches!(e.kind, IoErrorKind::Corrupt(_)), "{e:?}");
    assert_message(
        &e,
        &path,
        "corrupt file: strip 0: Deflate data cannot be decoded",
    );
}

#[test]
fn error_in_a_later_page_names_the_page() {
    use tiff::encoder::{TiffEncoder, colortype};
    let dir = tempfile::tempdir().unwrap();
    let mut buf = std::io::Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut buf).unwrap();
    enc.write_image::<colortype::Gray16>(4, 4, &[7u16; 16])
        .unwrap();
    enc.write_image::<colortype::Gray16>(4, 4, &[8u16; 16])
        .unwrap();
    enc.write_image::<colortype::RGB8>(4, 4, &[9u8; 48])
        .unwrap();
    let path = write(dir.path(), "mixed.tif", buf.get_ref());
    let e = read_stack(&path).unwrap_err();
    assert!(
        matches!(e.kind, IoErrorKind::InPage { page: 2, .. }),
        "{e:?}"
    );
    assert!(matches!(e.kind.innermost(), IoErrorKind::Unsupported(_)));
    assert_message(&e, &path, "page 2: unsupported: 3 samples per pixel");
    assert!(matches!(
        probe(&path).unwrap_err().kind,
        IoErrorKind::InPage { page: 2, .. }
    ));
}

#[test]
fn mask_of_the_wrong_size() {
    let path = fixture("le_u8_whiteiszero.tif"); // 37 x 23
    assert!(read_mask_for(&path, 37, 23).is_ok());
    let e = read_mask_for(&path, 1024, 1024).unwrap_err();
    assert!(
        matches!(
            e.kind,
            IoErrorKind::SizeMismatch {
                found_width: 37,
                found_height: 23,
                ..
            }
        ),
        "{e:?}"
    );
    assert_message(
        &e,
        &path,
        "mask is 37 x 23 pixels but the image is 1024 x 1024",
    );
}

#[test]
fn colour_png_is_unsupported() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rgb.png");
    image::RgbImage::from_pixel(3, 2, image::Rgb([1, 2, 3]))
        .save(&path)
        .unwrap();
    let e = read_image(&path).unwrap_err();
    assert_message(&e, &path, "unsupported: PNG colour type Rgb8");
}

#[test]
fn non_finite_samples_cannot_be_written_as_integers() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.tif");
    let img = Image::new(2, 1, vec![1.0, f64::NAN], ImageMeta::synthetic(16)).unwrap();
    let e = write_tiff_u16(&path, &img).unwrap_err();
    assert!(
        matches!(e.kind, IoErrorKind::NonFinite { count: 1 }),
        "{e:?}"
    );
    assert_message(&e, &path, "1 of the samples are not finite");
    assert!(!path.exists(), "nothing written");
}

#[test]
fn absurd_size_in_a_damaged_header_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = gray8_tiff(16, 16);
    patch_tag_le(&mut bytes, 256, 1 << 20); // ImageWidth
    patch_tag_le(&mut bytes, 257, 1 << 10); // ImageLength: 2^30 pixels, one strip
    let path = write(dir.path(), "huge.tif", &bytes);
    let e = read_image(&path).unwrap_err();
    assert!(
        matches!(
            e.kind,
            IoErrorKind::TooLarge {
                width: 1_048_576,
                height: 1024,
                ..
            }
        ),
        "{e:?}"
    );
    assert_message(
        &e,
        &path,
        "1048576 x 1024 pixels exceed this reader's limit of 268435456 pixels",
    );
}
