//! [`Figure`]: a figure description that renders itself to PNG bytes or an SVG string.

use image::ImageEncoder;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::FigureError;
use crate::error::plot_err;
use crate::font::ensure_font;
use crate::hist::HistFigure;
use crate::map::MapFigure;
use crate::xy::PanelsFigure;

/// Smallest and largest accepted figure side, in output pixels.
const MIN_SIDE: u32 = 200;
const MAX_SIDE: u32 = 8000;

/// A validated figure, ready to render.
///
/// Built by the figure functions of this crate ([`displacement_map`](crate::displacement_map),
/// [`uncertainty_histogram`](crate::uncertainty_histogram), [`xy_plot`](crate::xy_plot), …); it
/// owns everything it needs (binned counts, dot positions and colours), so it can be rendered
/// more than once, to both formats. This crate never touches the filesystem: the caller writes
/// the returned bytes.
#[derive(Debug, Clone)]
pub struct Figure {
    width: u32,
    height: u32,
    title: String,
    content: Content,
}

#[derive(Debug, Clone)]
pub(crate) enum Content {
    Map(Box<MapFigure>),
    Hist(HistFigure),
    Panels(PanelsFigure),
}

impl Figure {
    pub(crate) fn new(width: u32, height: u32, title: String, content: Content) -> Self {
        Self {
            width,
            height,
            title,
            content,
        }
    }

    #[cfg(test)]
    pub(crate) fn content(&self) -> &Content {
        &self.content
    }

    /// Output size `(width, height)` in pixels (PNG pixels; SVG user units).
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The title drawn at the top of the figure.
    pub fn title(&self) -> &str {
        &self.title
    }

    /// The same figure at another output size (each side 200–8000 px). Maps keep the image's
    /// aspect ratio inside the new size (the plot is letter-boxed) and need about 400 × 300 px
    /// for their labels, colour bar and legend: smaller sizes give [`FigureError::InvalidInput`]
    /// when rendered.
    pub fn with_size(mut self, width: u32, height: u32) -> Result<Self, FigureError> {
        for (name, v) in [("width", width), ("height", height)] {
            if !(MIN_SIDE..=MAX_SIDE).contains(&v) {
                return Err(FigureError::invalid(
                    &self.title,
                    format!("figure {name} {v} px outside {MIN_SIDE}..={MAX_SIDE}"),
                ));
            }
        }
        self.width = width;
        self.height = height;
        Ok(self)
    }

    /// Renders to an 8-bit RGB PNG, in memory.
    pub fn to_png(&self) -> Result<Vec<u8>, FigureError> {
        let rgb = self.to_rgb()?;
        let mut out = Vec::new();
        image::codecs::png::PngEncoder::new(&mut out)
            .write_image(
                &rgb,
                self.width,
                self.height,
                image::ExtendedColorType::Rgb8,
            )
            .map_err(|e| FigureError::Encode(e.to_string()))?;
        Ok(out)
    }

    /// Renders to raw RGB8 samples (row-major, `3 · width · height` bytes).
    pub fn to_rgb(&self) -> Result<Vec<u8>, FigureError> {
        ensure_font()?;
        let mut buf = vec![255u8; 3 * self.width as usize * self.height as usize];
        {
            let root =
                BitMapBackend::with_buffer(&mut buf, (self.width, self.height)).into_drawing_area();
            self.draw(&root)?;
            root.present().map_err(plot_err)?;
        }
        Ok(buf)
    }

    /// Renders to an SVG document. Text is emitted as `<text>` in the `sans-serif` family.
    pub fn to_svg(&self) -> Result<String, FigureError> {
        ensure_font()?;
        let mut s = String::new();
        {
            let root =
                SVGBackend::with_string(&mut s, (self.width, self.height)).into_drawing_area();
            self.draw(&root)?;
            root.present().map_err(plot_err)?;
        }
        Ok(s)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), FigureError>
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE).map_err(plot_err)?;
        let body = crate::style::draw_title(root, &self.title)?;
        match &self.content {
            Content::Map(m) => m.draw(&body),
            Content::Hist(h) => h.draw(&body),
            Content::Panels(p) => p.draw(&body),
        }
    }
}
