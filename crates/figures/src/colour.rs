//! The colour scale of the maps (viridis) and its colour bar.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, VPos};

use crate::FigureError;
use crate::error::plot_err;
use crate::style::{LABEL_SIZE, TICK_SIZE, text, text_at};
use crate::util::{fmt_fixed, fmt_num, percentile, tick_decimals, widen_zero_range};

/// How the colour scale of a map is bounded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ColourRange {
    /// From the `low`-th to the `high`-th percentile of the valid values (0 ≤ low < high ≤ 100);
    /// values beyond are drawn in the end colours and the colour-bar label says so.
    /// The default is 1st–99th: one outlier does not wash out the map.
    Percentile {
        /// Lower percentile (0–100).
        low: f64,
        /// Upper percentile (0–100).
        high: f64,
    },
    /// Fixed bounds (e.g. the same scale for every frame of a campaign).
    Fixed {
        /// Value drawn in the darkest colour.
        min: f64,
        /// Value drawn in the brightest colour.
        max: f64,
    },
    /// Minimum to maximum of the valid values.
    Full,
}

impl Default for ColourRange {
    fn default() -> Self {
        ColourRange::Percentile {
            low: 1.0,
            high: 99.0,
        }
    }
}

impl ColourRange {
    pub(crate) fn validate(&self, figure: &str) -> Result<(), FigureError> {
        match *self {
            ColourRange::Percentile { low, high } => {
                if !(low.is_finite()
                    && high.is_finite()
                    && 0.0 <= low
                    && low < high
                    && high <= 100.0)
                {
                    return Err(FigureError::invalid(
                        figure,
                        format!(
                            "colour range percentiles {low}..{high} not within 0 ≤ low < high ≤ 100"
                        ),
                    ));
                }
            }
            ColourRange::Fixed { min, max } => {
                if !(min.is_finite() && max.is_finite() && min < max) {
                    return Err(FigureError::invalid(
                        figure,
                        format!("fixed colour range {min}..{max} is not a finite increasing range"),
                    ));
                }
            }
            ColourRange::Full => {}
        }
        Ok(())
    }

    /// Resolves the bounds from the sorted valid values; returns `(min, max, note)` where the
    /// note describes clipping when some values fall outside.
    pub(crate) fn resolve(&self, sorted: &[f64]) -> Option<(f64, f64, Option<String>)> {
        let (&first, &last) = (sorted.first()?, sorted.last()?);
        let (lo, hi, what) = match *self {
            ColourRange::Percentile { low, high } => (
                percentile(sorted, low)?,
                percentile(sorted, high)?,
                format!("{}–{} percentile", ordinal(low), ordinal(high)),
            ),
            ColourRange::Fixed { min, max } => {
                (min, max, format!("[{}, {}]", fmt_num(min), fmt_num(max)))
            }
            ColourRange::Full => (first, last, String::new()),
        };
        let (lo, hi) = widen_zero_range(lo, hi);
        let clipped = first < lo || last > hi;
        let note = clipped.then(|| format!("clipped to {what}"));
        Some((lo, hi, note))
    }
}

