//! Tables (CSV, Markdown) and figures of the studies. Everything writes to an `impl Write`
//! or returns an in-memory figure; the caller opens the files.

use crate::PaperError;
use crate::ar::ArResult;
use crate::config::Rendering;
use crate::study::{DrawRow, StudyResult};
use bostrack_figures::{Figure, SeriesStyle, XyPlot, XySeries, xy_plot};
use serde::Serialize;
use std::io::Write;

/// Significant digits of the floating-point values in the CSV files (the Monte Carlo's own
/// relative error is ~1e-2; six digits keep the files reviewable).
const SIGNIFICANT: usize = 6;

/// A floating-point field rounded to [`SIGNIFICANT`] digits, in the shortest form that reads
/// back to the rounded value; `None` for integers, booleans, flags and NaN (kept as written).
fn round_field(field: &str) -> Option<String> {
    if !(field.contains('.') || field.contains('e')) {
        return None;
    }
    let v: f64 = field.parse().ok()?;
    let r: f64 = format!("{:.*e}", SIGNIFICANT - 1, v).parse().ok()?;
    Some(r.to_string())
}

fn write_csv<T: Serialize>(
    what: &'static str,
    rows: &[T],
    w: impl Write,
) -> Result<(), PaperError> {
    let csv_err = |source| PaperError::Csv { what, source };
    let mut raw = csv::Writer::from_writer(Vec::new());
    for r in rows {
        raw.serialize(r).map_err(csv_err)?;
    }
    let raw = raw.into_inner().map_err(|e| PaperError::Io {
        what,
        source: e.into_error(),
    })?;
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(false)
        .from_reader(raw.as_slice());
    let mut wtr = csv::Writer::from_writer(w);
    for rec in rdr.records() {
        let rec = rec.map_err(csv_err)?;
        let out: Vec<String> = rec
            .iter()
            .map(|f| round_field(f).unwrap_or_else(|| f.to_string()))
            .collect();
        wtr.write_record(&out).map_err(csv_err)?;
    }
    wtr.flush()
        .map_err(|source| PaperError::Io { what, source })
}

/// One line per draw ([`DrawRow`]'s fields as columns, `NaN` where a value does not exist:
/// see the field docs); floating-point values to six significant digits.
pub fn write_draws_csv(rows: &[DrawRow], w: impl Write) -> Result<(), PaperError> {
    write_csv("draws", rows, w)
}

/// One line per gradient dot of the amplification-ratio study (six significant digits).
pub fn write_ar_csv(result: &ArResult, w: impl Write) -> Result<(), PaperError> {
    write_csv("amplification ratio", &result.rows, w)
}

/// Human name of a rendering.
pub fn rendering_label(r: Rendering) -> String {
    match r {
        Rendering::RayTraced { rays } => format!("ray-traced ({rays} rays)"),
        Rendering::EffectiveModel => "effective model".to_string(),
    }
}

/// Three decimals, or scientific notation below 0.001.
fn short(v: f64) -> String {
    if v != 0.0 && v.abs() < 1e-3 {
        format!("{v:.1e}")
    } else {
        format!("{v:.3}")
    }
}

/// A Markdown table of the studies' group summaries: one line per study and group.
pub fn write_study_markdown(results: &[&StudyResult], mut w: impl Write) -> Result<(), PaperError> {
    let io = |source| PaperError::Io {
        what: "study table",
        source,
    };
    writeln!(
        w,
        "| study | rendering | group | draws | σ (px) | max blur σ (px) | max blur σ / σ_ref | non-Gaussian draws | MC std (px) | Eq. 35 (px) | MC − Eq. 35 (px): mean ± s.e. (median) | MC / bound − 1: median (median \\|·\\|) | (MC / bound)²: mean ± s.e. | fits (singular) | failures |"
    )
    .map_err(io)?;
    writeln!(
        w,
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    .map_err(io)?;
    for r in results {
        for g in &r.groups {
            writeln!(
                w,
                "| {} | {} | {} | {} | {:.3}-{:.3} | {} | {} | {} | {:.4} | {:.4} | {:+.4} ± {:.4} ({:+.4}) | {:+.3} ({:.3}) | {:.3} ± {:.3} | {} ({}) | {} |",
                r.config.name,
                rendering_label(r.config.rendering),
                g.label,
                g.draws,
                g.sigma_min,
                g.sigma_max,
                short(g.blur_max),
                short(g.blur_over_ref_max),
                g.non_gaussian,
                g.mc_std_mean,
                g.eq35_mean,
                g.offset_eq35_mean,
                g.offset_eq35_se,
                g.offset_eq35_median,
                g.bound_rel_median,
                g.bound_abs_rel_median,
                g.var_ratio_mean,
                g.var_ratio_se,
                g.fits,
                g.singular,
                g.failures,
            )
            .map_err(io)?;
        }
    }
    Ok(())
}

/// A Markdown table of the amplification-ratio formulas against the Monte Carlo.
pub fn write_ar_markdown(result: &ArResult, mut w: impl Write) -> Result<(), PaperError> {
    let io = |source| PaperError::Io {
        what: "amplification-ratio table",
        source,
    };
    writeln!(
        w,
        "| formula | vs Monte Carlo: median \\|rel. error\\| | mean rel. error ± s.e. | max \\|rel. error\\| | vs ratio of exact bounds: median \\|rel. error\\| | max |"
    )
    .map_err(io)?;
    writeln!(w, "|---|---|---|---|---|---|").map_err(io)?;
    for f in &result.formulas {
        writeln!(
            w,
            "| {} | {:.4} | {:+.4} ± {:.4} | {:.4} | {:.5} | {:.5} |",
            f.formula,
            f.mc_abs_rel_median,
            f.mc_rel_mean,
            f.mc_rel_se,
            f.mc_abs_rel_max,
            f.bound_abs_rel_median,
            f.bound_abs_rel_max
        )
        .map_err(io)?;
    }
    Ok(())
}

fn identity_line(lo: f64, hi: f64) -> XySeries {
    XySeries {
        label: "y = x".into(),
        points: vec![(lo, lo), (hi, hi)],
        style: SeriesStyle::Line,
    }
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        })
}

