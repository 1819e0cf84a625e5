//! The dot image model of bostrack: an elliptical Gaussian on a background, sampled at pixel
//! centres or integrated over pixels, its derivatives, and the exact Cramér-Rao bound.
//!
//! This crate is pure arithmetic (no I/O, no images): the fit engine, the synthetic-image
//! generator and the theory module all evaluate dots through it, so there is one definition of
//! the model (docs/CONVENTIONS.md):
//!
//! `I(x, y) = B + I0 · exp(-q / (2(1 - ρ²)))`, `q = u² - 2ρuv + v²`, `u = (x-x0)/σx`, `v = (y-y0)/σy`.
//!
//! ```
//! use bostrack_core::{Gaussian2D, NoiseModel, Window};
//! use bostrack_model::{crlb, crlb_closed_form, ModelKind, Sampling};
//! let dot = Gaussian2D::circular(10.0, 10.0, 1000.0, 2.0, 100.0);
//! let w = Window::centred(10.0, 10.0, 10);
//! let b = crlb(&dot, w, &NoiseModel::read(20.0), Sampling::Point, ModelKind::Elliptical).unwrap();
//! let closed = crlb_closed_form(&dot, 20.0);
//! assert!((b.std[0] / closed[0] - 1.0).abs() < 0.01);
//! ```

mod ar;
mod bound;
mod pixel;
mod quadrature;

pub use ar::{ArVariant, amplification_ratio, bound_ratio};
pub use bound::{Bound, crlb, crlb_closed_form, crlb_masked, fisher_information, invert_spd};
pub use pixel::{
    ModelKind, N_PARAMS, PARAM_NAMES, Sampling, add_dot, pixel_gradient, pixel_value, render,
};
