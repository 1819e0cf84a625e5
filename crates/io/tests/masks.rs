//! Masks in every encoding users write them in: the one rule of `read_mask` (a pixel is kept
//! when it displays brighter than the midpoint of the mask's darkest and brightest samples)
//! gives the same region for {0, 1}, {0, 255} and {0, 65535}, 8 and 16 bit, TIFF and PNG,
//! BlackIsZero and WhiteIsZero. The region is the real sample's `mask.tif` (read in place,
//! re-encoded into a temporary folder, never copied into the repository), whose kept region is
//! known independently (rows 32..=857, columns 34..=991, 791 308 pixels; see real_data.rs).

mod support;

use bostrack_core::{Image, ImageMeta, Mask};
use bostrack_io::{IoErrorKind, bos_sample_dir, read_mask, read_mask_for};
use std::path::Path;
use support::patch_tag_le;
use tiff::encoder::{TiffEncoder, colortype};

/// `keep` written as an 8-bit TIFF with the raw values `(dark, bright)`; `white_is_zero`
/// patches PhotometricInterpretation to 0 (the raw values then display inverted).
fn tiff8(path: &Path, keep: &Mask, raw: (u8, u8), white_is_zero: bool) {
    let data: Vec<u8> = keep
        .as_slice()
        .iter()
        .map(|&k| if k { raw.1 } else { raw.0 })
        .collect();
    let mut buf = std::io::Cursor::new(Vec::new());
    TiffEncoder::new(&mut buf)
        .unwrap()
        .write_image::<colortype::Gray8>(keep.width() as u32, keep.height() as u32, &data)
        .unwrap();
    let mut bytes = buf.into_inner();
    if white_is_zero {
        patch_tag_le(&mut bytes, 262, 0);
    }
    std::fs::write(path, bytes).unwrap();
}

/// `keep` written as a 16-bit TIFF with the raw values `(0, bright)`.
fn tiff16(path: &Path, keep: &Mask, bright: u16) {
    let data: Vec<u16> = keep
        .as_slice()
        .iter()
        .map(|&k| if k { bright } else { 0 })
        .collect();
    let mut f = std::fs::File::create(path).unwrap();
    TiffEncoder::new(&mut f)
        .unwrap()
        .write_image::<colortype::Gray16>(keep.width() as u32, keep.height() as u32, &data)
        .unwrap();
}

fn image_of(keep: &Mask, bright: f64, bits: u16) -> Image {
    let mut img = Image::from_fn(keep.width(), keep.height(), |x, y| {
        if keep.keeps(x, y) { bright } else { 0.0 }
    });
    img.meta = ImageMeta::synthetic(bits);
    img
}

#[test]
fn every_usual_mask_encoding_keeps_the_real_region() {
    let Some(dir) = bos_sample_dir() else { return };
    let truth = read_mask_for(&dir.join("mask.tif"), 1024, 1024).unwrap();
    assert_eq!(truth.count_kept(), 791_308);
    assert!(truth.keeps(34, 32) && truth.keeps(991, 857) && !truth.keeps(33, 32));

    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    type Writer<'a> = Box<dyn Fn(&Path) + 'a>;
    let cases: Vec<(&str, Writer)> = vec![
        ("u8 {0,1}", Box::new(|p| tiff8(p, &truth, (0, 1), false))),
        (
            "u8 {0,255}",
            Box::new(|p| tiff8(p, &truth, (0, 255), false)),
        ),
        (
            "u8 WhiteIsZero {1,0}",
            Box::new(|p| tiff8(p, &truth, (1, 0), true)),
        ),
        ("u16 {0,1}", Box::new(|p| tiff16(p, &truth, 1))),
        ("u16 {0,65535}", Box::new(|p| tiff16(p, &truth, 65535))),
        (
            "png u8 {0,1}",
            Box::new(|p| bostrack_io::write_png_u8(p, &image_of(&truth, 1.0, 8)).unwrap()),
        ),
        (
            "png u8 {0,255}",
            Box::new(|p| bostrack_io::write_png_u8(p, &image_of(&truth, 255.0, 8)).unwrap()),
        ),
        (
            "png u16 {0,1}",
            Box::new(|p| bostrack_io::write_png_u16(p, &image_of(&truth, 1.0, 16)).unwrap()),
        ),
        (
            "png u16 {0,65535}",
            Box::new(|p| bostrack_io::write_png_u16(p, &image_of(&truth, 65535.0, 16)).unwrap()),
        ),
    ];
    for (k, (name, write)) in cases.iter().enumerate() {
        let path = t.join(format!(
            "mask{k}.{}",
            if name.starts_with("png") {
                "png"
            } else {
                "tif"
            }
        ));
        write(&path);
        let m = read_mask_for(&path, 1024, 1024).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(m.count_kept(), truth.count_kept(), "{name}");
        assert!(m == truth, "{name}: another region");
    }
}

#[test]
fn a_mask_that_keeps_nothing_is_an_error_that_names_it() {
    let tmp = tempfile::tempdir().unwrap();
    let none = Mask::from_fn(20, 10, |_, _| false);
    let path = tmp.path().join("roi.tif");
    tiff8(&path, &none, (0, 0), false);
    let e = read_mask(&path).unwrap_err();
    assert!(matches!(e.kind, IoErrorKind::EmptyMask(_)), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.starts_with(&format!("{}: mask keeps no pixel", path.display())),
        "{msg}"
    );

    // raw 255 everywhere under WhiteIsZero displays black: nothing kept either
    tiff8(&path, &none, (255, 255), true);
    assert!(matches!(
        read_mask(&path).unwrap_err().kind,
        IoErrorKind::EmptyMask(_)
    ));
}

#[test]
fn a_single_bright_value_keeps_everything() {
    let tmp = tempfile::tempdir().unwrap();
    let all = Mask::all(20, 10);
    for (raw, wiz) in [((1, 1), false), ((255, 255), false), ((0, 0), true)] {
        let path = tmp.path().join("all.tif");
        tiff8(&path, &all, raw, wiz);
        assert_eq!(read_mask(&path).unwrap(), all, "{raw:?} {wiz}");
    }
}

#[test]
fn grey_levels_split_at_the_midpoint() {
    // an anti-aliased edge: 0, 100, 160, 255 -> the midpoint 127.5 keeps 160 and 255
    let tmp = tempfile::tempdir().unwrap();
    let levels = [0.0, 100.0, 160.0, 255.0];
    let mut img = Image::from_fn(4, 1, |x, _| levels[x]);
    img.meta = ImageMeta::synthetic(8);
    let path = tmp.path().join("soft.png");
    bostrack_io::write_png_u8(&path, &img).unwrap();
    let m = read_mask(&path).unwrap();
    assert_eq!(m.as_slice(), [false, false, true, true]);
}
