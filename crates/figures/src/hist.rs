//! Histograms: several series on shared bins (u_ref and u_grad, max(AR_x, AR_y)).

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::FigureError;
use crate::error::plot_err;
use crate::map::Quantity;
use crate::render::{Content, Figure};
use crate::style::{LABEL_SIZE, LEGEND_SIZE, TICK_SIZE, series_colour, text};
use crate::util::{
    fmt_count, fmt_fixed, fmt_num, percentile, sorted_finite, tick_decimals, widen_zero_range,
};

/// One histogram series: a legend label and its values (non-finite values are counted in the
/// legend, not binned).
#[derive(Debug, Clone, Copy)]
pub struct HistSeries<'a> {
    /// Legend label, e.g. `"u_ref"`.
    pub label: &'a str,
    /// The values.
    pub values: &'a [f64],
}

/// Options of [`histogram`]. `HistOptions::default()`: automatic bins and range, no markers.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HistOptions {
    /// Number of bins (1–1000). `None`: Freedman–Diaconis width `2·IQR·n^(-1/3)` on the pooled
    /// values in range, clamped to 10–80 bins.
    pub bins: Option<usize>,
    /// Axis range. `None`: 0.5th to 99.5th percentile of the pooled finite values, starting at 0
    /// when all values are ≥ 0 and the lower percentile is within 25 % of the span from 0.
    /// Values outside are counted in the legend ("k beyond axis").
    pub range: Option<(f64, f64)>,
    /// Vertical reference lines `(x, label)`, drawn dotted grey (e.g. AR = 1).
    pub markers: Vec<(f64, String)>,
}

#[derive(Debug, Clone)]
struct Binned {
    label: String,
    counts: Vec<u64>,
    n_finite: usize,
    non_finite: usize,
    beyond: usize,
    median: Option<f64>,
}

#[derive(Debug, Clone)]
pub(crate) struct HistFigure {
    x_label: String,
    unit: String,
    lo: f64,
    hi: f64,
    series: Vec<Binned>,
    markers: Vec<(f64, String)>,
}

