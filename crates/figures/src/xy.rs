//! Line and scatter plots: benchmark figures, theory curves, campaign time series.

use plotters::coord::Shift;
use plotters::coord::ranged1d::{
    AsRangedCoord, DefaultFormatting, KeyPointHint, KeyPointWeight, Ranged, ValueFormatter,
};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, VPos};

use crate::FigureError;
use crate::error::plot_err;
use crate::render::{Content, Figure};
use crate::style::{LABEL_SIZE, LEGEND_SIZE, TICK_SIZE, series_colour, text, text_at};
use crate::util::{fmt_count, fmt_fixed, fmt_num, tick_decimals, widen_zero_range};

/// Scale of a plot axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AxisScale {
    /// Linear axis, range = data range + 5 %.
    #[default]
    Linear,
    /// Base-10 logarithmic axis, range rounded out to whole decades; values ≤ 0 cannot be
    /// drawn and are counted in the legend.
    Log10,
    /// Linear axis of whole numbers (frame numbers, counts): ticks only at integers.
    Integer,
    /// Linear axis whose range includes 0 (magnitudes), so that small differences between
    /// values look as small as they are.
    FromZero,
}

impl AxisScale {
    fn is_log(self) -> bool {
        self == AxisScale::Log10
    }
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SeriesStyle {
    /// Points joined by a line, in the given order.
    Line,
    /// Markers only (a scatter plot).
    Points,
    /// A line with a marker on every point.
    #[default]
    LinePoints,
}

/// One series of an [`XyPlot`]; non-finite points are skipped (and counted in the legend).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct XySeries {
    /// Legend label (e.g. the estimator or model name).
    pub label: String,
    /// `(x, y)` points, in drawing order.
    pub points: Vec<(f64, f64)>,
    /// Line, markers or both.
    pub style: SeriesStyle,
}

/// A horizontal reference line (e.g. `RMS / bound = 1`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RefLine {
    /// Its y value.
    pub y: f64,
    /// Text written at its right end.
    pub label: String,
}

/// A line or scatter plot: one panel with axes, series and a legend.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct XyPlot {
    /// Title of the figure ([`xy_plot`]) or caption of the panel ([`xy_panels`]).
    pub title: String,
    /// x-axis label with unit, e.g. `"time per dot (µs)"`.
    pub x_label: String,
    /// y-axis label with unit.
    pub y_label: String,
    /// Scale of the x axis.
    pub x_scale: AxisScale,
    /// Scale of the y axis.
    pub y_scale: AxisScale,
    /// The series, drawn in order with colours blue, orange, green, red, purple, …
    pub series: Vec<XySeries>,
    /// Horizontal reference lines, drawn dashed grey.
    pub ref_lines: Vec<RefLine>,
}

/// One row of a campaign: the medians over the valid dots of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CampaignRow {
    /// Frame index.
    pub frame: usize,
    /// Median `|d|` (px); NaN leaves a gap.
    pub median_d: f64,
    /// Median displacement uncertainty `|u_d|` (px, 1σ); NaN leaves a gap.
    pub median_u: f64,
}

#[derive(Debug, Clone)]
struct Panel {
    caption: Option<String>,
    plot: XyPlot,
    /// Per series: points dropped (non-finite or ≤ 0 on a log axis).
    dropped: Vec<usize>,
    x_range: (f64, f64),
    y_range: (f64, f64),
}

#[derive(Debug, Clone)]
pub(crate) struct PanelsFigure {
    panels: Vec<Panel>,
}

/// A single line/scatter plot (benchmark figures such as error against time per dot on a log
/// x axis, theory curves such as the CRLB against f-number).
///
/// Errors: [`FigureError::NoData`] when no series has a drawable point,
/// [`FigureError::InvalidInput`] for a non-finite reference line.
pub fn xy_plot(plot: &XyPlot) -> Result<Figure, FigureError> {
    let panel = make_panel(plot, false)?;
    Ok(Figure::new(
        900,
        620,
        plot.title.clone(),
        Content::Panels(PanelsFigure {
            panels: vec![panel],
        }),
    ))
}

/// Most panels [`xy_panels`] stacks.
const MAX_PANELS: usize = 8;

