//! Per-frame maps: displacement field (arrows over |d|), and scalar maps (max(AR_x, AR_y), uncertainty).

use bostrack_core::Mask;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, VPos};

use crate::FigureError;
use crate::colour::{ColourRange, Scale, bar_panel_width, draw_colour_bar, viridis};
use crate::error::plot_err;
use crate::render::{Content, Figure};
use crate::style::{LABEL_SIZE, LEGEND_SIZE, TICK_SIZE, TITLE_H, text, text_at};
use crate::util::{
    fmt_count, fmt_fixed, fmt_num, nice_floor, percentile, sorted_finite, tick_decimals,
};

/// One dot of a per-frame map, in image coordinates (px, origin at the centre of the top-left
/// pixel, x right, y down; docs/CONVENTIONS.md).
///
/// The figure functions read the fields they need: [`displacement_map`] draws arrows from
/// `(dx, dy)` and colours the dot by `|d| = √(dx² + dy²)` (it ignores `value`); the scalar maps
/// ([`ar_map`], [`uncertainty_map`], [`scalar_map`]) colour by `value` (they ignore `dx, dy`).
///
/// A dot is drawn in colour when `valid && in_mask` and its plotted quantity is finite; a dot
/// with `!in_mask` as a grey hollow circle ("outside mask"); a dot inside the mask that is not
/// valid, or whose quantity is not finite, as a red cross ("invalid"). Dots without a finite
/// position cannot be placed; the legend counts them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    /// Dot position x (px), usually the reference position.
    pub x: f64,
    /// Dot position y (px, down).
    pub y: f64,
    /// Displacement x = x_grad − x_ref (px).
    pub dx: f64,
    /// Displacement y = y_grad − y_ref (px).
    pub dy: f64,
    /// The scalar of a scalar map (max(AR_x, AR_y), |u_d|, …).
    pub value: f64,
    /// The dot's fit and match are usable (status ok, no disqualifying flag).
    pub valid: bool,
    /// The dot lies in the kept region of the mask.
    pub in_mask: bool,
}

impl MapPoint {
    /// A dot of a scalar map (`dx = dy = 0`).
    pub fn scalar(x: f64, y: f64, value: f64, valid: bool, in_mask: bool) -> Self {
        Self {
            x,
            y,
            dx: 0.0,
            dy: 0.0,
            value,
            valid,
            in_mask,
        }
    }

    /// A dot of a displacement map; `value` is set to `|d|`.
    pub fn vector(x: f64, y: f64, dx: f64, dy: f64, valid: bool, in_mask: bool) -> Self {
        Self {
            x,
            y,
            dx,
            dy,
            value: dx.hypot(dy),
            valid,
            in_mask,
        }
    }
}

/// The frame a map belongs to.
#[derive(Debug, Clone, Copy)]
pub struct MapFrame<'a> {
    /// Image width (px); the x axis spans the pixels `0..width`.
    pub width: usize,
    /// Image height (px); the y axis spans `0..height`, pointing down.
    pub height: usize,
    /// Names the frame in the title, e.g. `"frame 3 (grad_0003.tif)"`.
    pub title: &'a str,
    /// When given, the excluded region is shaded light grey under the dots (the mask is
    /// downsampled to at most 256 blocks per side; a block is shaded when most of its pixels
    /// are excluded). Must have the frame's size.
    pub mask: Option<&'a Mask>,
}

/// Options of the map figures. `MapOptions::default()`: 1st–99th percentile colour range,
/// automatic arrow scale, at most 900 arrows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapOptions {
    /// Bounds of the colour scale.
    pub range: ColourRange,
    /// Displacement map only: arrow length = `arrow_scale · |d|` (image px per px). `None`
    /// picks the largest 1-2-5 number for which the 95th-percentile arrow is at most 0.9 of the
    /// arrow spacing. The legend states the scale and a reference arrow.
    pub arrow_scale: Option<f64>,
    /// Displacement map only: at most this many arrows. With more valid dots, the image is cut
    /// into square cells of side `√(area / max_arrows)` and the dot nearest each cell's centre
    /// carries the arrow; every dot keeps its colour.
    pub max_arrows: usize,
}

impl Default for MapOptions {
    fn default() -> Self {
        Self {
            range: ColourRange::default(),
            arrow_scale: None,
            max_arrows: 900,
        }
    }
}

/// Which uncertainty a [`uncertainty_map`] shows (the caller fills `MapPoint::value` with it;
/// this only names it in the title and colour bar).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UncertaintyComponent {
    /// `|u_d| = √(u_d,x² + u_d,y²)`, with `u_d = √(u_ref² + u_grad²)` per axis
    /// (docs/CONVENTIONS.md).
    Magnitude,
    /// `u_d,x` (px).
    X,
    /// `u_d,y` (px).
    Y,
}

