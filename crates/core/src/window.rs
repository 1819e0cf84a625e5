use crate::{DotFlags, GridIndex};
use serde::{Deserialize, Serialize};

/// A rectangle of pixels: columns `x .. x + width`, rows `y .. y + height` (pixel indices; may
/// start outside an image, e.g. for synthetic windows centred near an edge).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Window {
    pub x: i64,
    pub y: i64,
    pub width: usize,
    pub height: usize,
}

impl Window {
    pub const fn new(x: i64, y: i64, width: usize, height: usize) -> Self {
        Window {
            x,
            y,
            width,
            height,
        }
    }
    /// The (2·half+1)² window centred on the pixel nearest to `(cx, cy)`.
    pub fn centred(cx: f64, cy: f64, half: usize) -> Self {
        let side = 2 * half + 1;
        Window::new(
            cx.round() as i64 - half as i64,
            cy.round() as i64 - half as i64,
            side,
            side,
        )
    }
    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width * self.height
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Whether the point lies inside the window's pixel area (pixel centre ± 0.5).
    pub fn contains_point(&self, px: f64, py: f64) -> bool {
        px >= self.x as f64 - 0.5
            && px <= (self.x + self.width as i64) as f64 - 0.5
            && py >= self.y as f64 - 0.5
            && py <= (self.y + self.height as i64) as f64 - 0.5
    }
    /// The part of the window inside a `width` x `height` image; `None` if nothing is left.
    pub fn clip(&self, width: usize, height: usize) -> Option<Window> {
        let x0 = self.x.max(0);
        let y0 = self.y.max(0);
        let x1 = (self.x + self.width as i64).min(width as i64);
        let y1 = (self.y + self.height as i64).min(height as i64);
        (x1 > x0 && y1 > y0).then(|| Window::new(x0, y0, (x1 - x0) as usize, (y1 - y0) as usize))
    }
}

/// One lattice site as found by detection: what the fit stage needs to fit that dot.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Seed {
    pub index: GridIndex,
    /// Position predicted by the lattice model (px).
    pub predicted: [f64; 2],
    /// Rough detected centre (e.g. intensity-weighted centroid); equals `predicted` when the
    /// dot was not found (then `flags` has MISSING or FAINT).
    pub centre: [f64; 2],
    /// Fit window (already clipped to the image).
    pub window: Window,
    pub flags: DotFlags,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clip_and_contains() {
        let w = Window::centred(1.2, 10.0, 4);
        assert_eq!(w, Window::new(-3, 6, 9, 9));
        assert_eq!(w.clip(100, 100), Some(Window::new(0, 6, 6, 9)));
        assert!(w.contains_point(-3.4, 6.0) && !w.contains_point(-3.6, 6.0));
        assert_eq!(Window::new(200, 0, 3, 3).clip(100, 100), None);
    }
}
