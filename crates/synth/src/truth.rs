//! Ground truth per dot, its Cramér-Rao bound, and the truth CSV.

use crate::SynthError;
use crate::config::{DefectKind, SceneConfig};
use bostrack_core::{DotFlags, Gaussian2D, GridIndex, Image, Mask, Window};
use bostrack_model::ModelKind;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};

/// One lattice site of a synthetic image, with its exact parameters.
///
/// `params` is the dot as drawn (the background field is `params.background` at the dot centre);
/// `crlb_x`, `crlb_y` are the exact Cramér-Rao bounds (px, 1σ) of x0 and y0 (see
/// [`compute_bounds`]); NaN when the dot is MISSING, when the bound was not requested
/// ([`crate::TruthConfig::crlb`]), or when the window left after border, mask and saturation
/// carries no information (then BORDER, MASKED or SATURATED is set).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthDot {
    pub index: GridIndex,
    pub params: Gaussian2D,
    /// MISSING (not drawn), DEFECT, FAINT (amplitude below half the nominal), BORDER (the bound
    /// window reaches past the image), MASKED (it reaches a masked-out pixel), SATURATED (the
    /// noise-free quantised image reaches the saturation level in it).
    pub flags: DotFlags,
    /// Which defect, if any.
    pub defect: Option<DefectKind>,
    pub crlb_x: f64,
    pub crlb_y: f64,
}

impl TruthDot {
    /// Whether the dot centre lies on the image (inside the pixel area `[-0.5, w-0.5] × [-0.5, h-0.5]`).
    /// The truth also lists dots centred just outside whose tails reach the image.
    pub fn centre_inside(&self, width: usize, height: usize) -> bool {
        Window::new(0, 0, width, height).contains_point(self.params.x0, self.params.y0)
    }
}

/// The bound window of a dot: `Window::centred(x0, y0, half)`.
pub(crate) fn bound_window(g: &Gaussian2D, half: usize) -> Window {
    Window::centred(g.x0, g.y0, half)
}

/// Sets BORDER, MASKED and SATURATED and computes the exact per-dot bound of every drawn dot.
///
/// The bound is [`bostrack_model::crlb_masked`] of the dot's own parameters (all 7 free,
/// [`ModelKind::Elliptical`]) with the scene's sampling and noise model
/// ([`SceneConfig::noise_model`]) over the square window `Window::centred(x0, y0, h)`,
/// `h = `[`SceneConfig::crlb_half_width`] (default round(spacing/2): the dot's Voronoi cell on
/// a square lattice), clipped to the image, leaving out masked-out pixels and pixels whose
/// noise-free value saturates. It is the bound of an isolated dot on a constant background:
/// the neighbours' tails and the slope of a varying background are not part of it.
pub fn compute_bounds(
    cfg: &SceneConfig,
    truth: &mut [TruthDot],
    mean: &Image,
    mask: Option<&Mask>,
) {
    let (w, h) = (cfg.width, cfg.height);
    let half = cfg.crlb_half_width();
    let noise = cfg.noise_model();
    let sampling = cfg.render.sampling;
    let sat = cfg.saturation().map(|s| s - 0.5);
    let do_bound = cfg.truth.crlb;
    truth.par_iter_mut().for_each(|t| {
        t.flags
            .remove(DotFlags::BORDER | DotFlags::MASKED | DotFlags::SATURATED);
        t.crlb_x = f64::NAN;
        t.crlb_y = f64::NAN;
        // A centre beyond ±1e12 px cannot have a window on the image (and would overflow the
        // integer window arithmetic).
        if !(t.params.x0.abs() < 1e12 && t.params.y0.abs() < 1e12) {
            t.flags.insert(DotFlags::BORDER);
            return;
        }
        let win = bound_window(&t.params, half);
        let clipped = win.clip(w, h);
        if clipped != Some(win) {
            t.flags.insert(DotFlags::BORDER);
        }
        let Some(cw) = clipped else { return };
        let keep = |x: i64, y: i64| -> bool {
            if x < 0 || y < 0 || x as usize >= w || y as usize >= h {
                return false;
            }
            let (xu, yu) = (x as usize, y as usize);
            mask.is_none_or(|m| m.keeps(xu, yu)) && sat.is_none_or(|s| mean.get(xu, yu) < s)
        };
        for y in cw.y..cw.y + cw.height as i64 {
            for x in cw.x..cw.x + cw.width as i64 {
                let (xu, yu) = (x as usize, y as usize);
                if mask.is_some_and(|m| !m.keeps(xu, yu)) {
                    t.flags.insert(DotFlags::MASKED);
                }
                if sat.is_some_and(|s| mean.get(xu, yu) >= s) {
                    t.flags.insert(DotFlags::SATURATED);
                }
            }
        }
        if !do_bound || t.flags.contains(DotFlags::MISSING) {
            return;
        }
        if let Some(b) = bostrack_model::crlb_masked(
            &t.params,
            cw,
            &noise,
            sampling,
            ModelKind::Elliptical,
            &keep,
        ) && b.std[0].is_finite()
            && b.std[1].is_finite()
        {
            t.crlb_x = b.std[0];
            t.crlb_y = b.std[1];
        }
    });
}

