//! Shared helpers of the integration tests: synthetic scenes and their comparison with truth.
#![allow(dead_code)]

use bostrack_core::{DotFlags, GridIndex, Mask, Seed, Window};
use bostrack_detect::Detection;
use bostrack_synth::{
    BackgroundConfig, DefectConfig, DotConfig, LatticeConfig, LatticeKind, MaskConfig, NoiseConfig,
    Scene, SceneConfig, TruthConfig, TruthDot,
};
use std::collections::HashMap;

/// One synthetic case.
#[derive(Clone, Debug)]
pub struct Case {
    pub spacing: f64,
    /// Dot diameter 4σ, px.
    pub diameter: f64,
    pub angle_deg: f64,
    /// Read noise as a fraction of the dot's peak pixel (the pixel-integrated value of a dot
    /// centred on a pixel, above the background).
    pub noise: f64,
    pub hexagonal: bool,
    pub mask: bool,
    pub seed: u64,
}

/// Scene of a case: 256x256, amplitude 1000 on a background of 100, vignetting 0.4, 5 %
/// missing dots, 1 % defects, a rectangular or circular mask, 16-bit samples.
pub fn scene_config(c: &Case) -> SceneConfig {
    let kind = if c.hexagonal {
        LatticeKind::Hexagonal
    } else {
        LatticeKind::Square
    };
    let mask = c.mask.then(|| {
        if c.seed.is_multiple_of(2) {
            MaskConfig::Rect {
                x: [20.0, 230.0],
                y: [12.0, 240.0],
            }
        } else {
            MaskConfig::Circle {
                centre: [130.0, 125.0],
                radius: 115.0,
            }
        }
    });
    SceneConfig {
        width: 256,
        height: 256,
        bits: 16,
        seed: c.seed,
        lattice: LatticeConfig {
            kind,
            spacing: c.spacing,
            angle_deg: c.angle_deg,
            // A non-centred origin so that the lattice is not symmetric about the image centre.
            origin: Some([127.5 + 0.31 * c.spacing, 127.5 - 0.17 * c.spacing]),
        },
        dots: DotConfig {
            sigma_x: c.diameter / 4.0,
            sigma_y: c.diameter / 4.0,
            amplitude: 1000.0,
            amplitude_jitter: 0.05,
            ..Default::default()
        },
        background: BackgroundConfig {
            level: 100.0,
            vignetting: 0.4,
            ..Default::default()
        },
        defects: DefectConfig {
            missing: 0.05,
            defective: 0.01,
            ..Default::default()
        },
        noise: NoiseConfig {
            read_noise: c.noise * 1000.0 * peak_pixel_fraction(c.diameter / 4.0),
            gain: 0.0,
            offset: 0.0,
        },
        truth: TruthConfig {
            crlb: false,
            ..Default::default()
        },
        mask,
        ..Default::default()
    }
}

/// Pixel-integrated value of a unit-amplitude Gaussian of sigma `s` centred on a pixel
/// (midpoint rule on a 40x40 grid over the pixel).
pub fn peak_pixel_fraction(s: f64) -> f64 {
    let n = 40;
    let mut acc = 0.0;
    for a in 0..n {
        for b in 0..n {
            let x = (a as f64 + 0.5) / n as f64 - 0.5;
            let y = (b as f64 + 0.5) / n as f64 - 0.5;
            acc += (-(x * x + y * y) / (2.0 * s * s)).exp();
        }
    }
    acc / (n * n) as f64
}

/// Whether the truth dot lies fully inside the kept region: its ±2σ box (at least ±1 px) is on
/// the image and every pixel of it is kept.
pub fn fully_inside(t: &TruthDot, w: usize, h: usize, mask: Option<&Mask>) -> bool {
    let g = &t.params;
    let half = (2.0 * g.sigma_x.max(g.sigma_y)).ceil().max(1.0) as usize;
    let win = Window::centred(g.x0, g.y0, half);
    if win.clip(w, h) != Some(win) {
        return false;
    }
    let Some(m) = mask else { return true };
    (win.y..win.y + win.height as i64)
        .all(|y| (win.x..win.x + win.width as i64).all(|x| m.keeps(x as usize, y as usize)))
}

