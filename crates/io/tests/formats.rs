//! The format matrix: every fixture's pixels against the formula it was made from.
//!
//! Committed fixtures (`tests/fixtures`, made by `make_fixtures.py` with tifffile and by hand for
//! 12-bit, see the README there) cover big-endian, tiles, 12-bit and WhiteIsZero files; the
//! little-endian strip files of every sample type and compression are written here with the
//! `tiff` crate's encoder.

mod support;

use bostrack_core::{Image, Photometric, SampleFormat};
use bostrack_io::{ByteOrder, FileFormat, probe, read_image, read_stack};
use support::{H, Kind, W, fixture, value};

struct Case {
    file: &'static str,
    kind: Kind,
    compression: &'static str,
    order: ByteOrder,
    tiled: bool,
    white_is_zero: bool,
    pages: usize,
}

const BE: ByteOrder = ByteOrder::BigEndian;
const LE: ByteOrder = ByteOrder::LittleEndian;

#[rustfmt::skip]
fn cases() -> Vec<Case> {
    let c = |file, kind, compression, order, tiled, white_is_zero, pages| Case { file, kind, compression, order, tiled, white_is_zero, pages };
    vec![
        c("be_u8_none.tif", Kind::U8, "none", BE, false, false, 1),
        c("be_u16_packbits.tif", Kind::U16, "packbits", BE, false, false, 1),
        c("be_u16_lzw.tif", Kind::U16, "lzw", BE, false, false, 1),
        c("be_u16_deflate_predictor.tif", Kind::U16, "deflate", BE, false, false, 1),
        c("le_u16_lzw_predictor.tif", Kind::U16, "lzw", LE, false, false, 1),
        c("be_f32_deflate.tif", Kind::F32, "deflate", BE, false, false, 1),
        c("le_f32_deflate_floatpredictor.tif", Kind::F32, "deflate", LE, false, false, 1),
        c("be_f64_none.tif", Kind::F64, "none", BE, false, false, 1),
        c("le_u16_tiles_none.tif", Kind::U16, "none", LE, true, false, 1),
        c("be_u16_tiles_deflate.tif", Kind::U16, "deflate", BE, true, false, 1),
        c("le_u8_tiles_packbits.tif", Kind::U8, "packbits", LE, true, false, 1),
        c("le_u8_whiteiszero.tif", Kind::U8, "none", LE, false, true, 1),
        c("be_u16_whiteiszero_lzw.tif", Kind::U16, "lzw", BE, false, true, 1),
        c("be_u16_3pages.tif", Kind::U16, "none", BE, false, false, 3),
        c("le_u12_none.tif", Kind::U12, "none", LE, false, false, 1),
        c("be_u12_none.tif", Kind::U12, "none", BE, false, false, 1),
        c("le_u12_packbits.tif", Kind::U12, "packbits", LE, false, false, 1),
        c("be_u12_lzw.tif", Kind::U12, "lzw", BE, false, false, 1),
        c("le_u12_deflate.tif", Kind::U12, "deflate", LE, false, false, 1),
        c("be_u12_tiles_packbits.tif", Kind::U12, "packbits", BE, true, false, 1),
        c("le_u12_tiles_none.tif", Kind::U12, "none", LE, true, false, 1),
        c("le_u12_whiteiszero.tif", Kind::U12, "none", LE, false, true, 1),
        c("le_u12_3pages.tif", Kind::U12, "packbits", LE, false, false, 3),
    ]
}

/// Compares every pixel of `img` with the formula: raw samples for BlackIsZero,
/// `max - raw` for WhiteIsZero (exactly one inversion).
fn check_pixels(img: &Image, kind: Kind, page: usize, white_is_zero: bool, what: &str) {
    assert_eq!((img.width(), img.height()), (W, H), "{what}");
    for y in 0..H {
        for x in 0..W {
            let raw = value(kind, x, y, page);
            let want = if white_is_zero { kind.max() - raw } else { raw };
            assert_eq!(img.get(x, y), want, "{what} page {page} pixel ({x}, {y})");
        }
    }
}

