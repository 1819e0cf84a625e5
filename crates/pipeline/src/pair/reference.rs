//! The reference side of a campaign: computed once, shared by every frame.

use super::stats::{Stopwatch, median2};
use super::{NoiseSummary, StackSummary, StageTimes};
use crate::config::{Quantities, ReferencePosition};
use crate::error::PipelineError;
use crate::plan::{Plan, ReferenceImage};
use bostrack_core::{DotFit, DotFlags, Image, Mask, NoiseModel};
use bostrack_detect::Detection;
use bostrack_displacement::{ArShapes, ReferenceStats};
use bostrack_fit::{Estimator, FitConfig, FitSampling};
use bostrack_io::{ClipLevel, ClipSource, Saturation};
use bostrack_uncertainty::{CommonMode, StackConfig, reference_stack};
use rayon::prelude::*;
use serde::Serialize;
use serde_json::json;
use std::path::{Path, PathBuf};

/// Fewest stack images for a per-dot u_ref (`bostrack_uncertainty::StackConfig::min_images`).
const MIN_STACK_IMAGES: usize = 3;

/// Gradient frames from which a campaign without a no-flow stack builds the reference's linear
/// coupling map for the frames' no-flow parts ([`bostrack_fit::FitMemory::linearised`]): it
/// costs about as much as it saves on 9 frames of the real sample (with a stack the map is made
/// for the stack's images and shared, at no cost).
const MAP_MIN_FRAMES: usize = 10;

/// Everything computed once per campaign: reference image + mask, its detection and fits, the
/// noise model (from the stack when given, else from the reference image), the no-flow stack's
/// per-dot scatter (u_ref, K) when a stack is configured and the outputs need it.
///
/// Build it with [`ReferenceContext::prepare`] (from the files of a [`Plan`]) or
/// [`ReferenceContext::from_images`] (images already in memory).
///
/// ```
/// use bostrack_pipeline::{Plan, ReferenceContext, frame_is_complete, process_frame, write_frame};
/// use bostrack_synth::{DisplacementField, FlowConfig, Scene, SceneConfig, stack};
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// // a synthetic campaign: reference, one gradient frame moved by (0.25, -0.1) px, 3 no-flow images
/// let dir = tempfile::tempdir()?;
/// let camp = dir.path();
/// std::fs::create_dir_all(camp.join("gradient"))?;
/// std::fs::create_dir_all(camp.join("stack"))?;
/// let sc = SceneConfig { width: 96, height: 96, ..Default::default() };
/// let flow = FlowConfig {
///     displacement: DisplacementField::Uniform { dx: 0.25, dy: -0.1 },
///     ..Default::default()
/// };
/// bostrack_io::write_tiff_u16(&camp.join("reference.tif"), &Scene::reference(&sc)?.image)?;
/// bostrack_io::write_tiff_u16(&camp.join("gradient/f1.tif"), &Scene::gradient(&sc, &flow)?.image)?;
/// for (k, img) in stack(&sc, 3)?.iter().enumerate() {
///     bostrack_io::write_tiff_u16(&camp.join(format!("stack/s{k}.tif")), img)?;
/// }
/// std::fs::write(camp.join("pipeline.toml"), "[detect]\nspacing = 8.0\n")?;
///
/// let plan = Plan::load(&camp.join("pipeline.toml"))?;
/// let ctx = ReferenceContext::prepare(&plan)?; // noise model, detection, fits, stack u_ref
/// let frame = process_frame(&ctx, &plan, &plan.gradients[0])?;
/// let dx = frame.summary.medians.d[0].unwrap();
/// assert!((dx - 0.25).abs() < 0.01);
/// assert!(frame.summary.medians.u_d[0].unwrap() > 0.0);
/// write_frame(&camp.join("out"), &frame)?; // out/f1/dots.csv, out/f1/summary.json
/// assert!(frame_is_complete(&camp.join("out"), "f1"));
/// # Ok(())
/// # }
/// ```
#[derive(Debug)]
pub struct ReferenceContext {
    /// The reference file, or `<stack mean>`.
    pub(crate) source: PathBuf,
    pub(crate) size: (usize, usize),
    pub(crate) mask: Option<Mask>,
    pub(crate) detection: Detection,
    /// One per reference seed, in the detection's order.
    pub(crate) fits: Vec<DotFit>,
    /// What the reference's fits keep for the frames' first passes (scaled to a frame's noise
    /// for a stack-mean reference).
    pub(crate) memory: bostrack_fit::FitMemory,
    /// The noise model of one camera frame (fits of gradient and stack images).
    pub(crate) noise: NoiseModel,
    pub(crate) noise_source: &'static str,
    /// The model the reference fits were weighted with (`noise`, or `noise / K` for a
    /// stack-mean reference image).
    pub(crate) reference_noise: NoiseModel,
    /// The reference positions' nearest neighbours for every frame's median test (the frames'
    /// vectors sit at the reference positions).
    pub(crate) neighbour_lists: bostrack_match::NeighbourLists,
    /// Per reference fit, the stack statistics (`None` everywhere without stack fits).
    pub(crate) stack_stats: Vec<Option<ReferenceStats>>,
    pub(crate) stack: Option<StackSummary>,
    pub(crate) stack_note: Option<String>,
    pub(crate) quantities: Quantities,
    pub(crate) ar_shapes: ArShapes,
    pub(crate) times: StageTimes,
    /// The clip levels of the files read ([`ReferenceContext::prepare`]); `None` for images
    /// handed over in memory, whose `meta.saturation` is used as it is.
    pub(crate) clip: Option<ClipSummary>,
    /// `[density] reference_mask` (the quiescent gas), read by [`ReferenceContext::prepare`].
    pub(crate) density_mask: Option<Mask>,
}

