//! A converged fitted-dot record for the matching tests and benchmarks.

use bostrack_core::{DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex};

/// A converged circular dot (σ 1.5 px, amplitude 1000, background 100) at `p` with grid index
/// `index` and bound 0.01 px.
pub fn dot(index: GridIndex, p: [f64; 2]) -> DotFit {
    DotFit {
        index,
        params: Gaussian2D::circular(p[0], p[1], 1000.0, 1.5, 100.0),
        crlb_x: 0.01,
        crlb_y: 0.01,
        rms: 1.0,
        iterations: 4,
        status: FitStatus::Converged,
        flags: DotFlags::NONE,
    }
}
