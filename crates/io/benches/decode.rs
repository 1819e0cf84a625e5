//! Decoding the real sample files (run: `cargo bench -p bostrack-io --bench decode`).
//!
//! `read_image` end to end (file read from the page cache + decode + conversion to f64) of the
//! 1024 x 1024 16-bit PackBits reference and of one 1024 x 1024 12-bit packed stack image.

use bostrack_io::{bos_sample_dir, read_image, read_mask};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

fn decode(c: &mut Criterion) {
    let Some(dir) = bos_sample_dir() else { return };
    let mut g = c.benchmark_group("read_image_1Mpx");
    let reference = dir.join("pair/reference.tif");
    g.bench_function("u16_packbits_reference", |b| {
        b.iter(|| read_image(black_box(&reference)).unwrap())
    });
    let stack = dir.join("ref-stack/im_0001.tif");
    g.bench_function("u12_packed_stack_image", |b| {
        b.iter(|| read_image(black_box(&stack)).unwrap())
    });
    let mask = dir.join("mask.tif");
    g.bench_function("u8_whiteiszero_mask", |b| {
        b.iter(|| read_mask(black_box(&mask)).unwrap())
    });
    g.finish();
}

criterion_group!(benches, decode);
criterion_main!(benches);