/// The clip levels of the reference side, for the run record (`saturation`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub(crate) struct ClipSummary {
    /// `[input] saturation` as configured.
    setting: Saturation,
    /// The reference file's level (absent for a stack-mean reference: each stack image's own).
    reference: Option<ClipLevel>,
    /// The distinct levels of the stack images: level, source, images.
    stack: Vec<StackClip>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
struct StackClip {
    level: Option<f64>,
    source: ClipSource,
    images: usize,
}

impl ClipSummary {
    fn new(setting: Saturation, reference: Option<ClipLevel>, stack: &[ClipLevel]) -> Self {
        let mut distinct: Vec<StackClip> = Vec::new();
        for c in stack {
            match distinct
                .iter_mut()
                .find(|d| d.level == c.level && d.source == c.source)
            {
                Some(d) => d.images += 1,
                None => distinct.push(StackClip {
                    level: c.level,
                    source: c.source,
                    images: 1,
                }),
            }
        }
        ClipSummary {
            setting,
            reference,
            stack: distinct,
        }
    }
}

/// Shapes the amplification ratio is evaluated on, by the fit's sampling (see the module
/// documentation): pixel-blurred for least-squares fits of the pixel-integrated model, the
/// fitted shapes otherwise.
pub(crate) fn ar_shapes_for(fit: &FitConfig) -> ArShapes {
    if fit.estimator == Estimator::Lsg && fit.sampling != FitSampling::Point {
        ArShapes::PixelBlurred
    } else {
        ArShapes::Fitted
    }
}

pub(crate) fn ar_shapes_name(s: ArShapes) -> &'static str {
    match s {
        ArShapes::PixelBlurred => "pixel-blurred",
        ArShapes::Fitted => "fitted",
    }
}

/// The file an image came from, or a description of it.
pub(crate) fn image_path(img: &Image, fallback: &str) -> PathBuf {
    img.meta
        .source
        .clone()
        .unwrap_or_else(|| PathBuf::from(fallback))
}

pub(crate) fn size_text(w: usize, h: usize) -> String {
    format!("{w}x{h} px")
}

