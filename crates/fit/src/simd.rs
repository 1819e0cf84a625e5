//! The evaluation pass's per-pixel loops, with SIMD chosen at run time (`pulp`: AVX2 on x86-64
//! CPUs that have it, the portable scalar path otherwise; safe code on our side).
//!
//! Lanes are the columns of a window. Every kernel does, per pixel, the same operations in the
//! same order on every path (no fused multiply-add, no reassociation): a column's sums run over
//! the rows in order whatever the lane count, and the fold over the columns is scalar. So the
//! dispatched and the portable path give the same bits (test
//! `dispatched_kernels_equal_the_portable_path`), and `BOSTRACK_SIMD=portable` (read once)
//! forces the portable path, for benchmarks against it.

use pulp::{Arch, Simd, WithSimd};

/// The instruction set the kernels run on ([`bostrack_core::simd_arch`]: the best the CPU has
/// unless `BOSTRACK_SIMD=portable`).
#[inline]
pub(crate) fn arch() -> Arch {
    bostrack_core::simd_arch()
}

/// The lanes of `s` (a full vector, or fewer values at the window's last columns).
#[inline(always)]
fn load_lanes<S: Simd>(simd: S, s: &[f64]) -> S::f64s {
    if s.len() == S::F64_LANES {
        S::as_simd_f64s(s).0[0]
    } else {
        simd.partial_load_f64s(s)
    }
}

/// `v` into `o` (a full vector, or its first lanes at the window's last columns).
#[inline(always)]
fn store_lanes<S: Simd>(simd: S, o: &mut [f64], v: S::f64s) {
    if o.len() == S::F64_LANES {
        S::as_mut_simd_f64s(o).0[0] = v;
    } else {
        simd.partial_store_f64s(o, v);
    }
}

/// The sums of a column kernel over its inputs `inp` ([`MomentsIn`]: a point-sampled pass's
/// moments; [`BasisIn`]: a pass over a per-pixel basis; [`LookIn`]: a look at a dot) on the
/// given path (columns as lanes, each column's sums over the rows in order, the columns folded
/// in order: the same bits on every path); `acc` is scratch of at least [`acc_len`]`(w)`
/// values.
pub(crate) fn column_sums<'a, I>(
    arch: Arch,
    inp: &'a I,
    acc: &'a mut [f64],
) -> <Columns<'a, I> as WithSimd>::Output
where
    Columns<'a, I>: WithSimd,
{
    arch.dispatch(Columns { inp, acc })
}

/// A kernel whose lanes are a window's columns: its inputs and the scratch of the columns'
/// sums (at least [`acc_len`] of the window's width).
pub(crate) struct Columns<'a, I> {
    inp: &'a I,
    acc: &'a mut [f64],
}

impl<I> Columns<'_, I> {
    /// The column loop of a kernel over a `w × h` window: for each group of lanes (first column
    /// `c0`), `row(t, c0, j)` adds the terms of row `j` to the group's `N` sums `t` in
    /// registers, row after row in order; the sums then go to the scratch. Then
    /// `column(i, sums)` for every column `i` in order, with `sums.at(q)` its sum `q` (the
    /// scalar fold).
    #[inline(always)]
    fn sums<S: Simd, const N: usize>(
        &mut self,
        simd: S,
        (w, h): (usize, usize),
        mut row: impl FnMut(&mut [S::f64s; N], usize, usize),
        mut column: impl FnMut(usize, Lane),
    ) {
        let lanes = S::F64_LANES;
        let groups = w.div_ceil(lanes);
        let zero = simd.splat_f64s(0.0);
        for k in 0..groups {
            let mut t = [zero; N];
            for j in 0..h {
                row(&mut t, k * lanes, j);
            }
            let out = &mut self.acc[k * N * lanes..(k + 1) * N * lanes];
            S::as_mut_simd_f64s(out).0.copy_from_slice(&t);
        }
        for (k, group) in self.acc[..groups * N * lanes]
            .chunks_exact(N * lanes)
            .enumerate()
        {
            for l in 0..lanes.min(w - k * lanes) {
                column(k * lanes + l, Lane { group, l, lanes });
            }
        }
    }
}

/// One column's sums in the scratch of [`Columns::sums`].
#[derive(Clone, Copy)]
struct Lane<'a> {
    group: &'a [f64],
    l: usize,
    lanes: usize,
}

impl Lane<'_> {
    /// Sum `q` of the column.
    #[inline(always)]
    fn at(self, q: usize) -> f64 {
        self.group[q * self.lanes + self.l]
    }
}

/// The lanes of `a` (a `w`-wide row-major window) at row `j` from column `c0`.
#[inline(always)]
fn row_lanes<S: Simd>(simd: S, a: &[f64], w: usize, c0: usize, j: usize) -> S::f64s {
    load_lanes(simd, &a[j * w + c0..j * w + (c0 + S::F64_LANES).min(w)])
}

/// Widest lane count of any path (sizes the column accumulators).
pub(crate) const MAX_LANES: usize = 8;
/// Column accumulators per window column: `Σ_rows w E² Yⁿ` (n = 0..4), `Σ w E Yⁿ` (0..2),
/// `Σ w r E Yⁿ` (0..2), `Σ w`, `Σ w r`, `Σ w r²`, `Σ keep r²`.
pub(crate) const N_ACC: usize = 15;
/// [`N_ACC`] and `Σ w r E Yⁿ` (n = 3, 4): the pass that also gives the residual's moments of
/// degree 3 and 4 (the Newton step's second-order term).
pub(crate) const N_ACC_HESS: usize = N_ACC + 2;

/// The sums of one point-sampled pass (before the constant-noise scale): `m2[m][n] = Σ w E² XᵐYⁿ`
/// (m + n ≤ 4), `m1[m][n] = Σ w E XᵐYⁿ`, `r1[m][n] = Σ w r E XᵐYⁿ` (m + n ≤ 2), `m0 = Σ w`,
/// `r0 = Σ w r`, `cost = Σ w r²`, `ssr = Σ keep r²`; with [`MomentsIn::hess`] also
/// `rh[m][n] = Σ w r E XᵐYⁿ` for m + n = 3, 4 (0 elsewhere).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Moments {
    pub m2: [[f64; 5]; 5],
    pub m1: [[f64; 3]; 3],
    pub r1: [[f64; 3]; 3],
    pub rh: [[f64; 5]; 5],
    pub m0: f64,
    pub r0: f64,
    pub cost: f64,
    pub ssr: f64,
}

/// Inputs of [`column_sums`] of a [`MomentsIn`]: row-major `w × h` arrays of `E`, the data, `keep` and the
/// weights; the model is `bg + amp·E`; the first column and row are at `X = x_first`,
/// `Y = y_first`.
pub(crate) struct MomentsIn<'a> {
    pub e: &'a [f64],
    pub d: &'a [f64],
    pub keep: &'a [f64],
    pub wt: &'a [f64],
    pub w: usize,
    pub h: usize,
    pub amp: f64,
    pub bg: f64,
    pub x_first: f64,
    pub y_first: f64,
    /// Also the residual's moments of degree 3 and 4 ([`Moments::rh`]).
    pub hess: bool,
}

