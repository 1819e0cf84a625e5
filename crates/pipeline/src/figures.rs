//! The figures of a run, drawn with `bostrack-figures` from the per-frame files on disk
//! (`DIR/<frame>/dots.csv`, `DIR/campaign.csv`), so a figure is the same whether it was drawn
//! right after its frame was computed, on a rerun or by `bostrack merge`.
//!
//! Per frame (into `DIR/<frame>/`): `displacement.*` (arrows over |d|), `amplification.*`
//! (max(AR_x, AR_y): 1 where nothing is amplified), `uncertainty.*` (|u_d| = √(u_dx² + u_dy²)),
//! `uncertainty-histogram.*` (magnitudes √(u_x² + u_y²) of u_ref and u_grad over the valid dots
//! inside the mask, the paper's Fig. 6c,f) and `ar-histogram.*` (max(AR_x, AR_y) over the same
//! dots). Every
//! map is in image coordinates (px, y down, docs/CONVENTIONS.md); dots outside the mask are grey
//! rings, invalid dots red crosses. `DIR/<frame>/figures.json` is written last and lists what
//! was requested, written and skipped (a figure with nothing to plot, e.g. uncertainties
//! without a no-flow stack): its presence marks the frame's figures complete.
//!
//! Per campaign (into `DIR/`): `campaign.*` (median |d| and median |u_d| against the frame
//! number) and `detections.*` (the reference dots coloured by |CRLB_ref|).

use crate::batch::BatchError;
use crate::batch::dots::{FrameDots, read_dots};
use crate::batch::fsx::write_atomic;
use crate::config::{ArrayFormat, Figure, FigureFormat};
use bostrack_core::Mask;
use bostrack_figures as bf;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Name of the per-frame record of figures.
pub(crate) const FIGURES_RECORD: &str = "figures.json";

/// Which figures, in which formats, and which lattice array files: the per-frame outputs
/// drawn from a frame's `dots.csv` after it is written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct FigureSpec {
    pub figures: Vec<Figure>,
    pub formats: Vec<FigureFormat>,
    pub arrays: Vec<ArrayFormat>,
}

/// What the figures of a run need besides the data: the image size and the mask.
#[derive(Clone, Debug)]
pub(crate) struct FigureSetup {
    pub spec: FigureSpec,
    pub width: usize,
    pub height: usize,
    pub mask: Option<Mask>,
    /// Names the reference image in the detections figure (its file name, or "the mean of the
    /// no-flow stack").
    pub reference_name: String,
}

/// One per-frame figure kind and its file stem.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum FrameFigure {
    Displacement,
    Amplification,
    Uncertainty,
    UncertaintyHistogram,
    ArHistogram,
    Density,
    DensityUncertainty,
}

impl FrameFigure {
    fn file_stem(self) -> &'static str {
        match self {
            FrameFigure::Displacement => "displacement",
            FrameFigure::Amplification => "amplification",
            FrameFigure::Uncertainty => "uncertainty",
            FrameFigure::UncertaintyHistogram => "uncertainty-histogram",
            FrameFigure::ArHistogram => "ar-histogram",
            FrameFigure::Density => "density",
            FrameFigure::DensityUncertainty => "density-uncertainty",
        }
    }
}

/// `DIR/<frame>/figures.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
struct FiguresRecord {
    /// The files requested (every figure in every format), in order.
    requested: Vec<String>,
    /// The files written.
    written: Vec<String>,
    /// Figures not drawn, with the reason.
    skipped: Vec<Skipped>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct Skipped {
    figure: String,
    reason: String,
}

impl FigureSpec {
    fn frame_figures(&self) -> Vec<FrameFigure> {
        let mut out = Vec::new();
        for f in &self.figures {
            match f {
                Figure::Displacement => out.push(FrameFigure::Displacement),
                Figure::Amplification => out.push(FrameFigure::Amplification),
                Figure::Uncertainty => out.push(FrameFigure::Uncertainty),
                Figure::Histograms => {
                    out.push(FrameFigure::UncertaintyHistogram);
                    out.push(FrameFigure::ArHistogram);
                }
                Figure::Density => {
                    out.push(FrameFigure::Density);
                    out.push(FrameFigure::DensityUncertainty);
                }
                Figure::Campaign | Figure::Detections => {}
            }
        }
        out
    }

    /// Whether any per-frame figure is requested.
    pub fn has_frame_figures(&self) -> bool {
        !self.frame_figures().is_empty()
    }

    /// The per-frame files requested, in order.
    fn requested(&self) -> Vec<String> {
        let mut out = Vec::new();
        for f in self.frame_figures() {
            for fmt in &self.formats {
                out.push(format!("{}.{}", f.file_stem(), fmt.extension()));
            }
        }
        out
    }