/// The reference fits' [`bostrack_fit::FitMemory`] for single frames: a stack-mean reference
/// was weighted with the frame's noise model divided by K (every variance 1/K of a frame's).
fn memory_for_frames(
    memory: bostrack_fit::FitMemory,
    frame: &NoiseModel,
    reference: &NoiseModel,
) -> bostrack_fit::FitMemory {
    if reference == frame {
        return memory;
    }
    let ratio = if reference.read_variance > 0.0 {
        frame.read_variance / reference.read_variance
    } else {
        frame.gain / reference.gain
    };
    memory.for_variance_ratio(ratio)
}

pub(crate) fn usable(d: &DotFit) -> bool {
    d.status.is_ok() && d.params.x0.is_finite() && d.params.y0.is_finite()
}

impl ReferenceContext {
    /// Prepares the reference side of a campaign from the files of `plan`: reads the stack (if
    /// configured), the reference image (or the stack's pixel mean) and the mask, then
    /// [`ReferenceContext::from_images`]. Runs inside the caller's rayon pool.
    pub fn prepare(plan: &Plan) -> Result<ReferenceContext, PipelineError> {
        let mut sw = Stopwatch::start();
        let mut times = StageTimes::default();
        let saturation = plan.config.input.saturation;
        // every page of every stack file is a no-flow image (a multi-page TIFF is a stack),
        // each with its clip level
        let (stack, stack_clips): (Vec<Image>, Vec<ClipLevel>) = plan
            .stack
            .par_iter()
            .map(
                |p| -> Result<Vec<(Image, ClipLevel)>, bostrack_io::IoError> {
                    bostrack_io::read_stack(p)?
                        .into_iter()
                        .map(|mut img| {
                            let clip =
                                bostrack_io::apply_saturation(&mut img, saturation, Some(p))?;
                            Ok((img, clip))
                        })
                        .collect()
                },
            )
            .collect::<Result<Vec<_>, _>>()?
            .into_iter()
            .flatten()
            .unzip();
        if !stack.is_empty() {
            times.push("stack_decode", sw.lap());
        }
        check_stack_kind(&stack)?;
        let (reference, source, reference_clip) = match &plan.reference {
            ReferenceImage::File(p) => {
                let (img, clip) = bostrack_io::read_image_clipped(p, saturation)?;
                (img, p.clone(), Some(clip))
            }
            ReferenceImage::StackMean => {
                let first = stack.first().ok_or_else(|| PipelineError::NoDots {
                    path: plan.config_file.clone(),
                    message: "the reference is the stack mean but the stack is empty".into(),
                })?;
                (
                    pixel_mean(&stack, first)?,
                    PathBuf::from("<stack mean>"),
                    None,
                )
            }
        };
        let (w, h) = (reference.width(), reference.height());
        let mask = plan
            .mask
            .as_ref()
            .map(|p| bostrack_io::read_mask_for(p, w, h))
            .transpose()?;
        times.push("decode", sw.lap());
        let mut ctx = Self::build(plan, reference, source, mask, stack, times)?;
        ctx.clip = Some(ClipSummary::new(saturation, reference_clip, &stack_clips));
        ctx.density_mask = plan
            .density
            .as_ref()
            .and_then(|d| d.reference_mask.as_ref())
            .map(|p| bostrack_io::read_mask_for(p, w, h))
            .transpose()?;
        Ok(ctx)
    }

    /// Prepares the reference side from images in memory. `stack` are the no-flow images
    /// (empty for none); the stage settings come from `plan` (its file lists are not read;
    /// with `plan.reference = StackMean`, `reference` must be the stack's pixel mean and its
    /// fits are weighted with the noise model divided by K).
    pub fn from_images(
        plan: &Plan,
        reference: Image,
        mask: Option<Mask>,
        stack: Vec<Image>,
    ) -> Result<ReferenceContext, PipelineError> {
        check_stack_kind(&stack)?;
        let source = image_path(&reference, "<reference image>");
        Self::build(plan, reference, source, mask, stack, StageTimes::default())
    }

