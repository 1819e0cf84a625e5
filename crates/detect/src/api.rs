//! The two entry points: [`detect`] (reference image) and [`track`] (any other image of the
//! same target, seeded by the reference detection).

use crate::acf;
use crate::classify::{
    Ctx, Measure, Neighbourhoods, PAR_MIN, Scratch, Site, Template, classify, interstitial_noise,
};
use crate::filter::{DotMap, FilterParams, Maximum, Peak, dist2, nearest_strong_of};
use crate::grow::{IndexGrid, find_start, grow};
use crate::linalg::{hypot_exceeds, median};
use crate::map::GridMap;
use crate::size::{Patch, fit_sigma};
use crate::{DetectConfig, DetectError, LatticeKind};
use bostrack_core::{DotFlags, GridIndex, Image, Lattice, Mask, Seed};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Smallest image side accepted.
const MIN_SIDE: usize = 32;
/// Fewest dots for a lattice.
const MIN_DOTS: usize = 9;

/// Counts and diagnostics of one detection.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DetectStats {
    /// Reported sites (= seeds).
    pub sites: usize,
    /// Seeds with a dot (not MISSING), FAINT ones included.
    pub found: usize,
    pub faint: usize,
    pub missing: usize,
    pub border: usize,
    pub masked: usize,
    pub defect: usize,
    pub merged: usize,
    /// Robust spread of the matched-filter statistic at the lattice's cell centres (counts):
    /// the unit of `min_snr` (about the pixel noise).
    pub noise: f64,
    /// RMS residual of the grid map over the dots it was fitted to (px).
    pub map_rms: f64,
    /// Dots the grid map was fitted to (after outlier rejection).
    pub map_inliers: usize,
    /// Binning factor of the dot map (1 = full resolution; larger for large dots).
    pub binning: usize,
    /// Measured spacing / spacing hint, when a hint was given.
    pub spacing_hint_ratio: Option<f64>,
}

/// Result of [`detect`] or [`track`]: one [`Seed`] per lattice site, with the lattice it lies on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// Size of the image the detection was made on.
    pub width: usize,
    pub height: usize,
    /// The local lattice at site (0, 0) (origin = its predicted position, `a` = ∂p/∂i,
    /// `b` = ∂p/∂j of the grid map).
    pub lattice: Lattice,
    /// The smooth grid → image map (see [`GridMap::predict`]). [`track`] keeps the reference's.
    pub map: GridMap,
    /// Mean nearest-neighbour spacing at site (0, 0), px.
    pub spacing: f64,
    /// Typical dot diameter d = 4σ measured on the image, px: a least-squares fit of the
    /// lattice of Gaussian dots around up to 32 well-surrounded dots, or the autocorrelation's
    /// estimate when there are too few (a typical value: the fit stage measures each dot).
    pub diameter: f64,
    /// One seed per reported site, in grid order (`j`, then `i`); [`track`] keeps the
    /// reference's seeds and order.
    pub seeds: Vec<Seed>,
    /// Amplitude of each seed's dot above the local level (counts, the least-squares amplitude
    /// of a Gaussian of the dot's size at its centre; same order as `seeds`; 0 when MISSING).
    pub contrast: Vec<f64>,
    pub stats: DetectStats,
}

impl Detection {
    /// Predicted image position of a (possibly fractional) grid index (px).
    pub fn predict(&self, i: f64, j: f64) -> [f64; 2] {
        self.map.predict(i, j)
    }

    /// The seed of a grid index, if reported (binary search: the seeds are in grid order).
    pub fn seed(&self, idx: GridIndex) -> Option<&Seed> {
        self.seeds
            .binary_search_by_key(&(idx.j, idx.i), |s| (s.index.j, s.index.i))
            .ok()
            .map(|k| &self.seeds[k])
    }
}

pub(crate) fn image_name(img: &Image) -> String {
    match &img.meta.source {
        Some(p) if img.meta.page > 0 => format!("{} (page {})", p.display(), img.meta.page),
        Some(p) => p.display().to_string(),
        None => "in-memory image".to_string(),
    }
}

/// Checks shared by detect and track; `want_centre`: whether the centroid of the kept region
/// is needed (detect).
fn check_inputs(
    img: &Image,
    mask: Option<&Mask>,
    name: &str,
    want_centre: bool,
) -> Result<Inputs, DetectError> {
    let (w, h) = (img.width(), img.height());
    if w < MIN_SIDE || h < MIN_SIDE {
        return Err(DetectError::ImageTooSmall {
            image: name.into(),
            width: w,
            height: h,
            min: MIN_SIDE,
        });
    }
    if let Some(m) = mask {
        if !m.matches(img) {
            return Err(DetectError::MaskSize {
                image: name.into(),
                width: w,
                height: h,
                mask_width: m.width(),
                mask_height: m.height(),
            });
        }
        if !m.as_slice().iter().any(|&k| k) {
            return Err(DetectError::EmptyMask { image: name.into() });
        }
    }
    // Range of the finite samples (a constant image has none), whether any is non-finite, and
    // the centroid of the kept region; blocks of rows in parallel (minimum, maximum and integer
    // sums do not depend on the order).
    let rows_per_block = (65536 / w).max(1);
    let (lo, hi, nonfinite) = img
        .data()
        .par_chunks(rows_per_block * w)
        .map(range_of)
        .reduce(
            || (f64::INFINITY, f64::NEG_INFINITY, false),
            |a, b| (a.0.min(b.0), a.1.max(b.1), a.2 | b.2),
        );
    let (sx, sy, n) = match mask.filter(|_| want_centre) {
        Some(m) => m
            .as_slice()
            .par_chunks(rows_per_block * w)
            .enumerate()
            .map(|(b, block)| {
                let (mut sx, mut sy, mut n) = (0u64, 0u64, 0u64);
                for (r, row) in block.chunks_exact(w).enumerate() {
                    let y = (b * rows_per_block + r) as u64;
                    let mut cnt = 0u64;
                    let mut xs = 0u64;
                    for (x, &k) in row.iter().enumerate() {
                        cnt += k as u64;
                        xs += x as u64 * k as u64;
                    }
                    n += cnt;
                    sx += xs;
                    sy += cnt * y;
                }
                (sx, sy, n)
            })
            .reduce(|| (0, 0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2)),
        None => (0, 0, 0),
    };
    let (sx, sy) = (sx as f64, sy as f64);
    if hi.is_nan() || lo.is_nan() || hi - lo <= 1e-9 * hi.abs().max(lo.abs()) {
        return Err(DetectError::NoContrast { image: name.into() });
    }
    let centre = if n > 0 {
        [sx / n as f64, sy / n as f64]
    } else {
        [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0]
    };
    Ok(Inputs {
        fill: 0.5 * (lo + hi),
        centre,
        nonfinite,
    })
}

