//! The real sample files (../shared/data/bos-sample) decode exactly.
//!
//! Expected numbers were obtained independently with Python (numpy 2.4.6, tifffile 2026.3.3 +
//! imagecodecs 2026.3.6), not with this crate: 16-bit and 8-bit files with `tifffile.imread`;
//! the 12-bit files by concatenating the strips (StripOffsets/StripByteCounts) and unpacking
//! MSB-first with numpy (`p0 = b0<<4 | b1>>4`, `p1 = (b1&15)<<8 | b2`), which agreed with
//! `tifffile.imread` on all ten files. Sums are over all 1024 x 1024 pixels as integers.
//! The script is `tests/fixtures/real_data_values.py`.

use bostrack_core::{Photometric, SampleFormat};
use bostrack_io::{
    ByteOrder, bos_sample_dir, image_stats, probe, read_image, read_mask, read_mask_for, read_stack,
};

/// (file, sum, min, max, [(x, y, value)])
type Expect = (&'static str, u64, f64, f64, &'static [(usize, usize, f64)]);

#[rustfmt::skip]
const EXPECTED: &[Expect] = &[
    ("pair/reference.tif", 389_700_717, 0.0, 3250.0, &[(0, 0, 82.0), (1, 0, 90.0), (2, 0, 57.0), (3, 0, 61.0), (517, 301, 88.0), (100, 900, 57.0), (1023, 1023, 0.0), (1015, 15, 3250.0), (1023, 500, 555.0), (1022, 500, 647.0), (400, 400, 153.0)]),
    ("pair/gradient.tif", 388_101_377, 0.0, 3292.0, &[(0, 0, 108.0), (1, 0, 104.0), (2, 0, 77.0), (3, 0, 63.0), (517, 301, 66.0), (100, 900, 66.0)]),
    ("ref-stack/im_0001.tif", 390_447_869, 0.0, 3270.0, &[(0, 0, 67.0), (1, 0, 74.0), (2, 0, 34.0), (3, 0, 31.0), (517, 301, 95.0), (100, 900, 46.0), (1023, 1023, 0.0), (1007, 15, 3270.0), (1023, 500, 517.0), (1022, 500, 629.0), (400, 400, 165.0)]),
    ("ref-stack/im_0002.tif", 390_695_212, 0.0, 3291.0, &[(0, 0, 81.0), (1, 0, 95.0), (2, 0, 60.0), (3, 0, 81.0), (517, 301, 79.0), (100, 900, 44.0)]),
    ("ref-stack/im_0003.tif", 390_573_071, 0.0, 3311.0, &[(0, 0, 90.0), (1, 0, 95.0), (2, 0, 30.0), (3, 0, 103.0), (517, 301, 90.0), (100, 900, 61.0)]),
    ("ref-stack/im_0004.tif", 390_366_005, 0.0, 3328.0, &[(0, 0, 58.0), (1, 0, 87.0), (2, 0, 25.0), (3, 0, 36.0), (517, 301, 110.0), (100, 900, 39.0)]),
    ("ref-stack/im_0005.tif", 390_692_778, 0.0, 3259.0, &[(0, 0, 76.0), (1, 0, 87.0), (2, 0, 77.0), (3, 0, 63.0), (517, 301, 66.0), (100, 900, 44.0)]),
    ("ref-stack/im_0006.tif", 390_392_234, 0.0, 3349.0, &[(0, 0, 94.0), (1, 0, 91.0), (2, 0, 81.0), (3, 0, 67.0), (517, 301, 95.0), (100, 900, 58.0)]),
    ("ref-stack/im_0007.tif", 390_692_006, 0.0, 3307.0, &[(0, 0, 94.0), (1, 0, 82.0), (2, 0, 47.0), (3, 0, 58.0), (517, 301, 103.0), (100, 900, 55.0)]),
    ("ref-stack/im_0008.tif", 390_904_877, 0.0, 3321.0, &[(0, 0, 81.0), (1, 0, 117.0), (2, 0, 60.0), (3, 0, 58.0), (517, 301, 79.0), (100, 900, 69.0)]),
    ("ref-stack/im_0009.tif", 391_154_082, 0.0, 3276.0, &[(0, 0, 94.0), (1, 0, 108.0), (2, 0, 56.0), (3, 0, 63.0), (517, 301, 93.0), (100, 900, 66.0)]),
    ("ref-stack/im_0010.tif", 390_796_306, 0.0, 3245.0, &[(0, 0, 81.0), (1, 0, 91.0), (2, 0, 51.0), (3, 0, 54.0), (517, 301, 115.0), (100, 900, 61.0), (1022, 15, 3245.0), (1023, 500, 517.0), (1022, 500, 558.0), (400, 400, 142.0)]),
];

