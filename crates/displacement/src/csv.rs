//! The per-dot CSV row of a reference/gradient pair.

use crate::pair::{PairDot, usable};
use bostrack_core::DotFit;
// a float cell by the one convention of every table: unknown is the empty field
use bostrack_core::table::optional as num;

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

fn pair(v: Option<[f64; 2]>) -> [String; 2] {
    [num(v.map(|a| a[0])), num(v.map(|a| a[1]))]
}

/// `[sigma_x, sigma_y, rho, amplitude]` of a fit.
fn shape(d: Option<&DotFit>) -> [String; 4] {
    [
        num(d.map(|d| d.params.sigma_x)),
        num(d.map(|d| d.params.sigma_y)),
        num(d.map(|d| d.params.rho)),
        num(d.map(|d| d.params.amplitude)),
    ]
}

/// The values of one pair in the order of [`COLUMNS`]: floats with [`DECIMALS`] decimals,
/// empty strings for absent or non-finite values (never `NaN`). The fitted values of a record
/// whose fit is not usable (status not ok, non-finite position) are left empty; its problem
/// shows in `flags` (`fit_failed`).
pub fn to_row(p: &PairDot) -> [String; 30] {
    // a fit that is not usable (failed, non-finite position) shows only in the flags
    let r = p.reference.as_ref().filter(|d| usable(d));
    let g = p.gradient.as_ref().filter(|d| usable(d));
    let [x_ref, y_ref] = pair(p.reference_position);
    let [x_grad, y_grad] = pair(g.map(|d| [d.params.x0, d.params.y0]));
    let [dx, dy] = pair(p.displacement);
    let [sxr, syr, rr, ar_] = shape(r);
    let [sxg, syg, rg, ag] = shape(g);
    let [arx, ary] = pair(p.ar);
    let [cxr, cyr] = pair(r.map(|d| [d.crlb_x, d.crlb_y]));
    let [cxg, cyg] = pair(g.map(|d| [d.crlb_x, d.crlb_y]));
    let [urx, ury] = pair(p.u_ref);
    let [ugx, ugy] = pair(p.u_grad);
    let [udx, udy] = pair(p.u_d);
    [
        p.index.i.to_string(),
        p.index.j.to_string(),
        x_ref,
        y_ref,
        x_grad,
        y_grad,
        dx,
        dy,
        sxr,
        syr,
        rr,
        ar_,
        sxg,
        syg,
        rg,
        ag,
        arx,
        ary,
        cxr,
        cyr,
        cxg,
        cyg,
        urx,
        ury,
        ugx,
        ugy,
        udx,
        udy,
        p.valid.to_string(),
        p.flags.to_string(),
    ]
}
