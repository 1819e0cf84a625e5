//! The joint Cramér-Rao bound of a dot whose window holds its neighbours' tails: the position
//! bound when the overlapping neighbours' parameters are unknown too.
//!
//! For dot `i` with window `W_i`, the parameters are its own free parameters θ_i (background
//! included) and, for every neighbour `j` whose 5σ reach touches `W_i` with a share of its
//! squared profile of at least [`MIN_SHARE`] inside it, the neighbour's free dot parameters φ_j
//! (its background is not part of `W_i`'s model). The information is
//!
//! `M = Σ_{p ∈ W_i} ∇μ ∇μᵀ / var(μ)  +  blockdiag(0, P_1, …, P_m)`,
//!
//! with `μ = B_i + G_i + Σ_j G_j` and `P_j` the information about φ_j from the pixels of `W_j`
//! outside `W_i` (its own window, with its own background marginalised out), so that no pixel is
//! counted twice. The bound is `sqrt((M⁻¹)_xx)`, `sqrt((M⁻¹)_yy)`: never below the bound of the dot
//! alone over `W_i`. Neglected: the neighbours' own other neighbours, and the pixels of `W_j`
//! that lie in a third dot's window (second order). Dots are evaluated as the pixel-blurred
//! point-sampled Gaussian (exact to the second moment; for dots narrower than 1 px an
//! approximation of the pixel-integrated model).

use crate::eval::{IB, Kind, Shape, Theta, exp_grid, pixel_blur, theta_from_gaussian};
use bostrack_core::{DotFit, Gaussian2D, Mask, NoiseModel, Window};
use nalgebra::DMatrix;

/// Neighbours with a smaller share of their squared profile inside a window are taken as known
/// (left out of the joint model; the bound of the dot alone applies where none is left). On the
/// real sample this under-states the joint bound of 1 % of the dots by up to ~2.5 % (99th
/// percentile of joint / dot-alone 1.02 against 1.045 with 0.003) and saves ~100 ms of a
/// reference's 1-thread fit; on a lattice of spacing 7 px at σ 1.6 px the mean ratio is 1.028 with
/// either.
pub(crate) const MIN_SHARE: f64 = 1e-2;

/// A dot as the joint bound sees it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct JointDot {
    /// Pixel-blurred point-model parameters.
    theta: Theta,
    shape: Shape,
    /// Derivative coefficients of the model kind (rows: free parameters, columns: basis).
    coef: [[f64; 7]; 7],
    window: Window,
}

impl JointDot {
    pub(crate) fn new(f: &DotFit, window: Window, kind: Kind) -> Option<JointDot> {
        if !f.status.is_ok() {
            return None;
        }
        JointDot::from_params(&f.params, window, kind)
    }

    pub(crate) fn from_params(g: &Gaussian2D, window: Window, kind: Kind) -> Option<JointDot> {
        if !g.is_valid() {
            return None;
        }
        JointDot::from_theta(pixel_blur(&theta_from_gaussian(g)), window, kind)
    }

    /// The dot of point-model parameters `theta` (evaluated as given, without blurring).
    pub(crate) fn from_theta(theta: Theta, window: Window, kind: Kind) -> Option<JointDot> {
        let shape = Shape::of(&theta);
        theta.iter().all(|v| v.is_finite()).then(|| JointDot {
            theta,
            shape,
            coef: kind.coefficients(&theta, &shape),
            window,
        })
    }

    /// The dot's exponential factor `E` over the pixels of `win` (row-major; `v`, `q`: scratch of
    /// at least the window's larger side), by the recurrence of [`exp_grid`]: 8 values of `exp`
    /// per window instead of one per pixel (the values agree with the direct `exp` to ~1e-13).
    fn exp_over(&self, win: Window, out: &mut [f64], v: &mut [f64], q: &mut [f64]) {
        let s = &self.shape;
        exp_grid(
            s.a,
            s.b,
            s.c,
            win.x as f64 - self.theta[0],
            win.y as f64 - self.theta[1],
            win.width,
            win.height,
            out,
            v,
            q,
        );
    }