/// Scratch length [`column_sums`] of a [`MomentsIn`] and [`column_sums`] of a [`BasisIn`] need for a window `w` columns wide.
pub(crate) fn acc_len(w: usize) -> usize {
    w.div_ceil(MAX_LANES) * MAX_LANES * N_ACC_HESS.max(N_BASIS)
}

/// The moments of a pass ([`column_sums`] of a [`MomentsIn`]).
impl WithSimd for Columns<'_, MomentsIn<'_>> {
    type Output = Moments;

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> Moments {
        if self.inp.hess {
            self.moments::<S, N_ACC_HESS>(simd)
        } else {
            self.moments::<S, N_ACC>(simd)
        }
    }
}

impl Columns<'_, MomentsIn<'_>> {
    /// The pass's sums with `N` column accumulators: [`N_ACC`], or [`N_ACC_HESS`] with the
    /// residual's moments of degree 3 and 4 (`Σ w r E Y³`, `Σ w r E Y⁴` per column).
    #[inline(always)]
    fn moments<S: Simd, const N: usize>(mut self, simd: S) -> Moments {
        let MomentsIn {
            e,
            d,
            keep,
            wt,
            w,
            h,
            amp,
            bg,
            x_first,
            y_first,
            hess: _,
        } = *self.inp;
        let (vamp, vbg) = (simd.splat_f64s(amp), simd.splat_f64s(bg));
        let mut m = Moments::default();
        // column group after column group, every row in order, the sums in registers
        self.sums::<S, N>(
            simd,
            (w, h),
            |t, c0, j| {
                let load = |a: &[f64], j: usize| row_lanes(simd, a, w, c0, j);
                let y = y_first + j as f64;
                let y2 = y * y;
                let (ei, di, ki, wi) = (load(e, j), load(d, j), load(keep, j), load(wt, j));
                let r = simd.sub_f64s(di, simd.add_f64s(vbg, simd.mul_f64s(vamp, ei)));
                let wr = simd.mul_f64s(wi, r);
                let we = simd.mul_f64s(wi, ei);
                let we2 = simd.mul_f64s(we, ei);
                let wre = simd.mul_f64s(wr, ei);
                let (vy, vy2) = (simd.splat_f64s(y), simd.splat_f64s(y2));
                let (vy3, vy4) = (simd.splat_f64s(y2 * y), simd.splat_f64s(y2 * y2));
                t[0] = simd.add_f64s(t[0], we2);
                t[1] = simd.add_f64s(t[1], simd.mul_f64s(we2, vy));
                t[2] = simd.add_f64s(t[2], simd.mul_f64s(we2, vy2));
                t[3] = simd.add_f64s(t[3], simd.mul_f64s(we2, vy3));
                t[4] = simd.add_f64s(t[4], simd.mul_f64s(we2, vy4));
                t[5] = simd.add_f64s(t[5], we);
                t[6] = simd.add_f64s(t[6], simd.mul_f64s(we, vy));
                t[7] = simd.add_f64s(t[7], simd.mul_f64s(we, vy2));
                t[8] = simd.add_f64s(t[8], wre);
                t[9] = simd.add_f64s(t[9], simd.mul_f64s(wre, vy));
                t[10] = simd.add_f64s(t[10], simd.mul_f64s(wre, vy2));
                t[11] = simd.add_f64s(t[11], wi);
                t[12] = simd.add_f64s(t[12], wr);
                t[13] = simd.add_f64s(t[13], simd.mul_f64s(wr, r));
                t[14] = simd.add_f64s(t[14], simd.mul_f64s(simd.mul_f64s(ki, r), r));
                if N == N_ACC_HESS {
                    t[N_ACC] = simd.add_f64s(t[N_ACC], simd.mul_f64s(wre, vy3));
                    t[N_ACC + 1] = simd.add_f64s(t[N_ACC + 1], simd.mul_f64s(wre, vy4));
                }
            },
            // the columns folded (scalar, in order)
            |i, c| {
                let x = x_first + i as f64;
                let x2 = x * x;
                let (x3, x4) = (x2 * x, x2 * x2);
                let (c0, c1, c2, c3, c4) = (c.at(0), c.at(1), c.at(2), c.at(3), c.at(4));
                m.m2[0][0] += c0;
                m.m2[1][0] += c0 * x;
                m.m2[2][0] += c0 * x2;
                m.m2[3][0] += c0 * x3;
                m.m2[4][0] += c0 * x4;
                m.m2[0][1] += c1;
                m.m2[1][1] += c1 * x;
                m.m2[2][1] += c1 * x2;
                m.m2[3][1] += c1 * x3;
                m.m2[0][2] += c2;
                m.m2[1][2] += c2 * x;
                m.m2[2][2] += c2 * x2;
                m.m2[0][3] += c3;
                m.m2[1][3] += c3 * x;
                m.m2[0][4] += c4;
                let (d0, d1, d2) = (c.at(5), c.at(6), c.at(7));
                let (r0, r1, r2) = (c.at(8), c.at(9), c.at(10));
                m.m1[0][0] += d0;
                m.m1[1][0] += d0 * x;
                m.m1[2][0] += d0 * x2;
                m.m1[0][1] += d1;
                m.m1[1][1] += d1 * x;
                m.m1[0][2] += d2;
                m.r1[0][0] += r0;
                m.r1[1][0] += r0 * x;
                m.r1[2][0] += r0 * x2;
                m.r1[0][1] += r1;
                m.r1[1][1] += r1 * x;
                m.r1[0][2] += r2;
                m.m0 += c.at(11);
                m.r0 += c.at(12);
                m.cost += c.at(13);
                m.ssr += c.at(14);
                if N == N_ACC_HESS {
                    let (r3, r4) = (c.at(N_ACC), c.at(N_ACC + 1));
                    m.rh[3][0] += r0 * x3;
                    m.rh[4][0] += r0 * x4;
                    m.rh[2][1] += r1 * x2;
                    m.rh[3][1] += r1 * x3;
                    m.rh[1][2] += r2 * x;
                    m.rh[2][2] += r2 * x2;
                    m.rh[0][3] += r3;
                    m.rh[1][3] += r3 * x;
                    m.rh[0][4] += r4;
                }
            },
        );
        m
    }
}

/// Inputs of [`column_sums`] of a [`LookIn`]: row-major `w × h` arrays of `E`, the data and `keep`; the model is
/// `bg + amp·E` and a pixel's weight `keep / variance(model)`, with the variance of
/// `NoiseModel::variance`, `max(read + gain · max(model − offset, 0), 1e-12)`; the first column
/// and row are at `X = x_first`, `Y = y_first`.
pub(crate) struct LookIn<'a> {
    pub e: &'a [f64],
    pub d: &'a [f64],
    pub keep: &'a [f64],
    pub w: usize,
    pub h: usize,
    pub amp: f64,
    pub bg: f64,
    pub x_first: f64,
    pub y_first: f64,
    pub read: f64,
    pub gain: f64,
    pub offset: f64,
}