/// Histogram of one or more series on the same bins and axes, with a legend giving each
/// series' count and median (dashed vertical line in the series colour).
///
/// Errors: [`FigureError::NoData`] when no series has a finite value,
/// [`FigureError::InvalidInput`] for no series, a bad bin count or range.
pub fn histogram(
    title: &str,
    quantity: &Quantity<'_>,
    series: &[HistSeries<'_>],
    options: &HistOptions,
) -> Result<Figure, FigureError> {
    if series.is_empty() {
        return Err(FigureError::invalid(title, "no series"));
    }
    if let Some(b) = options.bins
        && !(1..=1000).contains(&b)
    {
        return Err(FigureError::invalid(
            title,
            format!("{b} bins (1–1000 allowed)"),
        ));
    }
    if let Some((lo, hi)) = options.range
        && !(lo.is_finite() && hi.is_finite() && lo < hi)
    {
        return Err(FigureError::invalid(
            title,
            format!("range {lo}..{hi} is not finite and increasing"),
        ));
    }
    let pooled = sorted_finite(series.iter().flat_map(|s| s.values.iter().copied()));
    if pooled.is_empty() {
        return Err(FigureError::no_data(title, "no finite value in any series"));
    }
    let (lo, hi) = match options.range {
        Some(r) => r,
        None => {
            let lo = percentile(&pooled, 0.5).unwrap_or(pooled[0]);
            let hi = percentile(&pooled, 99.5).unwrap_or(pooled[pooled.len() - 1]);
            let lo = if pooled[0] >= 0.0 && lo <= 0.25 * (hi - lo) {
                0.0
            } else {
                lo
            };
            widen_zero_range(lo, hi)
        }
    };
    let nb = match options.bins {
        Some(b) => b,
        None => {
            let inside: Vec<f64> = pooled
                .iter()
                .copied()
                .filter(|v| (lo..=hi).contains(v))
                .collect();
            let iqr =
                percentile(&inside, 75.0).unwrap_or(0.0) - percentile(&inside, 25.0).unwrap_or(0.0);
            if iqr > 0.0 {
                let bw = 2.0 * iqr * (inside.len() as f64).powf(-1.0 / 3.0);
                ((hi - lo) / bw).ceil().clamp(10.0, 80.0) as usize
            } else {
                30
            }
        }
    };
    let bw = (hi - lo) / nb as f64;
    let binned = series
        .iter()
        .map(|s| {
            let mut counts = vec![0u64; nb];
            let mut beyond = 0;
            for &v in s.values.iter().filter(|v| v.is_finite()) {
                if v < lo || v > hi {
                    beyond += 1;
                } else {
                    let k = (((v - lo) / bw) as usize).min(nb - 1);
                    counts[k] += 1;
                }
            }
            let mut finite = sorted_finite(s.values.iter().copied());
            let median = bostrack_core::median(&mut finite);
            Binned {
                label: s.label.to_string(),
                counts,
                n_finite: finite.len(),
                non_finite: s.values.len() - finite.len(),
                beyond,
                median: (!median.is_nan()).then_some(median),
            }
        })
        .collect();
    let fig = HistFigure {
        x_label: quantity.label(),
        unit: quantity.unit.to_string(),
        lo,
        hi,
        series: binned,
        markers: options.markers.clone(),
    };
    Ok(Figure::new(900, 620, title.to_string(), Content::Hist(fig)))
}

/// Histograms of the reference and gradient position uncertainties of one frame on the same
/// axes (the paper's Fig. 6c,f), in px. Pass one value per dot: the norm of its two axes,
/// `|u| = √(u_x² + u_y²)` (the figure says so: it is √2 times the per-axis value of a round
/// dot).
pub fn uncertainty_histogram(
    u_ref: &[f64],
    u_grad: &[f64],
    frame_title: &str,
) -> Result<Figure, FigureError> {
    histogram(
        &format!("Position uncertainty — {frame_title}"),
        &Quantity {
            name: "|u| = √(u_x² + u_y²), 1σ",
            unit: "px",
        },
        &[
            HistSeries {
                label: "|u_ref| (reference image)",
                values: u_ref,
            },
            HistSeries {
                label: "|u_grad| (gradient image)",
                values: u_grad,
            },
        ],
        &HistOptions::default(),
    )
}

/// Histogram of the amplification ratio of one frame as the larger of its two axes,
/// `max(AR_x, AR_y)` (1: no amplification), with a reference line at 1.
pub fn ar_histogram(ar: &[f64], frame_title: &str) -> Result<Figure, FigureError> {
    histogram(
        &format!("Amplification ratio — {frame_title}"),
        &Quantity {
            name: "max(AR_x, AR_y)",
            unit: "",
        },
        &[HistSeries {
            label: "max(AR_x, AR_y)",
            values: ar,
        }],
        &HistOptions {
            markers: vec![(1.0, "1: no amplification".to_string())],
            ..HistOptions::default()
        },
    )
}

impl HistFigure {
    pub(crate) fn draw<DB: DrawingBackend>(
        &self,
        body: &DrawingArea<DB, Shift>,
    ) -> Result<(), FigureError>
    where
        DB::ErrorType: 'static,
    {
        let nb = self.series[0].counts.len();
        let bw = (self.hi - self.lo) / nb as f64;
        let ymax = self
            .series
            .iter()
            .flat_map(|s| s.counts.iter().copied())
            .max()
            .unwrap_or(0)
            .max(1) as f64;
        // headroom for the legend
        let ytop = ymax * (1.12 + 0.07 * self.series.len() as f64);
        let mut chart = ChartBuilder::on(body)
            .margin_left(10)
            .margin_right(24)
            .margin_top(6)
            .margin_bottom(8)
            .set_label_area_size(LabelAreaPosition::Left, 74)
            .set_label_area_size(LabelAreaPosition::Bottom, 52)
            .build_cartesian_2d(self.lo..self.hi, 0.0..ytop)
            .map_err(plot_err)?;
        let dec = tick_decimals(self.lo, self.hi, 10);
        chart
            .configure_mesh()
            .light_line_style(WHITE.mix(0.0))
            .bold_line_style(BLACK.mix(0.08))
            .x_labels(10)
            .y_labels(8)
            .x_label_formatter(&|v| fmt_fixed(*v, dec))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .label_style(text(TICK_SIZE))
            .x_desc(self.x_label.as_str())
            .y_desc("number of dots per bin")
            .axis_desc_style(text(LABEL_SIZE))
            .draw()
            .map_err(plot_err)?;

        // all fills first, so no fill veils another series' outline
        for (i, s) in self.series.iter().enumerate() {
            let c = series_colour(i);
            chart
                .draw_series(
                    s.counts
                        .iter()
                        .enumerate()
                        .filter(|(_, n)| **n > 0)
                        .map(|(k, &n)| {
                            let x0 = self.lo + k as f64 * bw;
                            Rectangle::new([(x0, 0.0), (x0 + bw, n as f64)], c.mix(0.25).filled())
                        }),
                )
                .map_err(plot_err)?;
        }
        for (i, s) in self.series.iter().enumerate() {
            let c = series_colour(i);
            // step outline from the first to the last non-empty bin
            let first = s.counts.iter().position(|&n| n > 0);
            let last = s.counts.iter().rposition(|&n| n > 0);
            let mut step = Vec::with_capacity(2 * nb + 2);
            if let (Some(a), Some(b)) = (first, last) {
                step.push((self.lo + a as f64 * bw, 0.0));
                for k in a..=b {
                    let x0 = self.lo + k as f64 * bw;
                    step.push((x0, s.counts[k] as f64));
                    step.push((x0 + bw, s.counts[k] as f64));
                }
                step.push((self.lo + (b + 1) as f64 * bw, 0.0));
            }
            let mut label = format!("{}: n = {}", s.label, fmt_count(s.n_finite));
            if let Some(m) = s.median {
                let unit = if self.unit.is_empty() {
                    String::new()
                } else {
                    format!(" {}", self.unit)
                };
                label.push_str(&format!(", median {}{unit}", fmt_num(m)));
            }
            if s.beyond > 0 {
                label.push_str(&format!(", {} beyond axis", fmt_count(s.beyond)));
            }
            if s.non_finite > 0 {
                label.push_str(&format!(", {} non-finite", fmt_count(s.non_finite)));
            }
            chart
                .draw_series(LineSeries::new(step, c.stroke_width(2)))
                .map_err(plot_err)?
                .label(label)
                .legend(move |(x, y)| {
                    Rectangle::new(
                        [(x, y - 6), (x + 16, y + 6)],
                        ShapeStyle::from(c.mix(0.5)).filled(),
                    )
                });
        }
        for (i, s) in self.series.iter().enumerate() {
            if let Some(m) = s.median.filter(|m| (self.lo..=self.hi).contains(m)) {
                chart
                    .draw_series(DashedLineSeries::new(
                        vec![(m, 0.0), (m, ymax * 1.05)],
                        8,
                        5,
                        series_colour(i).stroke_width(2),
                    ))
                    .map_err(plot_err)?;
            }
        }
        if self
            .series
            .iter()
            .any(|s| s.median.is_some_and(|m| (self.lo..=self.hi).contains(&m)))
        {
            // legend entry for the dashed medians (an empty series carries it)
            chart
                .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
                .map_err(plot_err)?
                .label("dashed line: median")
                .legend(|(x, y)| {
                    EmptyElement::at((x, y))
                        + PathElement::new(vec![(0, 0), (5, 0)], BLACK.stroke_width(2))
                        + PathElement::new(vec![(9, 0), (14, 0)], BLACK.stroke_width(2))
                });
        }
        for (x, label) in &self.markers {
            if (self.lo..=self.hi).contains(x) {
                chart
                    .draw_series(DashedLineSeries::new(
                        vec![(*x, 0.0), (*x, ymax * 1.05)],
                        3,
                        3,
                        RGBColor(90, 90, 90).stroke_width(1),
                    ))
                    .map_err(plot_err)?;
                chart
                    .draw_series(std::iter::once(Text::new(
                        label.clone(),
                        (*x, ymax * 1.07),
                        text(TICK_SIZE),
                    )))
                    .map_err(plot_err)?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .margin(10)
            .legend_area_size(22)
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK.mix(0.5))
            .label_font(text(LEGEND_SIZE))
            .draw()
            .map_err(plot_err)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hist_of(fig: &Figure) -> &HistFigure {
        match fig.content() {
            Content::Hist(h) => h,
            _ => panic!("not a histogram"),
        }
    }

    #[test]
    fn counts_per_bin_and_beyond() {
        // 0, 1, …, 99 into 10 bins over [0, 100): 10 per bin; 150 and -1 beyond
        let mut v: Vec<f64> = (0..100).map(f64::from).collect();
        v.extend([150.0, -1.0, f64::NAN]);
        let fig = histogram(
            "t",
            &Quantity {
                name: "q",
                unit: "",
            },
            &[HistSeries {
                label: "s",
                values: &v,
            }],
            &HistOptions {
                bins: Some(10),
                range: Some((0.0, 100.0)),
                ..HistOptions::default()
            },
        )
        .unwrap();
        let h = hist_of(&fig);
        let s = &h.series[0];
        assert_eq!(s.counts, vec![10; 10]);
        assert_eq!((s.beyond, s.non_finite, s.n_finite), (2, 1, 102));
        // 102 finite values: the median is the mean of the 51st and 52nd (49 and 50)
        assert_eq!(s.median, Some(49.5));
    }

    #[test]
    fn automatic_range_and_bins() {
        // uniform 1..=1000: percentiles 0.5 / 99.5 → 5.995 / 995.005, lower end moved to 0
        // (within 25 % of the span); Freedman–Diaconis: 2·IQR·n^(-1/3) ≈ 99.9 → 10 bins
        let v: Vec<f64> = (1..=1000).map(f64::from).collect();
        let fig = ar_histogram(&v, "t").unwrap();
        let h = hist_of(&fig);
        assert_eq!(h.lo, 0.0);
        assert!((h.hi - 995.005).abs() < 1e-9, "{}", h.hi);
        assert_eq!(h.series[0].counts.len(), 10);
        let total: u64 = h.series[0].counts.iter().sum();
        assert_eq!(total as usize + h.series[0].beyond, 1000);
    }
}
