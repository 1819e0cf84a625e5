//! Lattice layout and whole scenes (reference, gradient, stack).

use crate::config::{FlowConfig, LatticeKind, SceneConfig};
use crate::field::apply_flow;
use crate::render::{Illumination, add_noise, render_mean, scene_mask};
use crate::rng::{
    STREAM_GRADIENT, STREAM_REFERENCE, STREAM_STACK, frame_seed, image_seed, site_rng,
};
use crate::truth::compute_bounds;
use crate::{SynthError, TruthDot};
use bostrack_core::{DotFlags, Gaussian2D, GridIndex, Image, Lattice, Mask, NoiseModel};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_3, FRAC_PI_4, FRAC_PI_6};

/// The lattice of a scene, with the basis chosen per docs/CONVENTIONS.md whatever the angle.
///
/// The rotation is reduced to the lattice's symmetry: for a square lattice to `θ' ∈ (-45°, 45°]`
/// (a multiple of 90° removed), for a hexagonal one to `θ' ∈ (-30°, 30°]` (a multiple of 60°),
/// and the lattice is `Lattice::square(origin, spacing, θ')` / `Lattice::hexagonal(…)`. So `a`
/// is the basis vector closest to +x; on the square lattice `b` (a turned by +90°) is the one
/// closest to +y; on the hexagonal lattice `b` is `a` turned by +60° (towards +y).
pub fn lattice_for(cfg: &SceneConfig) -> Lattice {
    let l = &cfg.lattice;
    let origin = l
        .origin
        .unwrap_or([(cfg.width / 2) as f64, (cfg.height / 2) as f64]);
    let theta = l.angle_deg.to_radians();
    match l.kind {
        LatticeKind::Square => {
            let k = ((theta - FRAC_PI_4) / FRAC_PI_2).ceil();
            Lattice::square(origin, l.spacing, theta - k * FRAC_PI_2)
        }
        LatticeKind::Hexagonal => {
            let k = ((theta - FRAC_PI_6) / FRAC_PI_3).ceil();
            Lattice::hexagonal(origin, l.spacing, theta - k * FRAC_PI_3)
        }
    }
}

/// Every site whose dot can reach the image (centre within the render margin of the pixel
/// area), in grid order: `j` ascending, then `i` ascending.
fn sites(cfg: &SceneConfig, lat: &Lattice) -> Vec<GridIndex> {
    let m = cfg.render_margin();
    let (x0, y0) = (-0.5 - m, -0.5 - m);
    let (x1, y1) = (cfg.width as f64 - 0.5 + m, cfg.height as f64 - 0.5 + m);
    let corners = [[x0, y0], [x1, y0], [x0, y1], [x1, y1]];
    let (mut imin, mut imax, mut jmin, mut jmax) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for c in corners {
        // The basis is never degenerate (spacing > 0 checked, angle finite).
        let f = lat.fractional(c).unwrap_or([0.0, 0.0]);
        imin = imin.min(f[0]);
        imax = imax.max(f[0]);
        jmin = jmin.min(f[1]);
        jmax = jmax.max(f[1]);
    }
    let mut out = Vec::new();
    for j in jmin.floor() as i64..=jmax.ceil() as i64 {
        for i in imin.floor() as i64..=imax.ceil() as i64 {
            let (Ok(i), Ok(j)) = (i32::try_from(i), i32::try_from(j)) else {
                continue;
            };
            let idx = GridIndex::new(i, j);
            let p = lat.position(idx);
            if p[0] >= x0 && p[0] <= x1 && p[1] >= y0 && p[1] <= y1 {
                out.push(idx);
            }
        }
    }
    out
}

/// The reference (no-flow) truth of a scene before the bounds: every site that can reach the
/// image, with its dot (illumination, jitter, defects applied) and the layout flags MISSING,
/// DEFECT and FAINT. Each site's random draws come from a seed derived from the scene seed and
/// its grid index, so a site keeps its jitter and defects when the image size or an integer
/// origin shift changes which sites are in view.
pub fn layout(cfg: &SceneConfig) -> Result<Vec<TruthDot>, SynthError> {
    cfg.validate()?;
    let lat = lattice_for(cfg);
    let ill = Illumination::new(cfg);
    let (d, f, b) = (&cfg.dots, &cfg.defects, &cfg.background);
    let out = sites(cfg, &lat)
        .into_iter()
        .map(|idx| {
            let p = lat.position(idx);
            // A fixed number of draws per site, so changing one fraction does not reshuffle the rest.
            let mut rng = site_rng(cfg.seed, idx.i, idx.j);
            let u_missing: f64 = rng.random();
            let u_defect: f64 = rng.random();
            let u_kind: f64 = rng.random();
            let n_amp: f64 = StandardNormal.sample(&mut rng);
            let n_sig: f64 = StandardNormal.sample(&mut rng);

            let l = ill.at(p[0], p[1]);
            let size = (1.0 + d.sigma_jitter * n_sig).max(0.2);
            let mut amplitude = d.amplitude * (1.0 + d.amplitude_jitter * n_amp).max(0.05);
            if b.illuminate_dots {
                amplitude *= l;
            }
            let mut g = Gaussian2D {
                x0: p[0],
                y0: p[1],
                amplitude,
                sigma_x: d.sigma_x * size,
                sigma_y: d.sigma_y * size,
                rho: d.rho,
                background: b.level * l,
            };
            let mut flags = DotFlags::NONE;
            let mut defect = None;
            if u_missing < f.missing {
                flags.insert(DotFlags::MISSING);
            } else if u_defect < f.defective && !f.kinds.is_empty() {
                let kind =
                    f.kinds[((u_kind * f.kinds.len() as f64) as usize).min(f.kinds.len() - 1)];
                use crate::DefectKind::*;
                match kind {
                    Small => {
                        g.sigma_x *= f.small;
                        g.sigma_y *= f.small;
                    }
                    Large => {
                        g.sigma_x *= f.large;
                        g.sigma_y *= f.large;
                    }
                    Faint => g.amplitude *= f.faint,
                    Misshapen => {
                        g.sigma_x *= f.elongation;
                        g.sigma_y /= f.elongation;
                        g.rho = f.misshapen_rho;
                    }
                }
                flags.insert(DotFlags::DEFECT);
                defect = Some(kind);
            }
            if g.amplitude < 0.5 * d.amplitude {
                flags.insert(DotFlags::FAINT);
            }
            TruthDot {
                index: idx,
                params: g,
                flags,
                defect,
                crlb_x: f64::NAN,
                crlb_y: f64::NAN,
            }
        })
        .collect();
    Ok(out)
}