/// The sums of a look at a dot (`dots::look`): `g = Σ w r E·(1, X, Y, X², XY, Y²)` and
/// `g[6] = Σ w r`, `chi2 = Σ w r²`, `ssr = Σ keep r²`, with `r = data − model` and the weights
/// of [`LookIn`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct LookSums {
    pub g: [f64; 7],
    pub chi2: f64,
    pub ssr: f64,
}

/// Column accumulators of [`column_sums`] of a [`LookIn`]: `Σ w r E Yⁿ` (n = 0..2), `Σ w r`, `Σ w r²`,
/// `Σ keep r²`.
const N_LOOK: usize = 6;

/// The sums of a look ([`column_sums`] of a [`LookIn`]).
impl WithSimd for Columns<'_, LookIn<'_>> {
    type Output = LookSums;

    #[inline(always)]
    fn with_simd<S: Simd>(mut self, simd: S) -> LookSums {
        let LookIn {
            e,
            d,
            keep,
            w,
            h,
            amp,
            bg,
            x_first,
            y_first,
            read,
            gain,
            offset,
        } = *self.inp;
        let (vamp, vbg) = (simd.splat_f64s(amp), simd.splat_f64s(bg));
        let (vread, vgain) = (simd.splat_f64s(read), simd.splat_f64s(gain));
        let (voff, tiny) = (simd.splat_f64s(offset), simd.splat_f64s(1e-12));
        let mut s = LookSums::default();
        // column group after column group, every row in order, the sums in registers
        self.sums::<S, N_LOOK>(
            simd,
            (w, h),
            |t, c0, j| {
                let load = |a: &[f64], j: usize| row_lanes(simd, a, w, c0, j);
                let y = y_first + j as f64;
                let (vy, vy2) = (simd.splat_f64s(y), simd.splat_f64s(y * y));
                let (ei, di, ki) = (load(e, j), load(d, j), load(keep, j));
                let mu = simd.add_f64s(vbg, simd.mul_f64s(vamp, ei));
                let r = simd.sub_f64s(di, mu);
                let above = simd.max_f64s(simd.sub_f64s(mu, voff), simd.splat_f64s(0.0));
                let var = simd.max_f64s(simd.add_f64s(vread, simd.mul_f64s(vgain, above)), tiny);
                let kr = simd.mul_f64s(ki, r);
                let wr = simd.div_f64s(kr, var);
                let we = simd.mul_f64s(wr, ei);
                t[0] = simd.add_f64s(t[0], we);
                t[1] = simd.add_f64s(t[1], simd.mul_f64s(we, vy));
                t[2] = simd.add_f64s(t[2], simd.mul_f64s(we, vy2));
                t[3] = simd.add_f64s(t[3], wr);
                t[4] = simd.add_f64s(t[4], simd.mul_f64s(wr, r));
                t[5] = simd.add_f64s(t[5], simd.mul_f64s(kr, r));
            },
            // the columns folded (scalar, in order)
            |i, c| {
                let x = x_first + i as f64;
                let (c0, c1) = (c.at(0), c.at(1));
                s.g[0] += c0;
                s.g[1] += c0 * x;
                s.g[2] += c1;
                s.g[3] += c0 * x * x;
                s.g[4] += c1 * x;
                s.g[5] += c.at(2);
                s.g[6] += c.at(3);
                s.chi2 += c.at(4);
                s.ssr += c.at(5);
            },
        );
        s
    }
}

/// The rows of `E` from the recurrence of `exp_grid`: row `j` is `gy_j · v` with `v`
/// multiplied by `q` after every row but the last, `gy_{j+1} = gy_j · s_j`, `s_{j+1} = s_j · ec`.
pub(crate) struct ExpRows<'a> {
    pub out: &'a mut [f64],
    pub v: &'a mut [f64],
    pub q: &'a [f64],
    pub w: usize,
    pub gy: f64,
    pub s: f64,
    pub ec: f64,
}

pub(crate) fn exp_rows(arch: Arch, rows: ExpRows) {
    arch.dispatch(rows)
}

impl WithSimd for ExpRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let ExpRows {
            out,
            v,
            q,
            w,
            mut gy,
            mut s,
            ec,
        } = self;
        let (v, q) = (&mut v[..w], &q[..w]);
        let h = out.len() / w;
        for (j, row) in out.chunks_exact_mut(w).enumerate() {
            {
                let (rh, rt) = S::as_mut_simd_f64s(row);
                let (vh, vt) = S::as_simd_f64s(v);
                let g = simd.splat_f64s(gy);
                for (o, vv) in rh.iter_mut().zip(vh) {
                    *o = simd.mul_f64s(g, *vv);
                }
                for (o, vv) in rt.iter_mut().zip(vt) {
                    *o = gy * vv;
                }
            }
            if j + 1 < h {
                let (vh, vt) = S::as_mut_simd_f64s(v);
                let (qh, qt) = S::as_simd_f64s(q);
                for (vv, qq) in vh.iter_mut().zip(qh) {
                    *vv = simd.mul_f64s(*vv, *qq);
                }
                for (vv, qq) in vt.iter_mut().zip(qt) {
                    *vv *= qq;
                }
                gy *= s;
                s *= ec;
            }
        }
    }
}

/// `exp` of eight values at once, in code the compiler vectorises (through `pulp`'s dispatch on
/// `arch`: the same bits on every path, no fused multiply-add), for
/// [`crate::eval::exp_grid`]'s eight factors: ~9 instructions each with AVX2 where a call of
/// libm's `exp` took ~38. Within 2 ulp of libm's (test `exp8_is_libm_exp`): `x = k ln 2 + r`
/// with `k` the nearest integer to `x / ln 2` (by the 1.5·2⁵² shifter) and `r` by Cody and
/// Waite's two-part `ln 2` (exact products for `|k| < 2²¹`), `exp(r)` by its Taylor series to
/// degree 13 (`|r| ≤ ln 2 / 2`: truncation below 1e-17), times `2^k` built in the exponent
/// bits.
/// Below −708 (results near the smallest normal number and below) it returns 0 where libm
/// returns a tiny number or 0; above 709.78, +∞ (libm's overflow); NaN for NaN.
pub(crate) fn exp8(arch: Arch, x: [f64; 8]) -> [f64; 8] {
    arch.dispatch(Exp8(x))
}

/// The kernel of [`exp8`].
struct Exp8([f64; 8]);

impl WithSimd for Exp8 {
    type Output = [f64; 8];

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) -> [f64; 8] {
        exp8_lanes(self.0)
    }
}

