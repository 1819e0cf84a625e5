//! The neighbour iteration of a no-flow image, linearised once per scene.
//!
//! A no-flow image (one of the stack) differs from its reference only by noise (and a camera
//! shift far below a dot's size), so its joint solution lies within about one bound of the
//! reference's fits. Around those fits `b` the fixed point of the neighbour iteration is linear:
//! dot i fitted with its neighbours' models subtracted at `b_j + δ_j` lands at
//!
//! `δ_i = δ_i⁰ − Σ_j M_ij δ_j`,  `M_ij = F_i⁻¹ C_ij`
//!
//! (see [`crate::joint::coupling`]: `F_i` the Fisher matrix of dot i's window with its fit's
//! weights, `C_ij` the cross terms with neighbour j's dot parameters), where `δ_i⁰` is its fit
//! with the neighbours held at `b`: exactly the first pass of [`crate::refit_dots`] with the
//! tails rendered from `b`. So after that pass the rest of the iteration needs no pixel work: the
//! vectors `δ` of the dots' parameters are solved by red-black Gauss-Seidel sweeps on the map
//! `M`, computed once per reference and shared by every image of the stack. What the
//! linearisation leaves out is of second order in δ (about one bound, against a dot's size of
//! ~100 bounds). The map evaluates the dots as the pixel-blurred Gaussian (exact for the
//! point-sampled model and for `auto` above 1 px; an approximation of the pixel-integrated model
//! for narrower dots, as in the joint bound). Measured against the pixel iteration run deep
//! (`cargo run --release -p bostrack-pipeline --example converge -- --stack-only`, the real
//! stack): positions within a median 0.025, p99 0.12 of the bound (the pixel iteration at the
//! default tolerance: 0.015, 0.13).

use crate::eval::{
    Kind, Theta, gaussian_from_theta, pixel_blur, pixel_unblur, theta_from_gaussian,
};
use crate::joint::NB;
use bostrack_core::{DotFit, Gaussian2D};
use bostrack_model::Sampling;
use rayon::prelude::*;

/// Sweeps after which an iteration that has not settled is given up (the caller then runs the
/// pixel iteration).
const MAX_SWEEPS: u32 = 200;

/// A dot whose update changes none of its parameters by more than this many of their
/// standard deviations is settled (its neighbours are not updated again for it).
const SETTLED: f64 = 5e-3;

/// Links along which a move of one standard deviation in any one of the neighbour's parameters
/// moves none of the dot's by this many of its own are left out. On the real sample that
/// leaves 52,000 of 90,000 links and the stack's positions within a median 2e-4, a 99th
/// percentile 6e-4 of their bound of those with every link (`converge --stack-only`).
const MIN_LINK: f64 = 1e-2;

/// The linear coupling map of one scene's fits.
///
/// The matrices are kept in `f32`: they multiply corrections of about one bound, so their
/// rounding (6e-8 relative) is five orders below what the linearisation itself leaves. Measured
/// on the real stack (`converge --stack-only`, same settings otherwise): against the deep joint
/// solution median 0.0237, p90 0.0566, p99 0.1619 of the bound with `f64` matrices and the same
/// to those digits with `f32`; the sweeps stream half the memory (192 instead of 384 bytes per
/// link; their speed difference was within the machine's noise). The sums run in `f64`.
#[derive(Clone, Debug)]
pub(crate) struct Coupling {
    /// The fits the map is linearised at (their models are the neighbours pass 1 subtracts).
    pub fits: Vec<DotFit>,
    kind: Kind,
    /// The parameters are the pixel-blurred ones (`false`: point sampling, as fitted).
    blurred: bool,
    /// Per dot: its linearisation point in the map's parameters (`None`: not a neighbour
    /// model, not coupled), its dot parameters' standard deviations, its colour (red-black).
    base: Vec<Option<Theta>>,
    scale: Vec<[f64; 8]>,
    red: Vec<bool>,
    /// Per dot, the range of its links in `nb` and `m`.
    start: Vec<usize>,
    nb: Vec<u32>,
    /// Per link, `M` restricted to the dot parameters (the free ones without the background) of
    /// both dots, by columns, each padded to 8.
    m: Vec<[[f32; 8]; NB]>,
    /// Per dot, its Fisher matrix at `fits` over its window (with its fit's weights), for the
    /// Gauss-Newton step that stands for an image's first pass (`None`: that dot is fitted).
    pub(crate) looked: Vec<Option<crate::dots::Looked>>,
}

