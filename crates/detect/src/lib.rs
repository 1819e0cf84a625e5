//! Detect every dot of a dot target using prior knowledge of its lattice: from an image (and an
//! optional mask) to one [`Seed`](bostrack_core::Seed) per lattice site, each with its grid
//! index, predicted position, rough centre, fit window and flags. The first stage of the chain.
//!
//! [`detect`] works on a reference image; [`track`] follows its seeds into another image of the
//! same target (gradient image, no-flow stack), keeping the grid indices.
//!
//! ```
//! use bostrack_core::{DotFlags, Image};
//! use bostrack_detect::{detect, DetectConfig};
//!
//! // A 96x96 square lattice, spacing 8 px, rotated by 10°, dots of sigma 1.5 px.
//! let (s, th) = (8.0f64, 10f64.to_radians());
//! let img = Image::from_fn(96, 96, |x, y| {
//!     let mut v = 100.0;
//!     for j in -9..=9 {
//!         for i in -9..=9 {
//!             let (i, j) = (i as f64, j as f64);
//!             let cx = 47.5 + s * (i * th.cos() - j * th.sin());
//!             let cy = 47.5 + s * (i * th.sin() + j * th.cos());
//!             let r2 = (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2);
//!             v += 1000.0 * (-r2 / (2.0 * 1.5 * 1.5)).exp();
//!         }
//!     }
//!     v
//! });
//! let det = detect(&img, None, &DetectConfig::default()).unwrap();
//! assert!((det.spacing - 8.0).abs() < 0.05);
//! assert!((det.lattice.a[1].atan2(det.lattice.a[0]).to_degrees() - 10.0).abs() < 0.5);
//! // (0, 0) is the site nearest the image centre.
//! let origin = det.predict(0.0, 0.0);
//! assert!((origin[0] - 47.5).abs() < 0.05 && (origin[1] - 47.5).abs() < 0.05);
//! assert!(det.seeds.iter().all(|s| !s.flags.contains(DotFlags::MISSING)));
//! ```
//!
//! # Method
//! 1. **Lattice from the image.** The autocorrelation of a crop (64² first, doubling up to 512²
//!    until a lattice shows) has a peak at every lattice vector; the shortest clear peak and the
//!    shortest one in another direction (confirmed by a peak at their sum or difference) give
//!    the basis, whatever the rotation, missing dots or brightness; a fit of the lattice's
//!    lobes near lag 0 gives a first dot size. A spacing hint only sizes the first crop: the
//!    image wins (a hint wrong by 2x still works; [`DetectStats::spacing_hint_ratio`] reports
//!    measured / hint).
//! 2. **Dot map.** A band-pass image: Gaussian smoothing near the dot size minus the mean over
//!    one lattice period (removing the background, vignetting and dark regions' level), binned
//!    for large dots. A dot is a positive peak.
//! 3. **Grid index by region growing** from a dot near the centre of the kept region whose four
//!    neighbours are confirmed: each next site is predicted from the dots already found around
//!    it (weighted local affine fit over the 5x5 index neighbourhood) and accepted when the dot
//!    map peaks within 0.3 spacing, at `min_snr` times the map's noise (measured at the cell
//!    centres around the start) and at 30 % or more of the neighbours' peaks. Isolated missing
//!    dots and lines of them are bridged; noise, dust and scratches between sites never become
//!    dots.
//! 4. **Grid map.** A polynomial (total degree 3 by default) from `(i, j)` to `(x, y)` fitted by
//!    least squares to the grown dots in the kept region, affine first, with points beyond
//!    4 MAD left out; every site is predicted by it ([`Detection::predict`]), even where a dot
//!    is faint or missing. **Dot size:** a least-squares fit of the lattice of Gaussian dots
//!    (each dot with its 8 neighbours, positions from the map) to up to 32 patches; it stays
//!    right for dots that overlap (diameter up to the spacing), where the autocorrelation
//!    cannot tell the size.
//! 5. **Classification** of every site within two sites of a grown dot: a matched-filter test
//!    at the predicted position, `T = Σ(v - b) g / ‖g‖` with `g` a Gaussian of the dot's size
//!    and `b` the local level (the window border, or the surrounding cell centres for
//!    overlapping dots). A dot is found when `T` is at least `min_snr` times the spread of `T`
//!    at the lattice's cell centres (where there is no dot) and its amplitude
//!    `A = Σ(v - b) g / Σg²` at least `missing_ratio` of its neighbours' median; otherwise the
//!    site is MISSING and its `centre` is the prediction (a test at a searched peak away from the
//!    prediction needs one more unit of signal-to-noise). A found dot's `centre` is its
//!    Gaussian-weighted, background-subtracted centroid (weight `exp(-r²/2σw²)`,
//!    `σw = max(sqrt(σ² + 1/12), 0.8)`, level = mean of the window border, window half-width
//!    `min(ceil(2.5 sqrt(σ² + 1/12)), round(spacing/2))`, two steps each scaled by
//!    `1 + σ²/σw²` to undo the weight's pull), started at the grown peak or the prediction.
//!
//! [`track`] searches each reference dot in the dot map of the other image: within
//! `search_radius` (0.45) spacing of its reference position without a predictor, then, growing
//! outward from the largest region of small displacement, within 0.3 spacing of the position
//! predicted by the neighbours' median displacement; step 5 then classifies the sites.
//!
//! # Threads and speed
//! Both functions run their per-row and per-dot loops on the current rayon pool (the global
//! one unless the caller installs another, e.g. a one-thread pool for single-thread timing).
//! The result does not depend on the number of threads: each parallel loop computes every row
//! or dot on its own and collects them in order, the growth steps stay sequential, and the
//! dot map's row bands first replay the running column sums of the rows above them, so every
//! floating-point operation happens in the same order as in one pass. `benches/detect.rs`
//! times both on the real sample (about 12,200 dots per megapixel).
//!
//! # Conventions
//! - **Grid index:** `i` along `a`, the lattice vector closest to +x; `j` along `b`, the one at
//!   the smallest positive angle from `a` (about +90° towards +y on a square lattice, +60° on a
//!   hexagonal one, as [`bostrack_core::Lattice::hexagonal`]); docs/CONVENTIONS.md. **Anchor:**
//!   `(0, 0)` is the site whose *predicted* position is nearest the image centre
//!   `((w-1)/2, (h-1)/2)`. This anchor is fixed for a given target placement but not across
//!   images whose dots moved; therefore [`track`] never re-anchors: other images take the
//!   reference's indices.
//! - **Reported sites:** every found dot whose centre lies on a kept pixel of the image or
//!   next to one (the 3x3 pixels around it); and every MISSING site whose predicted position
//!   lies on a kept pixel and that is enclosed along its grid row or column by found dots or the
//!   edge of the kept region within two sites (so the area beyond the edge of a target that
//!   does not fill the image is not reported as missing). A reported site whose window is cut
//!   is flagged BORDER (the window reaches past the image; `window` is clipped) or MASKED (a
//!   window pixel is masked out).
//! - **Fit window:** square, half-width `window_half_width` or `max(2, min(round(spacing/2),
//!   ceil(1.5 d)))` around the centre (the dot's Voronoi cell on a square lattice, smaller for
//!   small dots), clipped to the image.
//! - **Flags:** MISSING (no dot), FAINT (template amplitude at the centre below `faint_ratio`
//!   of the 3x3 neighbours' median), DEFECT (over 2.5x their amplitude, size outside 0.67-1.5x
//!   or elongation over 1.4x theirs, or off its grid position by more than 0.25 spacing beyond
//!   their offset), MERGED (elongated along a lattice direction and larger than the
//!   neighbours), BORDER, MASKED, NAN_PIXELS (the window holds non-finite samples, which are
//!   left out everywhere). Shape tests run only on dots at 8 times the noise or more.

mod acf;
mod api;
mod classify;
mod config;
mod error;
mod fft;
mod filter;
mod grow;
mod linalg;
mod map;
mod size;

pub use api::{DetectStats, Detection, detect, track};
pub use config::{DetectConfig, LatticeKind, Polarity};
pub use error::DetectError;
pub use map::GridMap;