/// [`exp8`]'s arithmetic, lane by lane (which the compiler vectorises).
#[inline(always)]
fn exp8_lanes(x: [f64; 8]) -> [f64; 8] {
    const SHIFTER: f64 = 6_755_399_441_055_744.0;
    // ln 2 in two parts (fdlibm's): the first with its low 32 bits zero
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    // 1/n!, n = 13 down to 2
    const C: [f64; 12] = [
        1.0 / 6_227_020_800.0,
        1.0 / 479_001_600.0,
        1.0 / 39_916_800.0,
        1.0 / 3_628_800.0,
        1.0 / 362_880.0,
        1.0 / 40_320.0,
        1.0 / 5_040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
    ];
    const LO: f64 = -708.0;
    const HI: f64 = 709.78;
    let mut out = [0.0; 8];
    for (o, &xi) in out.iter_mut().zip(&x) {
        // (compare-and-select only, which vectorises: within [LO, HI] k + 1022 lies in
        // 1..=2046, a valid exponent field; NaN passes through and stays NaN)
        let xc = if xi < LO { LO } else { xi };
        let xc = if xc > HI { HI } else { xc };
        let t = xc * std::f64::consts::LOG2_E + SHIFTER;
        let kf = t - SHIFTER;
        let r = (xc - kf * LN2_HI) - kf * LN2_LO;
        let mut p = C[0];
        for &c in &C[1..] {
            p = p * r + c;
        }
        p = (p * r + 1.0) * r + 1.0;
        // 2^(k−1) (times 2 below: k reaches 1024 under the largest result), from the shifter's
        // bits, which hold k in their lowest ones
        let bits = t
            .to_bits()
            .wrapping_sub(SHIFTER.to_bits())
            .wrapping_add(1022)
            << 52;
        let e = (p * 2.0) * f64::from_bits(bits);
        let e = if xi < LO { 0.0 } else { e };
        *o = if xi > HI { f64::INFINITY } else { e };
    }
    out
}

/// The rows a coupling map's link keeps per column: a dot's parameters but its background, at
/// most six (a column widened to 8 lanes, its last two 0, in [`link_row`]; stored padded to 8,
/// a map's sweeps read a quarter more bytes, their cost on the real frame).
pub(crate) const LINK_ROWS: usize = 6;

/// A column of a coupling map's link matrix ([`LINK_ROWS`] rows).
pub(crate) type LinkColumn = [f32; LINK_ROWS];

/// One row of the coupling map's sweeps ([`crate::coupling`]): `v = own − Σ_links Σ_c m[c] · x_c`
/// over the links in order, each link's columns `c` in order (`m` its matrix by columns of
/// [`LINK_ROWS`], widened to 8 rows with zeros, `x = now[nb]` the neighbour's correction), a
/// product then a difference per row (no fused multiply-add), on every path: the same bits as
/// the plain loop.
pub(crate) struct LinkRow<'a, const NB: usize> {
    pub own: [f64; 8],
    pub nb: &'a [u32],
    pub m: &'a [[LinkColumn; NB]],
    pub now: &'a [[f64; 8]],
}

pub(crate) fn link_row<const NB: usize>(arch: Arch, k: LinkRow<'_, NB>) -> [f64; 8] {
    arch.dispatch(k)
}

impl<const NB: usize> WithSimd for LinkRow<'_, NB> {
    type Output = [f64; 8];

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> [f64; 8] {
        let LinkRow { own, nb, m, now } = self;
        let mut v = own;
        {
            let (vh, vt) = S::as_mut_simd_f64s(&mut v);
            for (&j, mj) in nb.iter().zip(m) {
                let dj = &now[j as usize];
                for (col, &x) in mj.iter().zip(dj) {
                    // (the f32 column widened once, then as lanes)
                    let c: [f64; 8] = std::array::from_fn(|r| {
                        if r < LINK_ROWS {
                            f64::from(col[r])
                        } else {
                            0.0
                        }
                    });
                    let (ch, ct) = S::as_simd_f64s(&c);
                    let xs = simd.splat_f64s(x);
                    for (o, cc) in vh.iter_mut().zip(ch) {
                        *o = simd.sub_f64s(*o, simd.mul_f64s(*cc, xs));
                    }
                    for (o, cc) in vt.iter_mut().zip(ct) {
                        *o -= cc * x;
                    }
                }
            }
        }
        v
    }
}

/// Column accumulators of [`column_sums`] of a [`BasisIn`]: `Σ w φ_b φ_c` (b ≤ c < 6: 21), `Σ w φ_b` (6),
/// `Σ w`, `Σ w r φ_b` (6), `Σ w r`, `Σ w r²`, `Σ keep r²`.
const N_BASIS: usize = 37;

/// The sums of one pass over a per-pixel basis (the pixel-integrated model): `gram` the upper
/// triangle of `Σ w φφᵀ` over `φ = (φ0..φ5, 1)` in row order (28 values), `grad = Σ w r φ`,
/// `cost = Σ w r²`, `ssr = Σ keep r²`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct BasisSums {
    pub gram: [f64; 28],
    pub grad: [f64; 7],
    pub cost: f64,
    pub ssr: f64,
}

/// Inputs of [`column_sums`] of a [`BasisIn`]: row-major `w × h` arrays of the basis `φ0..φ5`, the data, `keep`
/// and the weights; the model is `bg + amp·φ0`.
pub(crate) struct BasisIn<'a> {
    pub phi: [&'a [f64]; 6],
    pub d: &'a [f64],
    pub keep: &'a [f64],
    pub wt: &'a [f64],
    pub w: usize,
    pub h: usize,
    pub amp: f64,
    pub bg: f64,
}

/// The sums of a pass over a per-pixel basis ([`column_sums`] of a [`BasisIn`]).
impl WithSimd for Columns<'_, BasisIn<'_>> {
    type Output = BasisSums;

    #[inline(always)]
    fn with_simd<S: Simd>(mut self, simd: S) -> BasisSums {
        let BasisIn {
            phi,
            d,
            keep,
            wt,
            w,
            h,
            amp,
            bg,
        } = *self.inp;
        let (vamp, vbg) = (simd.splat_f64s(amp), simd.splat_f64s(bg));
        let mut out = BasisSums::default();
        // column group after column group, every row in order, the sums in registers
        self.sums::<S, N_BASIS>(
            simd,
            (w, h),
            |t, c0, j| {
                let load = |a: &[f64], j: usize| row_lanes(simd, a, w, c0, j);
                let f = [
                    load(phi[0], j),
                    load(phi[1], j),
                    load(phi[2], j),
                    load(phi[3], j),
                    load(phi[4], j),
                    load(phi[5], j),
                ];
                let (di, ki, wi) = (load(d, j), load(keep, j), load(wt, j));
                let r = simd.sub_f64s(di, simd.add_f64s(vbg, simd.mul_f64s(vamp, f[0])));
                let wr = simd.mul_f64s(wi, r);
                let mut idx = 0;
                for b in 0..6 {
                    let wf = simd.mul_f64s(wi, f[b]);
                    for &fc in &f[b..] {
                        t[idx] = simd.add_f64s(t[idx], simd.mul_f64s(wf, fc));
                        idx += 1;
                    }
                    t[21 + b] = simd.add_f64s(t[21 + b], wf);
                    t[28 + b] = simd.add_f64s(t[28 + b], simd.mul_f64s(wf, r));
                }
                t[27] = simd.add_f64s(t[27], wi);
                t[34] = simd.add_f64s(t[34], wr);
                t[35] = simd.add_f64s(t[35], simd.mul_f64s(wr, r));
                t[36] = simd.add_f64s(t[36], simd.mul_f64s(simd.mul_f64s(ki, r), r));
            },
            // the columns folded (scalar, in order)
            |_, c| {
                for (q, g) in out.gram.iter_mut().enumerate() {
                    *g += c.at(q);
                }
                for (q, g) in out.grad.iter_mut().enumerate() {
                    *g += c.at(28 + q);
                }
                out.cost += c.at(35);
                out.ssr += c.at(36);
            },
        );
        out
    }
}