/// Minimum and maximum of the finite samples of `data` (±∞ when there is none) and whether any
/// sample is non-finite.
fn range_of(data: &[f64]) -> (f64, f64, bool) {
    // Eight independent lanes so that the compiler vectorises the reductions; `v · 0` is NaN
    // exactly for non-finite samples, and a NaN in a lane sum stays NaN.
    let (mut lo8, mut hi8, mut bad8) = ([f64::INFINITY; 8], [f64::NEG_INFINITY; 8], [0.0f64; 8]);
    let chunks = data.chunks_exact(8);
    let rest = chunks.remainder();
    for ch in chunks {
        for k in 0..8 {
            let v = ch[k];
            bad8[k] += v * 0.0;
            lo8[k] = if v < lo8[k] { v } else { lo8[k] };
            hi8[k] = if v > hi8[k] { v } else { hi8[k] };
        }
    }
    let nonfinite = bad8.iter().any(|b| b.is_nan()) || rest.iter().any(|v| !v.is_finite());
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    if nonfinite {
        for &v in data.iter().filter(|v| v.is_finite()) {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    } else {
        for &v in rest {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        lo = lo8.iter().fold(lo, |a, &b| a.min(b));
        hi = hi8.iter().fold(hi, |a, &b| a.max(b));
    }
    (lo, hi, nonfinite)
}

/// What [`check_inputs`] learns about an image.
struct Inputs {
    /// Replacement for non-finite samples (mid-range of the finite ones).
    fill: f64,
    /// Centroid of the kept region (the image centre without a mask, or when not asked for).
    centre: [f64; 2],
    /// Whether any sample is non-finite.
    nonfinite: bool,
}

fn norm(v: [f64; 2]) -> f64 {
    v[0].hypot(v[1])
}

/// The basis per docs/CONVENTIONS.md from a reduced basis: `a` = the short lattice vector
/// closest to +x; `b` = the short lattice vector at the smallest positive angle from `a`
/// (turning towards +y): about +90° on a square lattice, +60° on a hexagonal one.
fn conventional_basis(
    v1: [f64; 2],
    v2: [f64; 2],
    kind: LatticeKind,
    name: &str,
) -> Result<([f64; 2], [f64; 2]), DetectError> {
    let lmax = norm(v2) * 1.15;
    let mut short: Vec<[f64; 2]> = Vec::new();
    for (p, q) in [(1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, -1.0)] {
        let v = [p * v1[0] + q * v2[0], p * v1[1] + q * v2[1]];
        if norm(v) <= lmax {
            short.push(v);
            short.push([-v[0], -v[1]]);
        }
    }
    let a = short
        .iter()
        .copied()
        .max_by(|p, q| (p[0] / norm(*p)).total_cmp(&(q[0] / norm(*q))))
        .unwrap_or(v1);
    let ang = |v: [f64; 2]| (a[0] * v[1] - a[1] * v[0]).atan2(a[0] * v[0] + a[1] * v[1]);
    let b = short
        .iter()
        .copied()
        .filter(|v| ang(*v) > 0.2)
        .min_by(|p, q| ang(*p).total_cmp(&ang(*q)))
        .unwrap_or(v2);
    let deg = ang(b).to_degrees();
    let expected = match kind {
        LatticeKind::Square => 90.0,
        LatticeKind::Hexagonal => 60.0,
    };
    if (deg - expected).abs() > 15.0 {
        return Err(DetectError::LatticeMismatch {
            image: name.into(),
            expected: kind,
            angle_deg: deg,
        });
    }
    Ok((a, b))
}

/// Autocorrelation crop sizes to try, smallest first: 64 px (or about 10 hinted spacings),
/// doubling up to 512 px or the largest power of two inside the image.
fn crop_sizes(w: usize, h: usize, hint: Option<f64>) -> Vec<usize> {
    let side = w.min(h);
    let largest = 1usize << (usize::BITS - 1 - side.leading_zeros());
    let first = match hint {
        Some(s) => ((10.0 * s).ceil() as usize)
            .next_power_of_two()
            .clamp(64, 256),
        None => 64,
    }
    .min(largest);
    let mut out = Vec::new();
    let mut n = first;
    while n <= largest.min(512) {
        out.push(n);
        n *= 2;
    }
    out
}

fn kept(mask: Option<&Mask>, w: usize, h: usize, p: [f64; 2]) -> bool {
    let (x, y) = (p[0].round(), p[1].round());
    if !(x >= 0.0 && y >= 0.0 && x < w as f64 && y < h as f64) {
        return false;
    }
    mask.is_none_or(|m| m.keeps(x as usize, y as usize))
}

/// Flags [`DotFlags::ROI_EDGE`] on every found seed one of whose 8 lattice neighbours is
/// predicted (`predict(i, j)`) inside the image but outside the region of interest.
/// Each seed on its own (rayon; 8 grid-map predictions per seed).
fn flag_roi_edge(
    seeds: &mut [Seed],
    mask: Option<&Mask>,
    (w, h): (usize, usize),
    predict: impl Fn(f64, f64) -> [f64; 2] + Sync,
) {
    if mask.is_none() {
        return;
    }
    // in the image, not in the region of interest
    let masked = |p: [f64; 2]| kept(None, w, h, p) && !kept(mask, w, h, p);
    seeds.par_iter_mut().with_min_len(PAR_MIN).for_each(|s| {
        if s.flags.contains(DotFlags::MISSING) {
            return;
        }
        let (i, j) = (s.index.i as f64, s.index.j as f64);
        let edge = [-1.0, 0.0, 1.0].iter().any(|&dj| {
            [-1.0, 0.0, 1.0]
                .iter()
                .any(|&di| (di != 0.0 || dj != 0.0) && masked(predict(i + di, j + dj)))
        });
        if edge {
            s.flags |= DotFlags::ROI_EDGE;
        }
    });
}

/// [`flag_roi_edge`] for the seeds of a tracked image, `known` the reference's in the same
/// order: a seed takes the reference's flag where the reference seed at its grid index was
/// found (its flag was computed from the same map and mask), and is computed otherwise.
fn flag_roi_edge_known(
    seeds: &mut [Seed],
    known: &[Seed],
    mask: Option<&Mask>,
    size: (usize, usize),
    predict: impl Fn(f64, f64) -> [f64; 2] + Sync,
) {
    if mask.is_none() {
        return;
    }
    let mut unknown: Vec<usize> = Vec::new();
    for (k, s) in seeds.iter_mut().enumerate() {
        if s.flags.contains(DotFlags::MISSING) {
            continue;
        }
        match known.get(k) {
            Some(r) if r.index == s.index && !r.flags.contains(DotFlags::MISSING) => {
                if r.flags.contains(DotFlags::ROI_EDGE) {
                    s.flags.insert(DotFlags::ROI_EDGE);
                }
            }
            _ => unknown.push(k),
        }
    }
    let mut rest: Vec<Seed> = unknown.iter().map(|&k| seeds[k]).collect();
    flag_roi_edge(&mut rest, mask, size, predict);
    for (&k, s) in unknown.iter().zip(rest) {
        seeds[k] = s;
    }
}

/// Whether a kept pixel of the image lies in the 3x3 block around the pixel nearest to `p`.
fn near_kept(mask: Option<&Mask>, w: usize, h: usize, p: [f64; 2]) -> bool {
    let (x, y) = (p[0].round(), p[1].round());
    if !(x >= -1.0 && y >= -1.0 && x <= w as f64 && y <= h as f64) {
        return false;
    }
    let (x, y) = (x as i64, y as i64);
    (y - 1..=y + 1).any(|yy| {
        (x - 1..=x + 1).any(|xx| {
            xx >= 0
                && yy >= 0
                && (xx as usize) < w
                && (yy as usize) < h
                && mask.is_none_or(|m| m.keeps(xx as usize, yy as usize))
        })
    })
}

fn stats_of(
    seeds: &[Seed],
    noise: f64,
    map_rms: f64,
    map_inliers: usize,
    binning: usize,
    hint: Option<f64>,
) -> DetectStats {
    let count = |f: DotFlags| seeds.iter().filter(|s| s.flags.contains(f)).count();
    DetectStats {
        sites: seeds.len(),
        found: seeds.len() - count(DotFlags::MISSING),
        faint: count(DotFlags::FAINT),
        missing: count(DotFlags::MISSING),
        border: count(DotFlags::BORDER),
        masked: count(DotFlags::MASKED),
        defect: count(DotFlags::DEFECT),
        merged: count(DotFlags::MERGED),
        noise,
        map_rms,
        map_inliers,
        binning,
        spacing_hint_ratio: hint,
    }
}

/// Detect every dot of a dot-target image (see the crate documentation for the method and the
/// conventions).
pub fn detect(
    image: &Image,
    mask: Option<&Mask>,
    cfg: &DetectConfig,
) -> Result<Detection, DetectError> {
    cfg.validate()?;
    let name = image_name(image);
    let (w, h) = (image.width(), image.height());
    let Inputs {
        fill,
        centre,
        nonfinite,
    } = check_inputs(image, mask, &name, true)?;
    let sign = cfg.polarity.sign();

    // 1-2. Lattice basis and dot size from the autocorrelation of a crop, the dot map, and
    //      region growing from a confirmed dot near the centre of the kept region. A crop that
    //      shows no lattice, or a lattice on which no dot can be grown, gives way to the next
    //      larger crop.
    let mut last_err = None;
    let mut mismatch = None;
    let mut setup = None;
    for n in crop_sizes(w, h, cfg.spacing) {
        let est = match acf::estimate(image, sign, mask, centre, n) {
            Ok(e) => e,
            Err(reason) => {
                last_err = Some(DetectError::NoLattice {
                    image: name.clone(),
                    reason,
                });
                continue;
            }
        };
        let (a, b) = match conventional_basis(est.v1, est.v2, cfg.lattice, &name) {
            Ok(ab) => ab,
            Err(DetectError::LatticeMismatch { angle_deg, .. }) => {
                // A clear lattice of the other kind is a mismatch; any other angle means the
                // autocorrelation peaks were not a dot lattice.
                let other = match cfg.lattice {
                    LatticeKind::Square => 60.0,
                    LatticeKind::Hexagonal => 90.0,
                };
                if (angle_deg - other).abs() <= 15.0 {
                    mismatch = Some(DetectError::LatticeMismatch {
                        image: name.clone(),
                        expected: cfg.lattice,
                        angle_deg,
                    });
                } else {
                    last_err = Some(DetectError::NoLattice {
                        image: name.clone(),
                        reason: format!(
                            "the autocorrelation peaks make {angle_deg:.1}°, neither a square nor a hexagonal lattice"
                        ),
                    });
                }
                continue;
            }
            Err(e) => {
                last_err = Some(e);
                continue;
            }
        };
        let spacing0 = 0.5 * (norm(a) + norm(b));
        if spacing0 < 2.5 {
            last_err = Some(DetectError::NoLattice {
                image: name.clone(),
                reason: format!("a lattice of {spacing0:.2} px is below the supported 2.5 px"),
            });
            continue;
        }
        let sigma = cfg.diameter.map_or(est.sigma, |d| d / 4.0);
        let fp = FilterParams::new(spacing0, sigma);
        let dmap = DotMap::build(image, sign, fill, nonfinite, &fp);
        let Some(start) = find_start(&dmap, a, b, centre, w, h) else {
            last_err = Some(DetectError::TooFewDots {
                image: name.clone(),
                found: 0,
                min: MIN_DOTS,
            });
            continue;
        };
        // Noise of the dot map at the cell centres around the start dot (the autocorrelation
        // basis is exact enough over ±6 sites), so that growth never accepts noise peaks.
        let local: Vec<GridIndex> = (-6..=6)
            .flat_map(|j| (-6..=6).map(move |i| GridIndex::new(i, j)))
            .collect();
        let noise0 = interstitial_noise(
            |c| Some(dmap.sample(c)),
            (w, h),
            mask,
            cfg.lattice,
            &local,
            |g| {
                Some([
                    start.x + g.i as f64 * a[0] + g.j as f64 * b[0],
                    start.y + g.i as f64 * a[1] + g.j as f64 * b[1],
                ])
            },
        )
        .unwrap_or_else(|| fallback_map_noise(&dmap));
        let grown = grow(&dmap, a, b, start, cfg.min_snr * noise0, w, h);
        if grown.len() < MIN_DOTS {
            last_err = Some(DetectError::TooFewDots {
                image: name.clone(),
                found: grown.len(),
                min: MIN_DOTS,
            });
            continue;
        }
        setup = Some((est, spacing0, sigma, fp, grown));
        break;
    }
    let Some((est, spacing0, sigma, fp, grown)) = setup else {
        return Err(mismatch.or(last_err).unwrap_or(DetectError::NoLattice {
            image: name,
            reason: "image too small for the analysis".into(),
        }));
    };

    // 3. Robust polynomial grid map over the grown dots in the kept region.
    let mut pts: Vec<(f64, f64, [f64; 2])> = grown
        .iter()
        .filter(|g| kept(mask, w, h, g.pos))
        .map(|g| (g.index.i as f64, g.index.j as f64, g.pos))
        .collect();
    if pts.len() < MIN_DOTS {
        pts = grown
            .iter()
            .map(|g| (g.index.i as f64, g.index.j as f64, g.pos))
            .collect();
    }
    let Some((mut map, inliers, map_rms)) =
        GridMap::fit_robust(&pts, cfg.map_degree, 0.05 * spacing0)
    else {
        return Err(DetectError::TooFewDots {
            image: name,
            found: grown.len(),
            min: MIN_DOTS,
        });
    };
    let map_inliers = inliers.iter().filter(|u| **u).count();

    // 4. Anchor: the site predicted nearest to the image centre is (0, 0).
    let img_centre = [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0];
    let anchor = map.nearest_site(img_centre).unwrap_or(GridIndex::new(0, 0));
    map.shift(anchor.i, anchor.j);
    let lattice = map.local_lattice(0.0, 0.0);
    let spacing = lattice.spacing();

    // 4b. Dot size from patches around dots whose 8 neighbours were all grown (up to 32, spread
    //     over the list); the autocorrelation's (or the hint's) value when too few.
    let (imin, imax) = grown.iter().fold((i32::MAX, i32::MIN), |(lo, hi), g| {
        (lo.min(g.index.i), hi.max(g.index.i))
    });
    let (jmin, jmax) = grown.iter().fold((i32::MAX, i32::MIN), |(lo, hi), g| {
        (lo.min(g.index.j), hi.max(g.index.j))
    });
    let mut grown_grid = IndexGrid::new(imin, imax, jmin, jmax, false);
    for g in &grown {
        if let Some(v) = grown_grid.get_mut(g.index.i, g.index.j) {
            *v = true;
        }
    }
    let surrounded: Vec<GridIndex> = grown
        .iter()
        .filter(|g| kept(mask, w, h, g.pos))
        .filter(|g| {
            let mut all = true;
            grown_grid.visit(g.index.i, g.index.j, 1, |_, _, &v| all &= v);
            all && (g.index.i > imin && g.index.i < imax && g.index.j > jmin && g.index.j < jmax)
        })
        .map(|g| GridIndex::new(g.index.i - anchor.i, g.index.j - anchor.j))
        .collect();
    let stride = surrounded.len().div_ceil(32).max(1);
    let patches: Vec<Patch> = surrounded
        .iter()
        .step_by(stride)
        .map(|g| {
            let mut dots = vec![map.position(*g)];
            for dj in -1..=1 {
                for di in -1..=1 {
                    if (di, dj) != (0, 0) {
                        dots.push(map.position(GridIndex::new(g.i + di, g.j + dj)));
                    }
                }
            }
            Patch { dots }
        })
        .collect();
    let fitted = fit_sigma(image, sign, &patches, spacing);
    let sigma = fitted.unwrap_or(sigma);
    let diameter = 4.0 * fitted.unwrap_or(est.sigma);

    // 5. Candidate sites: the grown dots and their 5x5 neighbourhoods, inside the image.
    // None: not a candidate; Some(None): a neighbour of a grown dot; Some(Some(p)): grown.
    let mut seen: IndexGrid<Option<Option<Peak>>> =
        IndexGrid::new(imin - 2, imax + 2, jmin - 2, jmax + 2, None);
    for g in &grown {
        seen.visit_mut(g.index.i, g.index.j, 2, |_, _, v| {
            if v.is_none() {
                *v = Some(None);
            }
        });
    }
    for g in &grown {
        if let Some(v) = seen.get_mut(g.index.i, g.index.j) {
            *v = Some(Some(Peak {
                x: g.pos[0],
                y: g.pos[1],
                v: g.v,
            }));
        }
    }
    // Sites in grid order (j, then i); a grown dot keeps its peak when the map agrees with it.
    let r_s = (0.25 * spacing).max(1.5);
    let mut sites: Vec<Site> = Vec::new();
    for (i, j, v) in seen.iter() {
        let Some(grown_peak) = *v else { continue };
        let idx = GridIndex::new(i - anchor.i, j - anchor.j);
        let p = map.position(idx);
        if p[0] < -0.5 || p[1] < -0.5 || p[0] > w as f64 - 0.5 || p[1] > h as f64 - 0.5 {
            continue;
        }
        // The grown dot's peak when the map agrees with it; else the test and the centroid
        // start at the prediction.
        let peak = grown_peak.filter(|q| dist2(q.pos(), p) <= r_s * r_s);
        sites.push(Site {
            index: idx,
            predicted: p,
            peak,
            peak_extra: 1.0,
            window_from: None,
            measured: None,
        });
    }
    // 6. Noise of the dot map at the cell centres, classification.
    let site_idx: Vec<GridIndex> = sites.iter().map(|s| s.index).collect();
    let mut pos_grid = IndexGrid::new(
        imin - anchor.i - 2,
        imax - anchor.i + 2,
        jmin - anchor.j - 2,
        jmax - anchor.j + 2,
        None,
    );
    for s in &sites {
        if let Some(v) = pos_grid.get_mut(s.index.i, s.index.j) {
            *v = Some(s.predicted);
        }
    }
    let tpl = Template::new(sigma, spacing, lattice.a, lattice.b, cfg.lattice, nonfinite);
    let stat = |c: [f64; 2]| tpl.eval(image, sign, c).map(|t| t.0);
    let noise = interstitial_noise(stat, (w, h), mask, cfg.lattice, &site_idx, |g| {
        pos_grid.get(g.i, g.j).copied().flatten()
    })
    .unwrap_or_else(|| fallback_noise(stat, w, h, spacing));
    let ctx = Ctx {
        img: image,
        sign,
        mask,
        nonfinite,
        spacing,
        sigma,
        a: lattice.a,
        b: lattice.b,
        cfg,
        noise,
    };
    let classified = classify(&ctx, &sites, None);

    // 7. Report: found dots centred on or next to a kept pixel; missing sites predicted on a kept
    //    pixel, and only when enclosed by found dots (or the edge of the kept region) along a
    //    grid row or column.
    let mut found_grid = IndexGrid::new(
        imin - anchor.i - 2,
        imax - anchor.i + 2,
        jmin - anchor.j - 2,
        jmax - anchor.j + 2,
        false,
    );
    for c in &classified {
        if !c.seed.flags.contains(DotFlags::MISSING)
            && let Some(v) = found_grid.get_mut(c.seed.index.i, c.seed.index.j)
        {
            *v = true;
        }
    }
    let is_found = |i: i32, j: i32| found_grid.get(i, j).copied().unwrap_or(false);
    let outside = |i: i32, j: i32| !kept(mask, w, h, map.predict(i as f64, j as f64));
    let enclosed = |idx: GridIndex| {
        [(1, 0), (0, 1)].iter().any(|&(di, dj)| {
            let side = |sg: i32| -> (bool, bool) {
                for k in 1..=2 {
                    let (i, j) = (idx.i + sg * k * di, idx.j + sg * k * dj);
                    if is_found(i, j) {
                        return (true, true);
                    }
                    if outside(i, j) {
                        return (true, false);
                    }
                }
                (false, false)
            };
            let (ok1, f1) = side(1);
            let (ok2, f2) = side(-1);
            ok1 && ok2 && (f1 || f2)
        })
    };
    let report: Vec<(Seed, f64)> = classified
        .into_iter()
        .filter(|c| {
            let missing = c.seed.flags.contains(DotFlags::MISSING);
            if missing {
                kept(mask, w, h, c.seed.predicted) && enclosed(c.seed.index)
            } else {
                near_kept(mask, w, h, c.seed.centre)
            }
        })
        .map(|c| (c.seed, c.contrast))
        .collect();
    let (mut seeds, contrast): (Vec<Seed>, Vec<f64>) = report.into_iter().unzip();
    flag_roi_edge(&mut seeds, mask, (w, h), |i, j| map.predict(i, j));
    let hint = cfg.spacing.map(|s| spacing / s);
    let stats = stats_of(&seeds, noise, map_rms, map_inliers, fp.k, hint);
    Ok(Detection {
        width: w,
        height: h,
        lattice,
        map,
        spacing,
        diameter,
        seeds,
        contrast,
        stats,
    })
}

/// Robust spread of the whole dot map, used only when the lattice gives too few cell centres.
fn fallback_map_noise(map: &DotMap) -> f64 {
    let step = (map.d.data.len() / 20000).max(1);
    let mut v: Vec<f64> = map.d.data.iter().step_by(step).map(|&x| x as f64).collect();
    let m = median(&mut v);
    let mut dev: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    1.4826 * median(&mut dev)
}

/// Spread of a statistic over a regular grid of points (every half spacing), from the half
/// below its median (where there is no dot), used only when the lattice gives too few cell
/// centres.
fn fallback_noise(stat: impl Fn([f64; 2]) -> Option<f64>, w: usize, h: usize, spacing: f64) -> f64 {
    let step = (0.5 * spacing).max(1.0);
    let mut v = Vec::new();
    let mut y = 0.0;
    while y < h as f64 && v.len() < 20000 {
        let mut x = 0.0;
        while x < w as f64 {
            if let Some(t) = stat([x, y]) {
                v.push(t);
            }
            x += step;
        }
        y += step;
    }
    let m = median(&mut v);
    let mut dev: Vec<f64> = v.iter().filter(|&&x| x <= m).map(|x| m - x).collect();
    1.4826 * median(&mut dev)
}

/// The dot map that tracking's searches read. `Whole`: the whole image's. `Crop`: that of a
/// crop of the image holding every point within `reach` of the dots still to be searched
/// (the interior) and the filter's support around it, its binned pixels those of the whole
/// map; inside the interior its values are the whole map's (but for the rounding of running
/// sums that start at the crop's edge), so are its peaks. A search beyond the interior, or
/// without a crop, reads the whole map (built once, when first needed). `Nothing`: no dot is
/// searched.
struct Maps<'a> {
    image: &'a Image,
    sign: f64,
    fill: f64,
    nonfinite: bool,
    fp: FilterParams,
    whole: std::sync::OnceLock<DotMap>,
    source: Source,
}

enum Source {
    Whole,
    Crop {
        map: DotMap,
        /// Full-resolution position of the crop's first pixel.
        origin: [f64; 2],
        /// `[x0, x1, y0, y1]`: full-resolution points whose map values the crop holds
        /// (infinite where the crop reaches the image's edge).
        interior: [f64; 4],
    },
    Nothing,
}

/// A crop is made only where it is at most this share of the image (else the whole map).
const CROP_MAX_SHARE: f64 = 0.5;

impl<'a> Maps<'a> {
    /// `around`: the points still to be searched (`None`: every dot is searched).
    fn new(
        image: &'a Image,
        sign: f64,
        fill: f64,
        nonfinite: bool,
        fp: &FilterParams,
        around: Option<&[[f64; 2]]>,
        reach: f64,
    ) -> Self {
        let source = match around {
            None => Source::Whole,
            Some([]) => Source::Nothing,
            Some(pts) => Self::crop(image, sign, fill, nonfinite, fp, pts, reach),
        };
        Maps {
            image,
            sign,
            fill,
            nonfinite,
            fp: *fp,
            whole: std::sync::OnceLock::new(),
            source,
        }
    }

    fn crop(
        image: &Image,
        sign: f64,
        fill: f64,
        nonfinite: bool,
        fp: &FilterParams,
        pts: &[[f64; 2]],
        reach: f64,
    ) -> Source {
        let k = fp.k;
        // the filter's support: the Gaussian's 3 sigma, the box, the maximum test and the
        // parabola's neighbours (binned px), in full-resolution px
        let margin = (k * ((3.0 * fp.sigma_f).ceil() as usize + fp.box_half + 2)) as f64;
        let (lo, hi) = pts.iter().fold(
            ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]),
            |(lo, hi), p| {
                (
                    [lo[0].min(p[0]), lo[1].min(p[1])],
                    [hi[0].max(p[0]), hi[1].max(p[1])],
                )
            },
        );
        // per axis: the crop's first pixel and its end, aligned with the bins and within the
        // whole map's extent (which drops a last partial bin); `None` when not finite
        let span = |lo: f64, hi: f64, size: usize| -> Option<(usize, usize)> {
            let end_max = (size / k) * k;
            let a = ((lo - reach - margin) / k as f64).floor();
            let b = ((hi + reach + margin + 1.0) / k as f64).ceil();
            if !(a.is_finite() && b.is_finite()) {
                return None;
            }
            let a = (a.max(0.0) as usize * k).min(end_max);
            let b = (b.max(0.0) as usize * k).min(end_max);
            (b > a).then_some((a, b))
        };
        let (w, h) = (image.width(), image.height());
        let (Some((x0, x1)), Some((y0, y1))) = (span(lo[0], hi[0], w), span(lo[1], hi[1], h))
        else {
            return Source::Whole;
        };
        if ((x1 - x0) * (y1 - y0)) as f64 > CROP_MAX_SHARE * (w * h) as f64 {
            return Source::Whole;
        }
        let crop = Image::from_fn(x1 - x0, y1 - y0, |x, y| image.row(y0 + y)[x0 + x]);
        let map = DotMap::build(&crop, sign, fill, nonfinite, fp);
        let inner = |a: usize, b: usize, size: usize| {
            let lo = if a == 0 {
                f64::NEG_INFINITY
            } else {
                a as f64 + margin
            };
            let hi = if b == (size / k) * k {
                f64::INFINITY
            } else {
                b as f64 - 1.0 - margin
            };
            [lo, hi]
        };
        let [ix0, ix1] = inner(x0, x1, w);
        let [iy0, iy1] = inner(y0, y1, h);
        Source::Crop {
            map,
            origin: [x0 as f64, y0 as f64],
            interior: [ix0, ix1, iy0, iy1],
        }
    }

    fn whole(&self) -> &DotMap {
        self.whole.get_or_init(|| {
            DotMap::build(self.image, self.sign, self.fill, self.nonfinite, &self.fp)
        })
    }

    /// The crop and its origin when the disc of `r` around `c` lies inside its interior.
    fn crop_for(&self, c: [f64; 2], r: f64) -> Option<(&DotMap, [f64; 2])> {
        match &self.source {
            Source::Crop {
                map,
                origin,
                interior: [x0, x1, y0, y1],
            } if c[0] - r >= *x0 && c[0] + r <= *x1 && c[1] - r >= *y0 && c[1] + r <= *y1 => {
                Some((map, *origin))
            }
            _ => None,
        }
    }

    /// [`DotMap::local_maxima_px`]; a list made from the crop (a disc inside its interior) is
    /// read back by [`Maps::maxima_within`] on a smaller disc inside it, from the crop too.
    fn local_maxima_px(&self, c: [f64; 2], radius: f64, out: &mut Vec<Maximum>) {
        match self.crop_for(c, radius) {
            Some((map, o)) => {
                let from = out.len();
                map.local_maxima_px([c[0] - o[0], c[1] - o[1]], radius, out);
                for m in &mut out[from..] {
                    m.peak.x += o[0];
                    m.peak.y += o[1];
                }
            }
            None => self.whole().local_maxima_px(c, radius, out),
        }
    }

    /// [`DotMap::maxima_within`] of a list from [`Maps::local_maxima_px`] of a disc that holds
    /// this one.
    fn maxima_within(&self, list: &[Maximum], c: [f64; 2], radius: f64, out: &mut Vec<Peak>) {
        match self.crop_for(c, radius) {
            Some((map, o)) => map.maxima_within(list, [c[0] - o[0], c[1] - o[1]], radius, out),
            None => self.whole().maxima_within(list, c, radius, out),
        }
    }

    /// [`DotMap::nearest_strong`].
    fn nearest_strong(&self, c: [f64; 2], radius: f64, buf: &mut Vec<Peak>) -> Option<Peak> {
        match self.crop_for(c, radius) {
            Some((map, o)) => map
                .nearest_strong([c[0] - o[0], c[1] - o[1]], radius, buf)
                .map(|p| Peak {
                    x: p.x + o[0],
                    y: p.y + o[1],
                    v: p.v,
                }),
            None => self.whole().nearest_strong(c, radius, buf),
        }
    }

    /// [`DotMap::sample`]: from the crop inside its interior (NaN outside it, and with nothing
    /// searched), from the whole map without a crop.
    fn sample(&self, c: [f64; 2]) -> f64 {
        match &self.source {
            Source::Whole => self.whole().sample(c),
            Source::Nothing => f64::NAN,
            Source::Crop { .. } => self
                .crop_for(c, 0.0)
                .map_or(f64::NAN, |(map, o)| map.sample([c[0] - o[0], c[1] - o[1]])),
        }
    }
}

