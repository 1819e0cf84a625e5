//! Writers: what is written reads back as expected, and writing is atomic.

use bostrack_core::{Image, ImageMeta, Photometric, SampleFormat};
use bostrack_io::{
    FileFormat, probe, read_image, read_stack, write_png_u8, write_png_u16, write_tiff_f32,
    write_tiff_stack_u16, write_tiff_u16,
};

fn ramp(w: usize, h: usize, f: impl Fn(usize, usize) -> f64) -> Image {
    Image::from_fn(w, h, f)
}

#[test]
fn tiff_u16_rounds_and_clamps() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("u16.tif");
    let vals = [
        -5.0, 0.0, 0.49, 0.5, 1.5, 2.5, 1234.4999, 65534.6, 65535.0, 1e9,
    ];
    let want = [
        0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 1234.0, 65535.0, 65535.0, 65535.0,
    ];
    let img = Image::new(5, 2, vals.to_vec(), ImageMeta::default()).unwrap();
    write_tiff_u16(&path, &img).unwrap();
    let back = read_image(&path).unwrap();
    assert_eq!(back.data(), &want);
    assert_eq!(
        (back.meta.bits_per_sample, back.meta.compression.as_str()),
        (16, "none")
    );
    assert_eq!(back.meta.photometric, Photometric::BlackIsZero);
    // read back with the tiff crate directly, not only with this crate's reader
    let mut dec = tiff::decoder::Decoder::new(std::fs::File::open(&path).unwrap()).unwrap();
    match dec.read_image().unwrap() {
        tiff::decoder::DecodingResult::U16(v) => {
            assert_eq!(v, [0, 0, 0, 1, 2, 3, 1234, 65535, 65535, 65535])
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn tiff_u16_round_trip_of_integers_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("u16.tif");
    let img = ramp(301, 17, |x, y| ((x * 977 + y * 65) % 65536) as f64);
    write_tiff_u16(&path, &img).unwrap();
    assert_eq!(read_image(&path).unwrap().data(), img.data());
}

#[test]
fn tiff_f32_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f32.tif");
    let img = ramp(33, 9, |x, y| {
        (x as f64 - 7.3) * 1.0e-3 + y as f64 * 1234.567
    });
    write_tiff_f32(&path, &img).unwrap();
    let back = read_image(&path).unwrap();
    assert_eq!(
        (back.meta.sample_format, back.meta.bits_per_sample),
        (SampleFormat::Float, 32)
    );
    assert_eq!(back.meta.saturation, None);
    for (a, b) in back.data().iter().zip(img.data()) {
        assert_eq!(*a, f64::from(*b as f32), "nearest f32");
        assert!((a - b).abs() <= b.abs() * 6e-8 + 1e-12);
    }
    // NaN survives a float file
    let nan = Image::new(2, 1, vec![f64::NAN, 1.0], ImageMeta::default()).unwrap();
    write_tiff_f32(&path, &nan).unwrap();
    let back = read_image(&path).unwrap();
    assert!(back.get(0, 0).is_nan() && back.get(1, 0) == 1.0);
    let mut dec = tiff::decoder::Decoder::new(std::fs::File::open(&path).unwrap()).unwrap();
    assert!(matches!(
        dec.read_image().unwrap(),
        tiff::decoder::DecodingResult::F32(_)
    ));
}

#[test]
fn tiff_u16_stack_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stack.tif");
    let pages: Vec<Image> = (0..3)
        .map(|p| ramp(20, 10, move |x, y| (x + 100 * y + 5000 * p) as f64))
        .collect();
    write_tiff_stack_u16(&path, &pages).unwrap();
    let back = read_stack(&path).unwrap();
    assert_eq!(back.len(), 3);
    for (p, (a, b)) in back.iter().zip(&pages).enumerate() {
        assert_eq!(a.data(), b.data());
        assert_eq!(a.meta.page, p);
    }
    assert_eq!(probe(&path).unwrap().pages, 3);
    assert!(write_tiff_stack_u16(&path, &[]).is_err());
}

#[test]
fn png_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let img = ramp(40, 7, |x, y| (x * 1601 + y * 3) as f64);
    let p16 = dir.path().join("a.png");
    write_png_u16(&p16, &img).unwrap();
    let back = read_image(&p16).unwrap();
    assert_eq!(back.data(), img.data());
    assert_eq!(probe(&p16).unwrap().format, FileFormat::Png);
    // independent decoder: the image crate
    let dynimg = image::open(&p16).unwrap().into_luma16();
    assert_eq!(dynimg.get_pixel(39, 6).0[0], (39 * 1601 + 18) as u16);

    let p8 = dir.path().join("b.png");
    write_png_u8(
        &p8,
        &Image::new(4, 1, vec![-1.0, 127.5, 254.4, 300.0], ImageMeta::default()).unwrap(),
    )
    .unwrap();
    assert_eq!(read_image(&p8).unwrap().data(), &[0.0, 128.0, 254.0, 255.0]);
    assert_eq!(read_image(&p8).unwrap().meta.saturation, Some(255.0));
}

#[test]
fn writing_is_atomic_and_replaces_the_old_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.tif");
    std::fs::write(&path, b"old").unwrap();
    // a failing write leaves the old file and no temporary behind
    let bad = Image::new(1, 1, vec![f64::INFINITY], ImageMeta::default()).unwrap();
    assert!(write_tiff_u16(&path, &bad).is_err());
    assert_eq!(std::fs::read(&path).unwrap(), b"old");
    let img = ramp(3, 3, |x, y| (x + y) as f64);
    write_tiff_u16(&path, &img).unwrap();
    assert_eq!(read_image(&path).unwrap().data(), img.data());
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        names,
        vec![std::ffi::OsString::from("out.tif")],
        "no temporary file left"
    );
    // writing into a folder that does not exist is an error naming the file
    let missing = dir.path().join("no/such/dir/x.tif");
    let e = write_tiff_u16(&missing, &img).unwrap_err();
    assert!(
        e.to_string().starts_with(&missing.display().to_string()),
        "{e}"
    );
}