/// A named quantity with its unit, for axis and colour-bar labels: `"name (unit)"`, or
/// `"name"` when `unit` is empty.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Quantity<'a> {
    /// Symbol or name, e.g. `"u_ref"`.
    pub name: &'a str,
    /// Unit, e.g. `"px"`; empty for a dimensionless quantity.
    pub unit: &'a str,
}

impl Quantity<'_> {
    pub(crate) fn label(&self) -> String {
        if self.unit.is_empty() {
            self.name.to_string()
        } else {
            format!("{} ({})", self.name, self.unit)
        }
    }
}

/// Displacement field of one frame: an arrow per dot (or per cell when subsampled, see
/// [`MapOptions::max_arrows`]) from the dot's position, `arrow_scale · (dx, dy)` long, over the
/// dots coloured by `|d| = √(dx² + dy²)` (viridis, colour bar in px).
///
/// Errors: [`FigureError::NoData`] when no dot has a finite position,
/// [`FigureError::InvalidInput`] for a zero image size, a mask of another size or bad options.
/// A frame whose dots are all invalid still gives a figure (every dot marked, "no valid values"
/// in place of the colour bar).
pub fn displacement_map(
    points: &[MapPoint],
    frame: &MapFrame<'_>,
    options: &MapOptions,
) -> Result<Figure, FigureError> {
    let title = format!("Displacement field — {}", frame.title);
    let q = Quantity {
        name: "|d|",
        unit: "px",
    };
    build_map(
        points,
        frame,
        options,
        &title,
        &q,
        "|d| = √(dx² + dy²)",
        true,
    )
}

/// Map of the amplification ratio per dot as the larger of its two axes,
/// `AR_max = max(AR_x, AR_y)` (AR per axis from `bostrack_model::amplification_ratio`; the
/// paper's Fig. 6b,e): 1 where the gradient image does not amplify the position uncertainty,
/// whatever the axis. `MapPoint::value` holds `AR_max`. Errors as [`displacement_map`].
pub fn ar_map(
    points: &[MapPoint],
    frame: &MapFrame<'_>,
    options: &MapOptions,
) -> Result<Figure, FigureError> {
    let title = format!("Amplification ratio max(AR_x, AR_y) — {}", frame.title);
    let q = Quantity {
        name: "max(AR_x, AR_y)",
        unit: "",
    };
    build_map(
        points,
        frame,
        options,
        &title,
        &q,
        "max(AR_x, AR_y), 1 = no amplification",
        false,
    )
}

/// Map of the displacement uncertainty (1σ, px); `MapPoint::value` holds the component named
/// by `component`. Errors as [`displacement_map`].
pub fn uncertainty_map(
    points: &[MapPoint],
    frame: &MapFrame<'_>,
    component: UncertaintyComponent,
    options: &MapOptions,
) -> Result<Figure, FigureError> {
    let (name, definition) = match component {
        UncertaintyComponent::Magnitude => ("|u_d|", "|u_d| = √(u_d,x² + u_d,y²)"),
        UncertaintyComponent::X => ("u_d,x", "u_d,x (x component)"),
        UncertaintyComponent::Y => ("u_d,y", "u_d,y (y component)"),
    };
    let title = format!("Displacement uncertainty {name} (1σ) — {}", frame.title);
    let q = Quantity { name, unit: "px" };
    build_map(points, frame, options, &title, &q, definition, false)
}

/// Map of any per-dot scalar (`MapPoint::value`), e.g. `u_ref` or a fit residual; the title
/// reads `"{quantity.name} — {frame.title}"`. Errors as [`displacement_map`].
pub fn scalar_map(
    points: &[MapPoint],
    frame: &MapFrame<'_>,
    quantity: &Quantity<'_>,
    options: &MapOptions,
) -> Result<Figure, FigureError> {
    let title = format!("{} — {}", quantity.name, frame.title);
    build_map(
        points,
        frame,
        options,
        &title,
        quantity,
        quantity.name,
        false,
    )
}

