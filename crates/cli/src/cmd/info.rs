//! `bostrack info`: what an image file holds, as JSON.

use crate::Outcome;
use crate::jobs::JobsArg;
use anyhow::Context as _;
use bostrack_io::{ImageInfo, find_clip_level, image_stats, max_sample_value, probe, read_stack};
use clap::Args;
use rayon::prelude::*;
use serde_json::{Map, Value, json};
use std::path::{Path, PathBuf};

/// Print what an image file holds, as one JSON object.
#[derive(Debug, Args)]
#[command(
    about = "Print an image file's format and sample statistics as JSON",
    long_about = "Print one JSON object per image file (one per line) with its format (width, height, \
bits_per_sample, sample_format, compression, photometric, pages, endianness, tiled) and the \
statistics of its samples over all pages (min, max, mean over the finite samples, \
saturated_pixels at or above the saturation level 2^bits - 1, non_finite_pixels). Samples are in \
camera counts, larger = brighter (WhiteIsZero files are inverted on reading).\n\n\
clip_level is the clip level that `saturation = \"auto\"` finds in the first page (level, source: \
max-sample-value, pile-up, significant-bits, container or none; clipped_pixels at or above it, \
max_sample, container): 12-bit data in a 16-bit file clip at 4095, not at 65535.\n\n\
With several files, a file that cannot be read is reported on stderr, the others are still \
printed, and the exit code is 2."
)]
pub(crate) struct InfoArgs {
    /// Image files (TIFF or PNG).
    #[arg(value_name = "IMAGE", required = true)]
    images: Vec<PathBuf>,
    #[command(flatten)]
    jobs: JobsArg,
}

pub(crate) fn run(args: InfoArgs) -> anyhow::Result<Outcome> {
    let pool = args.jobs.pool(0)?;
    let results: Vec<anyhow::Result<Value>> =
        pool.install(|| args.images.par_iter().map(|p| describe(p)).collect());
    if let [single] = results.as_slice() {
        let v = single
            .as_ref()
            .map_err(|e| anyhow::anyhow!("{}", crate::one_line(e)))?;
        println!("{v}");
        return Ok(Outcome::Done);
    }
    let mut failed = 0;
    for r in results {
        match r {
            Ok(v) => println!("{v}"),
            Err(e) => {
                eprintln!("error: {}", crate::one_line(&e));
                failed += 1;
            }
        }
    }
    Ok(if failed > 0 {
        Outcome::SomeFailed
    } else {
        Outcome::Done
    })
}

/// The JSON object of one file: the header facts of [`ImageInfo`] and the sample statistics.
fn describe(path: &Path) -> anyhow::Result<Value> {
    let info: ImageInfo = probe(path)?;
    let pages = read_stack(path)?;
    let mut obj = match serde_json::to_value(&info).context("serialising the file description")? {
        Value::Object(m) => m,
        _ => Map::new(),
    };
    obj.insert("saturation".into(), json!(pages[0].meta.saturation));
    let clip = find_clip_level(&pages[0], max_sample_value(path)?);
    obj.insert("clip_level".into(), json!(clip));
    // Statistics over every page: min of the minima, max of the maxima, mean weighted by the
    // number of finite samples of each page.
    let (mut min, mut max, mut sum, mut n_finite) = (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0usize);
    let (mut saturated, mut non_finite) = (0usize, 0usize);
    for img in &pages {
        let total = img.width() * img.height();
        match image_stats(img) {
            Some(s) => {
                min = min.min(s.min);
                max = max.max(s.max);
                let finite = total - s.non_finite_pixels;
                sum += s.mean * finite as f64;
                n_finite += finite;
                saturated += s.saturated_pixels;
                non_finite += s.non_finite_pixels;
            }
            None => non_finite += total,
        }
    }
    let stat = |v: f64| if n_finite > 0 { json!(v) } else { Value::Null };
    obj.insert("min".into(), stat(min));
    obj.insert("max".into(), stat(max));
    obj.insert(
        "mean".into(),
        stat(if n_finite > 0 {
            sum / n_finite as f64
        } else {
            f64::NAN
        }),
    );
    obj.insert("saturated_pixels".into(), json!(saturated));
    obj.insert("non_finite_pixels".into(), json!(non_finite));
    Ok(Value::Object(obj))
}
