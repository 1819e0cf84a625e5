//! Bounded reading: only the bytes the image structure needs are read, and files that are not
//! regular files are refused before they are opened (a FIFO would block, `/dev/zero` never
//! ends).
//!
//! The padded files are sparse (`File::set_len`), so they take no disk space; a reader that
//! read them whole would need more than 3 GB of memory, which the peak resident set size of
//! this test process (`VmHWM`, Linux) shows. The tests of this file are the only ones of their
//! process, and each reads files of a few hundred kilobytes at most besides the padded ones.

mod support;

use bostrack_core::{Image, ImageMeta};
use bostrack_io::{IoErrorKind, probe, read_image, read_mask, read_stack, write_tiff_u16};
use std::path::Path;
use support::fixture;

/// 3 GB: the padding of the files below (a sparse file).
const PAD: u64 = 3_000_000_000;

/// Peak resident set size of this process in MiB (`VmHWM` of /proc/self/status).
#[cfg(target_os = "linux")]
fn peak_rss_mib() -> f64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = s.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    let kib: f64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kib / 1024.0
}

/// Overwrites every element of the LONG array `tag` of the first IFD of a little-endian
/// classic TIFF with `value`.
fn patch_long_array_le(bytes: &mut [u8], tag: u16, value: u32) {
    let u16_at = |b: &[u8], o: usize| u16::from_le_bytes([b[o], b[o + 1]]);
    let u32_at = |b: &[u8], o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    assert_eq!(&bytes[..4], b"II*\0");
    let ifd = u32_at(bytes, 4) as usize;
    for i in 0..u16_at(bytes, ifd) as usize {
        let e = ifd + 2 + 12 * i;
        if u16_at(bytes, e) == tag {
            assert_eq!(u16_at(bytes, e + 2), 4, "LONG");
            let n = u32_at(bytes, e + 4) as usize;
            let at = if n == 1 {
                e + 8
            } else {
                u32_at(bytes, e + 8) as usize
            };
            for k in 0..n {
                bytes[at + 4 * k..at + 4 * k + 4].copy_from_slice(&value.to_le_bytes());
            }
            return;
        }
    }
    panic!("tag {tag} not in the first IFD");
}

#[test]
fn padded_files_are_read_without_their_padding() {
    let tmp = tempfile::tempdir().unwrap();
    // a 256 x 256 16-bit image padded to 3 GB after its data
    let mut img = Image::from_fn(256, 256, |x, y| (x * 7 + y * 13) as f64);
    img.meta = ImageMeta::synthetic(16);
    let padded = tmp.path().join("padded.tif");
    write_tiff_u16(&padded, &img).unwrap();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&padded)
        .unwrap()
        .set_len(PAD)
        .unwrap();
    let back = read_image(&padded).unwrap();
    assert_eq!(back.data(), img.data());
    assert_eq!(probe(&padded).unwrap().pages, 1);
    assert_eq!(read_stack(&padded).unwrap().len(), 1);

    // 12-bit files (decoded by this crate, not the tiff crate) whose strip byte counts claim
    // 3 GB each: only the bytes a strip needs are read (uncompressed), at most 2 x need + 4 KiB
    // (PackBits)
    for name in ["le_u12_none.tif", "le_u12_packbits.tif"] {
        let mut bytes = std::fs::read(fixture(name)).unwrap();
        patch_long_array_le(&mut bytes, 279, PAD as u32);
        let claims = tmp.path().join(name);
        std::fs::write(&claims, &bytes).unwrap();
        std::fs::OpenOptions::new()
            .write(true)
            .open(&claims)
            .unwrap()
            .set_len(PAD + 1_000_000)
            .unwrap();
        let want = read_image(&fixture(name)).unwrap();
        assert_eq!(read_image(&claims).unwrap().data(), want.data(), "{name}");
    }

    #[cfg(target_os = "linux")]
    {
        let peak = peak_rss_mib();
        eprintln!("peak RSS {peak:.1} MiB");
        assert!(
            peak < 200.0,
            "peak RSS {peak:.1} MiB: a padded file was read whole"
        );
    }
}

#[test]
fn devices_fifos_and_folders_are_refused_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let cases = [
        (Path::new("/dev/zero").to_path_buf(), "a character device"),
        (tmp.path().to_path_buf(), "a folder"),
    ];
    for (path, kind) in &cases {
        if !path.exists() {
            continue; // /dev/zero on a system without it
        }
        for e in [
            read_image(path).unwrap_err(),
            read_stack(path).unwrap_err(),
            read_mask(path).unwrap_err(),
            probe(path).unwrap_err(),
        ] {
            assert!(
                matches!(e.kind, IoErrorKind::NotRegularFile(k) if k == *kind),
                "{e:?}"
            );
            assert_eq!(
                e.to_string(),
                format!(
                    "{}: not a regular file ({kind}); images are read from regular files only",
                    path.display()
                )
            );
        }
    }
}

#[cfg(unix)]
#[test]
fn a_fifo_is_refused_without_blocking() {
    let tmp = tempfile::tempdir().unwrap();
    let fifo = tmp.path().join("frame.tif");
    let ok = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .expect("mkfifo runs")
        .success();
    assert!(ok, "mkfifo failed");
    // opening a FIFO for reading blocks until a writer comes: the reader must not open it
    let e = read_image(&fifo).unwrap_err();
    assert!(
        matches!(e.kind, IoErrorKind::NotRegularFile("a FIFO (named pipe)")),
        "{e:?}"
    );
    assert!(probe(&fifo).is_err() && read_stack(&fifo).is_err());
}
