//! `locate`: detect and fit every dot of one image in memory, one row per lattice site. The
//! library side of `bostrack locate` and of the Python package's `bostrack.locate`, so both give
//! the same rows and the same errors.

use crate::error::PipelineError;
use bostrack_core::{DotFit, FitStatus, Image, Mask, NoiseModel, Seed, table};
use bostrack_detect::{DetectConfig, detect};
use bostrack_fit::{FitConfig, NoiseFit, estimate_noise_detailed, fit_dots};
use std::path::{Path, PathBuf};

/// The columns of `locate`'s table, in order (units: [`LOCATE_UNITS`]).
pub const LOCATE_COLUMNS: [&str; 17] = [
    "i",
    "j",
    "x",
    "y",
    "status",
    "flags",
    "sigma_x",
    "sigma_y",
    "rho",
    "amplitude",
    "background",
    "crlb_x",
    "crlb_y",
    "rms",
    "iterations",
    "x_pred",
    "y_pred",
];

/// The unit of each of [`LOCATE_COLUMNS`].
pub const LOCATE_UNITS: [&str; 17] = [
    "index", "index", "px", "px", "", "", "px", "px", "1", "counts", "counts", "px", "px",
    "counts", "1", "px", "px",
];

/// A fit model by its name: `elliptical`, `axis-aligned` (or `axis_aligned`) or `circular`.
pub fn parse_model(s: &str) -> Result<bostrack_model::ModelKind, String> {
    use bostrack_model::ModelKind;
    match s.replace('-', "_").as_str() {
        "elliptical" => Ok(ModelKind::Elliptical),
        "axis_aligned" => Ok(ModelKind::AxisAligned),
        "circular" => Ok(ModelKind::Circular),
        _ => Err(format!(
            "unknown model `{s}` (expected elliptical, axis-aligned or circular)"
        )),
    }
}

/// What `locate` is asked to do.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LocateOptions {
    pub detect: DetectConfig,
    pub fit: FitConfig,
    /// The noise model; `None`: estimated from the image itself.
    pub noise: Option<NoiseModel>,
}

/// What `locate` found: one seed and one fit per lattice site, in the detector's order.
#[derive(Clone, Debug)]
pub struct Located {
    pub seeds: Vec<Seed>,
    pub fits: Vec<DotFit>,
    /// The lattice spacing (px).
    pub spacing: f64,
    /// The noise model the fits were weighted with.
    pub noise: NoiseModel,
    /// The estimate behind `noise` when it came from the image.
    pub noise_fit: Option<NoiseFit>,
}

/// One row of `locate`'s table: the site, its fit and the lattice's prediction. Values not known
/// (the position of a dot that was not fitted, ρ of the three-point Gaussian) are NaN.
#[derive(Clone, Debug, PartialEq)]
pub struct LocateRow {
    pub i: i32,
    pub j: i32,
    pub x: f64,
    pub y: f64,
    pub status: FitStatus,
    pub flags: bostrack_core::DotFlags,
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub rho: f64,
    pub amplitude: f64,
    pub background: f64,
    pub crlb_x: f64,
    pub crlb_y: f64,
    pub rms: f64,
    pub iterations: u32,
    pub x_pred: f64,
    pub y_pred: f64,
}

impl LocateRow {
    /// The row of a seed and its fit.
    pub fn new(seed: &Seed, f: &DotFit) -> LocateRow {
        let p = &f.params;
        // not fitted: the position is unknown whatever the record holds; the status and flags
        // say why, and x_pred, y_pred give the lattice's prediction
        let known = |v: f64| {
            if f.status == FitStatus::NotFitted {
                f64::NAN
            } else {
                v
            }
        };
        LocateRow {
            i: f.index.i,
            j: f.index.j,
            x: known(p.x0),
            y: known(p.y0),
            status: f.status,
            flags: f.flags,
            sigma_x: p.sigma_x,
            sigma_y: p.sigma_y,
            rho: p.rho,
            amplitude: p.amplitude,
            background: p.background,
            crlb_x: f.crlb_x,
            crlb_y: f.crlb_y,
            rms: f.rms,
            iterations: f.iterations,
            x_pred: seed.predicted[0],
            y_pred: seed.predicted[1],
        }
    }

    /// The CSV cells, in the order of [`LOCATE_COLUMNS`] (numbers by [`table::number`]: an
    /// unknown value is the empty field).
    pub fn cells(&self) -> [String; 17] {
        let mut cells: [String; 17] = Default::default();
        self.write_cells(&mut cells);
        cells
    }

    /// [`LocateRow::cells`] into `cells` (their contents replaced, their memory reused: one
    /// set of cells for a whole table, no allocation per cell; issue 17: writing the table was
    /// 6 % of `locate`'s instructions on the real sample).
    pub fn write_cells(&self, cells: &mut [String; 17]) {
        use std::fmt::Write as _;
        for c in cells.iter_mut() {
            c.clear();
        }
        let w = table::write_number;
        let [
            i,
            j,
            x,
            y,
            status,
            flags,
            sx,
            sy,
            rho,
            amp,
            bg,
            cx,
            cy,
            rms,
            it,
            xp,
            yp,
        ] = cells;
        let _ = write!(i, "{}", self.i);
        let _ = write!(j, "{}", self.j);
        w(x, self.x);
        w(y, self.y);
        status.push_str(self.status.as_str());
        let _ = write!(flags, "{}", self.flags);
        w(sx, self.sigma_x);
        w(sy, self.sigma_y);
        w(rho, self.rho);
        w(amp, self.amplitude);
        w(bg, self.background);
        w(cx, self.crlb_x);
        w(cy, self.crlb_y);
        w(rms, self.rms);
        let _ = write!(it, "{}", self.iterations);
        w(xp, self.x_pred);
        w(yp, self.y_pred);
    }
}

impl Located {
    /// The table's rows, one per site.
    pub fn rows(&self) -> Vec<LocateRow> {
        self.seeds
            .iter()
            .zip(&self.fits)
            .map(|(s, f)| LocateRow::new(s, f))
            .collect()
    }
}

/// Detects the lattice of `image` and fits every dot (in the current rayon pool): the noise
/// model from `options.noise` or estimated from the image, then `bostrack_detect::detect` and
/// `bostrack_fit::fit_dots`. `name` names the image in errors (its file, or a description of an
/// array). The clip level is `image.meta.saturation` as it is.
pub fn locate(
    image: &Image,
    mask: Option<&Mask>,
    options: &LocateOptions,
    name: &Path,
) -> Result<Located, PipelineError> {
    let path = || PathBuf::from(name);
    let (noise, noise_fit) = match options.noise {
        Some(n) => (n, None),
        None => {
            let fit =
                estimate_noise_detailed(image, mask).map_err(|source| PipelineError::Fit {
                    path: PathBuf::from(format!(
                        "{} (estimating its noise; give the read noise)",
                        name.display()
                    )),
                    source,
                })?;
            (fit.model, Some(fit))
        }
    };
    let det = detect(image, mask, &options.detect).map_err(|source| PipelineError::Detect {
        path: path(),
        source,
    })?;
    let fits = fit_dots(image, mask, &det.seeds, &options.fit, &noise).map_err(|source| {
        PipelineError::Fit {
            path: path(),
            source,
        }
    })?;
    Ok(Located {
        seeds: det.seeds,
        fits,
        spacing: det.spacing,
        noise,
        noise_fit,
    })
}
