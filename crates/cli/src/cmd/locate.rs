//! `bostrack locate`: detect and fit every dot of one image, one CSV row per lattice site.

use crate::Outcome;
use crate::jobs::JobsArg;
use anyhow::Context as _;
use bostrack_core::{DotFlags, FitStatus, NoiseModel};
use bostrack_detect::DetectConfig;
use bostrack_fit::{Estimator, FitConfig};
use bostrack_io::Saturation;
use bostrack_model::ModelKind;
use bostrack_pipeline::{CsvTable, LOCATE_COLUMNS, LocateOptions, Located, locate};
use clap::Args;
use std::io::Write as _;
use std::path::PathBuf;

/// The long help of `locate`: the CSV columns, with the status and flag names taken from the
/// code (`FitStatus::ALL`, every `DotFlags` name), so none is left out.
fn locate_long_about() -> String {
    let statuses: Vec<&str> = FitStatus::ALL.iter().map(FitStatus::as_str).collect();
    let flags: Vec<&str> = DotFlags::from_bits(u32::MAX).names().collect();
    format!(
        "\
Detect every dot of a dot-target image on its lattice (bostrack-detect), fit each one
(bostrack-fit) and write one CSV row per lattice site:

  i,j                  grid index (i along the lattice vector closest to +x, j closest to +y)
  x,y                  fitted centre, px (pixel centres at integers, origin at the centre of the
                       top-left pixel, y down); empty when the dot was not fitted
{}
{}
  sigma_x,sigma_y,rho  fitted shape, px (dot diameter d = 4 sigma)
  amplitude            peak height above the background, counts
  background           background level, counts
  crlb_x,crlb_y        exact per-dot Cramér-Rao bound of x and y (1 sigma, px)
  rms                  root-mean-square fit residual, counts
  iterations           Levenberg-Marquardt iterations
  x_pred,y_pred        position of the site predicted by the lattice map, px

The meaning of every status and flag is in the table of docs/CONVENTIONS.md. The noise model
(read + shot noise) that weights the fits and sets the bounds is estimated from the image itself
unless --read-noise is given. Per-dot problems are data (status and flags), never errors: the
command fails (exit 1) only when the image cannot be read or no lattice is found. Numbers have 6
decimals; a value that is not known (not fitted, or not estimated: the three-point Gaussian does
not estimate rho) is an empty field, as in every table bostrack writes.",
        column(
            "status",
            &format!("why the fit stopped: {}", statuses.join(", "))
        ),
        column(
            "flags",
            &format!("per-dot problems, a|b|c: {}", flags.join(", "))
        ),
    )
}

/// One entry of the column list of [`locate_long_about`]: the name in a 21-character field
/// after two spaces, the text wrapped at 96 characters and continued under itself.
fn column(name: &str, text: &str) -> String {
    const INDENT: usize = 23;
    const WIDTH: usize = 96;
    let mut out = format!("  {name:<21}");
    let mut line_len = INDENT;
    for (k, word) in text.split(' ').enumerate() {
        if k > 0 && line_len + 1 + word.len() > WIDTH {
            out.push('\n');
            out.push_str(&" ".repeat(INDENT));
            line_len = INDENT;
        } else if k > 0 {
            out.push(' ');
            line_len += 1;
        }
        out.push_str(word);
        line_len += word.len();
    }
    out
}

/// Detect and fit every dot of an image.
#[derive(Debug, Args)]
#[command(
    about = "Detect and fit every dot of an image; one CSV row per lattice site",
    long_about = locate_long_about()
)]
pub(crate) struct LocateArgs {
    /// Image of the dot target (TIFF or PNG).
    #[arg(value_name = "IMAGE")]
    image: PathBuf,
    /// Region-of-interest mask, the size of the image: pixels displaying brighter than the
    /// midpoint of its darkest and brightest values are kept ({0,1}, {0,255}, {0,65535}).
    #[arg(long, value_name = "MASK")]
    mask: Option<PathBuf>,
    /// Approximate dot spacing, px (a prior: the lattice is measured from the image).
    #[arg(long, value_name = "PX")]
    spacing: Option<f64>,
    /// Approximate dot diameter d = 4 sigma, px (a prior for the matched filter).
    #[arg(long, value_name = "PX")]
    diameter: Option<f64>,
    /// Free parameters of the fitted Gaussian: elliptical (7), axis-aligned (rho = 0) or
    /// circular (sigma_x = sigma_y, rho = 0).
    #[arg(long, value_name = "MODEL", value_parser = parse_model, default_value = "elliptical")]
    model: ModelKind,
    /// Estimator: lsg (least-squares Gaussian), iwc (intensity-weighted centroid) or tpg
    /// (three-point Gaussian).
    #[arg(long, value_name = "NAME", value_parser = parse_estimator, default_value = "lsg")]
    estimator: Estimator,
    /// Read-noise standard deviation, counts. The noise model weights the fit and sets the
    /// bound; without this option it is estimated from the image (read + shot noise).
    #[arg(long, value_name = "COUNTS")]
    read_noise: Option<f64>,
    /// Shot noise with --read-noise: counts per photo-electron
    /// (variance = read_noise² + gain · max(signal - offset, 0)).
    #[arg(
        long,
        value_name = "COUNTS",
        default_value_t = 0.0,
        requires = "read_noise"
    )]
    gain: f64,
    /// Dark level that carries no shot noise, counts (with --read-noise).
    #[arg(
        long,
        value_name = "COUNTS",
        default_value_t = 0.0,
        requires = "read_noise"
    )]
    offset: f64,
    /// Clip level of the camera, counts: samples at or above it are left out of the fits and
    /// flag their dot `saturated`. `auto` finds it in the image: the TIFF tag MaxSampleValue,
    /// else a pile-up of samples at the largest value, else the significant bits of the samples
    /// (12-bit data in a 16-bit file clip at 4095), else the file's maximum 2^bits - 1.
    #[arg(long, value_name = "auto|COUNTS", default_value = "auto", value_parser = parse_saturation)]
    saturation: Saturation,
    /// Output CSV file (replaced if it exists).
    #[arg(short = 'o', long = "out", value_name = "CSV")]
    out: PathBuf,
    #[command(flatten)]
    jobs: JobsArg,
}