fn ordinal(p: f64) -> String {
    if p.fract() != 0.0 {
        return format!("{}th", fmt_num(p));
    }
    let n = p as u64;
    let suffix = match (n % 10, n % 100) {
        (1, r) if r != 11 => "st",
        (2, r) if r != 12 => "nd",
        (3, r) if r != 13 => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

/// A linear colour scale `[min, max]` → viridis, clamped at both ends.
#[derive(Debug, Clone)]
pub(crate) struct Scale {
    pub min: f64,
    pub max: f64,
    /// Colour-bar label, e.g. "|d| (px)".
    pub label: String,
    /// "clipped to 1st–99th percentile" when some values lie outside.
    pub note: Option<String>,
}

impl Scale {
    pub(crate) fn colour(&self, v: f64) -> RGBColor {
        let t = ((v - self.min) / (self.max - self.min)).clamp(0.0, 1.0);
        viridis(t)
    }
}

pub(crate) fn viridis(t: f64) -> RGBColor {
    ViridisRGB.get_color(t.clamp(0.0, 1.0) as f32)
}

/// Width of the colour-bar panel (px) at least; wider where the tick labels need it
/// ([`bar_panel_width`]).
const BAR_PANEL_W: u32 = 150;
const BAR_GAP: u32 = 14;
const BAR_W: u32 = 24;
/// Length of the tick marks; plotters draws the tick labels at twice that from the bar.
const TICK_MARK: u32 = 6;
/// Gap between the widest tick label and the bar's label, and after the last line of text.
const LABEL_GAP: u32 = 8;
const N_STEPS: usize = 128;
const N_LABELS: usize = 7;

/// Half the thickness of a line of upright text of font `size` (px): its centre's distance from
/// its edges.
fn half_line(size: f64) -> u32 {
    (0.6 * size).ceil() as u32
}

impl Scale {
    /// The tick values plotters places on the bar and their labels (one number of decimals for
    /// all, from the step).
    fn tick_labels(&self) -> Vec<String> {
        use plotters::coord::ranged1d::Ranged;
        use plotters::coord::types::RangedCoordf64;
        let dec = tick_decimals(self.min, self.max, N_LABELS);
        RangedCoordf64::from(self.min..self.max)
            .key_points(N_LABELS)
            .into_iter()
            .map(|v| fmt_fixed(v, dec))
            .collect()
    }

    /// Room right of the bar for the tick marks and the widest tick label (px), measured with
    /// the font they are drawn in.
    fn tick_width(&self) -> u32 {
        let font = text(TICK_SIZE).font;
        let widest = self
            .tick_labels()
            .iter()
            .map(|l| {
                font.box_size(l)
                    .map_or(9 * l.chars().count() as u32, |(w, _)| w)
            })
            .max()
            .unwrap_or(0);
        2 * TICK_MARK + widest + 2
    }

    /// Centres (x from the panel's left edge) of the upright label and of the clipping note:
    /// right of the widest tick label, so that they never overlap it.
    fn label_x(&self) -> (u32, u32) {
        let label = BAR_GAP + BAR_W + self.tick_width() + LABEL_GAP + half_line(LABEL_SIZE);
        let note = label + half_line(LABEL_SIZE) + 4 + half_line(TICK_SIZE);
        (label, note)
    }
}

/// Width of the colour-bar panel of `scale` (px): [`BAR_PANEL_W`], or more where long tick
/// labels push the label and the note further right.
pub(crate) fn bar_panel_width(scale: Option<&Scale>) -> u32 {
    let Some(scale) = scale else {
        return BAR_PANEL_W;
    };
    let (label, note) = scale.label_x();
    let right = if scale.note.is_some() {
        note + half_line(TICK_SIZE)
    } else {
        label + half_line(LABEL_SIZE)
    };
    (right + LABEL_GAP).max(BAR_PANEL_W)
}

/// Draws a vertical colour bar into `area` (whose height is the height of the bar): a stack of
/// `N_STEPS` filled rectangles, ticks and tick labels on the right, then the label (quantity
/// and unit) and the clipping note, rotated to read upwards. `scale = None` writes
/// "no valid values" instead.
pub(crate) fn draw_colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    scale: Option<&Scale>,
) -> Result<(), FigureError>
where
    DB::ErrorType: 'static,
{
    let (_, h) = area.dim_in_pixel();
    let up = |size| text_at(size, HPos::Center, VPos::Center).transform(FontTransform::Rotate270);
    let Some(scale) = scale else {
        area.draw_text(
            "no valid values",
            &up(LABEL_SIZE),
            ((BAR_GAP + BAR_W / 2) as i32, (h / 2) as i32),
        )
        .map_err(plot_err)?;
        return Ok(());
    };
    let tick_w = scale.tick_width();
    let bar_area = area.clone().shrink((BAR_GAP, 0), (BAR_W + tick_w, h));
    let mut chart = ChartBuilder::on(&bar_area)
        .set_label_area_size(LabelAreaPosition::Right, tick_w)
        .build_cartesian_2d(0.0..1.0, scale.min..scale.max)
        .map_err(plot_err)?;
    let step = (scale.max - scale.min) / N_STEPS as f64;
    chart
        .draw_series((0..N_STEPS).map(|i| {
            let v0 = scale.min + i as f64 * step;
            let c = scale.colour(v0 + 0.5 * step);
            Rectangle::new([(0.0, v0), (1.0, v0 + step)], c.filled())
        }))
        .map_err(plot_err)?;
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(0.0, scale.min), (1.0, scale.max)],
            BLACK.stroke_width(1),
        )))
        .map_err(plot_err)?;
    let dec = tick_decimals(scale.min, scale.max, N_LABELS);
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .set_tick_mark_size(LabelAreaPosition::Right, TICK_MARK as i32)
        .y_labels(N_LABELS)
        .y_label_style(text(TICK_SIZE))
        .y_label_formatter(&|v| fmt_fixed(*v, dec))
        .draw()
        .map_err(plot_err)?;
    let (x_label, x_note) = scale.label_x();
    draw_fitted_upright(area, &scale.label, LABEL_SIZE, x_label as i32, h)?;
    if let Some(note) = &scale.note {
        draw_fitted_upright(area, &format!("({note})"), TICK_SIZE, x_note as i32, h)?;
    }
    Ok(())
}