/// Several plots (1–8) stacked vertically under one title (each `XyPlot::title` becomes its
/// panel's caption), 330 px per panel. Every panel must have a drawable point.
pub fn xy_panels(title: &str, panels: &[XyPlot]) -> Result<Figure, FigureError> {
    if panels.is_empty() || panels.len() > MAX_PANELS {
        return Err(FigureError::invalid(
            title,
            format!("{} panels (1–{MAX_PANELS} allowed)", panels.len()),
        ));
    }
    let panels = panels
        .iter()
        .map(|p| make_panel(p, true))
        .collect::<Result<Vec<_>, _>>()?;
    let h = 80 + 330 * panels.len() as u32;
    Ok(Figure::new(
        900,
        h.min(4000),
        title.to_string(),
        Content::Panels(PanelsFigure { panels }),
    ))
}

/// Campaign summary: median `|d|` (top panel) and median `|u_d|` (bottom panel) against the
/// frame index, one point per frame.
pub fn campaign_figure(title: &str, rows: &[CampaignRow]) -> Result<Figure, FigureError> {
    if rows.is_empty() {
        return Err(FigureError::no_data(title, "no frames"));
    }
    let series = |label: &str, f: fn(&CampaignRow) -> f64| XySeries {
        label: label.to_string(),
        points: rows.iter().map(|r| (r.frame as f64, f(r))).collect(),
        style: SeriesStyle::LinePoints,
    };
    let top = XyPlot {
        title: "Median displacement magnitude".to_string(),
        x_label: "frame index".to_string(),
        y_label: "median |d| (px)".to_string(),
        x_scale: AxisScale::Integer,
        y_scale: AxisScale::FromZero,
        series: vec![series("median |d| over valid dots", |r| r.median_d)],
        ..XyPlot::default()
    };
    let bottom = XyPlot {
        title: "Median displacement uncertainty".to_string(),
        x_label: "frame index".to_string(),
        y_label: "median |u_d| (px, 1σ)".to_string(),
        x_scale: AxisScale::Integer,
        y_scale: AxisScale::FromZero,
        series: vec![series("median |u_d| over valid dots", |r| r.median_u)],
        ..XyPlot::default()
    };
    xy_panels(title, &[top, bottom])
}

fn drawable(v: f64, scale: AxisScale) -> bool {
    v.is_finite() && (!scale.is_log() || v > 0.0)
}

fn axis_range(values: impl Iterator<Item = f64>, scale: AxisScale) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return None;
    }
    Some(match scale {
        AxisScale::Linear | AxisScale::Integer => {
            let (lo, hi) = widen_zero_range(lo, hi);
            let pad = 0.05 * (hi - lo);
            (lo - pad, hi + pad)
        }
        AxisScale::FromZero => {
            let (lo, hi) = widen_zero_range(lo.min(0.0), hi.max(0.0));
            let pad = 0.05 * (hi - lo);
            (
                if lo < 0.0 { lo - pad } else { lo },
                if hi > 0.0 { hi + pad } else { hi },
            )
        }
        AxisScale::Log10 => {
            let (a, b) = (lo.log10(), hi.log10());
            let (a, b) = if b > a { (a, b) } else { (a - 0.5, b + 0.5) };
            let pad = 0.05 * (b - a);
            (10f64.powf(a - pad), 10f64.powf(b + pad))
        }
    })
}

/// How many ticks to ask for on an axis: `most`, and on an [`AxisScale::Integer`] axis no more
/// than there are whole numbers in its range (so that the step is at least 1).
fn tick_count(scale: AxisScale, (lo, hi): (f64, f64), most: usize) -> usize {
    if scale == AxisScale::Integer {
        let whole = (hi.floor() - lo.ceil() + 1.0).max(1.0);
        (whole as usize).clamp(1, most)
    } else {
        most
    }
}

/// The tick labels of an axis: significant figures on a log axis, whole numbers only on an
/// [`AxisScale::Integer`] axis (a tick between two is left unlabelled), else fixed decimals
/// suited to the range.
fn tick_format(scale: AxisScale, (lo, hi): (f64, f64), ticks: usize) -> impl Fn(&f64) -> String {
    let dec = tick_decimals(lo, hi, ticks);
    move |v: &f64| match scale {
        AxisScale::Log10 => fmt_num(*v),
        AxisScale::Integer if (v - v.round()).abs() > 1e-9 * v.abs().max(1.0) => String::new(),
        AxisScale::Integer => fmt_fixed(v.round(), 0),
        _ => fmt_fixed(*v, dec),
    }
}