/// The connected groups (through `neighbours`) of the indices `k` with `member[k]`, each in
/// the order it is reached from its lowest index (breadth first), the groups in the order of
/// their lowest index.
fn connected_groups(
    member: &[bool],
    neighbours: impl Fn(usize, &mut Vec<usize>),
) -> Vec<Vec<usize>> {
    let mut seen = vec![false; member.len()];
    let mut nb = Vec::with_capacity(24);
    let mut groups = Vec::new();
    for k0 in 0..member.len() {
        if !member[k0] || seen[k0] {
            continue;
        }
        seen[k0] = true;
        let mut members = vec![k0];
        let mut head = 0;
        while head < members.len() {
            let k = members[head];
            head += 1;
            neighbours(k, &mut nb);
            for &o in &nb {
                if member[o] && !seen[o] {
                    seen[o] = true;
                    members.push(o);
                }
            }
        }
        groups.push(members);
    }
    groups
}

/// How far (spacings) from its reference centre a tracked dot's centroid may lie for the dot to
/// be still (see [`track`]).
const STILL_SPACING: f64 = 0.1;

/// The least share of the seeds in the largest connected group of still dots for that group to
/// be taken as found without a search (see [`track`]); below it every dot is searched.
const ANCHOR_SHARE: f64 = 0.5;