/// What [`Coupling::solve`] found.
pub(crate) struct Solved {
    /// Per dot, its corrected parameters (`None`: unchanged).
    pub params: Vec<Option<Gaussian2D>>,
    /// Sweeps made.
    pub sweeps: u32,
}

/// One dot's links as the builder gives them: its free parameters' standard deviations, and
/// per neighbour its index and matrix (see [`crate::joint::DotCoupling`]) as the map keeps it
/// ([`Coupling::link`]).
pub(crate) type DotLinks = Option<([f64; 7], Vec<(u32, [[f32; 8]; NB])>)>;

/// The positions among the free parameters of `kind` of its dot parameters (all but the
/// background).
fn dot_params(kind: Kind) -> Vec<usize> {
    let free = kind.free();
    (0..free.len())
        .filter(|&q| free[q] != crate::eval::IB)
        .collect()
}

impl Coupling {
    /// A link's matrix as the map keeps it: `m` (from [`crate::joint::coupling`], rows and
    /// columns over the free parameters) restricted to the dot parameters of both dots.
    pub(crate) fn link(kind: Kind, m: &[[f64; 8]; NB]) -> [[f32; 8]; NB] {
        let dp = dot_params(kind);
        let mut out = [[0.0f32; 8]; NB];
        for (c32, c) in out.iter_mut().zip(m) {
            for (o, &q) in dp.iter().enumerate() {
                c32[o] = c[q] as f32;
            }
        }
        out
    }

    /// The map of `base` (the fits it is linearised at; a dot without links is not coupled).
    pub(crate) fn new(
        kind: Kind,
        sampling: crate::config::FitSampling,
        base: &[DotFit],
        red: Vec<bool>,
        links: Vec<DotLinks>,
        looked: Vec<Option<crate::dots::Looked>>,
    ) -> Coupling {
        let blurred = sampling.image_model() != Sampling::Point;
        let dp = dot_params(kind);
        // each dot's dot parameters' standard deviations
        let sd: Vec<[f64; 8]> = links
            .iter()
            .map(|l| {
                let mut sc = [0.0; 8];
                if let Some((s, _)) = l {
                    for (o, &q) in dp.iter().enumerate() {
                        sc[o] = s[q];
                    }
                }
                sc
            })
            .collect();
        let nd = dp.len();
        let mut start = Vec::with_capacity(links.len() + 1);
        let (mut nb, mut m) = (Vec::new(), Vec::new());
        let mut theta = Vec::with_capacity(links.len());
        start.push(0);
        for (i, (f, l)) in base.iter().zip(links).enumerate() {
            let Some((_, ls)) = l else {
                theta.push(None);
                start.push(nb.len());
                continue;
            };
            theta.push(Some(rep(&f.params, blurred)));
            let s = &sd[i];
            for (j, mj) in ls {
                // the largest move of the dot (in its standard deviations) for a move of one
                // standard deviation in one of the neighbour's parameters (a neighbour whose
                // own map failed has no known scale: kept)
                let sj = &sd[j as usize];
                let mut big = 0.0f64;
                for (c, col) in mj.iter().enumerate().take(nd) {
                    for o in 0..nd {
                        big = big.max((f64::from(col[o]) * sj[c] / s[o]).abs());
                    }
                }
                let known = sj[..nd].iter().all(|v| *v > 0.0 && v.is_finite());
                if known && big < MIN_LINK {
                    continue;
                }
                nb.push(j);
                m.push(mj);
            }
            start.push(nb.len());
        }
        let scale = sd;
        Coupling {
            fits: base.to_vec(),
            kind,
            blurred,
            base: theta,
            scale,
            red,
            start,
            nb,
            m,
            looked,
        }
    }