/// Everything a map needs at draw time, in image coordinates.
#[derive(Debug, Clone)]
pub(crate) struct MapFigure {
    img_w: f64,
    img_h: f64,
    /// Coloured dots: x, y, colour.
    dots: Vec<(f64, f64, RGBColor)>,
    outside: Vec<(f64, f64)>,
    invalid: Vec<(f64, f64)>,
    unplaced: usize,
    /// Typical dot spacing (image px), sets the marker size.
    spacing: f64,
    scale: Option<Scale>,
    /// Width of the colour-bar panel (px), from the scale's tick labels.
    bar_w: u32,
    arrows: Option<Arrows>,
    /// Excluded mask region: rectangles `[x0, y0, x1, y1]` in image coordinates.
    mask_rects: Vec<[f64; 4]>,
    /// The quantity as named in the legend (with its definition).
    legend_name: String,
}

#[derive(Debug, Clone)]
struct Arrows {
    list: Vec<[f64; 4]>,
    /// Arrow length per px of displacement.
    scale: f64,
    /// `Some((n, cell))` when subsampled from `n` valid dots on square cells of side `cell` px.
    subsampled_from: Option<(usize, f64)>,
}

/// Left and bottom label areas, margins and legend height of a map (px).
const Y_LABEL_W: u32 = 72;
const X_LABEL_H: u32 = 52;
const MARGIN: u32 = 10;
/// The legend: first text x, line height and the padding around its lines (px); its height is
/// [`MapFigure::legend_height`].
const LEGEND_X: i32 = 14;
const LEGEND_LINE_H: i32 = 24;
const LEGEND_PAD: u32 = 14;
/// Default plot height (px) of a map.
const PLOT_H: f64 = 700.0;

fn build_map(
    points: &[MapPoint],
    frame: &MapFrame<'_>,
    options: &MapOptions,
    title: &str,
    quantity: &Quantity<'_>,
    definition: &str,
    vector: bool,
) -> Result<Figure, FigureError> {
    // the layout (colour-bar panel, legend) measures text with the font
    crate::font::ensure_font()?;
    // errors name the figure and the frame
    let what = title;
    if frame.width == 0 || frame.height == 0 {
        return Err(FigureError::invalid(
            what,
            format!("image size {}×{} px", frame.width, frame.height),
        ));
    }
    options.range.validate(what)?;
    if options.max_arrows == 0 {
        return Err(FigureError::invalid(what, "max_arrows must be at least 1"));
    }
    if let Some(s) = options.arrow_scale
        && !(s.is_finite() && s > 0.0)
    {
        return Err(FigureError::invalid(
            what,
            format!("arrow scale {s} is not finite and > 0"),
        ));
    }
    if points.is_empty() {
        return Err(FigureError::no_data(what, "no dots"));
    }
    let (w, h) = (frame.width as f64, frame.height as f64);
    let mask_rects = match frame.mask {
        Some(m) => {
            if m.width() != frame.width || m.height() != frame.height {
                return Err(FigureError::invalid(
                    what,
                    format!(
                        "mask is {}×{} px, image {}×{} px",
                        m.width(),
                        m.height(),
                        frame.width,
                        frame.height
                    ),
                ));
            }
            mask_rectangles(m)
        }
        None => Vec::new(),
    };

    let quantity_of = |p: &MapPoint| if vector { p.dx.hypot(p.dy) } else { p.value };
    let placed = |p: &MapPoint| p.x.is_finite() && p.y.is_finite();
    let is_valid = |p: &MapPoint| placed(p) && p.in_mask && p.valid && quantity_of(p).is_finite();

    let n_placed = points.iter().filter(|p| placed(p)).count();
    if n_placed == 0 {
        return Err(FigureError::no_data(what, "no dot has a finite position"));
    }
    let sorted = sorted_finite(points.iter().filter(|p| is_valid(p)).map(quantity_of));
    let scale = options
        .range
        .resolve(&sorted)
        .map(|(min, max, note)| Scale {
            min,
            max,
            label: quantity.label(),
            note,
        });

    let spacing = typical_spacing(points.iter().filter(|p| placed(p)), n_placed, w, h);

    let mut dots = Vec::with_capacity(sorted.len());
    let mut outside = Vec::new();
    let mut invalid = Vec::new();
    for p in points.iter().filter(|p| placed(p)) {
        if !p.in_mask {
            outside.push((p.x, p.y));
        } else if is_valid(p) {
            let c = match &scale {
                Some(s) => s.colour(quantity_of(p)),
                None => viridis(0.5),
            };
            dots.push((p.x, p.y, c));
        } else {
            invalid.push((p.x, p.y));
        }
    }

    let arrows = if vector {
        let valid: Vec<&MapPoint> = points.iter().filter(|p| is_valid(p)).collect();
        make_arrows(&valid, options, spacing, w, h)
    } else {
        None
    };

    // default size keeps the image aspect ratio in the plot area
    let (mut pw, mut ph) = (PLOT_H * w / h, PLOT_H);
    if pw > 1200.0 {
        (pw, ph) = (1200.0, 1200.0 * h / w);
    } else if pw < 300.0 {
        (pw, ph) = (300.0, (300.0 * h / w).min(1400.0));
    }
    let bar_w = bar_panel_width(scale.as_ref());
    let fig_w = Y_LABEL_W + pw.round() as u32 + bar_w + 2 * MARGIN;
    let map = MapFigure {
        img_w: w,
        img_h: h,
        dots,
        outside,
        invalid,
        unplaced: points.len() - n_placed,
        spacing,
        scale,
        bar_w,
        arrows,
        mask_rects,
        legend_name: definition.to_string(),
    };
    let legend_h = map.legend_height(fig_w.max(200));
    let fig_h = TITLE_H + MARGIN + ph.round().max(100.0) as u32 + X_LABEL_H + legend_h;
    Ok(Figure::new(
        fig_w.max(200),
        fig_h.max(200),
        title.to_string(),
        Content::Map(Box::new(map)),
    ))
}

