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
use std::sync::OnceLock;

/// The instruction set the kernels run on: the best the CPU has unless `BOSTRACK_SIMD=portable`.
pub(crate) fn arch() -> Arch {
    static ARCH: OnceLock<Arch> = OnceLock::new();
    *ARCH.get_or_init(|| {
        if std::env::var("BOSTRACK_SIMD").is_ok_and(|v| v == "portable") {
            Arch::Scalar
        } else {
            Arch::new()
        }
    })
}

/// Widest lane count of any path (sizes the column accumulators).
pub(crate) const MAX_LANES: usize = 8;
/// Column accumulators per window column: `Σ_rows w E² Yⁿ` (n = 0..4), `Σ w E Yⁿ` (0..2),
/// `Σ w r E Yⁿ` (0..2), `Σ w`, `Σ w r`, `Σ w r²`, `Σ keep r²`.
pub(crate) const N_ACC: usize = 15;

/// The sums of one point-sampled pass (before the constant-noise scale): `m2[m][n] = Σ w E² XᵐYⁿ`
/// (m + n ≤ 4), `m1[m][n] = Σ w E XᵐYⁿ`, `r1[m][n] = Σ w r E XᵐYⁿ` (m + n ≤ 2), `m0 = Σ w`,
/// `r0 = Σ w r`, `cost = Σ w r²`, `ssr = Σ keep r²`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Moments {
    pub m2: [[f64; 5]; 5],
    pub m1: [[f64; 3]; 3],
    pub r1: [[f64; 3]; 3],
    pub m0: f64,
    pub r0: f64,
    pub cost: f64,
    pub ssr: f64,
}

/// Inputs of [`point_moments`]: row-major `w × h` arrays of `E`, the data, `keep` and the
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
}

/// The moments of a pass on the given path; `acc` is scratch of at least
/// [`acc_len`]`(w)` values.
pub(crate) fn point_moments(arch: Arch, inp: &MomentsIn, acc: &mut [f64]) -> Moments {
    arch.dispatch(MomentsKernel { inp, acc })
}

/// Scratch length [`point_moments`] needs for a window `w` columns wide.
pub(crate) fn acc_len(w: usize) -> usize {
    w.div_ceil(MAX_LANES) * MAX_LANES * N_ACC
}

struct MomentsKernel<'a, 'b> {
    inp: &'a MomentsIn<'b>,
    acc: &'a mut [f64],
}

impl WithSimd for MomentsKernel<'_, '_> {
    type Output = Moments;

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> Moments {
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
        } = *self.inp;
        let lanes = S::F64_LANES;
        let nch = w.div_ceil(lanes);
        let (vamp, vbg) = (simd.splat_f64s(amp), simd.splat_f64s(bg));
        // column group after column group, every row in order, the sums in registers
        for k in 0..nch {
            let c0 = k * lanes;
            let full = c0 + lanes <= w;
            let load = |a: &[f64], j: usize| {
                let s = &a[j * w + c0..j * w + (c0 + lanes).min(w)];
                if full {
                    S::as_simd_f64s(s).0[0]
                } else {
                    simd.partial_load_f64s(s)
                }
            };
            let zero = simd.splat_f64s(0.0);
            let mut t = [zero; N_ACC];
            for j in 0..h {
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
            }
            let out = &mut self.acc[k * N_ACC * lanes..(k + 1) * N_ACC * lanes];
            let (out, _) = S::as_mut_simd_f64s(out);
            out.copy_from_slice(&t);
        }
        // fold the columns with their X powers (scalar, columns in order)
        let mut m = Moments::default();
        for (k, a) in self.acc[..nch * N_ACC * lanes]
            .chunks_exact(N_ACC * lanes)
            .enumerate()
        {
            for l in 0..lanes.min(w - k * lanes) {
                let c = |q: usize| a[q * lanes + l];
                let x = x_first + (k * lanes + l) as f64;
                let x2 = x * x;
                let (x3, x4) = (x2 * x, x2 * x2);
                let (c0, c1, c2, c3, c4) = (c(0), c(1), c(2), c(3), c(4));
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
                let (d0, d1, d2) = (c(5), c(6), c(7));
                let (r0, r1, r2) = (c(8), c(9), c(10));
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
                m.m0 += c(11);
                m.r0 += c(12);
                m.cost += c(13);
                m.ssr += c(14);
            }
        }
        m
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

    #[test]
    fn dispatched_kernels_equal_the_portable_path() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let fast = Arch::new();
        for (w, h) in [(1, 1), (3, 5), (4, 4), (7, 9), (9, 9), (13, 11), (17, 3)] {
            let [e, d, keep, wt] = random_window(&mut rng, w, h);
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
            };
            let mut acc = vec![f64::NAN; acc_len(w)];
            let a = point_moments(fast, &inp, &mut acc);
            let b = point_moments(Arch::Scalar, &inp, &mut acc);
            assert_eq!(a, b, "{w}x{h}");
            // against the direct sums
            let mut m2_11 = 0.0;
            let mut ssr = 0.0;
            for j in 0..h {
                for i in 0..w {
                    let k = j * w + i;
                    let (x, y) = (inp.x_first + i as f64, inp.y_first + j as f64);
                    let r = d[k] - (inp.bg + inp.amp * e[k]);
                    m2_11 += wt[k] * e[k] * e[k] * x * y;
                    ssr += keep[k] * r * r;
                }
            }
            assert!((a.m2[1][1] - m2_11).abs() <= 1e-12 * (1.0 + m2_11.abs()));
            assert!((a.ssr - ssr).abs() <= 1e-12 * (1.0 + ssr));

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
        }
    }
}
