//! Damaged files never panic: every truncation length and many single-byte corruptions of
//! small fixtures give either an image or an `IoError`.

mod support;

use bostrack_io::{probe, read_stack};
use support::fixture;

const FILES: &[&str] = &[
    "le_u12_packbits.tif",
    "be_u12_lzw.tif",
    "le_u12_deflate.tif",
    "be_u12_tiles_packbits.tif",
    "be_u16_packbits.tif",
    "le_u16_tiles_none.tif",
    "le_u8_whiteiszero.tif",
    "be_f32_deflate.tif",
    "mask_1bit.png",
];

fn try_all(dir: &std::path::Path, bytes: &[u8]) {
    let path = dir.join("damaged");
    std::fs::write(&path, bytes).unwrap();
    // errors are fine; a panic fails the test
    let _ = read_stack(&path);
    let _ = probe(&path);
}

#[test]
fn truncation_at_every_length_never_panics() {
    let dir = tempfile::tempdir().unwrap();
    for f in FILES {
        let bytes = std::fs::read(fixture(f)).unwrap();
        for len in (0..bytes.len()).step_by(11) {
            try_all(dir.path(), &bytes[..len]);
        }
    }
}

#[test]
fn corrupted_bytes_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    // deterministic xorshift, so that a failure is reproducible
    let mut s = 0x9E37_79B9_7F4A_7C15_u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    for f in FILES {
        let orig = std::fs::read(fixture(f)).unwrap();
        for _ in 0..100 {
            let mut bytes = orig.clone();
            // mostly the header and tags (first 400 bytes), sometimes anywhere
            for _ in 0..1 + next() % 3 {
                let span = if next() % 4 == 0 {
                    bytes.len()
                } else {
                    bytes.len().min(400)
                };
                let i = (next() % span as u64) as usize;
                bytes[i] = next() as u8;
            }
            try_all(dir.path(), &bytes);
        }
    }
}
