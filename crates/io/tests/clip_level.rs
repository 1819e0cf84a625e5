//! The clip level of files (`bostrack_io::clip`): the TIFF tag MaxSampleValue, a 12-bit camera's
//! data in a 16-bit file, the real sample, and errors that name the file.

use bostrack_core::{Image, ImageMeta};
use bostrack_io::{
    ClipSource, Saturation, bos_sample_dir, max_sample_value, read_image_clipped, write_tiff_u16,
};
use tiff::encoder::{TiffEncoder, colortype};
use tiff::tags::Tag;

/// A 16-bit TIFF of a ramp 0..3000 with a pile-up of 20 samples at 3000 and, when given, the
/// MaxSampleValue tag.
fn write_with_tag(path: &std::path::Path, tag: Option<u16>) {
    let mut data: Vec<u16> = (0..3000).collect();
    data.extend(std::iter::repeat_n(3000, 20));
    let file = std::fs::File::create(path).unwrap();
    let mut enc = TiffEncoder::new(file).unwrap();
    let mut img = enc.new_image::<colortype::Gray16>(302, 10).unwrap();
    if let Some(t) = tag {
        img.encoder().write_tag(Tag::MaxSampleValue, t).unwrap();
    }
    img.write_data(&data).unwrap();
}

#[test]
fn the_max_sample_value_tag_comes_first_then_the_pile_up() {
    let dir = tempfile::tempdir().unwrap();
    let tagged = dir.path().join("tagged.tif");
    write_with_tag(&tagged, Some(4000));
    assert_eq!(max_sample_value(&tagged).unwrap(), Some(4000.0));
    let (img, c) = read_image_clipped(&tagged, Saturation::Auto).unwrap();
    assert_eq!(
        (c.level, c.source),
        (Some(4000.0), ClipSource::MaxSampleValue)
    );
    assert_eq!(img.meta.saturation, Some(4000.0));

    let plain = dir.path().join("plain.tif");
    write_with_tag(&plain, None);
    assert_eq!(max_sample_value(&plain).unwrap(), None);
    let (img, c) = read_image_clipped(&plain, Saturation::Auto).unwrap();
    assert_eq!(
        (c.level, c.source, c.clipped_pixels),
        (Some(3000.0), ClipSource::PileUp, 20)
    );
    assert_eq!(img.meta.saturation, Some(3000.0));
    // a given level wins over everything
    let (img, c) = read_image_clipped(&tagged, Saturation::Counts(2500.0)).unwrap();
    assert_eq!(
        (c.level, c.source, c.clipped_pixels),
        (Some(2500.0), ClipSource::Given, 520)
    );
    assert_eq!(img.meta.saturation, Some(2500.0));
}

#[test]
fn twelve_bit_data_in_a_16_bit_file_clip_at_4095() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.tif");
    // 12-bit samples without a pile-up: the significant bits say 4095
    let img = Image::new(
        4,
        2,
        vec![0.0, 17.0, 3000.0, 4095.0, 12.0, 5.0, 7.0, 9.0],
        ImageMeta::synthetic(16),
    )
    .unwrap();
    write_tiff_u16(&path, &img).unwrap();
    let (back, c) = read_image_clipped(&path, Saturation::Auto).unwrap();
    assert_eq!(
        (c.level, c.source, c.clipped_pixels),
        (Some(4095.0), ClipSource::SignificantBits, 1)
    );
    assert_eq!(c.container, Some(65535.0));
    assert!(back.is_saturated(4095.0) && !back.is_saturated(4094.0));
}

#[test]
fn errors_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.tif");
    let e = read_image_clipped(&missing, Saturation::Auto)
        .unwrap_err()
        .to_string();
    assert!(e.ends_with("missing.tif: file not found"), "{e}");
    let e = max_sample_value(&missing).unwrap_err().to_string();
    assert!(e.ends_with("missing.tif: file not found"), "{e}");
    let png = dir.path().join("a.png");
    bostrack_io::write_png_u16(&png, &Image::from_fn(3, 3, |x, _| x as f64)).unwrap();
    assert_eq!(max_sample_value(&png).unwrap(), None);
}

#[test]
fn the_real_sample_is_12_bit() {
    let Some(dir) = bos_sample_dir() else { return };
    // the reference is a 16-bit file of 12-bit data (largest sample 3250, nothing clipped)
    let (img, c) = read_image_clipped(&dir.join("pair/reference.tif"), Saturation::Auto).unwrap();
    assert_eq!(img.meta.bits_per_sample, 16);
    assert_eq!(
        (c.level, c.source, c.clipped_pixels),
        (Some(4095.0), ClipSource::SignificantBits, 0)
    );
    assert_eq!(c.max_sample, Some(3250.0));
    // the stack is stored as 12-bit: the container's level
    let (_, c) = read_image_clipped(&dir.join("ref-stack/im_0001.tif"), Saturation::Auto).unwrap();
    assert_eq!((c.level, c.source), (Some(4095.0), ClipSource::Container));
}

/// The clip level's passes run over blocks of the image on rayon: level, source, clipped count
/// and largest sample are the same on 1 and 3 threads, for a pile-up spread over many blocks
/// (300,000 samples: 5 blocks) and for 12-bit data in a 16-bit container.
#[test]
fn the_clip_level_does_not_depend_on_the_thread_count() {
    let n = 300_000usize;
    // a pile-up at 3000 in every block (one sample in 500), the rest below
    let piled: Vec<f64> = (0..n)
        .map(|k| {
            if k % 500 == 7 {
                3000.0
            } else {
                (k % 2990) as f64
            }
        })
        .collect();
    let twelve: Vec<f64> = (0..n).map(|k| ((k * 7919) % 4000) as f64).collect();
    for data in [piled, twelve] {
        let img = Image::new(600, n / 600, data, ImageMeta::synthetic(16)).unwrap();
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| bostrack_io::find_clip_level(&img, None))
        };
        let (a, b) = (on(1), on(3));
        assert_eq!(
            (a.level, a.source, a.clipped_pixels, a.max_sample),
            (b.level, b.source, b.clipped_pixels, b.max_sample)
        );
        assert!(a.level.is_some());
    }
}