/// `√(bounding-box area / n)`: the lattice pitch for dots that fill their bounding box.
fn typical_spacing<'a>(pts: impl Iterator<Item = &'a MapPoint>, n: usize, w: f64, h: f64) -> f64 {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        x0 = x0.min(p.x);
        x1 = x1.max(p.x);
        y0 = y0.min(p.y);
        y1 = y1.max(p.y);
    }
    let area = (x1 - x0).max(0.0) * (y1 - y0).max(0.0);
    let fallback = 0.01 * w.max(h);
    if n < 2 || area <= 0.0 {
        return fallback.max(1.0);
    }
    (area / n as f64).sqrt().clamp(0.5, 0.1 * w.max(h))
}

fn make_arrows(
    valid: &[&MapPoint],
    options: &MapOptions,
    spacing: f64,
    w: f64,
    h: f64,
) -> Option<Arrows> {
    if valid.is_empty() {
        return None;
    }
    let (chosen, pitch, subsampled_from): (Vec<&MapPoint>, f64, Option<(usize, f64)>) =
        if valid.len() <= options.max_arrows {
            (valid.to_vec(), spacing, None)
        } else {
            let cell = (w * h / options.max_arrows as f64).sqrt().max(spacing);
            let nx = (w / cell).ceil().max(1.0) as usize;
            let ny = (h / cell).ceil().max(1.0) as usize;
            let mut best: Vec<Option<(f64, usize)>> = vec![None; nx * ny];
            for (k, p) in valid.iter().enumerate() {
                let fx = ((p.x + 0.5) / cell).floor();
                let fy = ((p.y + 0.5) / cell).floor();
                if fx < 0.0 || fy < 0.0 || fx >= nx as f64 || fy >= ny as f64 {
                    continue;
                }
                let (cx, cy) = ((fx + 0.5) * cell - 0.5, (fy + 0.5) * cell - 0.5);
                let d2 = (p.x - cx).powi(2) + (p.y - cy).powi(2);
                let slot = &mut best[fy as usize * nx + fx as usize];
                if slot.is_none_or(|(b, _)| d2 < b) {
                    *slot = Some((d2, k));
                }
            }
            let chosen: Vec<&MapPoint> = best.iter().flatten().map(|&(_, k)| valid[k]).collect();
            (chosen, cell, Some((valid.len(), cell)))
        };
    let mags = sorted_finite(chosen.iter().map(|p| p.dx.hypot(p.dy)));
    let scale = match options.arrow_scale {
        Some(s) => s,
        None => {
            let p95 = percentile(&mags, 95.0).unwrap_or(0.0);
            if p95 > 0.0 {
                nice_floor(0.9 * pitch / p95)
            } else {
                1.0
            }
        }
    };
    Some(Arrows {
        list: chosen.iter().map(|p| [p.x, p.y, p.dx, p.dy]).collect(),
        scale,
        subsampled_from,
    })
}