    /// Whether `frame_dir` holds this setup's per-frame figures: its `figures.json` lists
    /// exactly the requested files (none requested: always complete).
    pub fn frame_complete(&self, frame_dir: &Path) -> bool {
        if !self
            .arrays
            .iter()
            .all(|a| frame_dir.join(a.file_name()).is_file())
        {
            return false;
        }
        if !self.has_frame_figures() {
            return true;
        }
        let Ok(bytes) = std::fs::read(frame_dir.join(FIGURES_RECORD)) else {
            return false;
        };
        match serde_json::from_slice::<FiguresRecord>(&bytes) {
            Ok(r) => {
                r.requested == self.requested()
                    && r.written.iter().all(|f| frame_dir.join(f).is_file())
            }
            Err(_) => false,
        }
    }

    /// Whether any campaign figure is requested.
    pub fn has_campaign_figures(&self) -> bool {
        self.figures
            .iter()
            .any(|f| matches!(f, Figure::Campaign | Figure::Detections))
    }
}

impl FigureSetup {
    /// Whether `(x, y)` (px) is kept by the mask (no mask: everywhere).
    fn in_mask(&self, x: f64, y: f64) -> bool {
        let Some(m) = &self.mask else { return true };
        if !(x.is_finite() && y.is_finite()) {
            return true;
        }
        m.keeps_point(x, y)
    }

    fn map_frame<'a>(&'a self, title: &'a str) -> bf::MapFrame<'a> {
        bf::MapFrame {
            width: self.width,
            height: self.height,
            title,
            mask: self.mask.as_ref(),
        }
    }