    fn build(
        plan: &Plan,
        reference: Image,
        source: PathBuf,
        mask: Option<Mask>,
        stack: Vec<Image>,
        mut times: StageTimes,
    ) -> Result<ReferenceContext, PipelineError> {
        let mut sw = Stopwatch::start();
        let (w, h) = (reference.width(), reference.height());
        for (k, img) in stack.iter().enumerate() {
            if (img.width(), img.height()) != (w, h) {
                return Err(PipelineError::SizeMismatch {
                    path: image_path(img, &format!("stack image {k}")),
                    what: format!("image size (the reference {} has)", source.display()),
                    expected: size_text(w, h),
                    got: size_text(img.width(), img.height()),
                });
            }
        }
        let mask_path = plan.mask.clone().unwrap_or_else(|| PathBuf::from("<mask>"));
        if let Some(m) = mask.as_ref().filter(|m| !m.matches(&reference)) {
            return Err(PipelineError::SizeMismatch {
                path: mask_path,
                what: "mask size".into(),
                expected: size_text(w, h),
                got: size_text(m.width(), m.height()),
            });
        }
        let quantities = plan.config.output.quantities;
        let mask_ref = mask.as_ref();

        // the noise model (the stack when there is one, >= 2 images, else the reference image)
        // and the detection are independent: computed concurrently (each stage's own wall
        // time is reported)
        fn timed<T>(
            f: impl FnOnce() -> Result<T, PipelineError>,
        ) -> Result<(T, f64), PipelineError> {
            let t = std::time::Instant::now();
            f().map(|v| (v, t.elapsed().as_secs_f64()))
        }
        let noise_job = || -> Result<(NoiseModel, &'static str), PipelineError> {
            if stack.len() >= 2 {
                let n = bostrack_fit::noise_from_stack(&stack, mask_ref).map_err(|e| {
                    PipelineError::Fit {
                        path: image_path(&stack[0], "stack"),
                        source: e,
                    }
                })?;
                Ok((n, "stack"))
            } else {
                let n = bostrack_fit::estimate_noise(&reference, mask_ref).map_err(|e| {
                    PipelineError::Fit {
                        path: source.clone(),
                        source: e,
                    }
                })?;
                Ok((n, "reference image"))
            }
        };
        let detect_job = || {
            bostrack_detect::detect(&reference, mask_ref, &plan.detect).map_err(|e| {
                PipelineError::Detect {
                    path: source.clone(),
                    source: e,
                }
            })
        };
        // a failure of the reference side while a mask is given names the mask too
        let with_mask = |e: PipelineError| match &mask {
            Some(m) => PipelineError::Masked {
                mask: mask_path.clone(),
                kept: m.count_kept(),
                total: m.width() * m.height(),
                source: Box::new(e),
            },
            None => e,
        };
        let (noise_result, detect_result) = rayon::join(|| timed(noise_job), || timed(detect_job));
        let (((noise, noise_source), noise_time), (detection, detect_time)) = (
            noise_result.map_err(with_mask)?,
            detect_result.map_err(with_mask)?,
        );
        let reference_noise = if plan.reference == ReferenceImage::StackMean && !stack.is_empty() {
            let k = stack.len() as f64;
            NoiseModel {
                read_variance: noise.read_variance / k,
                gain: noise.gain / k,
                offset: noise.offset,
            }
        } else {
            noise
        };
        sw.lap();
        times.push("noise", noise_time);
        times.push("detect", detect_time);
        let (fits, _, memory) = bostrack_fit::fit_dots_remembered(
            &reference,
            mask_ref,
            &detection.seeds,
            &plan.fit,
            &reference_noise,
        )
        .map_err(|e| {
            with_mask(PipelineError::Fit {
                path: source.clone(),
                source: e,
            })
        })?;
        times.push("fit", sw.lap());
        if !fits.iter().any(usable) {
            return Err(with_mask(PipelineError::NoDots {
                path: source,
                message: format!(
                    "none of the {} detected dots could be fitted",
                    detection.seeds.len()
                ),
            }));
        }

        let positions: Vec<[f64; 2]> = fits.iter().map(|d| [d.params.x0, d.params.y0]).collect();
        let neighbour_lists = bostrack_match::NeighbourLists::new(
            &positions,
            bostrack_match::MedianTest::default().neighbours,
        );
        let mut ctx = ReferenceContext {
            source,
            size: (w, h),
            mask,
            detection,
            neighbour_lists,
            stack_stats: vec![None; fits.len()],
            fits,
            memory: memory_for_frames(memory, &noise, &reference_noise),
            noise,
            noise_source,
            reference_noise,
            stack: None,
            stack_note: None,
            quantities,
            ar_shapes: ar_shapes_for(&plan.fit),
            times,
            clip: None,
            density_mask: None,
        };
        ctx.stack_note = if quantities < Quantities::Uncertainty {
            Some(format!(
                "not computed: [output] quantities = \"{}\" (u_ref, u_grad, u_d need \"uncertainty\")",
                quantities.name()
            ))
        } else if stack.is_empty() {
            Some("no no-flow stack configured ([input] stack = \"\" and stack_dir = \"\"): no u_ref, u_grad, u_d; the per-dot bounds crlb_* are still given".into())
        } else if stack.len() < MIN_STACK_IMAGES {
            Some(format!(
                "the no-flow stack has {} image(s); a per-dot u_ref needs at least {MIN_STACK_IMAGES}",
                stack.len()
            ))
        } else {
            ctx.fit_stack(plan, &stack)?;
            None
        };
        // without the stack's map: the reference's own, where enough frames follow to repay it
        // (~90 ms once on the real sample, ~10 ms less per frame)
        if plan.fit.frame_map && !ctx.memory.has_map() && plan.gradients.len() >= MAP_MIN_FRAMES {
            let mut sw = Stopwatch::start();
            ctx.memory = std::mem::take(&mut ctx.memory).linearised(
                &ctx.fits,
                &ctx.detection.seeds,
                &plan.fit,
                &reference,
                ctx.mask.as_ref(),
                &ctx.noise,
            );
            ctx.times.push("coupling_map", sw.lap());
        }
        Ok(ctx)
    }