fn make_panel(plot: &XyPlot, caption: bool) -> Result<Panel, FigureError> {
    let what = plot.title.as_str();
    for r in &plot.ref_lines {
        if !r.y.is_finite() {
            return Err(FigureError::invalid(
                what,
                format!("reference line at y = {}", r.y),
            ));
        }
    }
    let ok = |&(x, y): &(f64, f64)| drawable(x, plot.x_scale) && drawable(y, plot.y_scale);
    let pts = || {
        plot.series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(ok)
    };
    if pts().next().is_none() {
        return Err(FigureError::no_data(
            what,
            "no finite point (or none > 0 on a log axis)",
        ));
    }
    let x_range = axis_range(pts().map(|p| p.0), plot.x_scale)
        .ok_or_else(|| FigureError::no_data(what, "no finite x"))?;
    let ref_ys = plot
        .ref_lines
        .iter()
        .map(|r| r.y)
        .filter(|&y| drawable(y, plot.y_scale));
    let y_range = axis_range(pts().map(|p| p.1).chain(ref_ys), plot.y_scale)
        .ok_or_else(|| FigureError::no_data(what, "no finite y"))?;
    let dropped = plot
        .series
        .iter()
        .map(|s| s.points.iter().filter(|p| !ok(p)).count())
        .collect();
    Ok(Panel {
        caption: caption.then(|| plot.title.clone()),
        plot: plot.clone(),
        dropped,
        x_range,
        y_range,
    })
}

impl PanelsFigure {
    pub(crate) fn draw<DB: DrawingBackend>(
        &self,
        body: &DrawingArea<DB, Shift>,
    ) -> Result<(), FigureError>
    where
        DB::ErrorType: 'static,
    {
        let areas = body.split_evenly((self.panels.len(), 1));
        for (p, a) in self.panels.iter().zip(areas.iter()) {
            p.draw(a)?;
        }
        Ok(())
    }
}

impl Panel {
    /// The corner of the plot whose 40 % × 35 % box holds the fewest points (upper right wins
    /// ties), so the legend hides as little data as possible.
    fn legend_corner(&self) -> SeriesLabelPosition {
        let norm = |v: f64, (a, b): (f64, f64), s: AxisScale| match s {
            AxisScale::Log10 => (v.log10() - a.log10()) / (b.log10() - a.log10()),
            _ => (v - a) / (b - a),
        };
        let p = &self.plot;
        let ok = |&(x, y): &(f64, f64)| drawable(x, p.x_scale) && drawable(y, p.y_scale);
        let pts: Vec<(f64, f64)> = p
            .series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(ok)
            .map(|(x, y)| {
                (
                    norm(x, self.x_range, p.x_scale),
                    norm(y, self.y_range, p.y_scale),
                )
            })
            .collect();
        let count = |right: bool, upper: bool| {
            pts.iter()
                .filter(|(u, v)| {
                    (if right { *u > 0.6 } else { *u < 0.4 })
                        && (if upper { *v > 0.65 } else { *v < 0.35 })
                })
                .count()
        };
        [
            (SeriesLabelPosition::UpperRight, count(true, true)),
            (SeriesLabelPosition::UpperLeft, count(false, true)),
            (SeriesLabelPosition::LowerRight, count(true, false)),
            (SeriesLabelPosition::LowerLeft, count(false, false)),
        ]
        .into_iter()
        .min_by_key(|(_, n)| *n)
        .map(|(c, _)| c)
        .unwrap_or(SeriesLabelPosition::UpperRight)
    }