/// A synthetic image with its exact truth.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The lattice the grid indices refer to (see [`lattice_for`]).
    pub lattice: Lattice,
    /// Every site whose dot reaches the image, in grid order (`j`, then `i`), including MISSING
    /// ones and dots centred just outside the image.
    pub truth: Vec<TruthDot>,
    /// The noise-free image (float samples).
    pub mean: Image,
    /// The noisy (and, for 8/12/16 bits, quantised) image.
    pub image: Image,
    /// Region of interest, if the scene has one.
    pub mask: Option<Mask>,
    /// The noise model the bounds use ([`SceneConfig::noise_model`]).
    pub noise: NoiseModel,
}

impl Scene {
    /// The no-flow reference image of `cfg`.
    pub fn reference(cfg: &SceneConfig) -> Result<Scene, SynthError> {
        let truth = layout(cfg)?;
        Scene::build(cfg, truth, image_seed(cfg.seed, STREAM_REFERENCE))
    }

    /// The gradient image: the reference dots moved and blurred by `flow` (see [`FlowConfig`]),
    /// same grid indices, flags MISSING/DEFECT kept, independent noise. The displacement of a
    /// dot is `gradient.truth[k].params.x0 - reference.truth[k].params.x0` (same order).
    ///
    /// The sites are those of the reference (centres within the render margin, about
    /// `window_sigmas·σ`, of the image): a displacement larger than that margin would leave
    /// out dots that it carries into view.
    pub fn gradient(cfg: &SceneConfig, flow: &FlowConfig) -> Result<Scene, SynthError> {
        Scene::gradient_with_noise(cfg, flow, image_seed(cfg.seed, STREAM_GRADIENT))
    }

    /// Gradient frame `n` (numbered from 1) of a campaign, as `bostrack synth` writes it: the
    /// dots of [`Scene::gradient`] (the same flow in every frame) with the frame's own noise,
    /// independent of the other frames and of the reference and stack images.
    pub fn frame(cfg: &SceneConfig, flow: &FlowConfig, n: usize) -> Result<Scene, SynthError> {
        Scene::gradient_with_noise(cfg, flow, frame_seed(cfg.seed, n))
    }

    fn gradient_with_noise(
        cfg: &SceneConfig,
        flow: &FlowConfig,
        noise_seed: u64,
    ) -> Result<Scene, SynthError> {
        flow.validate()?;
        let mut truth = layout(cfg)?;
        for t in &mut truth {
            t.params = apply_flow(&t.params, flow);
            t.flags.remove(DotFlags::FAINT);
            if t.params.amplitude < 0.5 * cfg.dots.amplitude {
                t.flags.insert(DotFlags::FAINT);
            }
        }
        Scene::build(cfg, truth, noise_seed)
    }

    fn build(cfg: &SceneConfig, mut truth: Vec<TruthDot>, seed: u64) -> Result<Scene, SynthError> {
        let mean = render_mean(cfg, &truth)?;
        let mask = scene_mask(cfg);
        compute_bounds(cfg, &mut truth, &mean, mask.as_ref());
        let image = add_noise(cfg, &mean, seed)?;
        Ok(Scene {
            lattice: lattice_for(cfg),
            truth,
            mean,
            image,
            mask,
            noise: cfg.noise_model(),
        })
    }
}

/// `k` no-flow images of `cfg` that differ only by their noise (image `n` uses a noise seed
/// derived from the scene seed and `n`, independent of the reference and gradient images).
/// Their truth is `Scene::reference(cfg)?.truth`, or [`layout`] without the bounds.
pub fn stack(cfg: &SceneConfig, k: usize) -> Result<Vec<Image>, SynthError> {
    let truth = layout(cfg)?;
    let mean = render_mean(cfg, &truth)?;
    (0..k)
        .map(|n| add_noise(cfg, &mean, image_seed(cfg.seed, STREAM_STACK + n as u64)))
        .collect()
}
