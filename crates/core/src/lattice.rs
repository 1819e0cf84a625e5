use crate::GridIndex;
use serde::{Deserialize, Serialize};

/// An affine dot lattice: site `(i, j)` is at `origin + i·a + j·b` (px).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Lattice {
    pub origin: [f64; 2],
    pub a: [f64; 2],
    pub b: [f64; 2],
}

impl Lattice {
    /// A square lattice of the given spacing rotated by `angle` (radians, counter-clockwise on
    /// screen is negative because y points down: a = spacing·(cos θ, sin θ), b = spacing·(-sin θ, cos θ)).
    pub fn square(origin: [f64; 2], spacing: f64, angle: f64) -> Self {
        let (s, c) = angle.sin_cos();
        Lattice {
            origin,
            a: [spacing * c, spacing * s],
            b: [-spacing * s, spacing * c],
        }
    }
    /// A hexagonal lattice: b at 60° from a.
    pub fn hexagonal(origin: [f64; 2], spacing: f64, angle: f64) -> Self {
        let (s, c) = angle.sin_cos();
        let (s2, c2) = (angle + std::f64::consts::FRAC_PI_3).sin_cos();
        Lattice {
            origin,
            a: [spacing * c, spacing * s],
            b: [spacing * c2, spacing * s2],
        }
    }
    /// Position of site `idx`.
    pub fn position(&self, idx: GridIndex) -> [f64; 2] {
        let (i, j) = (idx.i as f64, idx.j as f64);
        [
            self.origin[0] + i * self.a[0] + j * self.b[0],
            self.origin[1] + i * self.a[1] + j * self.b[1],
        ]
    }
    /// Fractional lattice coordinates (i, j) of a point; `None` if the basis is degenerate.
    pub fn fractional(&self, p: [f64; 2]) -> Option<[f64; 2]> {
        let det = self.a[0] * self.b[1] - self.a[1] * self.b[0];
        if det.abs() < 1e-12 {
            return None;
        }
        let (dx, dy) = (p[0] - self.origin[0], p[1] - self.origin[1]);
        Some([
            (dx * self.b[1] - dy * self.b[0]) / det,
            (self.a[0] * dy - self.a[1] * dx) / det,
        ])
    }
    /// Nearest site to a point.
    pub fn nearest(&self, p: [f64; 2]) -> Option<GridIndex> {
        self.fractional(p)
            .map(|f| GridIndex::new(f[0].round() as i32, f[1].round() as i32))
    }
    /// Mean spacing |a|, |b|.
    pub fn spacing(&self) -> f64 {
        0.5 * (self.a[0].hypot(self.a[1]) + self.b[0].hypot(self.b[1]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fractional_inverts_position() {
        let l = Lattice::square([3.5, -2.0], 8.0, 0.3);
        let idx = GridIndex::new(7, -4);
        let p = l.position(idx);
        let f = l.fractional(p).unwrap();
        assert!((f[0] - 7.0).abs() < 1e-12 && (f[1] + 4.0).abs() < 1e-12);
        assert_eq!(l.nearest([p[0] + 1.0, p[1] - 1.5]), Some(idx));
    }
}