    /// Points within the right (or left) 30 % of the plot and 10 % of its height around `y`.
    fn crowded_near(&self, y: f64, right: bool) -> usize {
        let norm = |v: f64, (a, b): (f64, f64), s: AxisScale| match s {
            AxisScale::Log10 => (v.log10() - a.log10()) / (b.log10() - a.log10()),
            _ => (v - a) / (b - a),
        };
        let p = &self.plot;
        let vy = norm(y, self.y_range, p.y_scale);
        p.series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(|&(x, y)| drawable(x, p.x_scale) && drawable(y, p.y_scale))
            .filter(|&(x, yy)| {
                let u = norm(x, self.x_range, p.x_scale);
                let v = norm(yy, self.y_range, p.y_scale);
                (if right { u > 0.7 } else { u < 0.3 }) && (v - vy).abs() < 0.1
            })
            .count()
    }

    fn draw<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<(), FigureError>
    where
        DB::ErrorType: 'static,
    {
        let area = match &self.caption {
            Some(c) => {
                let (w, _) = area.dim_in_pixel();
                let (top, rest) = area.split_vertically(28);
                top.draw_text(
                    c,
                    &text_at(LABEL_SIZE, HPos::Center, VPos::Center),
                    ((w / 2) as i32, 16),
                )
                .map_err(plot_err)?;
                rest
            }
            None => area.clone(),
        };
        let (x0, x1) = self.x_range;
        let (y0, y1) = self.y_range;
        match (self.plot.x_scale.is_log(), self.plot.y_scale.is_log()) {
            (false, false) => self.draw_on(&area, x0..x1, y0..y1),
            (true, false) => self.draw_on(&area, LogAxis::new(x0, x1), y0..y1),
            (false, true) => self.draw_on(&area, x0..x1, LogAxis::new(y0, y1)),
            (true, true) => self.draw_on(&area, LogAxis::new(x0, x1), LogAxis::new(y0, y1)),
        }
    }

    fn draw_on<DB, XR, YR>(
        &self,
        area: &DrawingArea<DB, Shift>,
        xr: XR,
        yr: YR,
    ) -> Result<(), FigureError>
    where
        DB: DrawingBackend,
        DB::ErrorType: 'static,
        XR: AsRangedCoord<Value = f64>,
        YR: AsRangedCoord<Value = f64>,
        XR::CoordDescType: ValueFormatter<f64>,
        YR::CoordDescType: ValueFormatter<f64>,
    {
        let plot = &self.plot;
        let mut chart = ChartBuilder::on(area)
            .margin_left(10)
            .margin_right(28)
            .margin_top(8)
            .margin_bottom(6)
            .set_label_area_size(LabelAreaPosition::Left, 80)
            .set_label_area_size(LabelAreaPosition::Bottom, 52)
            .build_cartesian_2d(xr, yr)
            .map_err(plot_err)?;
        let xf = tick_format(plot.x_scale, self.x_range, 10);
        let yf = tick_format(plot.y_scale, self.y_range, 8);
        chart
            .configure_mesh()
            .light_line_style(BLACK.mix(0.04))
            .bold_line_style(BLACK.mix(0.12))
            .x_labels(tick_count(plot.x_scale, self.x_range, 10))
            .y_labels(tick_count(plot.y_scale, self.y_range, 8))
            .x_label_formatter(&xf)
            .y_label_formatter(&yf)
            .label_style(text(TICK_SIZE))
            .x_desc(plot.x_label.as_str())
            .y_desc(plot.y_label.as_str())
            .axis_desc_style(text(LABEL_SIZE))
            .draw()
            .map_err(plot_err)?;

        let ok = |&(x, y): &(f64, f64)| drawable(x, plot.x_scale) && drawable(y, plot.y_scale);
        for r in &plot.ref_lines {
            if !drawable(r.y, plot.y_scale) {
                continue;
            }
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(self.x_range.0, r.y), (self.x_range.1, r.y)],
                    6,
                    4,
                    RGBColor(100, 100, 100).stroke_width(1),
                ))
                .map_err(plot_err)?;
            // label at the end of the line with fewer points near it
            let (x_at, hpos) = if self.crowded_near(r.y, true) > self.crowded_near(r.y, false) {
                (self.x_range.0, HPos::Left)
            } else {
                (self.x_range.1, HPos::Right)
            };
            chart
                .draw_series(std::iter::once(Text::new(
                    format!(" {} ", r.label),
                    (x_at, r.y),
                    text_at(TICK_SIZE, hpos, VPos::Bottom),
                )))
                .map_err(plot_err)?;
        }

        for (i, s) in plot.series.iter().enumerate() {
            let c = series_colour(i);
            // split at dropped points so gaps stay gaps
            let mut runs: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
            for p in &s.points {
                if ok(p) {
                    if let Some(r) = runs.last_mut() {
                        r.push(*p);
                    }
                } else if runs.last().is_some_and(|r| !r.is_empty()) {
                    runs.push(Vec::new());
                }
            }
            let mut label = s.label.clone();
            if self.dropped[i] > 0 {
                let n = self.dropped[i];
                let what = if n == 1 { "point" } else { "points" };
                label.push_str(&format!(" ({} {what} not drawable)", fmt_count(n)));
            }
            let style = s.style;
            if matches!(style, SeriesStyle::Line | SeriesStyle::LinePoints) {
                for run in runs.iter().filter(|r| r.len() > 1) {
                    chart
                        .draw_series(LineSeries::new(run.iter().copied(), c.stroke_width(2)))
                        .map_err(plot_err)?;
                }
            }
            let markers = matches!(style, SeriesStyle::Points | SeriesStyle::LinePoints);
            // every point of a Line series that has no neighbour still shows as a marker
            let anno = chart
                .draw_series(
                    runs.iter()
                        .filter(|r| markers || r.len() == 1)
                        .flat_map(|r| r.iter().copied())
                        .map(move |p| Circle::new(p, 4, c.filled())),
                )
                .map_err(plot_err)?;
            let has_line = matches!(style, SeriesStyle::Line | SeriesStyle::LinePoints);
            let line_c = if has_line { c.to_rgba() } else { TRANSPARENT };
            let mark_c = if markers { c.to_rgba() } else { TRANSPARENT };
            anno.label(label).legend(move |(x, y)| {
                EmptyElement::at((x, y))
                    + PathElement::new(vec![(-2, 0), (22, 0)], line_c.stroke_width(2))
                    + Circle::new((10, 0), 4, mark_c.filled())
            });
        }
        chart
            .configure_series_labels()
            .position(self.legend_corner())
            .margin(10)
            .legend_area_size(30)
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK.mix(0.5))
            .label_font(text(LEGEND_SIZE))
            .draw()
            .map_err(plot_err)?;
        Ok(())
    }
}