/// Excluded region of the mask as row runs of blocks (image coordinates, pixel edges).
fn mask_rectangles(m: &Mask) -> Vec<[f64; 4]> {
    let (w, h) = (m.width(), m.height());
    let b = w.max(h).div_ceil(256).max(1);
    let (nbx, nby) = (w.div_ceil(b), h.div_ceil(b));
    let mut rects = Vec::new();
    for by in 0..nby {
        let ys = by * b..((by + 1) * b).min(h);
        let mut run_start: Option<usize> = None;
        for bx in 0..=nbx {
            let excluded = bx < nbx && {
                let xs = bx * b..((bx + 1) * b).min(w);
                let total = xs.len() * ys.len();
                let kept: usize = ys
                    .clone()
                    .map(|y| xs.clone().filter(|&x| m.keeps(x, y)).count())
                    .sum();
                2 * kept < total
            };
            match (excluded, run_start) {
                (true, None) => run_start = Some(bx),
                (false, Some(s)) => {
                    rects.push([
                        (s * b) as f64 - 0.5,
                        ys.start as f64 - 0.5,
                        ((bx * b).min(w)) as f64 - 0.5,
                        ys.end as f64 - 0.5,
                    ]);
                    run_start = None;
                }
                _ => {}
            }
        }
    }
    rects
}

const MASK_GREY: RGBColor = RGBColor(222, 222, 222);
const OUTSIDE_GREY: RGBColor = RGBColor(130, 130, 130);
const INVALID_RED: RGBColor = RGBColor(220, 30, 30);