    /// Tracks, fits and matches every stack image, then the per-dot scatter (u_ref).
    fn fit_stack(&mut self, plan: &Plan, stack: &[Image]) -> Result<(), PipelineError> {
        let mut sw = Stopwatch::start();
        // track every stack image, then render the reference dots' neighbour tails once, at
        // the stack's median shift from the reference (the images differ from it by the
        // camera's jitter, far below TAILS_MAX_SHIFT, so no image renders them again)
        let tracked = stack
            .par_iter()
            .enumerate()
            .map(|(k, img)| {
                let path = image_path(img, &format!("stack image {k}"));
                super::frame::track_image(self, plan, img, &path)
            })
            .collect::<Result<Vec<_>, PipelineError>>()?;
        let shifts: Vec<[Option<f64>; 2]> = tracked
            .iter()
            .map(|t| super::frame::median_shift(self, t))
            .collect();
        let at =
            median2(shifts.iter().map(|s| s.map(|v| v.unwrap_or(0.0)))).map(|v| v.unwrap_or(0.0));
        // and the neighbour iteration linearised there: after its first pass each image's
        // joint solution comes from that map, without refitting dots
        let tails = bostrack_fit::NeighbourTails::coupled(
            &super::frame::moved(&self.fits, at),
            &self.detection.seeds,
            &plan.fit,
            &stack[0],
            self.mask.as_ref(),
            &self.noise,
        );
        let per_image = stack
            .par_iter()
            .zip(tracked.par_iter().zip(&shifts))
            .enumerate()
            .map(|(k, (img, (tracked, &shift)))| {
                let path = image_path(img, &format!("stack image {k}"));
                let no_flow = super::frame::NoFlow {
                    tails: &tails,
                    at,
                };
                let m = super::frame::fit_match_timed(
                    self,
                    plan,
                    img,
                    &path,
                    tracked,
                    shift,
                    None,
                    Some(no_flow),
                )?;
                let fitted = self.fits.iter().filter(|d| usable(d)).count();
                let matched = m
                    .pairs
                    .iter()
                    .filter(|p| usable(&self.fits[p.reference]) && usable(&m.fits[p.gradient]))
                    .count();
                if matched == 0
                    || (matched as f64) < plan.matching.min_matched_fraction * fitted as f64
                {
                    return Err(PipelineError::NoDots {
                        path,
                        message: format!(
                            "no-flow stack image: only {matched} of the {fitted} fitted reference dots were found \
                             (below [match] min_matched_fraction = {})",
                            plan.matching.min_matched_fraction
                        ),
                    });
                }
                // pairs whose index and kd-tree disagree are left out; the others carry the
                // reference's grid index (kd-tree fall-back pairs too)
                Ok(m.pairs
                    .iter()
                    .filter(|p| !p.flags.contains(DotFlags::GRID_MISMATCH))
                    .map(|p| {
                        let mut d = m.fits[p.gradient];
                        d.index = self.fits[p.reference].index;
                        d
                    })
                    .collect::<Vec<DotFit>>())
            })
            .collect::<Result<Vec<_>, PipelineError>>()?;
        // with `[fit] frame_map`: the frames solve their no-flow parts on the same map (see
        // `FitMemory::with_map`)
        if plan.fit.frame_map {
            self.memory = std::mem::take(&mut self.memory).with_map(&tails);
        }
        self.times.push("stack_fit", sw.lap());
        let common_mode = if plan.uncertainty.common_mode {
            CommonMode::default()
        } else {
            CommonMode::Keep
        };
        let cfg = StackConfig {
            common_mode,
            min_images: MIN_STACK_IMAGES,
        };
        let rs =
            reference_stack(&self.fits, &per_image, &cfg).map_err(|e| PipelineError::Stack {
                path: image_path(&stack[0], "stack"),
                message: e.to_string(),
            })?;
        self.stack_stats = rs
            .dots
            .iter()
            .map(|d| {
                Some(ReferenceStats {
                    images: d.scatter.images,
                    mean: d.scatter.mean,
                    u: d.scatter.u,
                })
            })
            .collect();
        let with_u: Vec<[f64; 2]> = rs.dots.iter().filter_map(|d| d.scatter.u).collect();
        let k = stack.len();
        let n = rs.shifts.len().max(1) as f64;
        let shift_rms =
            [0, 1].map(|a| (rs.shifts.iter().map(|s| s[a] * s[a]).sum::<f64>() / n).sqrt());
        self.stack = Some(StackSummary {
            images: k,
            relative_standard_error: 1.0 / (2.0 * (k as f64 - 1.0)).sqrt(),
            dots_with_u_ref: with_u.len(),
            median_u_ref: median2(with_u.iter().copied()),
            common_mode_removed: plan.uncertainty.common_mode,
            shift_rms,
        });
        self.times.push("stack_scatter", sw.lap());
        Ok(())
    }

