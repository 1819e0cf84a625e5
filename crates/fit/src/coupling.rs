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

use crate::eval::{Kind, Theta, gaussian_from_theta, theta_from_gaussian, unblurred_params};
use crate::joint::NB;
use bostrack_core::{DotFit, Gaussian2D, Window};
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
    /// Per dot `j`, the dots whose links hold it (`rev[rev_start[j]..rev_start[j + 1]]`).
    rev_start: Vec<usize>,
    rev: Vec<u32>,
    /// Per link, `M` restricted to the dot parameters (the free ones without the background) of
    /// both dots, by columns of [`crate::simd::LINK_ROWS`] (f32).
    m: Vec<[crate::simd::LinkColumn; NB]>,
    /// Per dot, its Fisher matrix at `fits` over its window (with its fit's weights), for the
    /// Gauss-Newton step that stands for an image's first pass (`None`: that dot is fitted).
    pub(crate) looked: Vec<Option<crate::dots::Looked>>,
    /// Per dot, the (clipped) window its row was computed over.
    windows: Vec<Option<Window>>,
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
pub(crate) type DotLinks = Option<([f64; 7], Vec<(u32, [crate::simd::LinkColumn; NB])>)>;

/// The positions among the free parameters of `kind` of its dot parameters (all but the
/// background).
/// (Every kind's background is its last free parameter: they are the first `n_free − 1`.)
fn dot_params(kind: Kind) -> &'static [usize] {
    let free = kind.free();
    debug_assert_eq!(free.last(), Some(&crate::eval::IB));
    &[0, 1, 2, 3, 4, 5][..free.len() - 1]
}