impl MapFigure {
    pub(crate) fn draw<DB: DrawingBackend>(
        &self,
        body: &DrawingArea<DB, Shift>,
    ) -> Result<(), FigureError>
    where
        DB::ErrorType: 'static,
    {
        let (bw, bh) = body.dim_in_pixel();
        let avail_w = bw as f64 - (Y_LABEL_W + self.bar_w + 2 * MARGIN) as f64;
        let legend_h = self.legend_height(bw);
        let avail_h = bh as f64 - (MARGIN + X_LABEL_H + legend_h) as f64;
        if avail_w < 50.0 || avail_h < 50.0 {
            return Err(FigureError::invalid(
                "map",
                format!("figure too small ({bw}×{bh} px below the title)"),
            ));
        }
        let aspect = self.img_w / self.img_h;
        let (pw, ph) = if avail_w / avail_h > aspect {
            ((avail_h * aspect).floor(), avail_h.floor())
        } else {
            (avail_w.floor(), (avail_w / aspect).floor())
        };
        let (pw, ph) = (pw.max(1.0) as u32, ph.max(1.0) as u32);
        let total_w = Y_LABEL_W + pw + self.bar_w;
        let x0 = (bw.saturating_sub(total_w)) / 2;
        let y0 = MARGIN + (avail_h as u32 - ph) / 2;
        let chart_area = body
            .clone()
            .shrink((x0, y0), (Y_LABEL_W + pw, ph + X_LABEL_H));
        let bar_area = body
            .clone()
            .shrink((x0 + Y_LABEL_W + pw, y0), (self.bar_w, ph));
        // display px per image px (the same on both axes)
        let zoom = pw as f64 / self.img_w;

        let (w, h) = (self.img_w, self.img_h);
        let mut chart = ChartBuilder::on(&chart_area)
            .set_label_area_size(LabelAreaPosition::Left, Y_LABEL_W)
            .set_label_area_size(LabelAreaPosition::Bottom, X_LABEL_H)
            .build_cartesian_2d(-0.5..w - 0.5, h - 0.5..-0.5)
            .map_err(plot_err)?;
        let xdec = tick_decimals(-0.5, w - 0.5, 8);
        let ydec = tick_decimals(-0.5, h - 0.5, 8);
        chart
            .configure_mesh()
            .disable_mesh()
            .x_labels(8)
            .y_labels(8)
            .x_label_formatter(&|v| fmt_fixed(*v, xdec))
            .y_label_formatter(&|v| fmt_fixed(*v, ydec))
            .label_style(text(TICK_SIZE))
            .x_desc("x (px)")
            .y_desc("y (px, down)")
            .axis_desc_style(text(LABEL_SIZE))
            .draw()
            .map_err(plot_err)?;

        chart
            .draw_series(
                self.mask_rects
                    .iter()
                    .map(|r| Rectangle::new([(r[0], r[1]), (r[2], r[3])], MASK_GREY.filled())),
            )
            .map_err(plot_err)?;
        // squares a little wider than the lattice pitch tile the image without hairline gaps
        // (positional jitter, rounding to output pixels): a continuous-looking map
        let hs = 0.55 * self.spacing + 0.6 / zoom;
        chart
            .draw_series(
                self.dots.iter().map(|&(x, y, c)| {
                    Rectangle::new([(x - hs, y - hs), (x + hs, y + hs)], c.filled())
                }),
            )
            .map_err(plot_err)?;
        let r = ((0.4 * self.spacing * zoom).round() as i32).clamp(2, 8);
        chart
            .draw_series(
                self.outside
                    .iter()
                    .map(|&(x, y)| Circle::new((x, y), r, OUTSIDE_GREY.stroke_width(1))),
            )
            .map_err(plot_err)?;
        chart
            .draw_series(
                self.invalid
                    .iter()
                    .map(|&(x, y)| Cross::new((x, y), r, INVALID_RED.stroke_width(2))),
            )
            .map_err(plot_err)?;
        if let Some(a) = &self.arrows {
            let shapes: Vec<ArrowShape> = a
                .list
                .iter()
                .filter_map(|&[x, y, dx, dy]| arrow_shape(x, y, a.scale * dx, a.scale * dy, zoom))
                .collect();
            // white halo first, then the black arrow, so arrows read on dark and bright colours
            chart
                .draw_series(
                    shapes
                        .iter()
                        .map(|s| PathElement::new(vec![s.tail, s.tip], WHITE.stroke_width(3))),
                )
                .map_err(plot_err)?;
            chart
                .draw_series(shapes.iter().map(|s| {
                    PathElement::new(vec![s.tip, s.left, s.right, s.tip], WHITE.stroke_width(2))
                }))
                .map_err(plot_err)?;
            chart
                .draw_series(
                    shapes
                        .iter()
                        .map(|s| PathElement::new(vec![s.tail, s.base], BLACK.stroke_width(1))),
                )
                .map_err(plot_err)?;
            chart
                .draw_series(
                    shapes
                        .iter()
                        .map(|s| Polygon::new(vec![s.tip, s.left, s.right], BLACK.filled())),
                )
                .map_err(plot_err)?;
        }
        // frame the plot area
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(-0.5, -0.5), (w - 0.5, h - 0.5)],
                BLACK.stroke_width(1),
            )))
            .map_err(plot_err)?;

        draw_colour_bar(&bar_area, self.scale.as_ref())?;

        let legend_area = body.clone().shrink((0, bh - legend_h), (bw, legend_h));
        self.draw_legend(&legend_area, zoom)
    }

    /// The legend's entries in order; `true` starts a new line (the arrow scale). The arrow
    /// scale depends on the display `zoom` (display px per image px).
    fn legend_entries(&self, zoom: f64) -> Vec<(Marker, String, bool)> {
        let mut e = vec![(
            Marker::Square(viridis(0.6)),
            format!(
                "valid dot (n = {}), colour: {}",
                fmt_count(self.dots.len()),
                self.legend_name
            ),
            false,
        )];
        if !self.outside.is_empty() {
            let label = format!("outside mask (n = {})", fmt_count(self.outside.len()));
            e.push((Marker::Ring, label, false));
        }
        if !self.invalid.is_empty() {
            let label = format!("invalid (n = {})", fmt_count(self.invalid.len()));
            e.push((Marker::Cross, label, false));
        }
        if !self.mask_rects.is_empty() {
            e.push((
                Marker::Square(MASK_GREY),
                "masked region".to_string(),
                false,
            ));
        }
        if self.unplaced > 0 {
            let label = format!(
                "{} dots without position not drawn",
                fmt_count(self.unplaced)
            );
            e.push((Marker::None, label, false));
        }
        if let Some(a) = &self.arrows {
            // reference arrow about 50 display px long
            let reference = nice_floor(50.0 / (a.scale * zoom));
            let len = (reference * a.scale * zoom).round() as i32;
            let sub = match a.subsampled_from {
                Some((n, cell)) => format!(
                    "; one arrow per {c}×{c} px cell ({} of {} valid dots)",
                    fmt_count(a.list.len()),
                    fmt_count(n),
                    c = fmt_num(cell.round()),
                ),
                None => String::new(),
            };
            let label = format!(
                "= {} px displacement (arrows drawn ×{}){sub}",
                fmt_num(reference),
                fmt_num(a.scale)
            );
            e.push((Marker::Arrow(len), label, true));
        }
        e
    }

    /// Height (px) of the legend under a figure body `body_w` px wide: as many lines as the
    /// entries take when laid out as [`LegendRow`] does (text measured with the same font; the
    /// zoom, which only changes the arrow's length and scale text, taken at its largest).
    fn legend_height(&self, body_w: u32) -> u32 {
        let avail_w = body_w as f64 - (Y_LABEL_W + self.bar_w + 2 * MARGIN) as f64;
        let zoom = (avail_w / self.img_w).max(1e-6);
        let width = body_w as i32 - 10;
        let (mut x, mut lines) = (LEGEND_X, 1);
        for (marker, label, break_before) in self.legend_entries(zoom) {
            let tw = text(LEGEND_SIZE)
                .font
                .box_size(&label)
                .map_or(8 * label.chars().count() as u32, |(w, _)| w) as i32;
            // a margin for the arrow's length and the font's rounding
            let mw = marker.width().max(60) + 8;
            if break_before || (x > LEGEND_X && x + mw + tw > width) {
                lines += 1;
                x = LEGEND_X;
            }
            x += mw + tw + 26;
        }
        LEGEND_PAD + lines * LEGEND_LINE_H as u32
    }

    fn draw_legend<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        zoom: f64,
    ) -> Result<(), FigureError>
    where
        DB::ErrorType: 'static,
    {
        let (w, _) = area.dim_in_pixel();
        let mut row = LegendRow::new(area, w, LEGEND_X, LEGEND_LINE_H);
        for (marker, label, break_before) in self.legend_entries(zoom) {
            if break_before {
                row.newline();
            }
            row.item(marker, &label)?;
        }
        Ok(())
    }
}