    /// The dot's value (without background) and its derivatives with respect to the free
    /// parameters of `kind` (in `kind.free()` order; the background's is 1) at pixel (x, y),
    /// where its exponential factor is `e` ([`JointDot::exp_over`]).
    #[cfg(test)]
    fn eval(&self, kind: Kind, e: f64, x: f64, y: f64, out: &mut [f64; 7]) -> f64 {
        let (dx, dy) = (x - self.theta[0], y - self.theta[1]);
        let basis = [
            e,
            e * dx,
            e * dy,
            e * dx * dx,
            e * dx * dy,
            e * dy * dy,
            1.0,
        ];
        for (k, o) in out.iter_mut().enumerate().take(kind.n_free()) {
            *o = (0..7).map(|b| self.coef[k][b] * basis[b]).sum();
        }
        self.theta[2] * e
    }
}

fn inside(w: Window, x: i64, y: i64) -> bool {
    x >= w.x && y >= w.y && x < w.x + w.width as i64 && y < w.y + w.height as i64
}

/// The joint bound of `dot` with its `neighbours` (each with its share of `W_i` already checked);
/// `keep(x, y)`: the pixel is used (inside the image, the mask, not saturated). `None` when the
/// information matrix is not positive definite.
///
/// Every derivative is a combination of a dot's basis `E·X^m Y^n` (m + n ≤ 2, about its own
/// centre) and the background's 1 ([`Kind::coefficients`]), so each block of `M` between two
/// dots `i`, `j` of the window (a dot with itself included) is `coef_i G_ij coef_jᵀ` with
/// `G_ij = Σ w φ_i φ_jᵀ` made of the moments `Σ w E_i E_j X^m Y^n` (m + n ≤ 4) and
/// `Σ w E_j X^m Y^n` (m + n ≤ 2) about `i`'s centre ([`moments`], [`basis_products`], as the
/// coupling map's): ~8 multiply-adds per pixel and pair of dots, where the sum of `w ∇μ ∇μᵀ`
/// took the rank-one update of the whole `(7 + 6k)²` matrix per pixel (and each dot's
/// derivatives, 7 × 7 multiply-adds per pixel). The same sums in another order: equal to
/// [`joint_bound_direct`] to a median 4e-16 and a 99th percentile 3e-11 (relative) on random
/// groups, up to ~4e-8 in ill-conditioned ones (test `moment_form_is_the_direct_sum`).
pub(crate) fn joint_bound(
    kind: Kind,
    dot: &JointDot,
    neighbours: &[JointDot],
    noise: &NoiseModel,
    keep: &dyn Fn(i64, i64) -> bool,
) -> Option<[f64; 2]> {
    let Dims {
        n_own,
        n_nb,
        ib,
        dim,
    } = Dims::of(kind, neighbours.len())?;
    let w = dot.window;
    let npix = w.width * w.height;
    let dots: Vec<&JointDot> = std::iter::once(dot).chain(neighbours).collect();
    let (e, mut v, mut q) = rendered(dot, neighbours);
    // the weights at the sum of the models (0 where a pixel is not used)
    let mut wt = vec![0.0; npix];
    for (py, y) in (w.y..w.y + w.height as i64).enumerate() {
        for (px, x) in (w.x..w.x + w.width as i64).enumerate() {
            if !keep(x, y) {
                continue;
            }
            let p = py * w.width + px;
            let mut mu = dot.theta[IB] + dot.theta[2] * e[p];
            for (k, nb) in neighbours.iter().enumerate() {
                mu += nb.theta[2] * e[(k + 1) * npix + p];
            }
            wt[p] = 1.0 / noise.variance(mu);
        }
    }
    // each dot's rows of M and their coefficients over its basis: the dot's every free
    // parameter, a neighbour's but its background
    let rows = |k: usize| -> Vec<(usize, [f64; 7])> {
        let c = &dots[k].coef;
        if k == 0 {
            (0..n_own).map(|r| (r, c[r])).collect()
        } else {
            let at = n_own + (k - 1) * n_nb;
            (0..n_own)
                .filter(|&r| r != ib)
                .enumerate()
                .map(|(col, r)| (at + col, c[r]))
                .collect()
        }
    };
    let rows: Vec<Vec<(usize, [f64; 7])>> = (0..dots.len()).map(rows).collect();
    let mut mat = DMatrix::<f64>::zeros(dim, dim);
    for i in 0..dots.len() {
        let (xi, yi) = (dots[i].theta[0], dots[i].theta[1]);
        let ei = &e[i * npix..(i + 1) * npix];
        for j in i..dots.len() {
            let ej = &e[j * npix..(j + 1) * npix];
            let (s1, s2) = moments(w, w, xi, yi, &wt, ei, ej);
            let g = basis_products(&s1, &s2, dots[j].theta[0] - xi, dots[j].theta[1] - yi);
            // G over both bases with the background's 1 (only dot 0 has one among its
            // parameters; `g[6][b]` is Σ w φ_jb, so with j = i its transpose is i's column)
            let gg = if j == 0 {
                own_products(&g, wt.iter().sum())
            } else {
                let mut gg = [[0.0f64; 7]; 7];
                for a in 0..7 {
                    gg[a][..6].copy_from_slice(&g[a]);
                }
                gg
            };
            // T = G coef_jᵀ, then the block coef_i T
            for &(rj, cj) in &rows[j] {
                let mut t = [0.0f64; 7];
                for (a, ta) in t.iter_mut().enumerate() {
                    *ta = (0..7).map(|b| gg[a][b] * cj[b]).sum();
                }
                for &(ri, ci) in &rows[i] {
                    if i == j && ri > rj {
                        continue;
                    }
                    mat[(ri, rj)] = (0..7).map(|a| ci[a] * t[a]).sum();
                }
            }
        }
    }
    // each neighbour's information from its own window outside this one, background marginalised
    let (mut en, mut wn) = (Vec::new(), Vec::new());
    for (k, nb) in neighbours.iter().enumerate() {
        let nw = nb.window;
        let n = nw.width * nw.height;
        en.resize(n, 0.0);
        nb.exp_over(nw, &mut en, &mut v, &mut q);
        wn.clear();
        wn.resize(n, 0.0);
        for (py, y) in (nw.y..nw.y + nw.height as i64).enumerate() {
            for (px, x) in (nw.x..nw.x + nw.width as i64).enumerate() {
                if inside(w, x, y) || !keep(x, y) {
                    continue;
                }
                let p = py * nw.width + px;
                wn[p] = 1.0 / noise.variance(nb.theta[IB] + nb.theta[2] * en[p]);
            }
        }
        let (s1, s2) = moments(nw, nw, nb.theta[0], nb.theta[1], &wn, &en, &en);
        let gg = own_products(&basis_products(&s1, &s2, 0.0, 0.0), wn.iter().sum());
        let c = &nb.coef;
        let own = DMatrix::<f64>::from_fn(n_own, n_own, |r, s| {
            (0..7)
                .map(|a| c[r][a] * (0..7).map(|b| gg[a][b] * c[s][b]).sum::<f64>())
                .sum()
        });
        add_prior(&mut mat, &own, ib, n_own + k * n_nb)?;
    }
    fill_lower(&mut mat);
    bound_of(mat)
}

