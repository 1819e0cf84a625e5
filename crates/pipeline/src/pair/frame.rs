//! One gradient frame: track, fit, match, validate, pair.

use super::reference::{ReferenceContext, ar_shapes_name, image_path, size_text, usable};
use super::stats::{Stopwatch, median_of, median2, percentile_of};
use super::{FrameCounts, FrameMedians, FrameResult, FrameSummary, StageTimes};
use crate::config::Quantities;
use crate::error::PipelineError;
use crate::plan::Plan;
use bostrack_core::{DotFit, DotFlags, Image};
use bostrack_displacement::{DisplacementConfig, PairDot, PairInput, pair_dot_at};
use bostrack_match::{
    MatchConfig, MatchMode, MatchedBy, Matches, MedianTest, NearestConfig, ValidationConfig,
    match_dots, validate_at,
};
use rayon::prelude::*;
use std::path::Path;

/// The fits of one image matched to the reference fits.
pub(crate) struct Matched {
    pub fits: Vec<DotFit>,
    pub pairs: Vec<bostrack_match::Pair>,
    pub matches: Matches,
}

/// Neighbour tails rendered once for the images of a no-flow stack, and the shift (px) of the
/// reference fits they were rendered at.
pub(crate) struct NoFlow<'a> {
    pub tails: &'a bostrack_fit::NeighbourTails,
    pub at: [f64; 2],
}

/// Tracks the reference seeds into `img`.
pub(crate) fn track_image(
    ctx: &ReferenceContext,
    plan: &Plan,
    img: &Image,
    path: &Path,
) -> Result<bostrack_detect::Detection, PipelineError> {
    let (w, h) = ctx.size;
    if (img.width(), img.height()) != (w, h) {
        return Err(PipelineError::SizeMismatch {
            path: path.to_path_buf(),
            what: format!("image size (the reference {} has)", ctx.source().display()),
            expected: size_text(w, h),
            got: size_text(img.width(), img.height()),
        });
    }
    bostrack_detect::track(img, ctx.mask.as_ref(), &ctx.detection, &plan.detect).map_err(|e| {
        with_mask(
            ctx,
            plan,
            PipelineError::Detect {
                path: path.to_path_buf(),
                source: e,
            },
        )
    })
}

/// A failure of a frame's detection or fits while a mask limits the usable pixels names the
/// mask too (as the reference side's do), since it may be the cause.
fn with_mask(ctx: &ReferenceContext, plan: &Plan, e: PipelineError) -> PipelineError {
    match (&ctx.mask, &plan.mask) {
        (Some(m), Some(path)) => PipelineError::Masked {
            mask: path.clone(),
            kept: m.count_kept(),
            total: m.width() * m.height(),
            source: Box::new(e),
        },
        _ => e,
    }
}

/// The median displacement of the tracked dots from the reference seeds (track keeps the
/// reference's seed order), per axis; `None` without a dot found in both.
pub(crate) fn median_shift(
    ctx: &ReferenceContext,
    tracked: &bostrack_detect::Detection,
) -> [Option<f64>; 2] {
    let found = |f: &DotFlags| !f.contains(DotFlags::MISSING);
    median2(
        ctx.detection
            .seeds
            .iter()
            .zip(&tracked.seeds)
            .filter(|(r, g)| found(&r.flags) && found(&g.flags))
            .map(|(r, g)| [g.centre[0] - r.centre[0], g.centre[1] - r.centre[1]]),
    )
}

/// Track the reference seeds into `img`, fit them, match the fits to the reference fits.
/// Stage times go to `times` (detect, fit, match) when given.
pub(crate) fn track_fit_match_timed(
    ctx: &ReferenceContext,
    plan: &Plan,
    img: &Image,
    path: &Path,
    mut times: Option<&mut StageTimes>,
) -> Result<Matched, PipelineError> {
    let mut sw = Stopwatch::start();
    let tracked = track_image(ctx, plan, img, path)?;
    if let Some(t) = times.as_deref_mut() {
        t.push("detect", sw.lap());
    }
    let shift = median_shift(ctx, &tracked);
    fit_match_timed(ctx, plan, img, path, &tracked, shift, times, None)
}