/// A base-10 logarithmic axis `lo..hi` (both > 0) with ticks at 1·10^k when the range spans
/// many decades, at 1, 2, 5·10^k when that gives too few, and at 1…9·10^k for light grid
/// lines. (plotters' own log axis puts no tick below the first power of ten in range.)
#[derive(Debug, Clone)]
struct LogAxis {
    lo: f64,
    hi: f64,
}

impl LogAxis {
    fn new(lo: f64, hi: f64) -> Self {
        Self { lo, hi }
    }

    /// The values `m·10^k` in range for the mantissas `ms`, every `stride`-th decade.
    fn ticks(&self, ms: &[f64], stride: i32) -> Vec<f64> {
        let (k0, k1) = (
            self.lo.log10().floor() as i32,
            self.hi.log10().ceil() as i32,
        );
        let mut out = Vec::new();
        for k in k0..=k1 {
            if stride > 1 && k.rem_euclid(stride) != 0 {
                continue;
            }
            for &m in ms {
                // build 10^k by exponent so 0.1, 0.01 print exactly
                let v = m * 10f64.powi(k);
                if v >= self.lo * (1.0 - 1e-12) && v <= self.hi * (1.0 + 1e-12) {
                    out.push(v);
                }
            }
        }
        out
    }
}

impl Ranged for LogAxis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let t = (value.log10() - self.lo.log10()) / (self.hi.log10() - self.lo.log10());
        let p = limit.0 as f64 + t * (limit.1 - limit.0) as f64;
        // `as` saturates, and maps NaN (value ≤ 0) to 0: no panic
        p.round() as i32
    }

    fn key_points<H: KeyPointHint>(&self, hint: H) -> Vec<f64> {
        let max = hint.max_num_points().max(1);
        let all: Vec<f64> = (1..=9).map(f64::from).collect();
        let sets: [&[f64]; 3] = [&[1.0], &[1.0, 2.0, 5.0], &all];
        if matches!(hint.weight(), KeyPointWeight::Any) {
            // light lines: the finest set that fits
            for ms in sets.iter().rev() {
                let t = self.ticks(ms, 1);
                if t.len() <= max {
                    return t;
                }
            }
        }
        // labels: the coarsest set with at least 3 ticks, thinned to at most `max`
        for ms in sets {
            let t = self.ticks(ms, 1);
            if t.len() >= 3 {
                if t.len() <= max {
                    return t;
                }
                let mut stride = 2;
                loop {
                    let t = self.ticks(&[1.0], stride);
                    if t.len() <= max {
                        return t;
                    }
                    stride += 1;
                }
            }
        }
        self.ticks(&all, 1)
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.lo..self.hi
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_axis_ticks() {
        use plotters::coord::ranged1d::BoldPoints;
        let close = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x / y - 1.0).abs() < 1e-12)
        };
        // 2.5 decades: powers of ten only
        let t = LogAxis::new(0.3, 140.0).key_points(BoldPoints(10));
        assert!(close(&t, &[1.0, 10.0, 100.0]), "{t:?}");
        // less than a decade: 1-2-5 ticks
        let t = LogAxis::new(0.0035, 0.024).key_points(BoldPoints(10));
        assert!(close(&t, &[0.005, 0.01, 0.02]), "{t:?}");
        // 20 decades, at most 8 labels: every third power
        let t = LogAxis::new(1e-10, 1e10).key_points(BoldPoints(8));
        assert!(t.len() <= 8 && t.len() >= 3, "{t:?}");
        // light lines (a plain count is a light-line hint): 1..9 per decade where they fit
        let t = LogAxis::new(1.0, 100.0).key_points(100);
        assert_eq!(t.len(), 19);
        // map: ends of the range to the ends of the pixel range
        let a = LogAxis::new(1.0, 100.0);
        assert_eq!(a.map(&1.0, (0, 200)), 0);
        assert_eq!(a.map(&10.0, (0, 200)), 100);
        assert_eq!(a.map(&100.0, (0, 200)), 200);
        assert_eq!(a.map(&-1.0, (0, 200)), 0, "NaN maps to 0, no panic");
    }

    #[test]
    fn axis_ranges() {
        assert_eq!(
            axis_range([1.0, 3.0].into_iter(), AxisScale::Linear),
            Some((0.9, 3.1))
        );
        let (a, b) = axis_range([1.0, 100.0].into_iter(), AxisScale::Log10).unwrap();
        assert!((a.log10() + 0.1).abs() < 1e-12 && (b.log10() - 2.1).abs() < 1e-12);
        // a single value still gives a non-empty range
        let (a, b) = axis_range([5.0].into_iter(), AxisScale::Linear).unwrap();
        assert!(a < 5.0 && b > 5.0);
        assert_eq!(axis_range(std::iter::empty(), AxisScale::Linear), None);
        // magnitudes that differ by 10 %: from zero, they fill 90 % to 100 % of the axis, not
        // all of it
        let (a, b) = axis_range([0.031, 0.034].into_iter(), AxisScale::FromZero).unwrap();
        assert_eq!(a, 0.0);
        assert!((b - 0.034 * 1.05).abs() < 1e-12, "{b}");
        let (a, b) = axis_range([0.031, 0.034].into_iter(), AxisScale::Linear).unwrap();
        assert!(a > 0.03 && b < 0.035);
    }

    #[test]
    fn integer_axes_label_whole_numbers_only() {
        // three frames: the padded range 0.9..3.1 holds three whole numbers
        let range = axis_range([1.0, 2.0, 3.0].into_iter(), AxisScale::Integer).unwrap();
        assert_eq!(tick_count(AxisScale::Integer, range, 10), 3);
        assert_eq!(tick_count(AxisScale::Linear, range, 10), 10);
        let f = tick_format(AxisScale::Integer, range, 10);
        assert_eq!(
            (f(&1.0), f(&2.0), f(&1.5), f(&2.2)),
            ("1".into(), "2".into(), String::new(), String::new())
        );
        // one frame
        let range = axis_range([7.0].into_iter(), AxisScale::Integer).unwrap();
        assert_eq!(tick_count(AxisScale::Integer, range, 10), 1);
    }
}
