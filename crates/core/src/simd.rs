//! The instruction set that the SIMD paths of the stage crates run on, chosen once at run time.

use std::sync::OnceLock;

/// The best instruction set the CPU has (`pulp`: AVX2 with FMA on x86-64 CPUs that have it),
/// unless `BOSTRACK_SIMD=portable` (read once) asks for the portable path, for benchmarks and
/// tests against it. Every dispatched loop of the stage crates does the same operations in
/// the same order on every path (no fused multiply-add, no reassociation): the same bits.
#[inline]
pub fn simd_arch() -> pulp::Arch {
    static ARCH: OnceLock<pulp::Arch> = OnceLock::new();
    *ARCH.get_or_init(|| {
        if std::env::var("BOSTRACK_SIMD").is_ok_and(|v| v == "portable") {
            pulp::Arch::Scalar
        } else {
            pulp::Arch::new()
        }
    })
}

/// Runs `f` through `pulp`'s dispatch on `arch`: the same scalar code, which the compiler
/// vectorises for that instruction set where `f` and what it calls are inlined into it (mark
/// them `#[inline(always)]`). Scalar floating-point code keeps its bits: Rust neither fuses
/// a product and a sum nor reassociates (no fast-math), so only the vector width changes.
#[inline(always)]
pub fn dispatch<R>(arch: pulp::Arch, f: impl FnOnce() -> R) -> R {
    struct Run<F>(F);
    impl<R, F: FnOnce() -> R> pulp::WithSimd for Run<F> {
        type Output = R;
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) -> R {
            (self.0)()
        }
    }
    arch.dispatch(Run(f))
}