struct ArrowShape {
    tail: (f64, f64),
    base: (f64, f64),
    tip: (f64, f64),
    left: (f64, f64),
    right: (f64, f64),
}

/// An arrow from `(x, y)` along `(ax, ay)` (image px); `None` when shorter than 4 display px.
/// The head is 35 % of the length, at most 9 display px long, and 0.9 × its length wide.
fn arrow_shape(x: f64, y: f64, ax: f64, ay: f64, zoom: f64) -> Option<ArrowShape> {
    let len = ax.hypot(ay);
    if !(len.is_finite() && len * zoom >= 4.0) {
        return None;
    }
    let (ux, uy) = (ax / len, ay / len);
    let head = (0.35 * len).min(9.0 / zoom);
    let half = 0.45 * head;
    let tip = (x + ax, y + ay);
    let base = (tip.0 - head * ux, tip.1 - head * uy);
    Some(ArrowShape {
        tail: (x, y),
        base,
        tip,
        left: (base.0 - half * uy, base.1 + half * ux),
        right: (base.0 + half * uy, base.1 - half * ux),
    })
}

enum Marker {
    Square(RGBColor),
    Ring,
    Cross,
    /// A horizontal arrow of this many px.
    Arrow(i32),
    None,
}

impl Marker {
    /// Width (px) of the marker and the gap before its text.
    fn width(&self) -> i32 {
        match self {
            Marker::Arrow(len) => len + 8,
            Marker::None => 0,
            _ => 18,
        }
    }
}

/// Places legend items left to right, wrapping to a new line.
struct LegendRow<'a, DB: DrawingBackend> {
    area: &'a DrawingArea<DB, Shift>,
    width: u32,
    x: i32,
    y: i32,
    x_start: i32,
    line_h: i32,
}

