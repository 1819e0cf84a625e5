//! Figures of bostrack: per-frame maps (displacement field, amplification ratio,
//! displacement uncertainty), histograms (u_ref and u_grad, max(AR_x, AR_y)), campaign time series and a
//! generic line/scatter plot for benchmark and theory figures.
//!
//! Every figure function takes plain data (no stage-crate types) and returns a [`Figure`],
//! which renders to PNG bytes ([`Figure::to_png`]) or an SVG string ([`Figure::to_svg`]). The
//! crate does no filesystem access: the caller writes the files. Text uses the embedded DejaVu
//! Sans (assets/README.md), so no system fonts are needed.
//!
//! Maps are drawn in image coordinates (docs/CONVENTIONS.md): x to the right, **y down**, in
//! px, with the image's aspect ratio kept. Dots are coloured with viridis; the colour bar is
//! labelled with the quantity and unit and says when the range is clipped (default: 1st–99th
//! percentile). Dots outside the mask are grey rings, invalid dots red crosses, each with a
//! legend entry and count.
//!
//! ```
//! use bostrack_figures::{displacement_map, MapFrame, MapOptions, MapPoint};
//! let points: Vec<MapPoint> = (0..400)
//!     .map(|k| {
//!         let (x, y) = ((k % 20) as f64 * 10.0 + 5.0, (k / 20) as f64 * 10.0 + 5.0);
//!         MapPoint::vector(x, y, 0.01 * (y - 100.0), -0.01 * (x - 100.0), true, true)
//!     })
//!     .collect();
//! let frame = MapFrame { width: 200, height: 200, title: "frame 1", mask: None };
//! let fig = displacement_map(&points, &frame, &MapOptions::default()).unwrap();
//! let png: Vec<u8> = fig.to_png().unwrap();
//! assert_eq!(&png[1..4], b"PNG");
//! let svg: String = fig.to_svg().unwrap();
//! assert!(svg.contains("<svg") && svg.contains("frame 1"));
//! ```

mod colour;
mod error;
mod font;
mod hist;
mod map;
mod render;
mod style;
mod util;
mod xy;

pub use colour::ColourRange;
pub use error::FigureError;
pub use hist::{HistOptions, HistSeries, ar_histogram, histogram, uncertainty_histogram};
pub use map::{
    MapFrame, MapOptions, MapPoint, Quantity, UncertaintyComponent, ar_map, displacement_map,
    scalar_map, uncertainty_map,
};
pub use render::Figure;
pub use xy::{
    AxisScale, CampaignRow, RefLine, SeriesStyle, XyPlot, XySeries, campaign_figure, xy_panels,
    xy_plot,
};