/// The paper's Fig. 5 for a study: the Monte Carlo standard deviation of the position error
/// against Eq. 35 (the paper's model) and against the exact bound, x and y pooled, with the
/// line y = x.
pub fn fig5_figure(result: &StudyResult) -> Result<Figure, PaperError> {
    let pts = |f: fn(&DrawRow) -> [(f64, f64); 2]| -> Vec<(f64, f64)> {
        result.rows.iter().flat_map(f).collect()
    };
    let eq35 = pts(|r| [(r.eq35_x, r.std_x), (r.eq35_y, r.std_y)]);
    let bound = pts(|r| [(r.bound_x, r.std_x), (r.bound_y, r.std_y)]);
    let (lo, hi) = range(eq35.iter().chain(&bound).flat_map(|p| [p.0, p.1]));
    let plot = XyPlot {
        title: format!(
            "{}: position scatter vs prediction ({} draws × {} realisations, {})",
            result.config.name,
            result.config.draws,
            result.config.realisations,
            rendering_label(result.config.rendering)
        ),
        x_label: "predicted standard deviation (px)".into(),
        y_label: "Monte Carlo standard deviation (px)".into(),
        series: vec![
            XySeries {
                label: "Eq. 35 (the paper's model)".into(),
                points: eq35,
                style: SeriesStyle::Points,
            },
            XySeries {
                label: "exact bound of the fitted noise-free dot".into(),
                points: bound,
                style: SeriesStyle::Points,
            },
            identity_line(lo, hi),
        ],
        ..XyPlot::default()
    };
    xy_plot(&plot).map_err(|source| PaperError::Figure {
        what: "fig5",
        source,
    })
}

/// The amplification ratio: each formula against the measured ratio of Monte Carlo
/// standard deviations, x and y pooled, with the line y = x.
pub fn ar_figure(result: &ArResult) -> Result<Figure, PaperError> {
    let pts = |f: fn(&crate::ar::ArRow) -> [(f64, f64); 2]| -> Vec<(f64, f64)> {
        result.rows.iter().flat_map(f).collect()
    };
    let notes = pts(|r| [(r.ar_mc_x, r.ar_notes_x), (r.ar_mc_y, r.ar_notes_y)]);
    let published = pts(|r| [(r.ar_mc_x, r.ar_published_x), (r.ar_mc_y, r.ar_published_y)]);
    let pixel = pts(|r| [(r.ar_mc_x, r.ar_pixel_x), (r.ar_mc_y, r.ar_pixel_y)]);
    let (lo, hi) = range(
        notes
            .iter()
            .chain(&published)
            .chain(&pixel)
            .flat_map(|p| [p.0, p.1]),
    );
    let plot = XyPlot {
        title: format!(
            "Amplification ratio: formulas vs Monte Carlo ({} realisations per dot)",
            result.config.realisations
        ),
        x_label: "measured AR (ratio of Monte Carlo standard deviations)".into(),
        y_label: "AR from the fitted shapes".into(),
        series: vec![
            XySeries {
                label: "NOTES.md §2".into(),
                points: notes,
                style: SeriesStyle::Points,
            },
            XySeries {
                label: "published variant".into(),
                points: published,
                style: SeriesStyle::Points,
            },
            XySeries {
                label: "NOTES.md §2 on pixel-blurred shapes".into(),
                points: pixel,
                style: SeriesStyle::Points,
            },
            identity_line(lo, hi),
        ],
        ..XyPlot::default()
    };
    xy_plot(&plot).map_err(|source| PaperError::Figure {
        what: "amplification ratio",
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_are_rounded_to_six_digits() {
        assert_eq!(
            round_field("0.041992517247561924").as_deref(),
            Some("0.0419925")
        );
        assert_eq!(
            round_field("10616.327026808409").as_deref(),
            Some("10616.3")
        );
        assert_eq!(
            round_field("2.728066552881714e-6").as_deref(),
            Some("0.00000272807")
        );
        assert_eq!(round_field("NaN"), None);
        assert_eq!(round_field("1000"), None);
        assert_eq!(round_field("true"), None);
        assert_eq!(round_field("non_gaussian|undersampled"), None);
    }
}