/// Most quadrature nodes per axis of [`factored_sums`].
pub(crate) const MAX_NODES: usize = 12;

/// The coupling of the x and y nodes in [`FactoredSums`].
pub(crate) enum Coupling<'a> {
    /// `T_n[k][l] = T[k][l] s_l^n` (n = 0, 1, 2) with `T[k][l] = exp(−b s_k s_l)`: `m × m`,
    /// row-major.
    Full([&'a [f64]; 3]),
    /// For a rule symmetric about 0 (`s_{m−1−k} = −s_k`, the first `P = ⌊m/2⌋` nodes positive,
    /// a centre node 0 where `m` is odd): with `x = b s_k s_l` over the positive nodes, `C = cosh
    /// x`, `D = −sinh x` and `C s_l, D s_l, C s_l², D s_l²`, each `P × P`, row-major. Half the
    /// products of [`Coupling::Full`]; for `|x| ≤ 2` only (`C + D = e^{−x}` loses up to `e^{2|x|}`
    /// of the relative precision to cancellation).
    Symmetric([&'a [f64]; 6]),
}

/// Inputs of [`factored_sums`] (the factored quadrature of `eval::integrated_factored`): with
/// `m` nodes `s_k`, per pixel `(i, j)` the sums `S0 = g Σ_k α_k τ0_k`, `Sx = g Σ α_k s_k τ0_k`,
/// `Sxx = g Σ α_k s_k² τ0_k`, `Sy = g Σ α_k τ1_k`, `Sxy = g Σ α_k s_k τ1_k`,
/// `Syy = g Σ α_k τ2_k`, where `α_k = aq[k][j] · u[k][i]`, `β_l = bv[l][j] · p[l][i]` and
/// `τn_k = Σ_l T[k][l] s_l^n β_l`. Tables are node-major (`u[k * w + i]`, `aq[k * h + j]`);
/// `g` and the outputs are row-major `w × h`. The outputs are the pixel means of the basis
/// (`φ̄0 = S0, φ̄1 = X S0 + Sx, φ̄2 = Y S0 + Sy, φ̄3 = X² S0 + 2X Sx + Sxx`,
/// `φ̄4 = XY S0 + X Sy + Y Sx + Sxy, φ̄5 = Y² S0 + 2Y Sy + Syy`), the first column and row at
/// `X = x_first`, `Y = y_first`.
pub(crate) struct FactoredSums<'a> {
    pub nodes: &'a [f64],
    pub u: &'a [f64],
    pub p: &'a [f64],
    pub aq: &'a [f64],
    pub bv: &'a [f64],
    pub coupling: Coupling<'a>,
    pub g: &'a [f64],
    pub w: usize,
    pub h: usize,
    pub x_first: f64,
    pub y_first: f64,
    /// `φ̄0`, then `φ̄1..φ̄5`.
    pub s0: &'a mut [f64],
    pub out: [&'a mut [f64]; 5],
}

/// The per-pixel sums of [`FactoredSums`] on the given path.
pub(crate) fn factored_sums(arch: Arch, sums: FactoredSums) {
    arch.dispatch(sums)
}

impl WithSimd for FactoredSums<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        // (the node count a constant: the loops over the nodes unrolled, β in registers)
        match self.nodes.len() {
            1 => factored_rows::<S, 1>(simd, self),
            2 => factored_rows::<S, 2>(simd, self),
            3 => factored_rows::<S, 3>(simd, self),
            4 => factored_rows::<S, 4>(simd, self),
            5 => factored_rows::<S, 5>(simd, self),
            6 => factored_rows::<S, 6>(simd, self),
            7 => factored_rows::<S, 7>(simd, self),
            8 => factored_rows::<S, 8>(simd, self),
            9 => factored_rows::<S, 9>(simd, self),
            10 => factored_rows::<S, 10>(simd, self),
            11 => factored_rows::<S, 11>(simd, self),
            _ => factored_rows::<S, MAX_NODES>(simd, self),
        }
    }
}

/// The six node sums `S0, Sx, Sy, Sxx, Sxy, Syy` of one row's lanes from `β` (`M` vectors)
/// and `α_k` (by `alpha(k)`).
#[inline(always)]
fn node_sums<S: Simd, const M: usize>(
    simd: S,
    nodes: &[f64],
    coupling: &Coupling,
    be: &[S::f64s; M],
    alpha: impl Fn(usize) -> S::f64s,
) -> [S::f64s; 6] {
    let zero = simd.splat_f64s(0.0);
    let (add, mul) = (|a, b| simd.add_f64s(a, b), |a, b| simd.mul_f64s(a, b));
    let sp = |v: f64| simd.splat_f64s(v);
    let mut acc = [zero; 6];
    match coupling {
        Coupling::Full([t0, t1, t2]) => {
            let (t0, t1, t2) = (&t0[..M * M], &t1[..M * M], &t2[..M * M]);
            for k in 0..M {
                let (mut v0, mut v1, mut v2) = (zero, zero, zero);
                for (l, &b) in be.iter().enumerate() {
                    let at = k * M + l;
                    v0 = add(v0, mul(sp(t0[at]), b));
                    v1 = add(v1, mul(sp(t1[at]), b));
                    v2 = add(v2, mul(sp(t2[at]), b));
                }
                let sk = sp(nodes[k]);
                let al = alpha(k);
                let als = mul(al, sk);
                let alss = mul(als, sk);
                acc[0] = add(acc[0], mul(al, v0));
                acc[1] = add(acc[1], mul(als, v0));
                acc[2] = add(acc[2], mul(al, v1));
                acc[3] = add(acc[3], mul(alss, v0));
                acc[4] = add(acc[4], mul(als, v1));
                acc[5] = add(acc[5], mul(al, v2));
            }
        }
        Coupling::Symmetric([c, d, cs, ds, css, dss]) => {
            let half = M / 2;
            // (sliced to their constant length: the unrolled loops' indices need no checks)
            let n2 = half * half;
            let (c, d, cs) = (&c[..n2], &d[..n2], &cs[..n2]);
            let (ds, css, dss) = (&ds[..n2], &css[..n2], &dss[..n2]);
            // β± over the node pairs (l, M−1−l), and the centre's β
            let mut bp = [zero; M];
            let mut bm = [zero; M];
            for l in 0..half {
                bp[l] = add(be[l], be[M - 1 - l]);
                bm[l] = simd.sub_f64s(be[l], be[M - 1 - l]);
            }
            let bc = if M % 2 == 1 { be[half] } else { zero };
            for k in 0..half {
                let (mut a0, mut b0, mut a1, mut b1, mut a2, mut b2) =
                    (bc, zero, zero, zero, zero, zero);
                for l in 0..half {
                    let at = k * half + l;
                    a0 = add(a0, mul(sp(c[at]), bp[l]));
                    b0 = add(b0, mul(sp(d[at]), bm[l]));
                    a1 = add(a1, mul(sp(cs[at]), bm[l]));
                    b1 = add(b1, mul(sp(ds[at]), bp[l]));
                    a2 = add(a2, mul(sp(css[at]), bp[l]));
                    b2 = add(b2, mul(sp(dss[at]), bm[l]));
                }
                let (ak, ak2) = (alpha(k), alpha(M - 1 - k));
                let (ap, am) = (add(ak, ak2), simd.sub_f64s(ak, ak2));
                let sk = sp(nodes[k]);
                let e0 = add(mul(ap, a0), mul(am, b0));
                acc[0] = add(acc[0], e0);
                acc[1] = add(acc[1], mul(sk, add(mul(am, a0), mul(ap, b0))));
                acc[2] = add(acc[2], add(mul(ap, a1), mul(am, b1)));
                acc[3] = add(acc[3], mul(mul(sk, sk), e0));
                acc[4] = add(acc[4], mul(sk, add(mul(am, a1), mul(ap, b1))));
                acc[5] = add(acc[5], add(mul(ap, a2), mul(am, b2)));
            }
            if M % 2 == 1 {
                // the centre node (s = 0, T = 1 along its row): τ0 = Σ β, τ1 = Σ s β, τ2 = Σ s² β
                let (mut v0, mut v1, mut v2) = (bc, zero, zero);
                for l in 0..half {
                    let sl = nodes[l];
                    v0 = add(v0, bp[l]);
                    v1 = add(v1, mul(sp(sl), bm[l]));
                    v2 = add(v2, mul(sp(sl * sl), bp[l]));
                }
                let al = alpha(half);
                acc[0] = add(acc[0], mul(al, v0));
                acc[2] = add(acc[2], mul(al, v1));
                acc[5] = add(acc[5], mul(al, v2));
            }
        }
    }
    acc
}

#[inline(always)]
fn factored_rows<S: Simd, const M: usize>(simd: S, sums: FactoredSums) {
    let FactoredSums {
        nodes,
        u,
        p,
        aq,
        bv,
        coupling,
        g,
        w,
        h,
        x_first,
        y_first,
        s0,
        out,
    } = sums;
    let nodes = &nodes[..M];
    let [p1_out, p2_out, p3_out, p4_out, p5_out] = out;
    let lanes = S::F64_LANES;
    let (add, mul) = (|a, b| simd.add_f64s(a, b), |a, b| simd.mul_f64s(a, b));
    // the columns' X of a lane group: x_first + c0 + (0, 1, ..)
    let mut offsets = [0.0f64; MAX_LANES];
    for (l, o) in offsets.iter_mut().enumerate() {
        *o = l as f64;
    }
    let lane_x = simd.partial_load_f64s(&offsets[..lanes]);
    for c0 in (0..w).step_by(lanes) {
        let c1 = (c0 + lanes).min(w);
        let load = |a: &[f64], at: usize| load_lanes(simd, &a[at + c0..at + c1]);
        let x = add(simd.splat_f64s(x_first + c0 as f64), lane_x);
        let two_x = add(x, x);
        let xx = mul(x, x);
        // the column tables' lanes, the same for every row (loaded once per column group: at
        // the window's last columns a partial load is a call)
        let (mut pv, mut uv) = ([simd.splat_f64s(0.0); M], [simd.splat_f64s(0.0); M]);
        for l in 0..M {
            pv[l] = load(p, l * w);
            uv[l] = load(u, l * w);
        }
        for j in 0..h {
            // (plain loops, not `array::from_fn` / `map`: those are not inlined into the
            // target-feature function and run as calls)
            let mut be = [simd.splat_f64s(0.0); M];
            for (l, b) in be.iter_mut().enumerate() {
                *b = simd.mul_f64s(simd.splat_f64s(bv[l * h + j]), pv[l]);
            }
            let alpha = |k: usize| simd.mul_f64s(simd.splat_f64s(aq[k * h + j]), uv[k]);
            let acc = node_sums::<S, M>(simd, nodes, &coupling, &be, alpha);
            let gv = load(g, j * w);
            let [e, sx, sy, sxx, sxy, syy] = acc;
            let (e, sx, sy) = (mul(gv, e), mul(gv, sx), mul(gv, sy));
            let (sxx, sxy, syy) = (mul(gv, sxx), mul(gv, sxy), mul(gv, syy));
            let y = simd.splat_f64s(y_first + j as f64);
            let ph = [
                e,
                add(mul(x, e), sx),
                add(mul(y, e), sy),
                add(add(mul(xx, e), mul(two_x, sx)), sxx),
                add(add(add(mul(mul(x, y), e), mul(x, sy)), mul(y, sx)), sxy),
                add(add(mul(mul(y, y), e), mul(add(y, y), sy)), syy),
            ];
            let row = j * w + c0..j * w + c1;
            let store = |o: &mut [f64], v| store_lanes(simd, o, v);
            store(&mut s0[row.clone()], ph[0]);
            store(&mut p1_out[row.clone()], ph[1]);
            store(&mut p2_out[row.clone()], ph[2]);
            store(&mut p3_out[row.clone()], ph[3]);
            store(&mut p4_out[row.clone()], ph[4]);
            store(&mut p5_out[row], ph[5]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn random_window(rng: &mut rand::rngs::StdRng, w: usize, h: usize) -> [Vec<f64>; 4] {
        let mut v = || (0..w * h).map(|_| rng.random::<f64>()).collect::<Vec<_>>();
        let (e, d, wt) = (v(), v(), v());
        let keep = wt
            .iter()
            .map(|&x| if x < 0.1 { 0.0 } else { 1.0 })
            .collect();
        [e, d, keep, wt]
    }

    /// `exp8` against libm's `exp`: within 2 ulp (relative 4.5e-16) over the whole range of
    /// normal results (arguments spread over [−708, 709.7], dense near 0, integers and
    /// half-integers of ln 2 where the reduction switches `k`), the same bits on the dispatched
    /// and the portable path; the ends as documented.
    #[test]
    fn exp8_is_libm_exp() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let ln2 = std::f64::consts::LN_2;
        let mut xs: Vec<f64> = Vec::new();
        for _ in 0..40_000 {
            xs.push(-708.0 + 1417.7 * rng.random::<f64>());
            xs.push(40.0 * (rng.random::<f64>() - 0.5));
            xs.push(1e-3 * (rng.random::<f64>() - 0.5));
        }
        for k in -1020..1020 {
            for off in [0.0, 0.5, -0.5, 1e-12, -1e-12] {
                xs.push((k as f64 + off) * ln2);
            }
        }
        xs.extend([0.0, -0.0, 1e-300, -1e-300, 1.0, -1.0, 709.7, -707.9]);
        xs.retain(|x| (-708.0..=709.7).contains(x));
        xs.resize(xs.len().div_ceil(8) * 8, 0.5);
        let (mut worst, mut checked) = (0.0f64, 0);
        for chunk in xs.chunks_exact(8) {
            let x: [f64; 8] = chunk.try_into().unwrap();
            let got = exp8(Arch::new(), x);
            let portable = exp8(Arch::Scalar, x);
            assert_eq!(got.map(f64::to_bits), portable.map(f64::to_bits), "{x:?}");
            for (g, xi) in got.iter().zip(x) {
                let want = xi.exp();
                let rel = (g - want).abs() / want;
                worst = worst.max(rel);
                assert!(rel <= 4.5e-16, "exp({xi}) = {g}, libm {want}: {rel:e}");
                checked += 1;
            }
        }
        assert!(checked > 130_000, "{checked}");
        assert!(worst > 0.0, "{worst}");
        let ends = exp8(
            Arch::new(),
            [-800.0, -709.0, 710.0, 1e6, f64::NAN, -1e6, 709.78, -745.0],
        );
        assert_eq!(ends[..4], [0.0, 0.0, f64::INFINITY, f64::INFINITY]);
        assert!(ends[4].is_nan());
        assert_eq!(ends[5], 0.0);
        assert_eq!(ends[6], 709.78f64.exp());
        assert_eq!(ends[7], 0.0);
    }

    #[test]
    fn dispatched_kernels_equal_the_portable_path() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let fast = Arch::new();
        // a row of the coupling map's sweeps, against the plain loop
        for links in [0, 1, 3, 8] {
            let n = 11;
            let now: Vec<[f64; 8]> = (0..n)
                .map(|_| std::array::from_fn(|_| rng.random::<f64>() - 0.5))
                .collect();
            let nb: Vec<u32> = (0..links).map(|_| rng.random_range(0..n as u32)).collect();
            let m: Vec<[LinkColumn; 6]> = (0..links)
                .map(|_| {
                    std::array::from_fn(|_| std::array::from_fn(|_| rng.random::<f32>() - 0.5))
                })
                .collect();
            let own: [f64; 8] = std::array::from_fn(|_| rng.random::<f64>());
            let mut plain = own;
            for (&j, mj) in nb.iter().zip(&m) {
                for (col, &x) in mj.iter().zip(&now[j as usize]) {
                    for (vr, &c) in plain.iter_mut().zip(col) {
                        *vr -= f64::from(c) * x;
                    }
                }
            }
            for arch in [fast, Arch::Scalar] {
                let v = link_row(
                    arch,
                    LinkRow {
                        own,
                        nb: &nb,
                        m: &m,
                        now: &now,
                    },
                );
                assert_eq!(v, plain, "{links} links");
            }
        }
        for (w, h) in [(1, 1), (3, 5), (4, 4), (7, 9), (9, 9), (13, 11), (17, 3)] {
            let [e, d, keep, wt] = random_window(&mut rng, w, h);
            let mut acc = vec![f64::NAN; acc_len(w)];
            for hess in [false, true] {
                let inp = MomentsIn {
                    e: &e,
                    d: &d,
                    keep: &keep,
                    wt: &wt,
                    w,
                    h,
                    amp: 1.7,
                    bg: 0.2,
                    x_first: -(w as f64) / 2.0 + 0.3,
                    y_first: -(h as f64) / 2.0 - 0.1,
                    hess,
                };
                let a = column_sums(fast, &inp, &mut acc);
                let b = column_sums(Arch::Scalar, &inp, &mut acc);
                assert_eq!(a, b, "{w}x{h}");
                // against the direct sums
                let mut m2_11 = 0.0;
                let mut ssr = 0.0;
                let mut rh = [[0.0; 5]; 5];
                for j in 0..h {
                    for i in 0..w {
                        let k = j * w + i;
                        let (x, y) = (inp.x_first + i as f64, inp.y_first + j as f64);
                        let r = d[k] - (inp.bg + inp.amp * e[k]);
                        m2_11 += wt[k] * e[k] * e[k] * x * y;
                        ssr += keep[k] * r * r;
                        for (m, row) in rh.iter_mut().enumerate() {
                            for (n, v) in row.iter_mut().enumerate() {
                                if (3..=4).contains(&(m + n)) {
                                    *v += wt[k] * r * e[k] * x.powi(m as i32) * y.powi(n as i32);
                                }
                            }
                        }
                    }
                }
                assert!((a.m2[1][1] - m2_11).abs() <= 1e-12 * (1.0 + m2_11.abs()));
                assert!((a.ssr - ssr).abs() <= 1e-12 * (1.0 + ssr));
                for m in 0..5 {
                    for n in 0..5 {
                        let want = if hess { rh[m][n] } else { 0.0 };
                        let got = a.rh[m][n];
                        assert!(
                            (got - want).abs() <= 1e-12 * (1.0 + want.abs()),
                            "{w}x{h} hess {hess} rh{m}{n}: {got} vs {want}"
                        );
                    }
                }
            }

            let q: Vec<f64> = (0..w).map(|_| rng.random::<f64>() + 0.5).collect();
            let v0: Vec<f64> = (0..w).map(|_| rng.random::<f64>()).collect();
            let run = |arch: Arch| {
                let (mut out, mut v) = (vec![0.0; w * h], v0.clone());
                exp_rows(
                    arch,
                    ExpRows {
                        out: &mut out,
                        v: &mut v,
                        q: &q,
                        w,
                        gy: 0.9,
                        s: 0.8,
                        ec: 0.7,
                    },
                );
                out
            };
            assert_eq!(run(fast), run(Arch::Scalar), "{w}x{h}");

            // the pass over a per-pixel basis
            let phi: Vec<Vec<f64>> = (0..6)
                .map(|_| (0..w * h).map(|_| rng.random::<f64>() - 0.3).collect())
                .collect();
            let inp = BasisIn {
                phi: [&phi[0], &phi[1], &phi[2], &phi[3], &phi[4], &phi[5]],
                d: &d,
                keep: &keep,
                wt: &wt,
                w,
                h,
                amp: 1.3,
                bg: -0.4,
            };
            let a = column_sums(fast, &inp, &mut acc);
            assert_eq!(a, column_sums(Arch::Scalar, &inp, &mut acc), "{w}x{h}");
            let (mut g34, mut g5c, mut grad2, mut cost) = (0.0, 0.0, 0.0, 0.0);
            for k in 0..w * h {
                let r = d[k] - (inp.bg + inp.amp * phi[0][k]);
                g34 += wt[k] * phi[3][k] * phi[4][k];
                g5c += wt[k] * phi[5][k];
                grad2 += wt[k] * r * phi[2][k];
                cost += wt[k] * r * r;
            }
            // (upper triangle in row order: (3, 4) is entry 6 + 5 + 4 + 1 = 16; Σ w φ5 is 26)
            for (got, want) in [(a.gram[16], g34), (a.gram[26], g5c), (a.grad[2], grad2)] {
                assert!(
                    (got - want).abs() <= 1e-12 * (1.0 + want.abs()),
                    "{got} {want}"
                );
            }
            assert!((a.cost - cost).abs() <= 1e-12 * (1.0 + cost));

            // a look's sums (signal-dependent weights), against the direct ones
            let inp = LookIn {
                e: &e,
                d: &d,
                keep: &keep,
                w,
                h,
                amp: 1.7,
                bg: 0.2,
                x_first: -(w as f64) / 2.0 + 0.3,
                y_first: -(h as f64) / 2.0 - 0.1,
                read: 0.05,
                gain: 0.3,
                offset: 0.9,
            };
            let a = column_sums(fast, &inp, &mut acc);
            assert_eq!(a, column_sums(Arch::Scalar, &inp, &mut acc), "{w}x{h}");
            let mut want = LookSums::default();
            for j in 0..h {
                for i in 0..w {
                    let k = j * w + i;
                    if keep[k] == 0.0 {
                        continue;
                    }
                    let (x, y) = (inp.x_first + i as f64, inp.y_first + j as f64);
                    let mu = inp.bg + inp.amp * e[k];
                    let r = d[k] - mu;
                    let var = (inp.read + inp.gain * (mu - inp.offset).max(0.0)).max(1e-12);
                    let (wr, basis) = (r / var, [1.0, x, y, x * x, x * y, y * y]);
                    for (g, b) in want.g.iter_mut().zip(basis) {
                        *g += wr * e[k] * b;
                    }
                    want.g[6] += wr;
                    want.chi2 += wr * r;
                    want.ssr += r * r;
                }
            }
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * (1.0 + b.abs());
            assert!(
                a.g.iter().zip(&want.g).all(|(&a, &b)| close(a, b))
                    && close(a.chi2, want.chi2)
                    && close(a.ssr, want.ssr),
                "{w}x{h}: {a:?} against {want:?}"
            );

            // the factored quadrature's sums, for 1 to MAX_NODES nodes: both couplings on both
            // paths, against each other and against the definition
            for m in [1, 2, 3, 5, 8, 9, MAX_NODES] {
                let mut v = |len: usize| (0..len).map(|_| rng.random::<f64>()).collect::<Vec<_>>();
                let (u, p, aq, bv, g) = (v(m * w), v(m * w), v(m * h), v(m * h), v(w * h));
                // a rule symmetric about 0, positive nodes first
                let mut nodes = vec![0.0; m];
                for k in 0..m / 2 {
                    nodes[k] = 0.5 - 0.1 * k as f64 - 0.03 * rng.random::<f64>();
                    nodes[m - 1 - k] = -nodes[k];
                }
                let b = 3.0 * rng.random::<f64>() - 1.5;
                let t: Vec<Vec<f64>> = (0..3)
                    .map(|n| {
                        (0..m * m)
                            .map(|at| {
                                let (k, l) = (at / m, at % m);
                                (-b * nodes[k] * nodes[l]).exp() * nodes[l].powi(n)
                            })
                            .collect()
                    })
                    .collect();
                let half = m / 2;
                let pairs: Vec<Vec<f64>> = (0..6)
                    .map(|q| {
                        (0..half * half)
                            .map(|at| {
                                let (k, l) = (at / half, at % half);
                                let x = b * nodes[k] * nodes[l];
                                let cd = if q % 2 == 0 { x.cosh() } else { -x.sinh() };
                                cd * nodes[l].powi(q / 2)
                            })
                            .collect()
                    })
                    .collect();
                let (x_first, y_first) = (-3.2, 1.7);
                let run = |arch: Arch, symmetric: bool| {
                    let mut o: Vec<Vec<f64>> = vec![vec![0.0; w * h]; 6];
                    let (s0, rest) = o.split_first_mut().unwrap();
                    let [o1, o2, o3, o4, o5] = rest else {
                        unreachable!()
                    };
                    let coupling = if symmetric {
                        Coupling::Symmetric(std::array::from_fn(|q| &pairs[q][..]))
                    } else {
                        Coupling::Full([&t[0], &t[1], &t[2]])
                    };
                    factored_sums(
                        arch,
                        FactoredSums {
                            nodes: &nodes,
                            u: &u,
                            p: &p,
                            aq: &aq,
                            bv: &bv,
                            coupling,
                            g: &g,
                            w,
                            h,
                            x_first,
                            y_first,
                            s0,
                            out: [o1, o2, o3, o4, o5],
                        },
                    );
                    o
                };
                let full = run(fast, false);
                assert_eq!(full, run(Arch::Scalar, false), "{w}x{h}, {m} nodes");
                // φ̄4 = XY S0 + X Sy + Y Sx + Sxy at the last pixel against the definition
                let (i, j) = (w - 1, h - 1);
                let (x, y) = (x_first + i as f64, y_first + j as f64);
                let mut sum = [0.0; 4];
                for k in 0..m {
                    for l in 0..m {
                        let al = aq[k * h + j] * u[k * w + i];
                        let be = bv[l * h + j] * p[l * w + i];
                        let e = al * t[0][k * m + l] * be * g[j * w + i];
                        sum[0] += e;
                        sum[1] += e * nodes[k];
                        sum[2] += e * nodes[l];
                        sum[3] += e * nodes[k] * nodes[l];
                    }
                }
                let want = x * y * sum[0] + x * sum[2] + y * sum[1] + sum[3];
                let got = full[4][j * w + i];
                assert!(
                    (got - want).abs() <= 1e-12 * (1.0 + want.abs()),
                    "{got} {want}"
                );
                if m > 1 {
                    let paired = run(fast, true);
                    assert_eq!(paired, run(Arch::Scalar, true), "{w}x{h}, {m} nodes paired");
                    let scale = full[0].iter().fold(0.0f64, |a, v| a.max(v.abs()));
                    for (a, b) in full.iter().flatten().zip(paired.iter().flatten()) {
                        assert!((a - b).abs() <= 1e-12 * (1.0 + scale), "{a} {b}, {m} nodes");
                    }
                }
            }
        }
    }
}