/// `fits` with every centre moved by `shift` (px).
pub(crate) fn moved(fits: &[DotFit], shift: [f64; 2]) -> Vec<DotFit> {
    moved_by(fits, |_| shift)
}

/// `fits` (one per reference seed) with every centre moved by its own tracked displacement,
/// the tracked seed's centre less the reference seed's.
fn moved_each(
    fits: &[DotFit],
    reference: &[bostrack_core::Seed],
    tracked: &[bostrack_core::Seed],
) -> Vec<DotFit> {
    // (the caller checks the lengths; a seed without its pair keeps its centre)
    moved_by(fits, |i| match (reference.get(i), tracked.get(i)) {
        (Some(r), Some(t)) => [t.centre[0] - r.centre[0], t.centre[1] - r.centre[1]],
        _ => [0.0, 0.0],
    })
}

/// `fits` with centre `i` moved by `shift(i)` (px).
fn moved_by(fits: &[DotFit], shift: impl Fn(usize) -> [f64; 2]) -> Vec<DotFit> {
    fits.iter()
        .enumerate()
        .map(|(i, f)| {
            let [dx, dy] = shift(i);
            let mut p = *f;
            p.params.x0 += dx;
            p.params.y0 += dy;
            p
        })
        .collect()
}

/// Fits the tracked seeds in `img` and matches the fits to the reference fits; `init` is the
/// tracked dots' [`median_shift`]; `no_flow` for the images of the no-flow stack (one pass from
/// the reference fits, see below).
#[allow(clippy::too_many_arguments)]
pub(crate) fn fit_match_timed(
    ctx: &ReferenceContext,
    plan: &Plan,
    img: &Image,
    path: &Path,
    tracked: &bostrack_detect::Detection,
    init: [Option<f64>; 2],
    mut times: Option<&mut StageTimes>,
    no_flow: Option<NoFlow>,
) -> Result<Matched, PipelineError> {
    let mut sw = Stopwatch::start();
    let mask = ctx.mask.as_ref();
    let prior = if let Some(nf) = no_flow {
        // a no-flow image is the reference moved by the camera's common shift: a first pass
        // from the reference fits moved by the tracked dots' median displacement (neighbours
        // subtracted from those; their tails as rendered once for the stack while this image's
        // shift is within TAILS_MAX_SHIFT of theirs), instead of moment estimates and two
        // passes; then the neighbour iteration to convergence on this image's own fits
        let [sx, sy] = init.map(|v| v.unwrap_or(0.0));
        let small =
            (sx - nf.at[0]).abs().max((sy - nf.at[1]).abs()) <= bostrack_fit::TAILS_MAX_SHIFT;
        Some((moved(&ctx.fits, [sx, sy]), small.then_some(nf.tails)))
    } else if plan.fit.neighbours == bostrack_fit::Neighbours::Subtract
        && plan.fit.estimator == bostrack_fit::Estimator::Lsg
        && tracked.seeds.len() == ctx.fits.len()
    {
        // a gradient frame: the same joint solution from the reference fits, each moved by its
        // own tracked displacement (neighbours subtracted from those), instead of moment
        // estimates and two full passes; the neighbour iteration then refits the dots whose
        // neighbourhood changed (in the flow region) until it converges
        Some((
            moved_each(&ctx.fits, &ctx.detection.seeds, &tracked.seeds),
            None,
        ))
    } else {
        None
    };
    let fits = match prior {
        Some((prior, tails)) => bostrack_fit::refit_dots_remembered(
            img,
            mask,
            &tracked.seeds,
            &plan.fit,
            &ctx.noise,
            &prior,
            tails,
            Some(&ctx.memory),
        )
        .map(|r| r.0),
        None => bostrack_fit::fit_dots(img, mask, &tracked.seeds, &plan.fit, &ctx.noise),
    }
    .map_err(|e| {
        with_mask(
            ctx,
            plan,
            PipelineError::Fit {
                path: path.to_path_buf(),
                source: e,
            },
        )
    })?;
    if let Some(t) = times.as_deref_mut() {
        t.push("fit", sw.lap());
    }

    // kd-tree settings: radius = search_radius x spacing; the median displacement of the
    // tracked dots is the predictor of dots without usable index neighbours
    let spacing = ctx.detection.spacing;
    let initial_displacement = match init {
        [Some(x), Some(y)] => Some([x, y]),
        _ => None,
    };
    let cfg = MatchConfig {
        mode: MatchMode::GridIndex,
        nearest: NearestConfig {
            radius: plan.matching.search_radius * spacing,
            initial_displacement,
            ..NearestConfig::for_spacing(spacing)
        },
    };
    let matches = match_dots(&ctx.fits, &fits, &cfg).map_err(|e| PipelineError::Match {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    if let Some(t) = times {
        t.push("match", sw.lap());
    }
    Ok(Matched {
        fits,
        pairs: matches.pairs.clone(),
        matches,
    })
}

/// Processes one gradient frame: reads it, then [`process_image`]. `plan` must be the plan
/// the context was prepared from.
pub fn process_frame(
    ctx: &ReferenceContext,
    plan: &Plan,
    frame: &Path,
) -> Result<FrameResult, PipelineError> {
    let mut sw = Stopwatch::start();
    let (img, clip) = bostrack_io::read_image_clipped(frame, plan.config.input.saturation)?;
    let decode = sw.lap();
    let mut r = process_image(ctx, plan, &img, frame)?;
    r.summary.times.stages.insert(0, ("decode".into(), decode));
    r.summary.saturation = Some(clip);
    Ok(r)
}

/// Processes one gradient image already in memory; `frame` names it (its file stem is the
/// result's `stem`). One [`PairDot`] per reference dot, in the reference's order.
///
/// Errors: an image of another size than the reference ([`PipelineError::SizeMismatch`]),
/// detection or fit failures on the whole image, and an image in which no reference dot is
/// found ([`PipelineError::NoDots`]).
pub fn process_image(
    ctx: &ReferenceContext,
    plan: &Plan,
    img: &Image,
    frame: &Path,
) -> Result<FrameResult, PipelineError> {
    let mut times = StageTimes::default();
    let path = if img.meta.source.is_some() {
        image_path(img, "")
    } else {
        frame.to_path_buf()
    };
    let m = track_fit_match_timed(ctx, plan, img, &path, Some(&mut times))?;
    let mut sw = Stopwatch::start();
    let n = ctx.fits.len();
    let both =
        |p: &bostrack_match::Pair| usable(&ctx.fits[p.reference]) && usable(&m.fits[p.gradient]);
    let matched = m.pairs.iter().filter(|p| both(p)).count();
    let found = m.fits.iter().filter(|d| usable(d)).count();
    let reference_fitted = ctx.fits.iter().filter(|d| usable(d)).count();
    let fraction = matched as f64 / reference_fitted.max(1) as f64;
    if matched == 0 || fraction < plan.matching.min_matched_fraction {
        return Err(PipelineError::NoDots {
            path,
            message: format!(
                "only {matched} of the {reference_fitted} fitted reference dots were found in this image \
                 ({:.1} %, below [match] min_matched_fraction = {}): not an image of the target?",
                100.0 * fraction,
                plan.matching.min_matched_fraction
            ),
        });
    }

    // validation: optional threshold, then the normalised median test, at the reference
    // positions (the neighbour lists the reference context made of them)
    let position = |d: &DotFit| [d.params.x0, d.params.y0];
    let at: Vec<usize> = m.pairs.iter().map(|p| p.reference).collect();
    let disp: Vec<[f64; 2]> = m
        .pairs
        .iter()
        .map(|p| {
            if both(p) {
                let (r, g) = (
                    position(&ctx.fits[p.reference]),
                    position(&m.fits[p.gradient]),
                );
                [g[0] - r[0], g[1] - r[1]]
            } else {
                [f64::NAN, f64::NAN]
            }
        })
        .collect();
    let vcfg = ValidationConfig {
        max_displacement: plan.matching.max_displacement,
        median_test: Some(MedianTest {
            threshold: plan.matching.median_threshold,
            epsilon: plan.matching.median_epsilon,
            ..MedianTest::default()
        }),
        replace: false,
    };
    let v =
        validate_at(&ctx.neighbour_lists, &at, &disp, &vcfg).map_err(|e| PipelineError::Match {
            path: path.clone(),
            message: e.to_string(),
        })?;
    let mut partner: Vec<Option<usize>> = vec![None; n];
    let mut flags = vec![DotFlags::NONE; n];
    for (p, c) in m.pairs.iter().zip(&v.checks) {
        partner[p.reference] = Some(p.gradient);
        flags[p.reference] |= p.flags | c.flags();
    }
    // a centre outside the region of interest, in either image, is not a measurement there
    if let Some(mask) = ctx.mask.as_ref() {
        let outside = |d: &DotFit| usable(d) && !mask.keeps_point(d.params.x0, d.params.y0);
        for (i, f) in flags.iter_mut().enumerate() {
            if outside(&ctx.fits[i]) || partner[i].is_some_and(|j| outside(&m.fits[j])) {
                f.insert(DotFlags::OUTSIDE_MASK);
            }
        }
    }
    times.push("validate", sw.lap());

    let dcfg = DisplacementConfig {
        quantities: match ctx.quantities {
            Quantities::Displacement => bostrack_displacement::Quantities::Displacement,
            Quantities::Amplification => bostrack_displacement::Quantities::AmplificationRatio,
            Quantities::Uncertainty => bostrack_displacement::Quantities::Uncertainty,
        },
        ar_variant: plan.uncertainty.ar_variant,
        ar_shapes: ctx.ar_shapes,
        reference_position: ctx.reference_position(plan),
        invalid_if: plan.invalid_if,
    };
    // (each dot on its own, in parallel; in dot order)
    let dots: Vec<PairDot> = (0..n)
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let input = PairInput {
                reference: Some(&ctx.fits[i]),
                gradient: partner[i].map(|j| &m.fits[j]),
                stack: ctx.stack_stats[i],
                flags: flags[i],
            };
            // (every dot has its reference record: `pair_dot` of it, collected by position)
            pair_dot_at(&input, ctx.fits[i].index, &dcfg)
        })
        .collect();
    times.push("pair", sw.lap());

    // with [optics]: the density gradient per dot and the density field
    let (physical, density) = match &plan.density {
        None => (None, None),
        Some(dp) => {
            if dp.reference_mask.is_some() && ctx.density_mask.is_none() {
                return Err(PipelineError::Density {
                    path,
                    message: "[density] reference_mask is set but was not read (a context \
                              prepared from images in memory has no files)"
                        .into(),
                });
            }
            let physical = dp.physical(&dots, ctx.size);
            let field = crate::density::integrate_frame(
                dp,
                &dots,
                &physical,
                ctx.density_mask.as_ref(),
                &path,
            )?;
            times.push("density", sw.lap());
            (Some(physical), Some(field))
        }
    };

    let usable_pair = |p: &&bostrack_match::Pair| both(p);
    let counts = FrameCounts {
        reference_sites: n,
        reference_fitted,
        found,
        matched,
        matched_by_index: m
            .pairs
            .iter()
            .filter(usable_pair)
            .filter(|p| p.by == MatchedBy::GridIndex)
            .count(),
        matched_by_nearest: m
            .pairs
            .iter()
            .filter(usable_pair)
            .filter(|p| p.by == MatchedBy::Nearest)
            .count(),
        grid_mismatches: m.matches.grid_mismatches(),
        unmatched_reference: reference_fitted - matched,
        unmatched_gradient: found - matched,
        outliers: v.outliers(),
        valid: dots.iter().filter(|d| d.valid).count(),
    };
    // the summary's order statistics (18 selections over the frame's dots): the columns in one
    // pass over the valid dots (each ~0.3 kB record read once, not once per column: a column
    // each read them at random, a cache miss per dot), then each selection on its own, in
    // parallel
    let n_valid = counts.valid;
    type Columns = [Vec<f64>; 16];
    let push = |cols: &mut Columns, d: &PairDot| {
        let pair = |v: Option<[f64; 2]>| [v.map(|v| v[0]), v.map(|v| v[1])];
        let [dx, dy] = pair(d.displacement);
        let [ax, ay] = pair(d.ar);
        let [rx, ry] = pair(d.u_ref);
        let [gx, gy] = pair(d.u_grad);
        let [ux, uy] = pair(d.u_d);
        let row = [
            d.displacement.map(|v| v[0].hypot(v[1])),
            d.u_d.map(|v| v[0].hypot(v[1])),
            dx,
            dy,
            ax,
            ay,
            rx,
            ry,
            gx,
            gy,
            ux,
            uy,
            d.reference.map(|f| f.crlb_x),
            d.reference.map(|f| f.crlb_y),
            d.gradient.map(|f| f.crlb_x),
            d.gradient.map(|f| f.crlb_y),
        ];
        for (c, v) in cols.iter_mut().zip(row) {
            if let Some(v) = v {
                c.push(v);
            }
        }
    };
    // (blocks of dots in parallel, then each column's blocks in order: the dots' order)
    let blocks: Vec<Columns> = dots
        .par_chunks(2048)
        .map(|block| {
            let mut cols: Columns = std::array::from_fn(|_| Vec::with_capacity(block.len()));
            for d in block.iter().filter(|d| d.valid) {
                push(&mut cols, d);
            }
            cols
        })
        .collect();
    let mut cols: Columns = std::array::from_fn(|k| {
        let mut c = Vec::with_capacity(n_valid);
        for b in &blocks {
            c.extend_from_slice(&b[k]);
        }
        c
    });
    let m: Vec<Option<f64>> = cols.par_iter_mut().map(|c| median_of(c)).collect();
    // (the amplification ratios' columns, reordered by their medians: the same values)
    let p99: Vec<Option<f64>> = cols[4..6]
        .par_iter_mut()
        .map(|c| percentile_of(c, 99.0))
        .collect();
    let medians = FrameMedians {
        abs_d: m[0],
        abs_u_d: m[1],
        d: [m[2], m[3]],
        ar: [m[4], m[5]],
        ar_p99: [p99[0], p99[1]],
        u_ref: [m[6], m[7]],
        u_grad: [m[8], m[9]],
        u_d: [m[10], m[11]],
        crlb_ref: [m[12], m[13]],
        crlb_grad: [m[14], m[15]],
    };
    let stem = frame
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "frame".into());
    let summary = FrameSummary {
        version: env!("CARGO_PKG_VERSION").into(),
        frame: frame.to_path_buf(),
        quantities: ctx.quantities.name().into(),
        ar_shapes: ar_shapes_name(ctx.ar_shapes).into(),
        ar_variant: match plan.uncertainty.ar_variant {
            bostrack_displacement::ArVariant::Notes => "notes".into(),
            bostrack_displacement::ArVariant::Published => "published".into(),
            bostrack_displacement::ArVariant::Bounds => "bounds".into(),
        },
        counts,
        medians,
        noise: Some(ctx.noise_summary()),
        stack: ctx.stack.clone(),
        stack_note: ctx.stack_note.clone(),
        saturation: None,
        density: density.as_ref().map(|d| d.summary.clone()),
        times,
    };
    Ok(FrameResult {
        stem,
        dots,
        physical,
        density,
        summary,
    })
}