    /// The joint solution from the first pass's `fits` (each fitted with its neighbours held at
    /// the base): `admitted[i]`, fit i models a neighbour (its model replaces the base's; a dot
    /// whose fit is not admitted keeps the base's model, as in the pixel iteration). `None`
    /// where the linearisation does not hold: a dot modelled now that the base did not model
    /// (found in this image only), or sweeps that do not settle.
    pub(crate) fn solve(&self, fits: &[DotFit], admitted: &[bool]) -> Option<Solved> {
        let n = fits.len();
        if n != self.base.len() || admitted.len() != n {
            return None;
        }
        let free = self.kind.free();
        let dp = dot_params(self.kind);
        let nd = dp.len();
        // each dot's move with its neighbours held at the base (zero where not coupled), over
        // its dot parameters
        let mut own = vec![[0.0f64; 8]; n];
        for i in 0..n {
            match (&self.base[i], admitted[i]) {
                (Some(b), true) => {
                    let t = rep(&fits[i].params, self.blurred);
                    for (o, &q) in dp.iter().enumerate() {
                        own[i][o] = t[free[q]] - b[free[q]];
                    }
                    if own[i].iter().any(|v| !v.is_finite()) {
                        return None;
                    }
                }
                (None, true) => return None,
                _ => {}
            }
        }
        // a dot that never moved from the base (not coupled, not admitted) stays at δ = 0
        let live: Vec<bool> = (0..n)
            .map(|i| self.base[i].is_some() && admitted[i])
            .collect();
        let mut delta = own.clone();
        let mut changed = live.clone();
        // (one buffer for every half-sweep's updates: a fresh one each time cost its pages)
        let mut updates: Vec<([f64; 8], bool)> = Vec::new();
        let mut sweeps = 0;
        loop {
            if sweeps >= MAX_SWEEPS {
                return None;
            }
            sweeps += 1;
            let mut any = false;
            for colour in [true, false] {
                // the dots of this colour with a neighbour that changed since they were updated
                let active: Vec<usize> = (0..n)
                    .filter(|&i| {
                        live[i]
                            && self.red[i] == colour
                            && self.nb[self.start[i]..self.start[i + 1]]
                                .iter()
                                .any(|&j| changed[j as usize])
                    })
                    .collect();
                active
                    .par_iter()
                    .with_min_len(256)
                    .map(|&i| {
                        let (a, b) = (self.start[i], self.start[i + 1]);
                        let mut v = own[i];
                        for (&j, mj) in self.nb[a..b].iter().zip(&self.m[a..b]) {
                            let dj = &delta[j as usize];
                            for (col, &x) in mj.iter().zip(dj) {
                                for (vr, &c) in v.iter_mut().zip(col) {
                                    *vr -= f64::from(c) * x;
                                }
                            }
                        }
                        let s = &self.scale[i];
                        let moved = (0..nd)
                            .map(|k| (v[k] - delta[i][k]).abs() / s[k])
                            .fold(0.0f64, f64::max);
                        (v, moved > SETTLED)
                    })
                    .collect_into_vec(&mut updates);
                for i in 0..n {
                    if self.red[i] == colour {
                        changed[i] = false;
                    }
                }
                for (&i, &(v, c)) in active.iter().zip(&updates) {
                    if v.iter().any(|x| !x.is_finite()) {
                        return None;
                    }
                    delta[i] = v;
                    changed[i] = c;
                    any |= c;
                }
            }
            if !any {
                break;
            }
        }
        let params = (0..n)
            .map(|i| {
                if !live[i] || !fits[i].status.is_ok() {
                    return None;
                }
                let mut step = [0.0; 7];
                for (o, &q) in dp.iter().enumerate() {
                    step[q] = delta[i][o] - own[i][o];
                }
                let t = self
                    .kind
                    .apply_step(&rep(&fits[i].params, self.blurred), &step);
                let t = if self.blurred {
                    pixel_unblur(&t)
                } else {
                    Some(t)
                };
                match t
                    .map(|t| gaussian_from_theta(&t))
                    .filter(Gaussian2D::is_valid)
                {
                    Some(g) => Some(g),
                    // (a shape the map's parameters cannot give back: the position alone;
                    // every kind's first two free parameters are x0 and y0)
                    None => {
                        let mut g = fits[i].params;
                        g.x0 += step[0];
                        g.y0 += step[1];
                        Some(g)
                    }
                }
            })
            .collect();
        Some(Solved { params, sweeps })
    }
}

/// The map's parameters of a fit: its point-model θ, pixel-blurred unless `blurred` is false.
pub(crate) fn rep(g: &Gaussian2D, blurred: bool) -> Theta {
    let t = theta_from_gaussian(g);
    if blurred { pixel_blur(&t) } else { t }
}