    /// Reference-side stage wall times (s): `stack_decode`, `decode`, `noise`, `detect`,
    /// `fit`, `stack_fit`, `stack_scatter`, `coupling_map` (those that ran).
    pub fn timings(&self) -> &StageTimes {
        &self.times
    }

    /// Reference-side facts for the run record and the summary: the reference, its dots, the
    /// lattice, the noise model, the stack statistics (or why there are none).
    pub fn summary(&self) -> serde_json::Value {
        let found = self
            .detection
            .seeds
            .iter()
            .filter(|s| !s.flags.contains(DotFlags::MISSING))
            .count();
        json!({
            "reference": self.source,
            "width": self.size.0,
            "height": self.size.1,
            "sites": self.detection.seeds.len(),
            "dots_found": found,
            "dots_fitted": self.fits.iter().filter(|d| usable(d)).count(),
            "spacing": self.detection.spacing,
            "diameter": self.detection.diameter,
            "median_crlb_ref": median2(self.fits.iter().filter(|d| usable(d)).map(|d| [d.crlb_x, d.crlb_y])),
            "noise": self.noise_summary(),
            "reference_noise": self.reference_noise,
            "quantities": self.quantities.name(),
            "ar_shapes": ar_shapes_name(self.ar_shapes),
            "stack": self.stack,
            "stack_note": self.stack_note,
            "saturation": self.clip,
            "times": self.times,
        })
    }