/// The sizes of a group's information matrix: the dot's free parameters (`n_own`, the
/// background at `ib` among them), each neighbour's without its background (`n_nb`), and all
/// of them (`dim`). `None` for a kind without a background.
struct Dims {
    n_own: usize,
    n_nb: usize,
    ib: usize,
    dim: usize,
}

impl Dims {
    fn of(kind: Kind, neighbours: usize) -> Option<Dims> {
        let n_own = kind.n_free();
        let ib = kind.free().iter().position(|&p| p == IB)?;
        Some(Dims {
            n_own,
            n_nb: n_own - 1,
            ib,
            dim: n_own + (n_own - 1) * neighbours,
        })
    }
}

/// Every dot's exponential factor over `dot`'s window, rendered once (row-major, the dot's
/// then each neighbour's), and two scratch rows long enough for any of their windows.
fn rendered(dot: &JointDot, neighbours: &[JointDot]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let w = dot.window;
    let npix = w.width * w.height;
    let side = |v: Window| v.width.max(v.height);
    let m = neighbours
        .iter()
        .map(|nb| side(nb.window))
        .fold(side(w), usize::max);
    let (mut v, mut q) = (vec![0.0; m], vec![0.0; m]);
    let mut e = vec![0.0; npix * (1 + neighbours.len())];
    for (k, jd) in std::iter::once(dot).chain(neighbours).enumerate() {
        jd.exp_over(w, &mut e[k * npix..(k + 1) * npix], &mut v, &mut q);
    }
    (e, v, q)
}

