//! The fuzzing round of issue #14, shared by `examples/fuzz.rs` (the full round, ≥ 10⁵
//! executions) and `tests/fuzz.rs` (a reduced one in CI): mutated image files and mutated
//! configuration files through the code paths a user's files take, in-process. A panic is a
//! failure (the case is saved for reproduction); an error is the expected answer to a damaged
//! file. Everything is deterministic for a given seed.
//!
//! Seed corpus: the io crate's fixtures (`crates/io/tests/fixtures`: 8/12/16/32-bit and float
//! TIFF, strips and tiles, every compression, multi-page, PNG), a small synthetic dot target
//! written four ways (16-bit and float TIFF, 3 pages, 16-bit PNG), the real sample's reference,
//! gradient, mask and one no-flow image (when present), and the committed configurations
//! (`pipeline.toml`, `testdata/*.toml`). Each execution takes one seed and applies 1 to 4
//! mutations: a bit flip, a byte or a 2/4-byte field set to a boundary value, a chunk deleted
//! or duplicated, a truncation, or a splice from another seed; in a large file 80 % of the
//! mutations hit its first 8 KiB (header and directories). An image case goes through
//! `read_stack`, `probe`, `read_mask`, `read_image_clipped` (clip level `auto`) and, where it
//! decodes to at most 256 × 256 pixels, the noise estimate, the detector and the fits; a
//! configuration case through `Plan::load`.
#![allow(dead_code)]

use bostrack_detect::{DetectConfig, detect};
use bostrack_fit::{FitConfig, estimate_noise, fit_dots};
use bostrack_io::{Saturation, probe, read_image_clipped, read_mask, read_stack};
use bostrack_pipeline::Plan;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Writes an image file.
type Writer<'a> = dyn Fn(&Path) -> Result<(), bostrack_io::IoError> + 'a;

/// One seed of the corpus.
pub struct SeedFile {
    pub name: String,
    pub bytes: Vec<u8>,
    /// A configuration file (TOML text), not an image.
    pub config: bool,
}

/// What a round did.
#[derive(Debug, Default)]
pub struct Round {
    pub executions: u64,
    pub image_cases: u64,
    pub config_cases: u64,
    /// Image cases that decoded (the rest were errors).
    pub decoded: u64,
    /// Decoded cases small enough to go through detection and fits.
    pub fitted: u64,
    /// Saved cases that panicked (file name, what panicked).
    pub panics: Vec<(PathBuf, String)>,
    /// The slowest execution (seconds, seed name).
    pub slowest: (f64, String),
}

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The seed corpus (the real sample's files where `sample` is given).
pub fn corpus(sample: Option<&Path>) -> Vec<SeedFile> {
    let mut out = Vec::new();
    let fixtures = repo_root().join("crates/io/tests/fixtures");
    let mut names: Vec<PathBuf> = std::fs::read_dir(&fixtures)
        .expect("io fixtures")
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.extension()
                .is_some_and(|e| e == "tif" || e == "tiff" || e == "png")
        })
        .collect();
    names.sort();
    for p in names {
        out.push(SeedFile {
            name: p.file_name().unwrap().to_string_lossy().into_owned(),
            bytes: std::fs::read(&p).unwrap(),
            config: false,
        });
    }
    if let Some(dir) = sample {
        for f in [
            "pair/reference.tif",
            "pair/gradient.tif",
            "mask.tif",
            "ref-stack/im_0001.tif",
        ] {
            out.push(SeedFile {
                name: f.to_string(),
                bytes: std::fs::read(dir.join(f)).unwrap(),
                config: false,
            });
        }
    }
    // small dot images, so that decoded cases also go through detection and fits: a
    // synthetic 96 × 96 target (16-bit TIFF, multi-page, 16-bit PNG, float TIFF)
    let mut cfg = bostrack_synth::SceneConfig {
        width: 96,
        height: 96,
        seed: 3,
        ..Default::default()
    };
    cfg.lattice.spacing = 9.0;
    let img = bostrack_synth::Scene::reference(&cfg).unwrap().image;
    let tmp = tempfile::tempdir().unwrap();
    let written: [(&str, &Writer<'_>); 4] = [
        ("synth_u16.tif", &|p| bostrack_io::write_tiff_u16(p, &img)),
        ("synth_3pages.tif", &|p| {
            bostrack_io::write_tiff_stack_u16(p, &[img.clone(), img.clone(), img.clone()])
        }),
        ("synth_u16.png", &|p| bostrack_io::write_png_u16(p, &img)),
        ("synth_f32.tif", &|p| bostrack_io::write_tiff_f32(p, &img)),
    ];
    for (name, write) in written {
        let p = tmp.path().join(name);
        write(&p).unwrap();
        out.push(SeedFile {
            name: name.to_string(),
            bytes: std::fs::read(&p).unwrap(),
            config: false,
        });
    }
    for f in [
        "pipeline.toml",
        "testdata/bos-sample.toml",
        "testdata/crlb-setup.toml",
    ] {
        out.push(SeedFile {
            name: f.to_string(),
            bytes: std::fs::read(repo_root().join(f)).unwrap(),
            config: true,
        });
    }
    out
}