    /// `(width, height)` of the reference image.
    pub fn image_size(&self) -> (usize, usize) {
        self.size
    }

    /// The region-of-interest mask, if one is configured.
    pub fn mask(&self) -> Option<&Mask> {
        self.mask.as_ref()
    }

    /// The reference detection (lattice, seeds).
    pub fn detection(&self) -> &Detection {
        &self.detection
    }

    /// The reference fits, one per seed of [`ReferenceContext::detection`].
    pub fn fits(&self) -> &[DotFit] {
        &self.fits
    }

    /// The noise model of one camera frame, and where it came from ("stack" or "reference
    /// image").
    pub fn noise(&self) -> (NoiseModel, &'static str) {
        (self.noise, self.noise_source)
    }

    /// Per reference fit, `[u_ref_x, u_ref_y]` from the no-flow stack (`None` where the dot
    /// has none, or everywhere without stack fits).
    pub fn u_ref(&self) -> Vec<Option<[f64; 2]>> {
        self.stack_stats
            .iter()
            .map(|s| s.and_then(|s| s.u))
            .collect()
    }

    /// The stack statistics, when the stack was fitted.
    pub fn stack_summary(&self) -> Option<&StackSummary> {
        self.stack.as_ref()
    }

    /// Why there are no stack statistics, when there are none.
    pub fn stack_note(&self) -> Option<&str> {
        self.stack_note.as_deref()
    }

    pub(crate) fn noise_summary(&self) -> NoiseSummary {
        NoiseSummary {
            read_variance: self.noise.read_variance,
            gain: self.noise.gain,
            offset: self.noise.offset,
            source: self.noise_source.into(),
        }
    }

    pub(crate) fn reference_position(
        &self,
        plan: &Plan,
    ) -> bostrack_displacement::ReferencePosition {
        match plan.uncertainty.reference_position {
            ReferencePosition::Image => bostrack_displacement::ReferencePosition::SingleImage,
            ReferencePosition::StackMean => bostrack_displacement::ReferencePosition::StackMean,
        }
    }

    pub(crate) fn source(&self) -> &Path {
        &self.source
    }
}

/// Every stack image must have the bit depth and sample format of the first.
fn check_stack_kind(stack: &[Image]) -> Result<(), PipelineError> {
    let Some(first) = stack.first() else {
        return Ok(());
    };
    let kind = |img: &Image| {
        format!(
            "{}-bit {:?}",
            img.meta.bits_per_sample, img.meta.sample_format
        )
        .to_lowercase()
    };
    for (k, img) in stack.iter().enumerate().skip(1) {
        if img.meta.bits_per_sample != first.meta.bits_per_sample
            || img.meta.sample_format != first.meta.sample_format
        {
            return Err(PipelineError::SizeMismatch {
                path: image_path(img, &format!("stack image {k}")),
                what: format!(
                    "bit depth (the first stack image {} has)",
                    image_path(first, "0").display()
                ),
                expected: kind(first),
                got: kind(img),
            });
        }
    }
    Ok(())
}

/// The pixel-wise mean of the stack (sizes checked here too).
fn pixel_mean(stack: &[Image], first: &Image) -> Result<Image, PipelineError> {
    let (w, h) = (first.width(), first.height());
    let mut sum = vec![0.0; w * h];
    for (k, img) in stack.iter().enumerate() {
        if (img.width(), img.height()) != (w, h) {
            return Err(PipelineError::SizeMismatch {
                path: image_path(img, &format!("stack image {k}")),
                what: "image size (the first stack image has)".into(),
                expected: size_text(w, h),
                got: size_text(img.width(), img.height()),
            });
        }
        for (s, v) in sum.iter_mut().zip(img.data()) {
            *s += v;
        }
    }
    let k = stack.len() as f64;
    sum.iter_mut().for_each(|s| *s /= k);
    let mut meta = first.meta.clone();
    meta.source = None;
    Image::new(w, h, sum, meta).map_err(|e| PipelineError::NoDots {
        path: PathBuf::from("<stack mean>"),
        message: e.to_string(),
    })
}