/// `sqrt` of the first two diagonal entries of `M⁻¹` (Cholesky); `None` where `M` is not
/// positive definite.
fn bound_of(m: DMatrix<f64>) -> Option<[f64; 2]> {
    let dim = m.nrows();
    let chol = m.cholesky()?;
    let mut e = DMatrix::<f64>::zeros(dim, 2);
    e[(0, 0)] = 1.0;
    e[(1, 1)] = 1.0;
    let s = chol.solve(&e);
    let (vx, vy) = (s[(0, 0)], s[(1, 1)]);
    (vx > 0.0 && vy > 0.0 && vx.is_finite() && vy.is_finite()).then(|| [vx.sqrt(), vy.sqrt()])
}

/// [`joint_bound`] as the sum of `w ∇μ ∇μᵀ` over the pixels (each dot's derivatives evaluated
/// at every pixel, one rank-one update of `M` per pixel): the definition, kept as the test's
/// reference for the moment form.
#[cfg(test)]
pub(crate) fn joint_bound_direct(
    kind: Kind,
    dot: &JointDot,
    neighbours: &[JointDot],
    noise: &NoiseModel,
    keep: &dyn Fn(i64, i64) -> bool,
) -> Option<[f64; 2]> {
    let Dims {
        n_own,
        n_nb,
        ib,
        dim,
    } = Dims::of(kind, neighbours.len())?;
    // the upper triangle of M, row-major: each pixel adds `wt ∇μ ∇μᵀ` row by row
    let mut upper = vec![0.0; dim * dim];
    let mut grad = vec![0.0; dim];
    let mut d = [0.0; 7];
    let w = dot.window;
    let npix = w.width * w.height;
    let (mut e, mut v, mut q) = rendered(dot, neighbours);
    for (py, y) in (w.y..w.y + w.height as i64).enumerate() {
        for (px, x) in (w.x..w.x + w.width as i64).enumerate() {
            if !keep(x, y) {
                continue;
            }
            let p = py * w.width + px;
            let (fx, fy) = (x as f64, y as f64);
            let mut mu = dot.theta[IB] + dot.eval(kind, e[p], fx, fy, &mut d);
            grad[..n_own].copy_from_slice(&d[..n_own]);
            for (k, nb) in neighbours.iter().enumerate() {
                let v = nb.eval(kind, e[(k + 1) * npix + p], fx, fy, &mut d);
                mu += v;
                let at = n_own + k * n_nb;
                let part = &mut grad[at..at + n_nb];
                for (o, (_, v)) in part
                    .iter_mut()
                    .zip(d[..n_own].iter().enumerate().filter(|&(q, _)| q != ib))
                {
                    *o = *v;
                }
            }
            let wt = 1.0 / noise.variance(mu);
            for r in 0..dim {
                let gr = wt * grad[r];
                for c in r..dim {
                    upper[r * dim + c] += gr * grad[c];
                }
            }
        }
    }
    let mut m = DMatrix::<f64>::from_fn(dim, dim, |r, c| upper[r.min(c) * dim + r.max(c)]);
    // each neighbour's information from its own window outside this one, background marginalised
    for (k, nb) in neighbours.iter().enumerate() {
        let mut own = [[0.0; 7]; 7];
        let nw = nb.window;
        e.resize(nw.width * nw.height, 0.0);
        nb.exp_over(nw, &mut e, &mut v, &mut q);
        for (py, y) in (nw.y..nw.y + nw.height as i64).enumerate() {
            for (px, x) in (nw.x..nw.x + nw.width as i64).enumerate() {
                if inside(w, x, y) || !keep(x, y) {
                    continue;
                }
                let ep = e[py * nw.width + px];
                let mu = nb.theta[IB] + nb.eval(kind, ep, x as f64, y as f64, &mut d);
                let wt = 1.0 / noise.variance(mu);
                for r in 0..n_own {
                    for c in r..n_own {
                        own[r][c] += wt * d[r] * d[c];
                    }
                }
            }
        }
        let own = DMatrix::<f64>::from_fn(n_own, n_own, |r, c| own[r.min(c)][r.max(c)]);
        add_prior(&mut m, &own, ib, n_own + k * n_nb)?;
    }
    fill_lower(&mut m);
    bound_of(m)
}

/// Adds a neighbour's information from its own window (`own`, over its free parameters) with
/// its background (`ib`) marginalised out to the upper triangle of `m`'s block at `at`.
fn add_prior(m: &mut DMatrix<f64>, own: &DMatrix<f64>, ib: usize, at: usize) -> Option<()> {
    let prior = marginalise(own, ib)?;
    let n = prior.nrows();
    for r in 0..n {
        for c in r..n {
            m[(at + r, at + c)] += prior[(r, c)];
        }
    }
    Some(())
}

