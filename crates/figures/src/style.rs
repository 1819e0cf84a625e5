//! Shared look: fonts, sizes, series colours, the title.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::FigureError;
use crate::error::plot_err;
use crate::font::FAMILY;

/// Title band height (px).
pub(crate) const TITLE_H: u32 = 44;
pub(crate) const TITLE_SIZE: f64 = 22.0;
pub(crate) const LABEL_SIZE: f64 = 17.0;
pub(crate) const TICK_SIZE: f64 = 14.0;
pub(crate) const LEGEND_SIZE: f64 = 14.0;

/// Qualitative series colours (blue, orange, green, red, purple, brown, pink, grey, olive,
/// cyan), distinguishable in print and by most colour-blind readers for the first few.
pub(crate) const SERIES: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

pub(crate) fn series_colour(i: usize) -> RGBColor {
    SERIES[i % SERIES.len()]
}

pub(crate) fn font(size: f64) -> FontDesc<'static> {
    FontDesc::new(FontFamily::Name(FAMILY), size, FontStyle::Normal)
}

pub(crate) fn text(size: f64) -> TextStyle<'static> {
    TextStyle::from(font(size)).color(&BLACK)
}

pub(crate) fn text_at(size: f64, h: HPos, v: VPos) -> TextStyle<'static> {
    text(size).pos(Pos::new(h, v))
}

/// Draws the title centred in a band at the top; returns the area below it.
pub(crate) fn draw_title<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
) -> Result<DrawingArea<DB, Shift>, FigureError>
where
    DB::ErrorType: 'static,
{
    let (w, _) = root.dim_in_pixel();
    let (top, body) = root.split_vertically(TITLE_H);
    // shrink the font until the title fits the width
    let mut size = TITLE_SIZE;
    while size > 10.0 {
        let (tw, _) = top
            .estimate_text_size(title, &text(size))
            .map_err(plot_err)?;
        if tw + 20 <= w {
            break;
        }
        size -= 1.0;
    }
    top.draw_text(
        title,
        &text_at(size, HPos::Center, VPos::Center),
        ((w / 2) as i32, (TITLE_H / 2) as i32 + 2),
    )
    .map_err(plot_err)?;
    Ok(body)
}