const BYTES: [u8; 7] = [0, 1, 0x7f, 0x80, 0xfe, 0xff, b'='];
const WORDS: [u32; 8] = [
    0,
    1,
    2,
    0x7fff,
    0xffff,
    0x7fff_ffff,
    0xffff_ffff,
    0x4000_0000,
];
const TOKENS: [&str; 10] = [
    "-1",
    "0",
    "1e308",
    "nan",
    "\"\"",
    "4294967296",
    "[]",
    "\"../..\"",
    "true",
    "\"/dev/zero\"",
];

/// 1 to 4 mutations of `bytes` (`other`: bytes to splice from).
fn mutate(rng: &mut StdRng, bytes: &[u8], other: &[u8], config: bool) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let n = rng.random_range(1..=4);
    for _ in 0..n {
        if b.is_empty() {
            b.push(0);
        }
        let span = if b.len() > 65536 && rng.random_bool(0.8) {
            8192
        } else {
            b.len()
        };
        let at = rng.random_range(0..span.min(b.len()));
        match rng.random_range(0..8) {
            0 => b[at] ^= 1 << rng.random_range(0..8),
            1 => b[at] = BYTES[rng.random_range(0..BYTES.len())],
            2 => {
                let w = WORDS[rng.random_range(0..WORDS.len())];
                let le = rng.random_bool(0.5);
                let bytes = if le { w.to_le_bytes() } else { w.to_be_bytes() };
                let k = if rng.random_bool(0.5) { 2 } else { 4 };
                for (i, v) in bytes[if le { 0 } else { 4 - k }..][..k].iter().enumerate() {
                    if at + i < b.len() {
                        b[at + i] = *v;
                    }
                }
            }
            3 => {
                let len = rng.random_range(1..=64).min(b.len() - at);
                b.drain(at..at + len);
            }
            4 => {
                let len = rng.random_range(1..=64).min(b.len() - at);
                let chunk = b[at..at + len].to_vec();
                b.splice(at..at, chunk);
            }
            5 => b.truncate(rng.random_range(0..b.len())),
            6 if !other.is_empty() => {
                let from = rng.random_range(0..other.len());
                let len = rng.random_range(1..=256).min(other.len() - from);
                let end = (at + len).min(b.len());
                b.splice(at..end, other[from..from + len].iter().copied());
            }
            _ if config => {
                // a value replaced by a boundary token: after the next '='
                if let Some(eq) = b[at..].iter().position(|&c| c == b'=') {
                    let start = at + eq + 1;
                    let end = b[start..]
                        .iter()
                        .position(|&c| c == b'\n')
                        .map_or(b.len(), |e| start + e);
                    let t = TOKENS[rng.random_range(0..TOKENS.len())];
                    b.splice(start..end, format!(" {t}").into_bytes());
                }
            }
            _ => b[at] = rng.random(),
        }
    }
    b
}

/// Image cases: every reader, and the chain for small images.
fn image_case(path: &Path) -> (bool, bool) {
    let _ = probe(path);
    let _ = read_mask(path);
    let _ = read_stack(path);
    let Ok((img, _)) = read_image_clipped(path, Saturation::Auto) else {
        return (false, false);
    };
    if img.width() * img.height() > 256 * 256 {
        return (true, false);
    }
    let Ok(noise) = estimate_noise(&img, None) else {
        return (true, false);
    };
    let Ok(det) = detect(&img, None, &DetectConfig::default()) else {
        return (true, false);
    };
    let _ = fit_dots(&img, None, &det.seeds, &FitConfig::default(), &noise);
    (true, true)
}

/// `iterations` executions from `seed` over `corpus`, the cases written under `dir` (panicking
/// cases are kept there as `panic-N-<seed name>`).
pub fn run(corpus: &[SeedFile], iterations: u64, seed: u64, dir: &Path) -> Round {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut round = Round::default();
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let images: Vec<usize> = (0..corpus.len()).filter(|&k| !corpus[k].config).collect();
    let configs: Vec<usize> = (0..corpus.len()).filter(|&k| corpus[k].config).collect();
    for _ in 0..iterations {
        let config = rng.random_bool(0.1);
        let pool = if config { &configs } else { &images };
        let s = &corpus[pool[rng.random_range(0..pool.len())]];
        let other = &corpus[pool[rng.random_range(0..pool.len())]].bytes;
        let bytes = mutate(&mut rng, &s.bytes, other, config);
        let path = dir.join(if config { "case.toml" } else { "case.tif" });
        std::fs::write(&path, &bytes).unwrap();
        let t = Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            if config {
                let _ = Plan::load(&path);
                (false, false)
            } else {
                image_case(&path)
            }
        }));
        let dt = t.elapsed().as_secs_f64();
        round.executions += 1;
        if config {
            round.config_cases += 1;
        } else {
            round.image_cases += 1;
        }
        match outcome {
            Ok((decoded, fitted)) => {
                round.decoded += decoded as u64;
                round.fitted += fitted as u64;
            }
            Err(e) => {
                let what = e
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                let keep = dir.join(format!(
                    "panic-{}-{}",
                    round.panics.len(),
                    s.name.replace('/', "_")
                ));
                std::fs::write(&keep, &bytes).unwrap();
                round.panics.push((keep, what));
            }
        }
        if dt > round.slowest.0 {
            round.slowest = (dt, s.name.clone());
        }
    }
    std::panic::set_hook(previous);
    round
}

/// Peak resident memory of this process (MiB), from /proc (None elsewhere).
pub fn peak_rss_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}
