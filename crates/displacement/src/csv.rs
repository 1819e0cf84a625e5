//! The per-dot CSV row of a reference/gradient pair.

use crate::pair::{PairDot, usable};
use bostrack_core::DotFit;
// a float cell by the one convention of every table: unknown is the empty field
use bostrack_core::table::write_number;

/// Column names of the pair CSV, in order. Positions, displacements, sigmas and uncertainties
/// in px, amplitudes in counts, ρ and AR dimensionless; `x_ref, y_ref` is the position the
/// displacement is measured from (fit or stack mean); `valid` is `true`/`false`; `flags` is
/// `a|b|c` ([`bostrack_core::DotFlags`]).
pub const COLUMNS: [&str; 30] = [
    "i",
    "j",
    "x_ref",
    "y_ref",
    "x_grad",
    "y_grad",
    "dx",
    "dy",
    "sigma_x_ref",
    "sigma_y_ref",
    "rho_ref",
    "amp_ref",
    "sigma_x_grad",
    "sigma_y_grad",
    "rho_grad",
    "amp_grad",
    "ar_x",
    "ar_y",
    "crlb_x_ref",
    "crlb_y_ref",
    "crlb_x_grad",
    "crlb_y_grad",
    "u_ref_x",
    "u_ref_y",
    "u_grad_x",
    "u_grad_y",
    "u_dx",
    "u_dy",
    "valid",
    "flags",
];

/// Decimals of every float column: those of every table bostrack writes
/// ([`bostrack_core::table`]).
pub const DECIMALS: usize = bostrack_core::table::DECIMALS;

/// The values of one pair in the order of [`COLUMNS`]: floats with [`DECIMALS`] decimals,
/// empty strings for absent or non-finite values (never `NaN`). The fitted values of a record
/// whose fit is not usable (status not ok, non-finite position) are left empty; its problem
/// shows in `flags` (`fit_failed`).
pub fn to_row(p: &PairDot) -> [String; 30] {
    let mut cells: [String; 30] = Default::default();
    write_row(p, &mut cells);
    cells
}

/// [`to_row`] into `cells`, whose old contents are replaced: a table writer reuses one set of
/// cells for every row (no allocation per cell; issue 17).
pub fn write_row(p: &PairDot, cells: &mut [String; 30]) {
    use std::fmt::Write as _;
    // a fit that is not usable (failed, non-finite position) shows only in the flags
    let r = p.reference.as_ref().filter(|d| usable(d));
    let g = p.gradient.as_ref().filter(|d| usable(d));
    let xy = |v: Option<[f64; 2]>| [v.map(|a| a[0]), v.map(|a| a[1])];
    let shape = |d: Option<&DotFit>| {
        [
            d.map(|d| d.params.sigma_x),
            d.map(|d| d.params.sigma_y),
            d.map(|d| d.params.rho),
            d.map(|d| d.params.amplitude),
        ]
    };
    let numbers: [[Option<f64>; 2]; 13] = [
        xy(p.reference_position),
        xy(g.map(|d| [d.params.x0, d.params.y0])),
        xy(p.displacement),
        [shape(r)[0], shape(r)[1]],
        [shape(r)[2], shape(r)[3]],
        [shape(g)[0], shape(g)[1]],
        [shape(g)[2], shape(g)[3]],
        xy(p.ar),
        xy(r.map(|d| [d.crlb_x, d.crlb_y])),
        xy(g.map(|d| [d.crlb_x, d.crlb_y])),
        xy(p.u_ref),
        xy(p.u_grad),
        xy(p.u_d),
    ];
    for c in cells.iter_mut() {
        c.clear();
    }
    let _ = write!(cells[0], "{}", p.index.i);
    let _ = write!(cells[1], "{}", p.index.j);
    for (c, v) in cells[2..28].iter_mut().zip(numbers.iter().flatten()) {
        if let Some(v) = v {
            write_number(c, *v);
        }
    }
    let _ = write!(cells[28], "{}", p.valid);
    let _ = write!(cells[29], "{}", p.flags);
}