#[test]
fn committed_fixtures_decode_to_their_formulas() {
    for c in cases() {
        let path = fixture(c.file);
        let stack = read_stack(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(stack.len(), c.pages, "{}", c.file);
        for (p, img) in stack.iter().enumerate() {
            check_pixels(img, c.kind, p, c.white_is_zero, c.file);
            let m = &img.meta;
            assert_eq!(m.bits_per_sample, c.kind.bits(), "{}", c.file);
            assert_eq!(m.compression, c.compression, "{}", c.file);
            assert_eq!(m.page, p);
            assert_eq!(m.source.as_deref(), Some(path.as_path()));
            let wiz = if c.white_is_zero {
                Photometric::WhiteIsZero
            } else {
                Photometric::BlackIsZero
            };
            assert_eq!(m.photometric, wiz, "{}", c.file);
            match c.kind {
                Kind::F32 | Kind::F64 => {
                    assert_eq!(
                        (m.sample_format, m.saturation),
                        (SampleFormat::Float, None),
                        "{}",
                        c.file
                    )
                }
                k => assert_eq!(
                    (m.sample_format, m.saturation),
                    (SampleFormat::Unsigned, Some(k.max())),
                    "{}",
                    c.file
                ),
            }
        }
        let info = probe(&path).unwrap();
        assert_eq!(info.format, FileFormat::Tiff);
        assert_eq!(
            (info.width, info.height, info.pages),
            (W, H, c.pages),
            "{}",
            c.file
        );
        assert_eq!(
            (info.endianness, info.tiled),
            (c.order, c.tiled),
            "{}",
            c.file
        );
        assert_eq!(info.bits_per_sample, c.kind.bits(), "{}", c.file);
        assert_eq!(info.compression, c.compression, "{}", c.file);
        if c.pages == 1 {
            let one = read_image(&path).unwrap();
            assert_eq!(one, stack[0], "{}", c.file);
        }
    }
}

#[test]
fn twelve_bit_first_pixels_by_hand() {
    // Independent of the formula code: (x * 97 + y * 211 + 5) % 4096 at a few pixels, worked out
    // by hand: (0,0) = 5, (1,0) = 102, (36,0) = 3497, (36,22) = (3492 + 4642 + 5) - 4096 = 4043.
    let img = read_image(&fixture("be_u12_none.tif")).unwrap();
    assert_eq!(
        [
            img.get(0, 0),
            img.get(1, 0),
            img.get(36, 0),
            img.get(36, 22)
        ],
        [5.0, 102.0, 3497.0, 4043.0]
    );
}

/// Writes `pages` pages of `kind` with the tiff crate's encoder (little-endian strips).
fn encode(
    kind: Kind,
    compression: tiff::encoder::Compression,
    predictor: bool,
    pages: usize,
) -> Vec<u8> {
    use tiff::encoder::{TiffEncoder, colortype};
    let mut buf = std::io::Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut buf)
        .unwrap()
        .with_compression(compression);
    if predictor {
        enc = enc.with_predictor(tiff::tags::Predictor::Horizontal);
    }
    let (w, h) = (W as u32, H as u32);
    for p in 0..pages {
        let vals: Vec<f64> = (0..W * H).map(|i| value(kind, i % W, i / W, p)).collect();
        match kind {
            Kind::U8 => enc.write_image::<colortype::Gray8>(
                w,
                h,
                &vals.iter().map(|&v| v as u8).collect::<Vec<_>>(),
            ),
            Kind::U16 => enc.write_image::<colortype::Gray16>(
                w,
                h,
                &vals.iter().map(|&v| v as u16).collect::<Vec<_>>(),
            ),
            Kind::U32 => enc.write_image::<colortype::Gray32>(
                w,
                h,
                &vals.iter().map(|&v| v as u32).collect::<Vec<_>>(),
            ),
            Kind::F32 => enc.write_image::<colortype::Gray32Float>(
                w,
                h,
                &vals.iter().map(|&v| v as f32).collect::<Vec<_>>(),
            ),
            Kind::F64 => enc.write_image::<colortype::Gray64Float>(w, h, &vals),
            Kind::U12 => unreachable!("the tiff encoder has no 12-bit type"),
        }
        .unwrap();
    }
    buf.into_inner()
}