fn fill_lower(m: &mut DMatrix<f64>) {
    let n = m.nrows();
    for r in 0..n {
        for c in 0..r {
            m[(r, c)] = m[(c, r)];
        }
    }
}

/// The information about all parameters but `k` with parameter `k` unknown (Schur complement);
/// a zero matrix where the pixels said nothing (no pixel of the window outside the other).
fn marginalise(info: &DMatrix<f64>, k: usize) -> Option<DMatrix<f64>> {
    let n = info.nrows();
    let keep: Vec<usize> = (0..n).filter(|&r| r != k).collect();
    let mut out = DMatrix::<f64>::zeros(n - 1, n - 1);
    let kk = info[(k, k)];
    if kk <= 0.0 {
        return Some(out);
    }
    for (a, &r) in keep.iter().enumerate() {
        for (b, &c) in keep.iter().enumerate() {
            out[(a, b)] = info[(r, c)] - info[(r, k)] * info[(k, c)] / kk;
        }
    }
    Some(out)
}

/// The columns of a coupling matrix (a neighbour's free dot parameters: at most 6).
pub(crate) const NB: usize = 6;

/// A dot's linear coupling to its overlapping neighbours (see [`crate::coupling`]).
pub(crate) struct DotCoupling {
    /// Each free parameter's standard deviation, `sqrt((F⁻¹)_kk)`.
    pub scale: [f64; 7],
    /// `F` over the free parameters.
    pub fisher: [[f64; 7]; 7],
    /// Per neighbour (in the order given), `M = F⁻¹ C` by columns (the neighbour's free
    /// parameters without the background; in each the dot's free parameters, padded to 8).
    pub m: Vec<[[f64; 8]; NB]>,
}

/// The monomials `X^m Y^n` of the basis (`E·{1, X, Y, X², XY, Y²}`, see `crate::eval`).
const MONO: [(usize, usize); 6] = [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)];