    /// Renders `fig` in every format into `dir/<stem>.<ext>`; the names written are appended to
    /// `written`.
    fn write(
        &self,
        dir: &Path,
        stem: &str,
        fig: &bf::Figure,
        written: &mut Vec<String>,
    ) -> Result<(), FigureOutcome> {
        for fmt in &self.spec.formats {
            let bytes = match fmt {
                FigureFormat::Png => fig.to_png(),
                FigureFormat::Svg => fig.to_svg().map(String::into_bytes),
            }
            .map_err(FigureOutcome::Skip)?;
            let name = format!("{stem}.{}", fmt.extension());
            write_atomic(&dir.join(&name), &bytes).map_err(|e| FigureOutcome::Fail(Box::new(e)))?;
            written.push(name);
        }
        Ok(())
    }
}

/// Why a figure was not written: nothing to draw (a note), or the file could not be written.
enum FigureOutcome {
    Skip(bf::FigureError),
    Fail(Box<BatchError>),
}

/// Draws the requested per-frame figures of `frame_dir` from its `dots.csv`, then writes
/// `figures.json`. Returns the notes on figures skipped (nothing to draw).
/// Writes the lattice array files of `spec` (`fields.npz`, `fields.mat`) from the frame's
/// `dots.csv`, each atomically.
pub(crate) fn write_frame_arrays(frame_dir: &Path, spec: &FigureSpec) -> Result<(), BatchError> {
    if spec.arrays.is_empty() {
        return Ok(());
    }
    let dots = frame_dir.join("dots.csv");
    let fields = crate::LatticeFields::read(&dots)?;
    for a in &spec.arrays {
        let path = frame_dir.join(a.file_name());
        let bytes = match a {
            ArrayFormat::Npz => fields.to_npz(),
            ArrayFormat::Mat => fields.to_mat(),
        }
        .map_err(|message| BatchError::Corrupt {
            path: path.clone(),
            message,
        })?;
        write_atomic(&path, &bytes)?;
    }
    Ok(())
}

pub(crate) fn draw_frame_figures(
    frame_dir: &Path,
    title: &str,
    setup: &FigureSetup,
) -> Result<Vec<String>, BatchError> {
    let kinds = setup.spec.frame_figures();
    if kinds.is_empty() {
        return Ok(Vec::new());
    }
    let _ = std::fs::remove_file(frame_dir.join(FIGURES_RECORD));
    let mut dots = read_dots(&frame_dir.join("dots.csv"))?;
    if kinds
        .iter()
        .any(|k| matches!(k, FrameFigure::Density | FrameFigure::DensityUncertainty))
    {
        crate::batch::dots::read_density(&frame_dir.join("density.csv"), &mut dots)?;
    }
    let mut record = FiguresRecord {
        requested: setup.spec.requested(),
        ..FiguresRecord::default()
    };
    let mut notes = Vec::new();
    for kind in kinds {
        let fig = frame_figure(kind, &dots, title, setup);
        let result = fig
            .map_err(FigureOutcome::Skip)
            .and_then(|fig| setup.write(frame_dir, kind.file_stem(), &fig, &mut record.written));
        match result {
            Ok(()) => {}
            Err(FigureOutcome::Skip(e)) => {
                notes.push(format!(
                    "{}: {}: {e}",
                    frame_dir.display(),
                    kind.file_stem()
                ));
                record.skipped.push(Skipped {
                    figure: kind.file_stem().to_string(),
                    reason: e.to_string(),
                });
            }
            Err(FigureOutcome::Fail(e)) => return Err(*e),
        }
    }
    let json = serde_json::to_vec_pretty(&record).map_err(|e| BatchError::Corrupt {
        path: frame_dir.join(FIGURES_RECORD),
        message: e.to_string(),
    })?;
    write_atomic(&frame_dir.join(FIGURES_RECORD), &json)?;
    Ok(notes)
}

fn frame_figure(
    kind: FrameFigure,
    d: &FrameDots,
    title: &str,
    setup: &FigureSetup,
) -> Result<bf::Figure, bf::FigureError> {
    let n = d.len();
    let in_mask: Vec<bool> = (0..n)
        .map(|k| setup.in_mask(d.x_ref[k], d.y_ref[k]))
        .collect();
    let scalar = |value: &dyn Fn(usize) -> f64| -> Vec<bf::MapPoint> {
        (0..n)
            .map(|k| bf::MapPoint::scalar(d.x_ref[k], d.y_ref[k], value(k), d.valid[k], in_mask[k]))
            .collect()
    };
    // Histograms: the valid dots inside the mask, one value per dot from its two axes.
    let kept = |a: &[f64], b: &[f64], of_axes: fn(f64, f64) -> f64| -> Vec<f64> {
        (0..n)
            .filter(|&k| d.valid[k] && in_mask[k])
            .map(|k| of_axes(a[k], b[k]))
            .collect()
    };
    let frame = setup.map_frame(title);
    let options = bf::MapOptions::default();
    match kind {
        FrameFigure::Displacement => {
            let points: Vec<bf::MapPoint> = (0..n)
                .map(|k| {
                    bf::MapPoint::vector(
                        d.x_ref[k], d.y_ref[k], d.dx[k], d.dy[k], d.valid[k], in_mask[k],
                    )
                })
                .collect();
            bf::displacement_map(&points, &frame, &options)
        }
        FrameFigure::Amplification => {
            bf::ar_map(&scalar(&|k| larger(d.ar_x[k], d.ar_y[k])), &frame, &options)
        }
        FrameFigure::Uncertainty => bf::uncertainty_map(
            &scalar(&|k| d.u_dx[k].hypot(d.u_dy[k])),
            &frame,
            bf::UncertaintyComponent::Magnitude,
            &options,
        ),
        FrameFigure::UncertaintyHistogram => {
            let (u_ref, u_grad) = (
                kept(&d.u_ref_x, &d.u_ref_y, f64::hypot),
                kept(&d.u_grad_x, &d.u_grad_y, f64::hypot),
            );
            if !u_ref.iter().chain(&u_grad).any(|v| v.is_finite()) {
                return Err(no_data(
                    "uncertainty histogram",
                    "no u_ref or u_grad (they need a no-flow stack: input.stack or input.stack_dir)",
                ));
            }
            bf::uncertainty_histogram(&u_ref, &u_grad, title)
        }
        FrameFigure::ArHistogram => bf::ar_histogram(&kept(&d.ar_x, &d.ar_y, larger), title),
        FrameFigure::Density | FrameFigure::DensityUncertainty => {
            let (values, name) = if kind == FrameFigure::Density {
                (&d.rho, "Density ρ")
            } else {
                (&d.u_rho, "Density uncertainty u_ρ (1σ)")
            };
            if !values.iter().any(|v| v.is_finite()) {
                return Err(no_data("density map", "no density (no [optics] section?)"));
            }
            let points: Vec<bf::MapPoint> = (0..n)
                .map(|k| {
                    bf::MapPoint::scalar(
                        d.x_ref[k],
                        d.y_ref[k],
                        values[k],
                        values[k].is_finite(),
                        in_mask[k],
                    )
                })
                .collect();
            let q = bf::Quantity {
                name,
                unit: "kg/m³",
            };
            bf::scalar_map(&points, &frame, &q, &options)
        }
    }
}

/// The larger of two per-axis values (an amplification ratio: 1 where neither axis is
/// amplified); NaN when either is unknown.
fn larger(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

fn no_data(figure: &str, reason: &str) -> bf::FigureError {
    bf::FigureError::NoData {
        figure: figure.to_string(),
        reason: reason.to_string(),
    }
}

/// One frame of the campaign figure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct CampaignPoint {
    /// Frame number (from 1).
    pub frame: usize,
    /// Median |d| over the valid dots (px); NaN for a failed frame.
    pub median_d: f64,
    /// Median |u_d| over the valid dots (px); NaN when unknown.
    pub median_u: f64,
}

/// Draws the campaign figures requested (`campaign.*`, `detections.*`) into `out_dir`.
/// `detections_from` is the frame folder whose `dots.csv` supplies the reference dots (any
/// complete frame: the reference columns are the same in every frame). Returns notes on
/// figures skipped.
pub(crate) fn draw_campaign_figures(
    out_dir: &Path,
    title: &str,
    points: &[CampaignPoint],
    detections_from: Option<&Path>,
    setup: &FigureSetup,
) -> Result<Vec<String>, BatchError> {
    let mut notes = Vec::new();
    let mut written = Vec::new();
    let mut handle = |name: &str, fig: Result<bf::Figure, bf::FigureError>| match fig
        .map_err(FigureOutcome::Skip)
        .and_then(|f| setup.write(out_dir, name, &f, &mut written))
    {
        Ok(()) => Ok(()),
        Err(FigureOutcome::Skip(e)) => {
            notes.push(format!("{name}: {e}"));
            Ok(())
        }
        Err(FigureOutcome::Fail(e)) => Err(*e),
    };
    if setup.spec.figures.contains(&Figure::Campaign) {
        handle("campaign", campaign_figure(title, points))?;
    }
    if setup.spec.figures.contains(&Figure::Detections) {
        let fig = match detections_from {
            Some(dir) => {
                let d = read_dots(&dir.join("dots.csv"))?;
                let title = format!("reference dots in {}", setup.reference_name);
                detections_figure(&d, &title, setup)
            }
            None => Err(no_data("detections", "no complete frame")),
        };
        handle("detections", fig)?;
    }
    Ok(notes)
}

/// Median |d| (and median |u_d| when known) against the frame number, one panel each.
fn campaign_figure(title: &str, points: &[CampaignPoint]) -> Result<bf::Figure, bf::FigureError> {
    let panel =
        |title: &str, y_label: &str, label: &str, f: fn(&CampaignPoint) -> f64| bf::XyPlot {
            title: title.to_string(),
            x_label: "frame number (natural order of the file names)".to_string(),
            y_label: y_label.to_string(),
            // whole frame numbers; magnitudes from zero, so that small differences look small
            x_scale: bf::AxisScale::Integer,
            y_scale: bf::AxisScale::FromZero,
            series: vec![bf::XySeries {
                label: label.to_string(),
                points: points.iter().map(|p| (p.frame as f64, f(p))).collect(),
                // Markers only help while they can be told apart.
                style: if points.len() > 60 {
                    bf::SeriesStyle::Line
                } else {
                    bf::SeriesStyle::LinePoints
                },
            }],
            ..bf::XyPlot::default()
        };
    let mut panels = vec![panel(
        "Median displacement magnitude",
        "median |d| (px)",
        "median |d| over the valid dots",
        |p| p.median_d,
    )];
    if points.iter().any(|p| p.median_u.is_finite()) {
        panels.push(panel(
            "Median displacement uncertainty",
            "median |u_d| (px, 1σ)",
            "median |u_d| over the valid dots",
            |p| p.median_u,
        ));
    }
    bf::xy_panels(title, &panels)
}

/// The reference dots coloured by |CRLB_ref| = √(crlb_x² + crlb_y²); dots without a usable
/// reference fit are "invalid".
fn detections_figure(
    d: &FrameDots,
    title: &str,
    setup: &FigureSetup,
) -> Result<bf::Figure, bf::FigureError> {
    let points: Vec<bf::MapPoint> = (0..d.len())
        .map(|k| {
            let (x, y) = (d.x_ref[k], d.y_ref[k]);
            bf::MapPoint::scalar(
                x,
                y,
                d.crlb_x_ref[k].hypot(d.crlb_y_ref[k]),
                d.ref_fitted[k],
                setup.in_mask(x, y),
            )
        })
        .collect();
    let q = bf::Quantity {
        name: "Cramér-Rao bound |CRLB_ref|",
        unit: "px",
    };
    bf::scalar_map(
        &points,
        &setup.map_frame(title),
        &q,
        &bf::MapOptions::default(),
    )
}

#[cfg(test)]
mod tests {
    use super::larger;

    /// The AR figures' per-dot value is 1 for a dot amplified on neither axis (the norm
    /// √(AR_x² + AR_y²) is √2 there), follows the more amplified axis, and is unknown when
    /// either axis is.
    #[test]
    fn ar_shown_is_the_larger_axis() {
        assert_eq!(larger(1.0, 1.0), 1.0);
        assert_eq!(larger(1.0, 1.3), 1.3);
        assert_eq!(larger(1.2, 0.9), 1.2);
        assert!(larger(f64::NAN, 2.0).is_nan() && larger(2.0, f64::NAN).is_nan());
    }
}