/// Outcome of comparing a detection with the truth.
#[derive(Debug, Default)]
pub struct Score {
    /// Normal truth dots (not MISSING, no defect) fully inside the kept region.
    pub expected: usize,
    /// ... of which found (not MISSING) with the right grid index and centre within `tol` px.
    pub found: usize,
    /// Defective truth dots fully inside the kept region, and how many of them were found.
    pub defects: usize,
    pub defects_found: usize,
    /// Seeds claimed found (not MISSING) with no truth dot of that index within `tol` (a
    /// truth-MISSING site, a wrong index or a wrong place).
    pub spurious: usize,
    /// Index offset detection - truth.
    pub offset: (i32, i32),
    /// Centre errors of the found normal dots (px): median and largest.
    pub median_error: f64,
    pub worst_error: f64,
    pub problems: Vec<String>,
}

fn is_found(s: &Seed) -> bool {
    !s.flags.contains(DotFlags::MISSING)
}

/// Compare with the truth. The index offset is pinned by the truth dot nearest to the seed
/// (0, 0)'s predicted position (the detector anchors (0, 0) at the site nearest the image
/// centre, synth at its origin), then every index must agree with that single offset.
pub fn score(det: &Detection, scene: &Scene, tol: f64) -> Score {
    let (w, h) = (scene.image.width(), scene.image.height());
    let p0 = det.predict(0.0, 0.0);
    let t0 = scene
        .truth
        .iter()
        .min_by(|a, b| {
            let da = (a.params.x0 - p0[0]).hypot(a.params.y0 - p0[1]);
            let db = (b.params.x0 - p0[0]).hypot(b.params.y0 - p0[1]);
            da.total_cmp(&db)
        })
        .unwrap();
    let offset = (-t0.index.i, -t0.index.j);
    let truth: HashMap<GridIndex, &TruthDot> = scene
        .truth
        .iter()
        .map(|t| {
            (
                GridIndex::new(t.index.i + offset.0, t.index.j + offset.1),
                t,
            )
        })
        .collect();
    let seeds: HashMap<GridIndex, &Seed> = det.seeds.iter().map(|s| (s.index, s)).collect();
    let mut sc = Score {
        offset,
        ..Default::default()
    };
    let mut errors = Vec::new();
    for (idx, t) in &truth {
        if t.flags.contains(DotFlags::MISSING) || !fully_inside(t, w, h, scene.mask.as_ref()) {
            continue;
        }
        let defect = t.defect.is_some();
        if defect {
            sc.defects += 1;
        } else {
            sc.expected += 1;
        }
        match seeds.get(idx) {
            Some(s) if is_found(s) => {
                let e = (s.centre[0] - t.params.x0).hypot(s.centre[1] - t.params.y0);
                if defect {
                    sc.defects_found += 1;
                } else if e <= tol {
                    sc.found += 1;
                    errors.push(e);
                } else {
                    sc.problems
                        .push(format!("{idx:?}: centre off by {e:.2} px"));
                }
            }
            Some(_) if defect => {}
            Some(s) => sc.problems.push(format!(
                "{idx:?}: flagged {} at ({:.1}, {:.1}), amplitude {:.0}",
                s.flags, t.params.x0, t.params.y0, t.params.amplitude
            )),
            None => sc.problems.push(format!(
                "{idx:?}: not reported ({:.1}, {:.1})",
                t.params.x0, t.params.y0
            )),
        }
    }
    for s in det.seeds.iter().filter(|s| is_found(s)) {
        let ok = truth.get(&s.index).is_some_and(|t| {
            !t.flags.contains(DotFlags::MISSING)
                && (s.centre[0] - t.params.x0).hypot(s.centre[1] - t.params.y0) <= tol
        });
        if !ok {
            sc.spurious += 1;
            sc.problems.push(format!(
                "spurious seed {:?} at ({:.1}, {:.1}) flags {}",
                s.index, s.centre[0], s.centre[1], s.flags
            ));
        }
    }
    errors.sort_by(f64::total_cmp);
    if !errors.is_empty() {
        sc.median_error = errors[errors.len() / 2];
        sc.worst_error = errors[errors.len() - 1];
    }
    sc
}