impl<'a, DB: DrawingBackend> LegendRow<'a, DB>
where
    DB::ErrorType: 'static,
{
    fn new(area: &'a DrawingArea<DB, Shift>, width: u32, x_start: i32, line_h: i32) -> Self {
        Self {
            area,
            width,
            x: x_start,
            y: 4 + line_h / 2,
            x_start,
            line_h,
        }
    }

    fn newline(&mut self) {
        self.x = self.x_start;
        self.y += self.line_h;
    }

    fn item(&mut self, marker: Marker, label: &str) -> Result<(), FigureError> {
        let (tw, _) = self
            .area
            .estimate_text_size(label, &text(LEGEND_SIZE))
            .map_err(plot_err)?;
        let marker_w = marker.width();
        if self.x > self.x_start && self.x + marker_w + tw as i32 > self.width as i32 - 10 {
            self.newline();
        }
        let (x, y) = (self.x, self.y);
        let a = self.area;
        match marker {
            Marker::Square(c) => {
                a.draw(&Rectangle::new([(x, y - 5), (x + 10, y + 5)], c.filled()))
                    .map_err(plot_err)?;
                a.draw(&Rectangle::new(
                    [(x, y - 5), (x + 10, y + 5)],
                    BLACK.stroke_width(1),
                ))
                .map_err(plot_err)?;
            }
            Marker::Ring => a
                .draw(&Circle::new((x + 5, y), 4, OUTSIDE_GREY.stroke_width(1)))
                .map_err(plot_err)?,
            Marker::Cross => a
                .draw(&Cross::new((x + 5, y), 4, INVALID_RED.stroke_width(2)))
                .map_err(plot_err)?,
            Marker::Arrow(len) => {
                let head = 9.min(len / 2).max(3);
                a.draw(&PathElement::new(
                    vec![(x, y), (x + len - head, y)],
                    BLACK.stroke_width(1),
                ))
                .map_err(plot_err)?;
                a.draw(&Polygon::new(
                    vec![
                        (x + len, y),
                        (x + len - head, y - head / 2 - 1),
                        (x + len - head, y + head / 2 + 1),
                    ],
                    BLACK.filled(),
                ))
                .map_err(plot_err)?;
            }
            Marker::None => {}
        }
        a.draw_text(
            label,
            &text_at(LEGEND_SIZE, HPos::Left, VPos::Center),
            (x + marker_w, y),
        )
        .map_err(plot_err)?;
        self.x += marker_w + tw as i32 + 26;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice(n: usize, pitch: f64, d: f64) -> Vec<MapPoint> {
        (0..n * n)
            .map(|k| {
                let (x, y) = ((k % n) as f64 * pitch, (k / n) as f64 * pitch);
                MapPoint::vector(x, y, d, 0.0, true, true)
            })
            .collect()
    }

    #[test]
    fn arrows_are_subsampled_to_at_most_max_arrows() {
        // 110 × 110 dots at 9.3 px on a 1024 px image, limit 900 arrows
        let pts = lattice(110, 9.3, 0.5);
        let valid: Vec<&MapPoint> = pts.iter().collect();
        let o = MapOptions::default();
        let a = make_arrows(&valid, &o, 9.3, 1024.0, 1024.0).unwrap();
        // cells of √(1024²/900) = 34.1 px: 31 × 31 = 961 cells can hold at most 900 + one
        // partial row/column; every full cell holds a dot
        let cells = (1024.0f64 / (1024.0f64 * 1024.0 / 900.0).sqrt()).ceil() as usize;
        assert!(a.list.len() <= cells * cells);
        assert!(a.list.len() >= (cells - 1) * (cells - 1));
        assert_eq!(a.subsampled_from.map(|s| s.0), Some(110 * 110));
        // auto scale: a 1-2-5 number with the 95th-percentile arrow (0.5 px here) between
        // 0.9/2.5 and 0.9 of the cell side
        let cell = a.subsampled_from.unwrap().1;
        let len = a.scale * 0.5;
        assert!(
            len <= 0.9 * cell && len > 0.9 * cell / 2.5,
            "arrow {len} px, cell {cell}"
        );
        assert_eq!(nice_floor(a.scale), a.scale);
    }

    #[test]
    fn few_dots_get_an_arrow_each_and_a_fixed_scale_is_kept() {
        let pts = lattice(10, 10.0, 0.2);
        let valid: Vec<&MapPoint> = pts.iter().collect();
        let o = MapOptions {
            arrow_scale: Some(7.0),
            ..MapOptions::default()
        };
        let a = make_arrows(&valid, &o, 10.0, 100.0, 100.0).unwrap();
        assert_eq!(a.list.len(), 100);
        assert_eq!(a.scale, 7.0);
        assert!(a.subsampled_from.is_none());
    }

    #[test]
    fn mask_band_becomes_one_rectangle_per_block_row() {
        // 100 × 60 image (block = 1 px), rows 20..30 excluded
        let m = Mask::from_fn(100, 60, |_, y| !(20..30).contains(&y));
        let r = mask_rectangles(&m);
        assert_eq!(r.len(), 10);
        for (k, rect) in r.iter().enumerate() {
            assert_eq!(*rect, [-0.5, 19.5 + k as f64, 99.5, 20.5 + k as f64]);
        }
        // large image: blocks of 4 px (1024 / 256), excluded region 100..200 in x
        let m = Mask::from_fn(1024, 1024, |x, _| !(100..200).contains(&x));
        let r = mask_rectangles(&m);
        assert_eq!(r.len(), 256);
        // block columns 25..50 are fully excluded (x 100..200)
        assert_eq!((r[0][0], r[0][2]), (99.5, 199.5));
    }

    #[test]
    fn arrow_geometry() {
        let a = arrow_shape(10.0, 20.0, 30.0, 40.0, 1.0).unwrap();
        assert_eq!(a.tip, (40.0, 60.0));
        // head length min(0.35·50, 9) = 9 along the arrow, half width 0.45·9
        let (bx, by) = a.base;
        assert!((((40.0 - bx).powi(2) + (60.0 - by).powi(2)).sqrt() - 9.0).abs() < 1e-12);
        let w = ((a.left.0 - a.right.0).powi(2) + (a.left.1 - a.right.1).powi(2)).sqrt();
        assert!((w - 0.9 * 9.0).abs() < 1e-12);
        assert!(arrow_shape(0.0, 0.0, 1.0, 1.0, 1.0).is_none(), "too short");
        assert!(arrow_shape(0.0, 0.0, f64::NAN, 1.0, 1.0).is_none());
    }
}