/// One row of the truth CSV.
#[derive(Debug, Serialize, Deserialize)]
struct Row {
    i: i32,
    j: i32,
    x: f64,
    y: f64,
    sigma_x: f64,
    sigma_y: f64,
    rho: f64,
    amplitude: f64,
    background: f64,
    flags: DotFlags,
    defect: String,
    /// `None`: not available, an empty field (the one convention of every table).
    crlb_x: Option<f64>,
    crlb_y: Option<f64>,
}

/// The columns of the truth CSV, in order.
pub const TRUTH_CSV_COLUMNS: [&str; 13] = [
    "i",
    "j",
    "x",
    "y",
    "sigma_x",
    "sigma_y",
    "rho",
    "amplitude",
    "background",
    "flags",
    "defect",
    "crlb_x",
    "crlb_y",
];

/// Writes the truth as CSV with a header row: grid index `i, j`; `x, y` (px,
/// docs/CONVENTIONS.md); `sigma_x, sigma_y, rho, amplitude, background`; `flags` (`a|b`, empty
/// for none); `defect` (kind or empty); `crlb_x, crlb_y` (px, empty when not available). Floats are
/// written in shortest round-trip form, so [`read_truth_csv`] gives back the same bits.
pub fn write_truth_csv<W: Write>(w: W, truth: &[TruthDot]) -> Result<(), SynthError> {
    let mut wr = csv::Writer::from_writer(w);
    for t in truth {
        let p = &t.params;
        wr.serialize(Row {
            i: t.index.i,
            j: t.index.j,
            x: p.x0,
            y: p.y0,
            sigma_x: p.sigma_x,
            sigma_y: p.sigma_y,
            rho: p.rho,
            amplitude: p.amplitude,
            background: p.background,
            flags: t.flags,
            defect: t.defect.map(|d| d.as_str().to_string()).unwrap_or_default(),
            crlb_x: t.crlb_x.is_finite().then_some(t.crlb_x),
            crlb_y: t.crlb_y.is_finite().then_some(t.crlb_y),
        })?;
    }
    if truth.is_empty() {
        wr.write_record(TRUTH_CSV_COLUMNS)?;
    }
    wr.flush().map_err(|e| SynthError::Csv(e.into()))?;
    Ok(())
}

/// Reads a truth CSV written by [`write_truth_csv`].
pub fn read_truth_csv<R: Read>(r: R) -> Result<Vec<TruthDot>, SynthError> {
    let mut rd = csv::Reader::from_reader(r);
    let mut out = Vec::new();
    for rec in rd.deserialize::<Row>() {
        let row = rec?;
        let defect = if row.defect.is_empty() {
            None
        } else {
            Some(
                DefectKind::parse(&row.defect).ok_or_else(|| SynthError::CsvField {
                    line: out.len() as u64 + 2,
                    problem: format!("unknown defect kind `{}`", row.defect),
                })?,
            )
        };
        out.push(TruthDot {
            index: GridIndex::new(row.i, row.j),
            params: Gaussian2D {
                x0: row.x,
                y0: row.y,
                amplitude: row.amplitude,
                sigma_x: row.sigma_x,
                sigma_y: row.sigma_y,
                rho: row.rho,
                background: row.background,
            },
            flags: row.flags,
            defect,
            crlb_x: row.crlb_x.unwrap_or(f64::NAN),
            crlb_y: row.crlb_y.unwrap_or(f64::NAN),
        });
    }
    Ok(out)
}