fn parse_model(s: &str) -> Result<ModelKind, String> {
    bostrack_pipeline::parse_model(s)
}

fn parse_saturation(s: &str) -> Result<Saturation, String> {
    s.parse()
}

fn parse_estimator(s: &str) -> Result<Estimator, String> {
    match s {
        "lsg" => Ok(Estimator::Lsg),
        "iwc" => Ok(Estimator::Iwc),
        "tpg" => Ok(Estimator::Tpg),
        _ => Err(format!(
            "unknown estimator `{s}` (expected lsg, iwc or tpg)"
        )),
    }
}

pub(crate) fn run(args: LocateArgs) -> anyhow::Result<Outcome> {
    let detect_cfg = DetectConfig {
        spacing: args.spacing,
        diameter: args.diameter,
        ..DetectConfig::default()
    };
    detect_cfg.validate()?;
    let fit_cfg = FitConfig {
        model: args.model,
        estimator: args.estimator,
        ..FitConfig::default()
    };
    fit_cfg.validate()?;

    let (image, clip) = bostrack_io::read_image_clipped(&args.image, args.saturation)?;
    let mask = match &args.mask {
        Some(m) => Some(bostrack_io::read_mask_for(
            m,
            image.width(),
            image.height(),
        )?),
        None => None,
    };
    // The noise model: the flags when given, else estimated from the image itself (then said
    // with its standard errors, and whether the line was resolved).
    let noise = match args.read_noise {
        Some(read_noise) => {
            if !(read_noise.is_finite()
                && read_noise > 0.0
                && args.gain.is_finite()
                && args.gain >= 0.0
                && args.offset.is_finite())
            {
                anyhow::bail!(
                    "the noise model needs --read-noise > 0, --gain >= 0 and a finite --offset"
                );
            }
            Some(NoiseModel {
                read_variance: read_noise * read_noise,
                gain: args.gain,
                offset: args.offset,
            })
        }
        None => None,
    };
    let pool = args.jobs.pool(0)?;
    let options = LocateOptions {
        detect: detect_cfg,
        fit: fit_cfg,
        noise,
    };
    let found = pool.install(|| locate(&image, mask.as_ref(), &options, &args.image))?;
    let (noise, fits) = (found.noise, &found.fits);
    let noise_note = found.noise_fit.as_ref().map_or(String::new(), |fit| {
        format!(
            " (from the image: read variance {:.0} ± {:.0} counts², gain {:.3} ± {:.3}{})",
            fit.model.read_variance,
            fit.read_variance_se,
            fit.model.gain,
            fit.gain_se,
            if fit.resolved {
                ""
            } else {
                "; line not resolved: read variance of the darkest pixels"
            }
        )
    });

    write_csv(&args.out, &found)?;
    let ok = fits.iter().filter(|f| f.status.is_ok()).count();
    let missing = fits
        .iter()
        .filter(|f| f.flags.contains(DotFlags::MISSING))
        .count();
    eprintln!(
        "{}: {} sites ({} missing), spacing {:.3} px, clip level {}, noise {:.2} counts + gain {:.3}{}, {} fits usable, {} not; wrote {}",
        args.image.display(),
        fits.len(),
        missing,
        found.spacing,
        clip,
        noise.read_variance.sqrt(),
        noise.gain,
        noise_note,
        ok,
        fits.len() - ok,
        args.out.display()
    );
    Ok(Outcome::Done)
}

/// Writes `locate`'s table by the one table writer ([`CsvTable`]): float cells by
/// `table::number`, so an unknown value (not fitted, not estimated) is the empty field.
fn write_csv(path: &std::path::Path, found: &Located) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let io = |e: std::io::Error| anyhow::anyhow!("cannot write {}: {e}", path.display());
    let mut t = CsvTable::new(std::io::BufWriter::new(file), &LOCATE_COLUMNS).map_err(io)?;
    let mut cells: [String; LOCATE_COLUMNS.len()] = Default::default();
    for (seed, f) in found.seeds.iter().zip(&found.fits) {
        bostrack_pipeline::LocateRow::new(seed, f).write_cells(&mut cells);
        t.row(&cells).map_err(io)?;
    }
    t.finish().map_err(io)?.flush().map_err(io)
}