/// How the least-squares fit of `dot` over its window responds, to first order, to changes of
/// its `neighbours`' subtracted models: with `F = Σ w ∇μ ∇μᵀ` the dot's Fisher matrix over the
/// window (`∇` over its free parameters) and `C_k = Σ w ∇μ ∇μ_kᵀ` (`∇μ_k` over neighbour k's
/// free parameters without its background, whose own background is not subtracted), a change
/// `δ_k` of the neighbours moves the fit by `−Σ_k F⁻¹ C_k δ_k`. Weights `1 / var(μ)` at the dot's
/// own model, as its fit has them. `None` when F is singular.
///
/// Every derivative is a combination of the basis `E·X^m Y^n` (m + n ≤ 2) and 1, so `C_k` is
/// made of the moments `Σ w E E_k X^m Y^n` (m + n ≤ 4) and `Σ w E_k X^m Y^n` (m + n ≤ 2) in the
/// dot's coordinates (the neighbour's monomials expanded about the dot's centre): 8
/// multiply-adds per pixel and neighbour, each dot's `E` rendered with `exp_grid`.
pub(crate) fn coupling(
    kind: Kind,
    dot: &JointDot,
    neighbours: &[JointDot],
    noise: &NoiseModel,
    keep: &dyn Fn(i64, i64) -> bool,
) -> Option<DotCoupling> {
    let n_own = kind.n_free();
    let ib = kind.free().iter().position(|&p| p == IB)?;
    let win = dot.window;
    let (w, h) = (win.width, win.height);
    let n = w * h;
    let (x0, y0) = (dot.theta[0], dot.theta[1]);
    let m = w.max(h);
    let (mut v, mut q) = (vec![0.0; m], vec![0.0; m]);
    // each dot rendered over the part of the window within 6.5 of its standard deviations per
    // axis (beyond, `E` < 1e-9: nothing a sum of 81 pixels would see)
    let render = |d: &JointDot, sub: Window, out: &mut Vec<f64>, v: &mut [f64], q: &mut [f64]| {
        out.resize(sub.width * sub.height, 0.0);
        d.exp_over(sub, out, v, q);
    };
    let reach = |d: &JointDot| -> Option<Window> {
        let span = |c: f64, ln_s: f64, lo: i64, len: usize| -> Option<(i64, usize)> {
            let r = 6.5 * ln_s.exp();
            let a = ((c - r).ceil() as i64).max(lo);
            let b = ((c + r).floor() as i64).min(lo + len as i64 - 1);
            (a <= b).then(|| (a, (b - a + 1) as usize))
        };
        let (x, wx) = span(d.theta[0], d.theta[crate::eval::IU], win.x, w)?;
        let (y, wy) = span(d.theta[1], d.theta[crate::eval::IV], win.y, h)?;
        Some(Window::new(x, y, wx, wy))
    };
    let mut e = Vec::new();
    render(dot, win, &mut e, &mut v, &mut q);
    let mut ek: Vec<Option<(Window, Vec<f64>)>> = Vec::with_capacity(neighbours.len());
    for nb in neighbours {
        ek.push(reach(nb).map(|sub| {
            let mut o = Vec::new();
            render(nb, sub, &mut o, &mut v, &mut q);
            (sub, o)
        }));
    }
    // the fit's weights
    let mut wt = vec![0.0; n];
    for j in 0..h {
        for i in 0..w {
            let k = j * w + i;
            if !keep(win.x + i as i64, win.y + j as i64) {
                continue;
            }
            // (the dot's own model, as its fit weights the window: the neighbours' light is
            // subtracted, not modelled; with the sum of all models the map is not the fit's,
            // and on `dense_vortex` the stack's coverage fell from 0.658 to 0.644)
            let mu = dot.theta[IB] + dot.theta[2] * e[k];
            wt[k] = 1.0 / noise.variance(mu);
        }
    }
    // the dot's own Fisher matrix: the same moments with the dot as its own neighbour
    let (s1, s2) = moments(win, win, x0, y0, &wt, &e, &e);
    let gf = own_products(&basis_products(&s1, &s2, 0.0, 0.0), wt.iter().sum());
    let mut f = [[0.0f64; 7]; 7];
    for r in 0..n_own {
        let mut cg = [0.0f64; 7];
        for (b, v) in cg.iter_mut().enumerate() {
            *v = (0..7).map(|a| dot.coef[r][a] * gf[a][b]).sum();
        }
        for c in 0..n_own {
            f[r][c] = (0..7).map(|b| cg[b] * dot.coef[c][b]).sum();
        }
    }
    let fac = crate::solver::Factor::new(&f, n_own, 0.0)?;
    let mut scale = [0.0; 7];
    for (k, s) in scale.iter_mut().enumerate().take(n_own) {
        let mut u = [0.0; 7];
        u[k] = 1.0;
        let x = fac.solve(&u)[k];
        if !(x > 0.0 && x.is_finite()) {
            return None;
        }
        *s = x.sqrt();
    }
    // P = F⁻¹ coef (rows: free parameters, columns: basis), so that M_k = P g coef_kᵀ
    let mut p = [[0.0f64; 7]; 7];
    for a in 0..7 {
        let mut rhs = [0.0; 7];
        for r in 0..n_own {
            rhs[r] = dot.coef[r][a];
        }
        let x = fac.solve(&rhs);
        for r in 0..n_own {
            p[r][a] = x[r];
        }
    }
    let mut out = Vec::with_capacity(neighbours.len());
    for (nb, o) in neighbours.iter().zip(&ek) {
        let Some((sub, o)) = o else {
            out.push([[0.0; 8]; NB]);
            continue;
        };
        let (s1, s2) = moments(win, *sub, x0, y0, &wt, &e, o);
        let g = basis_products(&s1, &s2, nb.theta[0] - x0, nb.theta[1] - y0);
        // columns: the neighbour's free parameters without the background
        let mut mk = [[0.0; 8]; NB];
        let mut col = 0;
        for (sk, _) in kind.free().iter().enumerate() {
            if sk == ib {
                continue;
            }
            let ck_row = &nb.coef[sk];
            // gb[a] = Σ_b g[a][b] coef_k[sk][b]
            let mut gb = [0.0f64; 7];
            for (a, ga) in g.iter().enumerate() {
                gb[a] = (0..6).map(|b| ga[b] * ck_row[b]).sum();
            }
            for (r, pr) in p.iter().enumerate().take(n_own) {
                mk[col][r] = (0..7).map(|a| pr[a] * gb[a]).sum();
            }
            col += 1;
        }
        out.push(mk);
    }
    Some(DotCoupling {
        scale,
        fisher: f,
        m: out,
    })
}