/// Writes `s` rotated to read upwards, centred at `(x, h/2)`, shrinking the font until it fits
/// the height `h`.
fn draw_fitted_upright<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    s: &str,
    size: f64,
    x: i32,
    h: u32,
) -> Result<(), FigureError>
where
    DB::ErrorType: 'static,
{
    let mut size = size;
    while size > 8.0 {
        let (tw, _) = area.estimate_text_size(s, &text(size)).map_err(plot_err)?;
        if tw + 10 <= h {
            break;
        }
        size -= 1.0;
    }
    area.draw_text(
        s,
        &text_at(size, HPos::Center, VPos::Center).transform(FontTransform::Rotate270),
        (x, (h / 2) as i32),
    )
    .map_err(plot_err)
}

#[cfg(test)]
mod tests {
    use super::*;
    use plotters::backend::BitMapBackend;

    /// The columns of a colour bar panel with any dark pixel right of the bar.
    fn inked_columns(scale: &Scale, h: u32) -> Vec<bool> {
        crate::font::ensure_font().unwrap();
        let w = bar_panel_width(Some(scale));
        let mut buf = vec![255u8; (w * h * 3) as usize];
        {
            let area = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            draw_colour_bar(&area, Some(scale)).unwrap();
            area.present().unwrap();
        }
        (0..w)
            .map(|x| {
                x > BAR_GAP + BAR_W + 1
                    && (0..h).any(|y| {
                        let p = ((y * w + x) * 3) as usize;
                        buf[p..p + 3].iter().all(|&c| c < 128)
                    })
            })
            .collect()
    }

    /// Long tick labels (a density uncertainty of 2 × 10⁻³ kg/m³ varying in the sixth decimal)
    /// push the bar's label and note right: no column holds ink of both the tick labels and the
    /// label, and the panel is wide enough for all of it.
    #[test]
    fn the_label_never_overlaps_long_tick_labels() {
        for (min, max) in [
            (0.002, 0.0020027),
            (1.2035, 1.2041),
            (-0.00012, 0.00031),
            (0.0, 3.0),
        ] {
            let label = "Density uncertainty u_ρ (1σ) (kg/m³)".to_string();
            let with = Scale {
                min,
                max,
                label: label.clone(),
                note: Some("clipped to 1st–99th percentile".into()),
            };
            let ticks_only = Scale {
                label: String::new(),
                note: None,
                ..with.clone()
            };
            let h = 500;
            let (all, ticks) = (inked_columns(&with, h), inked_columns(&ticks_only, h));
            // the label's and note's columns: inked with them, blank without
            let last_tick = ticks.iter().rposition(|&c| c).unwrap();
            let first_label = all
                .iter()
                .zip(ticks.iter().chain(std::iter::repeat(&false)))
                .position(|(&a, &t)| a && !t)
                .unwrap();
            assert!(
                first_label > last_tick + 2,
                "{min}..{max}: tick labels end at column {last_tick}, the label starts at {first_label}"
            );
            assert!(
                !all[all.len() - 1],
                "{min}..{max}: text reaches the panel's edge"
            );
        }
    }
}