impl Coupling {
    /// A link's matrix as the map keeps it: `m` (from [`crate::joint::coupling`], rows and
    /// columns over the free parameters) restricted to the dot parameters of both dots.
    pub(crate) fn link(kind: Kind, m: &[[f64; 8]; NB]) -> [crate::simd::LinkColumn; NB] {
        let dp = dot_params(kind);
        let mut out = [[0.0f32; crate::simd::LINK_ROWS]; NB];
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
        windows: Vec<Option<Window>>,
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
        // the reverse links, by counting
        let n = start.len() - 1;
        let mut rev_start = vec![0usize; n + 1];
        for &j in &nb {
            rev_start[j as usize + 1] += 1;
        }
        for j in 0..n {
            rev_start[j + 1] += rev_start[j];
        }
        let mut fill = rev_start.clone();
        let mut rev = vec![0u32; nb.len()];
        for i in 0..n {
            for &j in &nb[start[i]..start[i + 1]] {
                rev[fill[j as usize]] = i as u32;
                fill[j as usize] += 1;
            }
        }
        Coupling {
            fits: base.to_vec(),
            kind,
            blurred,
            base: theta,
            scale,
            red,
            start,
            nb,
            rev_start,
            rev,
            m,
            looked,
            windows,
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
        // each dot's move with its neighbours held at the base (zero where not coupled), over
        // its dot parameters
        let mut own = vec![[0.0f64; 8]; n];
        for i in 0..n {
            match (&self.base[i], admitted[i]) {
                (Some(_), true) => {
                    own[i] = self.offset(i, &fits[i].params)?;
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
        let mut touched = vec![false; n];
        let sweeps = self.sweep(&own, &mut delta, &live, live.clone(), &mut touched)?;
        let params = (0..n)
            .map(|i| {
                if !live[i] || !fits[i].status.is_ok() {
                    return None;
                }
                Some(self.params_at(&fits[i].params, &own[i], &delta[i]))
            })
            .collect();
        Some(Solved { params, sweeps })
    }

    /// `g` less dot `i`'s base, over its dot parameters (in the map's parameters); `None` where
    /// not finite or the dot has no base.
    fn offset(&self, i: usize, g: &Gaussian2D) -> Option<[f64; 8]> {
        self.base.get(i)?.as_ref()?;
        self.offset_of(i, &rep(g, self.blurred))
    }

    /// Red-black Gauss-Seidel sweeps of `δ_i = own_i − Σ_j M_ij δ_j` over the `live` dots (the
    /// others' `delta` held), until no update changes a parameter by more than [`SETTLED`] of
    /// its standard deviation; `changed`: the dots whose `delta` changed since their neighbours
    /// were last updated (every live dot for a cold start). The sweeps made; `None` where they
    /// do not settle within [`MAX_SWEEPS`] or an update is not finite.
    fn sweep(
        &self,
        own: &[[f64; 8]],
        delta: &mut [[f64; 8]],
        live: &[bool],
        changed: Vec<bool>,
        touched: &mut [bool],
    ) -> Option<u32> {
        let n = own.len();
        let nd = dot_params(self.kind).len();
        // the dots with a neighbour that changed since they were last updated (marked through
        // the reverse links: no pass over every dot's links per half-sweep)
        let mut pending = vec![false; n];
        let mark = |pending: &mut [bool], j: usize| {
            for &i in &self.rev[self.rev_start[j]..self.rev_start[j + 1]] {
                pending[i as usize] = true;
            }
        };
        for (j, &c) in changed.iter().enumerate() {
            if c {
                mark(&mut pending, j);
            }
        }
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
                let active: Vec<usize> = (0..n)
                    .filter(|&i| pending[i] && live[i] && self.red[i] == colour)
                    .collect();
                let now: &[[f64; 8]] = delta;
                let arch = crate::simd::arch();
                active
                    .par_iter()
                    .with_min_len(256)
                    .map(|&i| {
                        let v = self.row(arch, i, own[i], now);
                        let s = &self.scale[i];
                        let moved = (0..nd)
                            .map(|k| (v[k] - now[i][k]).abs() / s[k])
                            .fold(0.0f64, f64::max);
                        (v, moved > SETTLED)
                    })
                    .collect_into_vec(&mut updates);
                for &i in &active {
                    pending[i] = false;
                }
                for (&i, &(v, c)) in active.iter().zip(&updates) {
                    if v.iter().any(|x| !x.is_finite()) {
                        return None;
                    }
                    if delta[i] != v {
                        touched[i] = true;
                    }
                    delta[i] = v;
                    if c {
                        mark(&mut pending, i);
                    }
                    any |= c;
                }
            }
            if !any {
                return Some(sweeps);
            }
        }
    }

    /// Dot `i`'s row of the map applied to `x`: `own − Σ_j M_ij x_j` over its links.
    fn row(&self, arch: pulp::Arch, i: usize, own: [f64; 8], x: &[[f64; 8]]) -> [f64; 8] {
        let (a, b) = (self.start[i], self.start[i + 1]);
        crate::simd::link_row(
            arch,
            crate::simd::LinkRow {
                own,
                nb: &self.nb[a..b],
                m: &self.m[a..b],
                now: x,
            },
        )
    }

    /// The parameters of a dot whose first-pass fit `g` lies `own` from its base (over its dot
    /// parameters, [`Coupling::offset`]) when it lies `delta` from it: `g` moved by the
    /// difference.
    fn params_at(&self, g: &Gaussian2D, own: &[f64; 8], delta: &[f64; 8]) -> Gaussian2D {
        let mut step = [0.0; 7];
        for (o, &q) in dot_params(self.kind).iter().enumerate() {
            step[q] = delta[o] - own[o];
        }
        let t = self.kind.apply_step(&rep(g, self.blurred), &step);
        let params = if self.blurred {
            unblurred_params(&t)
        } else {
            Some(gaussian_from_theta(&t))
        };
        match params.filter(Gaussian2D::is_valid) {
            Some(g) => g,
            // (a shape the map's parameters cannot give back: the position alone; every
            // kind's first two free parameters are x0 and y0)
            None => {
                let mut g = *g;
                g.x0 += step[0];
                g.y0 += step[1];
                g
            }
        }
    }

    /// The window dot `i`'s row of the map was computed over (`None`: not coupled).
    pub(crate) fn window(&self, i: usize) -> Option<Window> {
        self.base.get(i)?.as_ref()?;
        self.windows.get(i).copied().flatten()
    }

    /// Whether dot `i`'s fit `g` (of an image of the scene the map was made for, seen with a
    /// common shift `shift` from the base) lies within the map's linear reach of its base: its
    /// position within [`NEAR`] of its σ of the base moved by `shift`, its σs within that
    /// fraction of the base's, its ρ within [`NEAR`] of it, its amplitude within
    /// [`NEAR_AMPLITUDE`] of the base's. A link's response then differs from the map's by a
    /// fraction of that order (second order in the move), on a pull of a few standard
    /// deviations at most. (Compared in the fit's own parameters, where the map's are
    /// pixel-blurred: the blur makes the differences smaller.)
    pub(crate) fn near(&self, i: usize, g: &Gaussian2D, shift: [f64; 2]) -> bool {
        if self.base.get(i).is_none_or(|b| b.is_none()) {
            return false;
        }
        let b = &self.fits[i].params;
        let sigma = b.sigma_x.min(b.sigma_y);
        let within = |v: f64, limit: f64| v.abs() <= limit;
        within(g.x0 - b.x0 - shift[0], NEAR * sigma)
            && within(g.y0 - b.y0 - shift[1], NEAR * sigma)
            && within(g.sigma_x / b.sigma_x - 1.0, NEAR)
            && within(g.sigma_y / b.sigma_y - 1.0, NEAR)
            && within(g.rho - b.rho, NEAR)
            && within(g.amplitude / b.amplitude - 1.0, NEAR_AMPLITUDE)
    }

    /// The links of dot `i` (neighbour indices).
    pub(crate) fn neighbours(&self, i: usize) -> &[u32] {
        &self.nb[self.start[i]..self.start[i + 1]]
    }

    /// The offset of `g` from dot `i`'s base in position alone (`g` of the base's shape).
    fn position_offset(&self, i: usize, g: &Gaussian2D) -> [f64; 8] {
        let b = &self.fits[i].params;
        let mut d = [0.0; 8];
        let free = self.kind.free();
        for (o, &q) in dot_params(self.kind).iter().enumerate() {
            match free[q] {
                crate::eval::IX => d[o] = g.x0 - b.x0,
                crate::eval::IY => d[o] = g.y0 - b.y0,
                _ => {}
            }
        }
        d
    }

    /// The start of a frame's linear part: the `linear` dots of a gradient frame's first pass
    /// (`first`: its fits, each made with its neighbours held at `prior`, the base's fits moved
    /// in position) solved with the other dots held at `held`. A linear dot's first-pass offset
    /// is brought to neighbours held at the base by adding `Σ_j M_ij (prior_j − base_j)` (the
    /// caller makes every neighbour of a linear dot [`near`] in its first pass and in its
    /// prior, so that the map holds along every link). `rep_of(i, g, blurred)`: [`rep`]`(g,
    /// blurred)` of dot `i`'s fit `g` (taken from where the caller has it already).
    ///
    /// [`near`]: Coupling::near
    pub(crate) fn frame_start(
        &self,
        first: &[DotFit],
        prior: &[DotFit],
        linear: Vec<bool>,
        held: &[DotFit],
        rep_of: impl Fn(usize, &Gaussian2D, bool) -> Theta + Sync,
    ) -> Option<FrameState> {
        let n = first.len();
        if n != self.base.len() || prior.len() != n || linear.len() != n || held.len() != n {
            return None;
        }
        // per dot: (its first fit's map parameters, their offset) where linear, else its held
        // offset
        let per_dot: Vec<(Option<Theta>, [f64; 8])> = (0..n)
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                if linear[i] {
                    let t = rep_of(i, &first[i].params, self.blurred);
                    (Some(t), self.offset_of(i, &t).unwrap_or([f64::NAN; 8]))
                } else if self.rev[self.rev_start[i]..self.rev_start[i + 1]]
                    .iter()
                    .any(|&k| linear[k as usize])
                {
                    // (held: needed where a linear dot links to it; a dot without a base has
                    // no offset, and its representation is not computed)
                    let d = self.base[i]
                        .as_ref()
                        .and_then(|_| self.offset_of(i, &rep_of(i, &held[i].params, self.blurred)))
                        .unwrap_or([0.0; 8]);
                    (None, d)
                } else {
                    (None, [0.0; 8])
                }
            })
            .collect();
        let (first_rep, mut delta): (Vec<Option<Theta>>, Vec<[f64; 8]>) =
            per_dot.into_iter().unzip();
        if (0..n).any(|i| linear[i] && delta[i].iter().any(|v| !v.is_finite())) {
            return None;
        }
        let raw = delta.clone();
        // each prior's offset from the base (in position: the prior is the base moved), negated:
        // `own + Σ M h` is the sweeps' row with `−h` (`v − c·(−x)` is `v + c·x` to the bit)
        let minus_h: Vec<[f64; 8]> = (0..n)
            .map(|i| self.position_offset(i, &prior[i].params).map(|v| -v))
            .collect();
        let arch = crate::simd::arch();
        let own: Vec<[f64; 8]> = (0..n)
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                if linear[i] {
                    self.row(arch, i, raw[i], &minus_h)
                } else {
                    raw[i]
                }
            })
            .collect();
        for i in 0..n {
            if linear[i] {
                delta[i] = own[i];
            }
        }
        let mut st = FrameState {
            first: first_rep,
            taken: raw,
            own,
            delta,
            touched: linear.clone(),
            live: linear,
            sweeps: 0,
        };
        let changed = st.live.clone();
        st.sweeps = self.sweep(&st.own, &mut st.delta, &st.live, changed, &mut st.touched)?;
        Some(st)
    }

    /// `t` (map parameters) less dot `i`'s base, over its dot parameters.
    fn offset_of(&self, i: usize, t: &Theta) -> Option<[f64; 8]> {
        let b = self.base[i].as_ref()?;
        let free = self.kind.free();
        let mut d = [0.0; 8];
        for (o, &q) in dot_params(self.kind).iter().enumerate() {
            d[o] = t[free[q]] - b[free[q]];
        }
        d.iter().all(|v| v.is_finite()).then_some(d)
    }

    /// The frame's linear dots solved again after the other dots moved to `held` (those whose
    /// offset changed by more than [`SETTLED`] of a standard deviation start the sweeps;
    /// `moved`: the dots whose fit changed since the last call).
    pub(crate) fn frame_again(
        &self,
        st: &mut FrameState,
        held: &[DotFit],
        moved: &[bool],
    ) -> Option<()> {
        let n = st.live.len();
        let nd = dot_params(self.kind).len();
        let mut changed = vec![false; n];
        for i in 0..n {
            if st.live[i] || !moved[i] {
                continue;
            }
            let Some(d) = self.offset(i, &held[i].params) else {
                continue;
            };
            let s = &self.scale[i];
            changed[i] = (0..nd).any(|k| {
                let by = (d[k] - st.delta[i][k]).abs();
                // (a dot of unknown scale: any change)
                if s[k] > 0.0 {
                    by > SETTLED * s[k]
                } else {
                    by > 0.0
                }
            });
            st.delta[i] = d;
        }
        if changed.iter().any(|&c| c) {
            st.sweeps += self.sweep(&st.own, &mut st.delta, &st.live, changed, &mut st.touched)?;
        }
        Some(())
    }

    /// The linear dots whose solution changed since the last call, each with its parameters
    /// now and how far it moved since (the root sum of squares of its dot parameters' changes
    /// in their standard deviations).
    pub(crate) fn frame_take(&self, st: &mut FrameState) -> Vec<(usize, Gaussian2D, f64)> {
        let free = self.kind.free();
        let dp = dot_params(self.kind);
        let touched: Vec<usize> = (0..st.live.len()).filter(|&i| st.touched[i]).collect();
        let out: Vec<(usize, Gaussian2D, f64)> = touched
            .par_iter()
            .with_min_len(256)
            .filter_map(|&i| {
                let (Some(b), Some(f)) = (self.base[i].as_ref(), st.first[i].as_ref()) else {
                    return None;
                };
                let (d, was) = (&st.delta[i], &st.taken[i]);
                let mut t = *f;
                for (o, &q) in dp.iter().enumerate() {
                    t[free[q]] = b[free[q]] + d[o];
                }
                let params = if self.blurred {
                    unblurred_params(&t)
                } else {
                    Some(gaussian_from_theta(&t))
                };
                let g = params.filter(Gaussian2D::is_valid).or_else(|| {
                    // (a shape the map's parameters cannot give back: the position alone)
                    let mut g = gaussian_from_theta(f);
                    let p = |q: usize| dp.iter().position(|&k| free[k] == q);
                    if let Some(o) = p(crate::eval::IX) {
                        g.x0 = b[crate::eval::IX] + d[o];
                    }
                    if let Some(o) = p(crate::eval::IY) {
                        g.y0 = b[crate::eval::IY] + d[o];
                    }
                    g.is_valid().then_some(g)
                })?;
                let s = &self.scale[i];
                let by = (0..dp.len())
                    .filter(|&k| s[k] > 0.0)
                    .map(|k| ((d[k] - was[k]) / s[k]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                Some((i, g, by))
            })
            .collect();
        for &i in &touched {
            st.touched[i] = false;
            st.taken[i] = st.delta[i];
        }
        out
    }
}

/// Largest move from the base (a fraction of σ, of σ itself, and of ρ) at which
/// [`Coupling::near`] takes a fit as within the map's linear reach.
const NEAR: f64 = 0.05;

/// Largest relative amplitude change for [`Coupling::near`] (the model is linear in the
/// amplitude; the links scale with it).
const NEAR_AMPLITUDE: f64 = 0.1;

/// The linear part of a gradient frame's neighbour iteration ([`Coupling::frame_start`]).
pub(crate) struct FrameState {
    /// Per linear dot, its first-pass fit in the map's parameters.
    first: Vec<Option<Theta>>,
    /// Per dot, its offset from the base when its record was last written
    /// ([`Coupling::frame_take`]), and (linear dots) its first-pass offset brought to
    /// neighbours held at the base.
    taken: Vec<[f64; 8]>,
    own: Vec<[f64; 8]>,
    /// Per dot, its current offset from the base: solved (linear dots) or held.
    delta: Vec<[f64; 8]>,
    /// The linear dots whose `delta` changed since their record was last written.
    touched: Vec<bool>,
    /// Which dots are solved on the map.
    pub live: Vec<bool>,
    /// Sweeps made.
    pub sweeps: u32,
}

/// The map's parameters of a fit: its point-model θ, pixel-blurred unless `blurred` is false.
pub(crate) fn rep(g: &Gaussian2D, blurred: bool) -> Theta {
    if blurred {
        crate::eval::blurred_of(g).1
    } else {
        theta_from_gaussian(g)
    }
}

/// The median of each coordinate of `values` (their finite values); `None` where one has none.
pub(crate) fn median2(values: impl Iterator<Item = [f64; 2]>) -> Option<[f64; 2]> {
    let (mut x, mut y): (Vec<f64>, Vec<f64>) = values.map(|[a, b]| (a, b)).unzip();
    let m = [bostrack_core::median(&mut x), bostrack_core::median(&mut y)];
    m.iter().all(|v| v.is_finite()).then_some(m)
}