/// `s1[m][n] = Σ w E E_k X^m Y^n` (m + n ≤ 4) and `s2[m][n] = Σ w E_k X^m Y^n` (m + n ≤ 2) over
/// `sub`, a part of the window `win` (`wt`, `e` row-major over `win`, `ek` over `sub`), `X`, `Y`
/// about (x0, y0): row sums of the powers of X, folded with the powers of Y per row.
#[allow(clippy::too_many_arguments)]
fn moments(
    win: Window,
    sub: Window,
    x0: f64,
    y0: f64,
    wt: &[f64],
    e: &[f64],
    ek: &[f64],
) -> ([[f64; 5]; 5], [[f64; 3]; 3]) {
    let (dx, dy) = ((sub.x - win.x) as usize, (sub.y - win.y) as usize);
    let mut s1 = [[0.0f64; 5]; 5];
    let mut s2 = [[0.0f64; 3]; 3];
    for j in 0..sub.height {
        let y = (sub.y + j as i64) as f64 - y0;
        let row = (dy + j) * win.width + dx;
        let (wr, er) = (&wt[row..row + sub.width], &e[row..row + sub.width]);
        let kr = &ek[j * sub.width..(j + 1) * sub.width];
        let (mut r1, mut r2) = ([0.0f64; 5], [0.0f64; 3]);
        let mut x = sub.x as f64 - x0;
        for ((&wv, &ev), &kv) in wr.iter().zip(er).zip(kr) {
            let p2 = wv * kv;
            let p1 = p2 * ev;
            let x2 = x * x;
            r1[0] += p1;
            r1[1] += p1 * x;
            r1[2] += p1 * x2;
            r1[3] += p1 * x2 * x;
            r1[4] += p1 * x2 * x2;
            r2[0] += p2;
            r2[1] += p2 * x;
            r2[2] += p2 * x2;
            x += 1.0;
        }
        let mut yn = 1.0;
        for nn in 0..5 {
            for mm in 0..5 - nn {
                s1[mm][nn] += r1[mm] * yn;
            }
            if nn < 3 {
                for mm in 0..3 - nn {
                    s2[mm][nn] += r2[mm] * yn;
                }
            }
            yn *= y;
        }
    }
    (s1, s2)
}

/// `g[a][b] = Σ w φ_a φ_kb` from [`moments`]: `a` over the dot's basis (its 6 monomials times
/// `E`, then the background's 1), `b` over the neighbour's 6 (about its own centre, `(dx, dy)`
/// from the dot's: its monomials expanded about the dot's centre).
fn basis_products(s1: &[[f64; 5]; 5], s2: &[[f64; 3]; 3], dx: f64, dy: f64) -> [[f64; 6]; 7] {
    let poly: [[f64; 6]; 6] = [
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [-dx, 1.0, 0.0, 0.0, 0.0, 0.0],
        [-dy, 0.0, 1.0, 0.0, 0.0, 0.0],
        [dx * dx, -2.0 * dx, 0.0, 1.0, 0.0, 0.0],
        [dx * dy, -dy, -dx, 0.0, 1.0, 0.0],
        [dy * dy, 0.0, -2.0 * dy, 0.0, 0.0, 1.0],
    ];
    let mut g = [[0.0f64; 6]; 7];
    for (b, pb) in poly.iter().enumerate() {
        for (a, &(ma, na)) in MONO.iter().enumerate() {
            g[a][b] = pb
                .iter()
                .zip(&MONO)
                .map(|(&c, &(mc, nc))| c * s1[ma + mc][na + nc])
                .sum();
        }
        g[6][b] = pb
            .iter()
            .zip(&MONO)
            .map(|(&c, &(mc, nc))| c * s2[mc][nc])
            .sum();
    }
    g
}

/// A dot's products with itself over its whole basis, the background's 1 included, from
/// [`basis_products`] with the dot as its own neighbour (`g[6][b] = Σ w φ_b` is then the 1's
/// column too) and `sum_w = Σ w`.
fn own_products(g: &[[f64; 6]; 7], sum_w: f64) -> [[f64; 7]; 7] {
    let mut gf = [[0.0f64; 7]; 7];
    for a in 0..7 {
        gf[a][..6].copy_from_slice(&g[a]);
    }
    for b in 0..6 {
        gf[b][6] = g[6][b];
    }
    gf[6][6] = sum_w;
    gf
}

