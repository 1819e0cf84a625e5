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
//! 1. **Lattice from the image.** The autocorrelation of a crop (128² by default, larger when
//!    the spacing calls for it) has a peak at every lattice vector; the shortest clear peak
//!    and the shortest one in another direction (confirmed by a peak at their sum or
//!    difference) give the basis, whatever the rotation, missing dots or brightness. Its central
//!    lobe gives the dot size. A spacing hint only sizes the crop: the image wins (a hint wrong
//!    by 2x still works; [`DetectStats::spacing_hint_ratio`] says by how much it was off).
//! 2. **Dot map.** A band-pass image: Gaussian smoothing near the dot size minus the mean over
//!    one lattice period (removing background, vignetting and dark regions' level), binned for
//!    large dots. A dot is a positive peak whose height is its contrast.
//! 3. **Grid index by region growing** from a dot near the centre of the kept region whose four
//!    neighbours are confirmed: each next site is predicted from the dots already found around
//!    it (local affine fit over the 5x5 index neighbourhood) and accepted when the dot map peaks
//!    within 0.3 spacing at 30 % or more of the neighbours' contrast. Isolated missing dots or
//!    lines of them are bridged; noise, dust and scratches between sites never become dots.
//! 4. **Grid map.** A polynomial (total degree 3 by default) from `(i, j)` to `(x, y)` fitted
//!    by least squares to the grown dots, with outliers beyond 4 MAD rejected; every site is
//!    predicted by it ([`Detection::predict`]), even where a dot is faint or missing.
//! 5. **Classification** of each site (strongest dot-map peak within max(0.25 spacing, 1.5 px)
//!    of its prediction):
//!    a dot is found when its contrast is at least `min_snr` times the robust noise of the dot
//!    map (MAD of differences between neighbouring cell centres) and at least `missing_ratio`
//!    of its neighbours' median contrast; otherwise the site is MISSING and its `centre` is the
//!    prediction. A found dot's `centre` is its Gaussian-weighted, background-subtracted
//!    centroid, started at the dot-map peak (weight `exp(-r²/2σw²)`, `σw = max(σ, 0.8)`, level
//!    = mean of the window border, window half-width `min(ceil(2.5σw), round(spacing/2))`, two
//!    steps each scaled by `1 + σ²/σw²` to undo the weight's pull).
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
//!   next to one (the 3x3 pixels around it; a dot cut by the mask edge is still reported, with
//!   MASKED); and every MISSING site whose predicted position lies on a kept pixel
//!   and that is enclosed along its grid row or column by found dots or the edge of the kept
//!   region within two sites (so the area beyond the edge of a target that does not fill the
//!   image is not reported as missing). A site whose dot lies on a kept pixel is reported even when its
//!   window is cut: it is flagged BORDER (the window reaches past the image and `window` is
//!   clipped) or MASKED (a window pixel is masked out).
//! - **Fit window:** square, half-width `window_half_width` or `max(2, min(round(spacing/2),
//!   ceil(1.5 d)))` around the centre (the dot's Voronoi cell on a square lattice, smaller for
//!   small dots), clipped to the image.
//! - **Flags:** MISSING (no dot), FAINT (peak height above the centroid window border below
//!   `faint_ratio` of the neighbours' median), DEFECT (over 2.5x brighter, size outside
//!   0.67-1.5x or elongation 1.4x the neighbours', or off its grid position by more than 0.25
//!   spacing beyond the neighbours' offset), MERGED (elongated along a lattice direction and
//!   larger than the neighbours), BORDER, MASKED, NAN_PIXELS.

mod acf;
mod classify;
mod config;
mod detect;
mod error;
mod fft;
mod filter;
mod grow;
mod linalg;
mod map;
mod size;

pub use config::{DetectConfig, LatticeKind, Polarity};
pub use detect::{DetectStats, Detection, detect, track};
pub use error::DetectError;
pub use map::GridMap;