#[test]
fn real_images_decode_exactly() {
    let Some(dir) = bos_sample_dir() else { return };
    for &(file, sum, min, max, pixels) in EXPECTED {
        let path = dir.join(file);
        let img = read_image(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((img.width(), img.height()), (1024, 1024), "{file}");
        let s: f64 = img.data().iter().sum(); // exact: integers below 2^53
        assert_eq!(s as u64, sum, "{file} sum");
        let st = image_stats(&img).unwrap();
        assert_eq!(
            (st.min, st.max, st.non_finite_pixels),
            (min, max, 0),
            "{file}"
        );
        for &(x, y, v) in pixels {
            assert_eq!(img.get(x, y), v, "{file} ({x}, {y})");
        }
        let twelve = file.starts_with("ref-stack");
        let m = &img.meta;
        assert_eq!(m.bits_per_sample, if twelve { 12 } else { 16 }, "{file}");
        assert_eq!(
            m.saturation,
            Some(if twelve { 4095.0 } else { 65535.0 }),
            "{file}"
        );
        assert_eq!(
            m.compression,
            if twelve { "none" } else { "packbits" },
            "{file}"
        );
        assert_eq!(
            (m.sample_format, m.photometric, m.page),
            (SampleFormat::Unsigned, Photometric::BlackIsZero, 0)
        );
        let info = probe(&path).unwrap();
        assert_eq!(
            (info.width, info.height, info.pages, info.tiled),
            (1024, 1024, 1, false)
        );
        assert_eq!(
            (info.bits_per_sample, info.endianness),
            (m.bits_per_sample, ByteOrder::LittleEndian)
        );
    }
}

#[test]
fn real_mask_keeps_the_white_interior() {
    let Some(dir) = bos_sample_dir() else { return };
    let path = dir.join("mask.tif");
    // tifffile: raw samples are 0 (791308 pixels, displays white under WhiteIsZero) and 255
    // (257268); the raw-0 region spans rows 32..=857, columns 34..=991.
    let img = read_image(&path).unwrap();
    assert_eq!(img.meta.photometric, Photometric::WhiteIsZero);
    assert_eq!(img.meta.bits_per_sample, 8);
    let sum: f64 = img.data().iter().sum();
    assert_eq!(
        sum,
        255.0 * 791_308.0,
        "inverted exactly once: raw 0 -> 255"
    );
    assert_eq!((img.get(517, 301), img.get(0, 0)), (255.0, 0.0));

    let m = read_mask_for(&path, 1024, 1024).unwrap();
    assert_eq!(m.count_kept(), 791_308);
    let fraction = m.count_kept() as f64 / (1024.0 * 1024.0);
    assert!(
        (fraction - 0.755).abs() < 0.0005,
        "kept fraction {fraction}"
    ); // 75.5 %
    assert!(m.keeps(34, 32) && m.keeps(991, 857) && m.keeps(517, 301));
    assert!(!m.keeps(33, 32) && !m.keeps(34, 31) && !m.keeps(992, 857) && !m.keeps(991, 858));
    assert!(!m.keeps(0, 0) && !m.keeps(500, 950));

    let info = probe(&path).unwrap();
    assert_eq!(info.endianness, ByteOrder::BigEndian);
    assert_eq!(
        (info.photometric, info.compression.as_str()),
        (Photometric::WhiteIsZero, "none")
    );
    assert_eq!(read_mask(&path).unwrap(), m);
}

#[test]
fn real_12_bit_stack_reads_as_stack_of_one_page_each() {
    let Some(dir) = bos_sample_dir() else { return };
    let path = dir.join("ref-stack/im_0003.tif");
    let stack = read_stack(&path).unwrap();
    assert_eq!(stack.len(), 1);
    assert_eq!(stack[0], read_image(&path).unwrap());
}