/// Whether pixel (x, y) is usable: inside the image, kept by the mask, finite, not saturated.
pub(crate) fn usable(img: &bostrack_core::Image, mask: Option<&Mask>, x: i64, y: i64) -> bool {
    if x < 0 || y < 0 || x as usize >= img.width() || y as usize >= img.height() {
        return false;
    }
    let (ux, uy) = (x as usize, y as usize);
    let v = img.row(uy)[ux];
    v.is_finite() && !img.is_saturated(v) && mask.is_none_or(|m| m.keeps(ux, uy))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// The moment form of the joint bound against the sum over the pixels, on random groups: a
    /// dot with 0 to 5 neighbours (elliptical, up to touching it), the four kinds with a
    /// background among their parameters, windows cut by the image's edge and a mask (`keep`),
    /// a noise model with a photon term.
    #[test]
    fn moment_form_is_the_direct_sum() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let noise = NoiseModel {
            read_variance: 25.0,
            gain: 0.8,
            offset: 100.0,
        };
        let mut compared = 0;
        let mut diffs = Vec::new();
        for trial in 0..400 {
            let kind = [
                Kind::Elliptical,
                Kind::AxisAligned,
                Kind::Circular,
                Kind::FixedShape,
            ][trial % 4];
            let random_dot = |rng: &mut rand::rngs::StdRng, x: f64, y: f64| {
                let sx = 0.6 + 1.6 * rng.random::<f64>();
                Gaussian2D {
                    x0: x,
                    y0: y,
                    amplitude: 200.0 + 3000.0 * rng.random::<f64>(),
                    sigma_x: sx,
                    sigma_y: sx * (0.6 + 0.8 * rng.random::<f64>()),
                    rho: 1.4 * rng.random::<f64>() - 0.7,
                    background: 100.0 + 400.0 * rng.random::<f64>(),
                }
            };
            let c = [20.0 + rng.random::<f64>(), 20.0 + rng.random::<f64>()];
            let half = 3 + trial % 4;
            let window = |x: f64, y: f64| {
                let w = Window::new(
                    x.round() as i64 - half as i64,
                    y.round() as i64 - half as i64,
                    2 * half + 1,
                    2 * half + 1,
                );
                // (a window cut by the image's edge at x = 17 now and then)
                if trial % 5 == 0 {
                    w.clip(40, 40).unwrap()
                } else {
                    w
                }
            };
            let g = random_dot(&mut rng, c[0], c[1]);
            let Some(dot) = JointDot::from_params(&g, window(c[0], c[1]), kind) else {
                continue;
            };
            let nbs: Vec<JointDot> = (0..trial % 6)
                .filter_map(|_| {
                    let a = std::f64::consts::TAU * rng.random::<f64>();
                    // (within the window's reach, as the iteration's groups are: a neighbour
                    // whose derivatives all vanish in the window is not in a group)
                    let r = 2.5 + (half as f64 - 0.5) * rng.random::<f64>();
                    let (x, y) = (c[0] + r * a.cos(), c[1] + r * a.sin());
                    JointDot::from_params(&random_dot(&mut rng, x, y), window(x, y), kind)
                })
                .collect();
            let hole = (rng.random::<f64>() * 10.0) as i64;
            let keep = |x: i64, y: i64| x >= 17 && (x + 2 * y) % 11 != hole;
            let a = joint_bound(kind, &dot, &nbs, &noise, &keep);
            let b = joint_bound_direct(kind, &dot, &nbs, &noise, &keep);
            match (a, b) {
                (Some(a), Some(b)) => {
                    for k in 0..2 {
                        diffs.push((a[k] / b[k] - 1.0).abs());
                    }
                    compared += 1;
                }
                (None, None) => {}
                _ => panic!("trial {trial}: {a:?} against {b:?}"),
            }
        }
        diffs.sort_by(f64::total_cmp);
        let (p99, worst) = (diffs[diffs.len() * 99 / 100], diffs[diffs.len() - 1]);
        println!(
            "{compared} groups compared: relative difference median {:e}, 99th percentile \
             {p99:e}, largest {worst:e}",
            diffs[diffs.len() / 2]
        );
        assert!(compared > 300, "{compared}");
        // the same sums in another order; the largest differences are those of the
        // ill-conditioned groups (a neighbour seen only through its far tail), where both
        // orders' roundoff is amplified alike
        assert!(p99 < 1e-9, "{p99:e}");
        assert!(worst < 1e-6, "{worst:e}");
    }
}