/// Track the dots of a reference detection into another image of the same target (gradient
/// image, no-flow stack image): the result has the same grid indices, one seed per reference
/// seed in the reference's order.
///
/// Each dot is first searched without a predictor: the strong dot-map peak nearest to its
/// reference position within `search_radius · spacing` (this finds displacements up to about
/// 0.45 spacing). Dots whose displacement agrees with their neighbours' are confident; starting
/// from the confident dot of smallest displacement, the lattice is then grown outward, each dot
/// searched within 0.3 spacing of its reference position plus the median displacement of the
/// neighbours already tracked (3x3 index neighbourhood, 5x5 when it has fewer than two), so
/// smoothly varying displacements larger than half a spacing are followed. The growth starts
/// from the largest connected group of dots whose first-pass displacement is under a quarter
/// spacing and agrees with their neighbours' (a periodic target cannot tell a displacement from
/// the same minus a lattice vector: the largest such group is taken to be truly at rest).
/// `predicted` = reference position + the neighbours' median displacement. A tracked seed's fit
/// window is its reference seed's window moved by the whole pixels of its displacement from the
/// reference centre (rounded per axis), so that a dot that moved by less than half a pixel is
/// fitted over the pixels of its reference fit; where the reference window was cut by the
/// image's edge, the window centred on the tracked centre.
///
/// Where most of the target did not move (a gradient frame's flow is local), the search is
/// left out for the still dots: those whose template measure at the reference centre (the
/// test and centroid of classification, started there) finds the dot within
/// 0.1 spacing, in the largest connected group of such dots when it holds at least half of
/// the seeds. They are taken as found at their centroids, growth starts from all of them at
/// once, and their measure is classification's. Sites the reference found empty among them
/// are not searched either (classification tests them at their prediction), and the dot map
/// is built only over a crop around the dots still searched.
pub fn track(
    image: &Image,
    mask: Option<&Mask>,
    reference: &Detection,
    cfg: &DetectConfig,
) -> Result<Detection, DetectError> {
    cfg.validate()?;
    let name = image_name(image);
    let (w, h) = (image.width(), image.height());
    if (w, h) != (reference.width, reference.height) {
        return Err(DetectError::ReferenceSize {
            image: name,
            width: w,
            height: h,
            ref_width: reference.width,
            ref_height: reference.height,
        });
    }
    if reference.seeds.is_empty() {
        return Err(DetectError::EmptyReference);
    }
    let Inputs {
        fill, nonfinite, ..
    } = check_inputs(image, mask, &name, false)?;
    let sign = cfg.polarity.sign();
    let s = reference.spacing;
    let sigma = reference.diameter / 4.0;
    let fp = FilterParams::new(s, sigma);

    let seeds = &reference.seeds;
    let n = seeds.len();
    // Seed number per grid index and the seeds' 8-neighbourhoods (classification reuses them:
    // its sites are the seeds, in order).
    let nbhd = Neighbourhoods::new(|k| seeds[k].index, n);
    let (slot, ring) = (&nbhd.slot, &nbhd.ring);
    let neighbours = |k: usize, r: i32, out: &mut Vec<usize>| {
        out.clear();
        if r == 1 {
            out.extend(ring.of(k));
            return;
        }
        let idx = seeds[k].index;
        for dj in -r..=r {
            for di in -r..=r {
                if (di, dj) != (0, 0)
                    && let Some(&q) = slot.get(idx.i + di, idx.j + dj)
                    && q != usize::MAX
                {
                    out.push(q);
                }
            }
        }
    };
    let q: Vec<[f64; 2]> = seeds.iter().map(|t| t.centre).collect();
    let disp = |p: &Peak, k: usize| [p.x - q[k][0], p.y - q[k][1]];
    // (classification's template, the same as the one `classify` makes)
    let tpl = Template::new(
        sigma,
        s,
        reference.lattice.a,
        reference.lattice.b,
        cfg.lattice,
        nonfinite,
    );
    // Still dots. A gradient frame's flow is local: over most of the target the template
    // measure at a reference centre (classification's test and centroid, started there) finds
    // its dot within `STILL_SPACING` of a spacing. The largest connected group of such dots
    // (8-neighbours), where it holds at least `ANCHOR_SHARE` of the seeds, is taken as found
    // at its centroids (the anchors): no search for them, growth starts from all of them, and
    // classification takes their measure as it is. A dot that moved by a lattice vector can
    // look still too; it lies beyond a band of moving dots, outside the largest group (as in
    // the search below, the region of small displacement is taken to be the largest one).
    // (each still dot's measure; its centroid is that of its blob)
    let still: Vec<Option<Measure>> = (0..n)
        .into_par_iter()
        .with_min_len(PAR_MIN)
        .map_init(Scratch::new, |sc, k| {
            if seeds[k].flags.contains(DotFlags::MISSING) {
                return None;
            }
            let m = tpl.measure(image, sign, q[k], sigma, sc)?;
            let c = m.blob?.centre;
            (m.t > 0.0
                && c.iter().all(|v| v.is_finite())
                && dist2(c, q[k]) <= (STILL_SPACING * s).powi(2))
            .then_some(m)
        })
        .collect();
    let anchor: Vec<bool> = {
        let is_still: Vec<bool> = still.iter().map(Option::is_some).collect();
        let best = connected_groups(&is_still, |k, out| neighbours(k, 1, out))
            .into_iter()
            .fold(
                Vec::new(),
                |best, g| if g.len() > best.len() { g } else { best },
            );
        let mut anchor = vec![false; n];
        if best.len() as f64 >= ANCHOR_SHARE * n as f64 {
            for k in best {
                anchor[k] = true;
            }
        }
        anchor
    };
    // A site the reference found empty, among anchors (and other such sites) only, is not
    // searched either: classification tests it at its prediction, and the fit stage looks for
    // a dot there too. (Along a target's edges such sites would spread the map's crop.)
    let quiet: Vec<bool> = (0..n)
        .map(|k| {
            seeds[k].flags.contains(DotFlags::MISSING)
                && ring.of(k).any(|o| anchor[o])
                && ring
                    .of(k)
                    .all(|o| anchor[o] || seeds[o].flags.contains(DotFlags::MISSING))
        })
        .collect();
    let r1 = cfg.search_radius * s;
    // The dot map: the whole image's, or with anchors that of a crop around the dots still to
    // be searched (`Maps`).
    let searched: Vec<[f64; 2]> = (0..n)
        .filter(|&k| !anchor[k] && !quiet[k])
        .map(|k| q[k])
        .collect();
    let maps = Maps::new(
        image,
        sign,
        fill,
        nonfinite,
        &fp,
        anchor.iter().any(|&a| a).then_some(&searched[..]),
        r1 + 3.0 * s,
    );
    // an anchor's peak: its centroid, with the map's value there where the crop holds it
    // (growth reads the values of the anchors near the searched dots only; NaN elsewhere)
    let anchor_peak = |k: usize| {
        still[k].and_then(|m| m.blob).map(|b| Peak {
            x: b.centre[0],
            y: b.centre[1],
            v: maps.sample(b.centre),
        })
    };
    // The median displacement of the peaks in `found` at seed k's 3x3 index neighbours, or its
    // 5x5 ones when fewer than `min` of the 3x3 have one; None when the 5x5 have fewer too.
    type Bufs = (Vec<usize>, Vec<f64>, Vec<f64>);
    let new_bufs = || -> Bufs {
        (
            Vec::with_capacity(24),
            Vec::with_capacity(24),
            Vec::with_capacity(24),
        )
    };
    let neighbour_median =
        |k: usize, found: &[Option<Peak>], min: usize, (nb, tx, ty): &mut Bufs| {
            for r in 1..=2 {
                neighbours(k, r, nb);
                tx.clear();
                ty.clear();
                for &o in nb.iter() {
                    if let Some(p) = found[o] {
                        let d = disp(&p, o);
                        tx.push(d[0]);
                        ty.push(d[1]);
                    }
                }
                if tx.len() >= min {
                    return Some([median(tx), median(ty)]);
                }
            }
            None
        };

    // Pass 1: no predictor.
    let mut buf = Vec::new();
    // Every maximum within r1 of each reference position is kept: the growth's searches,
    // mostly within that disc, pick from them instead of scanning the map again. Blocks of
    // seeds in parallel, joined in seed order.
    // Per block: each seed's peak, the maxima kept and where each seed's maxima start.
    type Block = (Vec<Option<Peak>>, Vec<Maximum>, Vec<usize>);
    let blocks: Vec<Block> = (0..n.div_ceil(PAR_MIN))
        .into_par_iter()
        .map(|b| {
            let (lo, hi) = (b * PAR_MIN, ((b + 1) * PAR_MIN).min(n));
            let mut maxima = Vec::with_capacity(2 * (hi - lo));
            let mut at = Vec::with_capacity(hi - lo);
            let mut buf = Vec::new();
            let first = (lo..hi)
                .map(|k| {
                    let from = maxima.len();
                    at.push(from);
                    if anchor[k] {
                        return anchor_peak(k);
                    }
                    if quiet[k] {
                        return None;
                    }
                    maps.local_maxima_px(q[k], r1, &mut maxima);
                    buf.clear();
                    buf.extend(maxima[from..].iter().map(|m| m.peak));
                    nearest_strong_of(&buf, q[k]).filter(|p| p.v > 0.0)
                })
                .collect();
            (first, maxima, at)
        })
        .collect();
    let mut first: Vec<Option<Peak>> = Vec::with_capacity(n);
    let mut maxima: Vec<Maximum> = Vec::new();
    let mut maxima_at: Vec<usize> = Vec::with_capacity(n + 1);
    for (f, m, at) in blocks {
        let base = maxima.len();
        first.extend(f);
        maxima_at.extend(at.iter().map(|a| a + base));
        maxima.extend(m);
    }
    maxima_at.push(maxima.len());
    let mut nb = Vec::with_capacity(24);
    let mut tx = Vec::with_capacity(24);
    let mut ty = Vec::with_capacity(24);
    // Dots whose displacement agrees with their neighbours' (each seed on its own).
    let mut starts: Vec<(f64, usize)> = (0..n)
        .into_par_iter()
        .with_min_len(PAR_MIN)
        .map_init(new_bufs, |bufs, k| {
            if anchor[k] {
                return None;
            }
            let p = first[k]?;
            if let Some(med) = neighbour_median(k, &first, 3, bufs) {
                let d = disp(&p, k);
                if dist2(d, med) < (0.15 * s).powi(2) {
                    return Some((norm(d), k));
                }
            }
            None
        })
        // (collected by position, then flattened: rayon's `flatten` made a nested parallel
        // iterator of each seed's `Option`, a third of this step's time)
        .collect::<Vec<Option<(f64, usize)>>>()
        .into_iter()
        .flatten()
        .collect();
    // Where the true displacement exceeds half a spacing, the nearest peak is a neighbour's
    // and its (wrong) displacement can look small and consistent too. The region of truly small
    // displacement is taken to be the largest connected one: the start is the smallest
    // displacement of the largest connected group of consistent dots under a quarter spacing,
    // then of the next largest group for what growth from there cannot reach.
    // each consistent dot's displacement length (from `starts`; the groups' members are among
    // them), and whether it is small
    let mut dn_of = vec![f64::INFINITY; n];
    let small: Vec<bool> = {
        let mut v = vec![false; n];
        for &(dn, k) in &starts {
            v[k] = dn < 0.25 * s;
            dn_of[k] = dn;
        }
        v
    };
    let mut groups = connected_groups(&small, |k, out| neighbours(k, 1, out));
    groups.sort_by_key(|g| std::cmp::Reverse(g.len()));
    // (first the anchors, all at once: `usize::MAX` stands for them)
    let anchors: Vec<usize> = (0..n).filter(|&k| anchor[k]).collect();
    let mut ordered: Vec<(f64, usize)> = Vec::new();
    if !anchors.is_empty() {
        ordered.push((0.0, usize::MAX));
    }
    ordered.extend(
        groups
            .iter()
            .filter_map(|g| {
                g.iter()
                    .copied()
                    .min_by(|&a, &b| dn_of[a].total_cmp(&dn_of[b]))
            })
            .map(|k| (dn_of[k], k)),
    );
    // Then every other consistent dot, smallest displacement first (isolated parts).
    // Stable by displacement: `starts` is in index order, so ties keep the lower index first.
    starts.sort_unstable_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    ordered.extend(starts.iter().copied());
    let starts = ordered;

    // Growth with the neighbours' median displacement as predictor.
    #[derive(Clone, Copy, PartialEq)]
    enum St {
        Unvisited,
        Queued,
        Accepted,
        Failed,
    }
    let mut state = vec![St::Unvisited; n];
    let mut tries = vec![0u8; n];
    let mut result: Vec<Option<Peak>> = vec![None; n];
    let mut pred_disp: Vec<Option<[f64; 2]>> = vec![None; n];
    let mut queue = VecDeque::new();
    let mut vals = Vec::with_capacity(24);
    let r2 = 0.3 * s;
    let push_nb = |k: usize,
                   state: &mut Vec<St>,
                   tries: &[u8],
                   queue: &mut VecDeque<usize>,
                   nb: &mut Vec<usize>| {
        neighbours(k, 1, nb);
        for &o in nb.iter() {
            if state[o] == St::Unvisited || (state[o] == St::Failed && tries[o] < 3) {
                state[o] = St::Queued;
                queue.push_back(o);
            }
        }
    };
    for &a in &anchors {
        state[a] = St::Accepted;
        result[a] = first[a];
    }
    // (quiet sites: out of growth, as after its last failed try)
    for k in (0..n).filter(|&k| quiet[k]) {
        state[k] = St::Failed;
        tries[k] = 3;
    }
    for &(_, st) in &starts {
        if st == usize::MAX {
            for &a in &anchors {
                push_nb(a, &mut state, &tries, &mut queue, &mut nb);
            }
        } else {
            if state[st] != St::Unvisited {
                continue;
            }
            state[st] = St::Accepted;
            result[st] = first[st];
            push_nb(st, &mut state, &tries, &mut queue, &mut nb);
        }
        while let Some(t) = queue.pop_front() {
            if state[t] != St::Queued {
                continue;
            }
            for r in 1..=2 {
                neighbours(t, r, &mut nb);
                tx.clear();
                ty.clear();
                vals.clear();
                for &o in &nb {
                    if state[o] == St::Accepted
                        && let Some(p) = result[o]
                    {
                        let d = disp(&p, o);
                        tx.push(d[0]);
                        ty.push(d[1]);
                        vals.push(p.v);
                    }
                }
                if tx.len() >= 2 {
                    break;
                }
            }
            if tx.is_empty() {
                state[t] = St::Failed;
                tries[t] += 1;
                continue;
            }
            let pd = [median(&mut tx), median(&mut ty)];
            let m = median(&mut vals);
            pred_disp[t] = Some(pd);
            let c = [q[t][0] + pd[0], q[t][1] + pd[1]];
            // The disc of r2 around c lies inside the first pass's disc of r1 around q[t] (with
            // a margin far above rounding): its maxima are among those kept. (Either branch
            // finds the same maxima there; this one reads fewer.)
            let inside = !hypot_exceeds(pd[0], pd[1], r1 - 1e-6 - r2);
            let found = if inside {
                buf.clear();
                maps.maxima_within(&maxima[maxima_at[t]..maxima_at[t + 1]], c, r2, &mut buf);
                nearest_strong_of(&buf, c)
            } else {
                maps.nearest_strong(c, r2, &mut buf)
            };
            match found {
                Some(p) if p.v > 0.0 && p.v >= 0.3 * m => {
                    state[t] = St::Accepted;
                    result[t] = Some(p);
                    push_nb(t, &mut state, &tries, &mut queue, &mut nb);
                }
                _ => {
                    state[t] = St::Failed;
                    tries[t] += 1;
                }
            }
        }
    }
    // Dots never reached (isolated): keep a small first-pass displacement.
    for k in 0..n {
        if state[k] == St::Unvisited
            && let Some(p) = first[k]
            && norm(disp(&p, k)) < 0.25 * s
        {
            result[k] = Some(p);
        }
    }

    // Sites: predicted = reference position + the neighbours' median displacement (each seed
    // on its own), each with its reference window.
    let side = 2 * crate::classify::window_half(cfg, s, sigma) + 1;
    let sites: Vec<Site> = (0..n)
        .into_par_iter()
        .with_min_len(PAR_MIN)
        .map_init(new_bufs, |bufs, k| {
            let pd = neighbour_median(k, &result, 2, bufs)
                .unwrap_or_else(|| pred_disp[k].unwrap_or([0.0, 0.0]));
            // A dot the reference did not see must pass a stricter test when found by a
            // search.
            let peak_extra = if seeds[k].flags.contains(DotFlags::MISSING) {
                1.0
            } else {
                0.0
            };
            // (the reference window where it was not clipped by the image: a full window)
            let r = &seeds[k];
            let full = r.window.width == side && r.window.height == side;
            Site {
                index: r.index,
                predicted: [q[k][0] + pd[0], q[k][1] + pd[1]],
                peak: result[k],
                peak_extra,
                window_from: (full && r.centre.iter().all(|v| v.is_finite()))
                    .then_some((r.centre, r.window)),
                measured: if anchor[k] {
                    still[k].map(|m| (q[k], m))
                } else {
                    None
                },
            }
        })
        .collect();
    let site_idx: Vec<GridIndex> = seeds.iter().map(|t| t.index).collect();
    let stat = |c: [f64; 2]| tpl.eval(image, sign, c).map(|t| t.0);
    let noise = interstitial_noise(stat, (w, h), mask, cfg.lattice, &site_idx, |g| {
        slot.get(g.i, g.j)
            .filter(|&&k| k != usize::MAX)
            .and_then(|&k| result[k].map(|p| p.pos()))
    })
    .unwrap_or_else(|| fallback_noise(stat, w, h, s));
    let ctx = Ctx {
        img: image,
        sign,
        mask,
        nonfinite,
        spacing: s,
        sigma,
        a: reference.lattice.a,
        b: reference.lattice.b,
        cfg,
        noise,
    };
    let classified = classify(&ctx, &sites, Some(&nbhd));
    let (mut seeds, contrast): (Vec<Seed>, Vec<f64>) =
        classified.into_iter().map(|c| (c.seed, c.contrast)).unzip();
    // (a site's flag depends on its grid index alone, through the reference's map and the
    // mask: the reference's flag where the reference found its dot)
    flag_roi_edge_known(&mut seeds, &reference.seeds, mask, (w, h), |i, j| {
        reference.map.predict(i, j)
    });
    let stats = stats_of(
        &seeds,
        noise,
        reference.stats.map_rms,
        reference.stats.map_inliers,
        fp.k,
        None,
    );
    Ok(Detection {
        width: w,
        height: h,
        lattice: reference.lattice,
        map: reference.map.clone(),
        spacing: s,
        diameter: reference.diameter,
        seeds,
        contrast,
        stats,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn textured(w: usize, h: usize) -> Image {
        Image::from_fn(w, h, |x, y| {
            let (fx, fy) = (x as f64, y as f64);
            let dots = (fx * 0.79).sin() * (fy * 0.81).cos();
            let tex = ((x * 7919 + y * 104729) % 97) as f64 * 0.37;
            200.0 + 0.5 * fx - 0.3 * fy + 500.0 * dots * dots + tex
        })
    }

    fn near(a: &Peak, b: &Peak) -> bool {
        (a.x - b.x).abs() < 1e-6
            && (a.y - b.y).abs() < 1e-6
            && (a.v - b.v).abs() <= 1e-5 * b.v.abs().max(1.0)
    }

    /// Inside its interior the crop's map finds the whole map's peaks (positions to 1e-6 px,
    /// values to 1e-5: the crop's running sums start at its edge); beyond it, and without a
    /// crop, the searches read the whole map itself.
    #[test]
    fn a_cropped_maps_searches_are_the_whole_maps() {
        for (k, sigma_f, box_half) in [(1usize, 1.2, 4usize), (2, 0.9, 3)] {
            let img = textured(230, 190);
            let fp = FilterParams {
                k,
                sigma_f,
                box_half,
            };
            let whole = DotMap::build(&img, 1.0, 0.0, false, &fp);
            let around = [[120.3, 96.7], [131.0, 88.2]];
            let maps = Maps::new(&img, 1.0, 0.0, false, &fp, Some(&around), 9.0);
            assert!(matches!(maps.source, Source::Crop { .. }));
            assert!(maps.whole.get().is_none());
            let (mut a, mut b) = (Vec::new(), Vec::new());
            for c in [[120.3, 96.7], [131.0, 88.2], [118.0, 95.5], [133.4, 90.0]] {
                for r in [2.5, 6.0] {
                    assert!(maps.crop_for(c, r).is_some(), "{c:?} {r}");
                    a.clear();
                    b.clear();
                    maps.local_maxima_px(c, r, &mut a);
                    whole.local_maxima_px(c, r, &mut b);
                    assert_eq!(a.len(), b.len(), "{c:?} {r}");
                    assert!(a.iter().zip(&b).all(|(p, q)| near(&p.peak, &q.peak)));
                    // the list read back on a smaller disc
                    let (mut pa, mut pb) = (Vec::new(), Vec::new());
                    maps.maxima_within(&a, c, 0.5 * r, &mut pa);
                    whole.maxima_within(&b, c, 0.5 * r, &mut pb);
                    assert_eq!(pa.len(), pb.len());
                    assert!(pa.iter().zip(&pb).all(|(p, q)| near(p, q)));
                    let (mut ba, mut bb) = (Vec::new(), Vec::new());
                    let (sa, sb) = (
                        maps.nearest_strong(c, r, &mut ba),
                        whole.nearest_strong(c, r, &mut bb),
                    );
                    assert_eq!(sa.is_some(), sb.is_some());
                    if let (Some(p), Some(q)) = (sa, sb) {
                        assert!(near(&p, &q), "{p:?} {q:?}");
                    }
                    let (va, vb) = (maps.sample(c), whole.sample(c));
                    assert!((va - vb).abs() <= 1e-5 * vb.abs().max(1.0), "{va} {vb}");
                }
            }
            // nothing read the whole map so far; a search beyond the interior does, exactly
            assert!(maps.whole.get().is_none());
            let far = [6.0, 5.0];
            assert!(maps.crop_for(far, 3.0).is_none());
            let (mut pa, mut pb) = (Vec::new(), Vec::new());
            let got = maps.nearest_strong(far, 3.0, &mut pa);
            assert_eq!(got, whole.nearest_strong(far, 3.0, &mut pb));
            assert!(maps.whole.get().is_some());
            // an anchor's value beyond the interior is not read: NaN
            assert!(maps.sample(far).is_nan());
        }
        // nothing to search: no map; every dot searched: the whole map
        let img = textured(64, 64);
        let fp = FilterParams {
            k: 1,
            sigma_f: 1.0,
            box_half: 3,
        };
        let none = Maps::new(&img, 1.0, 0.0, false, &fp, Some(&[]), 9.0);
        assert!(matches!(none.source, Source::Nothing) && none.sample([30.0, 30.0]).is_nan());
        let all = Maps::new(&img, 1.0, 0.0, false, &fp, None, 9.0);
        assert!(matches!(all.source, Source::Whole));
        let whole = DotMap::build(&img, 1.0, 0.0, false, &fp);
        assert_eq!(all.sample([30.0, 30.0]), whole.sample([30.0, 30.0]));
        // a crop of more than half the image: the whole map
        let wide = Maps::new(&img, 1.0, 0.0, false, &fp, Some(&[[32.0, 32.0]]), 20.0);
        assert!(matches!(wide.source, Source::Whole));
    }
}