#[test]
fn encoder_written_strips_of_every_type_and_compression() {
    use tiff::encoder::{Compression, DeflateLevel};
    let dir = tempfile::tempdir().unwrap();
    let comps = [
        (Compression::Uncompressed, "none"),
        (Compression::Packbits, "packbits"),
        (Compression::Lzw, "lzw"),
        (Compression::Deflate(DeflateLevel::Balanced), "deflate"),
    ];
    for kind in [Kind::U8, Kind::U16, Kind::U32, Kind::F32, Kind::F64] {
        for (comp, name) in comps {
            for predictor in [false, true] {
                if predictor && (matches!(kind, Kind::F32 | Kind::F64) || name == "none") {
                    continue; // horizontal predictor is for integers and used with compression
                }
                let what = format!("{kind:?} {name} predictor={predictor}");
                // deliberately misleading extension: the content decides
                let path = dir.path().join(format!("{kind:?}-{name}-{predictor}.png"));
                std::fs::write(&path, encode(kind, comp, predictor, 1)).unwrap();
                let img = read_image(&path).unwrap_or_else(|e| panic!("{what}: {e}"));
                check_pixels(&img, kind, 0, false, &what);
                assert_eq!(img.meta.compression, name, "{what}");
                assert_eq!(img.meta.bits_per_sample, kind.bits(), "{what}");
                let info = probe(&path).unwrap();
                assert_eq!(
                    (info.format, info.endianness, info.tiled),
                    (FileFormat::Tiff, LE, false)
                );
            }
        }
    }
}

#[test]
fn encoder_written_multi_page_stack() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stack.tif");
    std::fs::write(
        &path,
        encode(Kind::U16, tiff::encoder::Compression::Lzw, false, 4),
    )
    .unwrap();
    let stack = read_stack(&path).unwrap();
    assert_eq!(stack.len(), 4);
    for (p, img) in stack.iter().enumerate() {
        check_pixels(img, Kind::U16, p, false, "stack");
        assert_eq!(img.meta.page, p);
    }
    assert_eq!(probe(&path).unwrap().pages, 4);
}

#[test]
fn png_8_and_16_bit() {
    let dir = tempfile::tempdir().unwrap();
    for kind in [Kind::U8, Kind::U16] {
        let vals: Vec<f64> = (0..W * H).map(|i| value(kind, i % W, i / W, 0)).collect();
        // written by the image crate, not by this crate's writer
        let path = dir.path().join(format!("{kind:?}.dat"));
        let dynimg = match kind {
            Kind::U8 => image::DynamicImage::ImageLuma8(
                image::GrayImage::from_raw(
                    W as u32,
                    H as u32,
                    vals.iter().map(|&v| v as u8).collect(),
                )
                .unwrap(),
            ),
            _ => image::DynamicImage::ImageLuma16(
                image::ImageBuffer::from_raw(
                    W as u32,
                    H as u32,
                    vals.iter().map(|&v| v as u16).collect(),
                )
                .unwrap(),
            ),
        };
        dynimg
            .save_with_format(&path, image::ImageFormat::Png)
            .unwrap();
        let img = read_image(&path).unwrap();
        check_pixels(&img, kind, 0, false, "png");
        assert_eq!(img.meta.bits_per_sample, kind.bits());
        assert_eq!(img.meta.saturation, Some(kind.max()));
        let info = probe(&path).unwrap();
        assert_eq!(
            (info.format, info.width, info.height, info.pages),
            (FileFormat::Png, W, H, 1)
        );
        assert_eq!(read_stack(&path).unwrap(), vec![img]);
    }
}

#[test]
fn one_bit_png_mask_expands_to_0_and_255() {
    // tests/fixtures/mask_1bit.png: 10 x 3, 1-bit grayscale, kept (white) where x >= 4 (README).
    let path = fixture("mask_1bit.png");
    let img = read_image(&path).unwrap();
    assert_eq!(
        (img.width(), img.height(), img.meta.bits_per_sample),
        (10, 3, 8)
    );
    for y in 0..3 {
        for x in 0..10 {
            assert_eq!(
                img.get(x, y),
                if x >= 4 { 255.0 } else { 0.0 },
                "({x}, {y})"
            );
        }
    }
    let m = bostrack_io::read_mask(&path).unwrap();
    assert_eq!(m.count_kept(), 18);
    assert!(m.keeps(4, 0) && !m.keeps(3, 2));
}

#[test]
fn bigtiff_is_read() {
    use tiff::encoder::{TiffEncoder, colortype};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.tif");
    let vals: Vec<u16> = (0..W * H)
        .map(|i| value(Kind::U16, i % W, i / W, 0) as u16)
        .collect();
    let mut buf = std::io::Cursor::new(Vec::new());
    TiffEncoder::new_big(&mut buf)
        .unwrap()
        .write_image::<colortype::Gray16>(W as u32, H as u32, &vals)
        .unwrap();
    assert_eq!(&buf.get_ref()[..4], b"II+\0", "BigTIFF signature");
    std::fs::write(&path, buf.get_ref()).unwrap();
    check_pixels(&read_image(&path).unwrap(), Kind::U16, 0, false, "bigtiff");
    assert_eq!(probe(&path).unwrap().format, FileFormat::Tiff);
}
