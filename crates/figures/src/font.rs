//! The vendored font (assets/DejaVuSans.ttf, see assets/README.md), registered once with
//! plotters' `ab_glyph` text renderer under the family name `sans-serif`.

use std::sync::OnceLock;

use plotters::style::FontStyle;

use crate::FigureError;

static DEJAVU_SANS: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// The family every text element of this crate uses.
pub(crate) const FAMILY: &str = "sans-serif";

static REGISTERED: OnceLock<bool> = OnceLock::new();

/// Registers the embedded font on first use; later calls only read the stored outcome.
pub(crate) fn ensure_font() -> Result<(), FigureError> {
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FAMILY, FontStyle::Normal, DEJAVU_SANS).is_ok()
    });
    if ok { Ok(()) } else { Err(FigureError::Font) }
}
