//! The paper's Monte Carlo (Rajendran, Bane & Vlachos, "Uncertainty amplification due to
//! density/refractive-index gradients in volumetric PTV and BOS experiments", Exp. Fluids
//! 61:139, 2020; Sec. 3, Table 1, Fig. 5), reproduced and extended, and the amplification
//! ratio (Sec. 2.4, corrected per `docs/paper/NOTES.md` §2) measured by Monte Carlo.
//!
//! - [`run_study`] (`StudyConfig` → [`StudyResult`]): random setups over Table 1's ranges
//!   ([`StudyConfig::volumetric`], or [`StudyConfig::bos`] where the blur matters), each dot
//!   ray-traced once (`bostrack_theory::ray_trace`; or the effective Gaussian as a control,
//!   [`Rendering`]), then fitted `realisations` times under white Gaussian noise by the
//!   least-squares Gaussian fit of `bostrack_fit`. Per draw, the Monte Carlo standard
//!   deviation of the position error is set against three predictions: Eq. 35 (the paper's
//!   model, with the predicted sigmas), Eq. 35 with ρ (NOTES.md §2), and the exact bound
//!   (`bostrack_model::crlb`, pixel-integrated, 7 free parameters) of the Gaussian that best
//!   fits the noise-free image, over the fit window, for the same noise.
//! - [`run_ar_study`] ([`ArStudyConfig`] → [`ArResult`]): a reference dot and blurred
//!   gradient dots (ρ, aspect ratio, intensity ratio), the measured ratio of their Monte Carlo
//!   scatters against the NOTES.md §2 formula, the published variant, and the formula on
//!   pixel-blurred shapes.
//! - Tables ([`write_draws_csv`], [`write_study_markdown`], [`write_ar_csv`],
//!   [`write_ar_markdown`]) to any `impl Write`, and figures ([`fig5_figure`], [`ar_figure`])
//!   as in-memory `bostrack_figures::Figure`s. No filesystem access; the `paper_mc` example
//!   writes the files (`cargo run --release -p bostrack-paper --example paper_mc -- --out
//!   docs/paper`).
//!
//! Every draw has its own random stream (derived from the seed and the draw index), so a
//! result depends on the seed alone, not on the number of threads. docs/theory.md reports the
//! full-size results.
//!
//! ```
//! use bostrack_paper::{Rendering, StudyConfig, run_study};
//! let mut cfg = StudyConfig::bos(3, 40); // 3 draws × 40 noise realisations
//! cfg.rendering = Rendering::EffectiveModel;
//! let r = run_study(&cfg).unwrap();
//! assert_eq!(r.rows.len(), 3);
//! let row = &r.rows[0];
//! // 5 % noise on the peak: Eq. 35 is sqrt(2/π)·0.05·sqrt(σx/σy)·… ≈ 0.04 px, and the
//! // exact bound of the pixel-integrated dot is a little above it
//! assert!(row.eq35_x > 0.03 && row.eq35_x < 0.06);
//! assert!(row.bound_x > row.eq35_x);
//! // the Monte Carlo scatter of 40 fits is within ~30 % of the bound (1/sqrt(2·39) = 11 %)
//! assert!((row.std_x / row.bound_x - 1.0).abs() < 0.35);
//! ```

mod ar;
mod config;
mod error;
mod output;
mod stats;
mod study;

pub use ar::{ArFormulaSummary, ArResult, ArRow, ArStudyConfig, DotScatter, run_ar_study};
pub use config::{GeometryRange, NoiseReference, Rendering, StudyConfig};
pub use error::PaperError;
pub use output::{
    ar_figure, fig5_figure, rendering_label, write_ar_csv, write_ar_markdown, write_draws_csv,
    write_study_markdown,
};
pub use study::{
    DrawParams, DrawRow, GroupSummary, StudyResult, draw_params, draw_setup, run_study, trace_setup,
};
