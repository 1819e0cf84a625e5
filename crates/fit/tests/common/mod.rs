//! Shared helpers of the integration tests: synthetic windows with known noise.
#![allow(dead_code)]

use bostrack_core::{DotFlags, Gaussian2D, GridIndex, NoiseModel, Seed, Window};
use bostrack_fit::WindowSamples;
use bostrack_model::{Sampling, add_dot, render};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;

pub fn rng(seed: u64) -> StdRng {
    StdRng::seed_from_u64(seed)
}

/// The model over `window` plus Gaussian noise of the model's variance.
pub fn noisy(
    g: &Gaussian2D,
    window: Window,
    sampling: Sampling,
    noise: &NoiseModel,
    rng: &mut StdRng,
) -> Vec<f64> {
    let mut v = render(g, window, sampling);
    for x in v.iter_mut() {
        let z: f64 = rng.sample(StandardNormal);
        *x += noise.sigma(*x) * z;
    }
    v
}

pub fn samples(window: Window, values: &[f64]) -> WindowSamples<'_> {
    WindowSamples {
        window,
        values,
        keep: None,
        saturation: None,
    }
}

/// A dot at a random sub-pixel position near the centre of a (2 half + 1)² window at the origin.
pub fn random_dot(
    rng: &mut StdRng,
    half: usize,
    amplitude: f64,
    sx: f64,
    sy: f64,
    rho: f64,
    bg: f64,
) -> (Gaussian2D, Window) {
    let c = half as f64;
    let g = Gaussian2D {
        x0: c + rng.random_range(-0.5..0.5),
        y0: c + rng.random_range(-0.5..0.5),
        amplitude,
        sigma_x: sx,
        sigma_y: sy,
        rho,
        background: bg,
    };
    (g, Window::new(0, 0, 2 * half + 1, 2 * half + 1))
}

/// One seed per dot, as detection delivers them: the centre rounded to a pixel, a 9 × 9 window,
/// grid index (k, 0).
pub fn seeds_of(dots: &[Gaussian2D]) -> Vec<Seed> {
    dots.iter()
        .enumerate()
        .map(|(k, g)| {
            let c = [g.x0.round(), g.y0.round()];
            Seed {
                index: GridIndex::new(k as i32, 0),
                predicted: c,
                centre: c,
                window: Window::centred(c[0], c[1], 4),
                flags: DotFlags::NONE,
            }
        })
        .collect()
}

/// A square lattice (`spacing`, rotated by `angle_deg`) of equal dots over a `size²` image,
/// pixel-integrated, without noise; only dots at least 6 px inside the image.
pub fn lattice(
    spacing: f64,
    sigma: f64,
    angle_deg: f64,
    size: usize,
) -> (Vec<f64>, Vec<Gaussian2D>) {
    lattice_shaped(spacing, [sigma, sigma, 0.0], angle_deg, size)
}

/// [`lattice`] of dots of shape `[σx, σy, ρ]`.
#[allow(dead_code)]
pub fn lattice_shaped(
    spacing: f64,
    shape: [f64; 3],
    angle_deg: f64,
    size: usize,
) -> (Vec<f64>, Vec<Gaussian2D>) {
    let (s, c) = angle_deg.to_radians().sin_cos();
    let mut dots = Vec::new();
    let n = (size as f64 / spacing) as i32 + 2;
    let centre = size as f64 / 2.0 + 0.3;
    for i in -n..=n {
        for j in -n..=n {
            let (u, v) = (i as f64 * spacing, j as f64 * spacing);
            let (x, y) = (centre + c * u - s * v, centre + s * u + c * v);
            if x < 6.0 || y < 6.0 || x > size as f64 - 7.0 || y > size as f64 - 7.0 {
                continue;
            }
            dots.push(Gaussian2D {
                x0: x,
                y0: y,
                amplitude: 1000.0,
                sigma_x: shape[0],
                sigma_y: shape[1],
                rho: shape[2],
                background: 0.0,
            });
        }
    }
    let mut v = vec![100.0; size * size];
    for g in &dots {
        if g.rho == 0.0 {
            add_dot(
                g,
                Window::new(0, 0, size, size),
                Sampling::Integrated,
                &mut v,
            );
            continue;
        }
        // over the dot's box of ±10 σ (an elliptical integrated dot over the whole image costs
        // a quadrature per pixel)
        let r = 10.0 * g.sigma_x.max(g.sigma_y) + 2.0;
        let (x0, y0) = ((g.x0 - r).floor().max(0.0), (g.y0 - r).floor().max(0.0));
        let (x1, y1) = (
            (g.x0 + r).ceil().min(size as f64),
            (g.y0 + r).ceil().min(size as f64),
        );
        let (w, h) = ((x1 - x0) as usize, (y1 - y0) as usize);
        let mut local = vec![0.0; w * h];
        let win = Window::new(x0 as i64, y0 as i64, w, h);
        add_dot(g, win, Sampling::Integrated, &mut local);
        for r in 0..h {
            let at = (y0 as usize + r) * size + x0 as usize;
            for (o, l) in v[at..at + w].iter_mut().zip(&local[r * w..(r + 1) * w]) {
                *o += l;
            }
        }
    }
    (v, dots)
}

/// A square `size × size` image of `clean` plus Gaussian noise of `noise`'s variance (seed
/// `seed`).
pub fn noisy_image(
    clean: &[f64],
    size: usize,
    noise: &NoiseModel,
    seed: u64,
) -> bostrack_core::Image {
    let mut rng = rng(seed);
    let v: Vec<f64> = clean
        .iter()
        .map(|&m| m + noise.sigma(m) * rng.sample::<f64, _>(StandardNormal))
        .collect();
    bostrack_core::Image::new(size, size, v, bostrack_core::ImageMeta::default()).unwrap()
}

/// The real sample's reference image, mask and 10-image no-flow stack; `None` (with a message)
/// when the data are missing, a panic when CI=true (`bostrack_io::bos_sample_dir`).
pub fn real_sample() -> Option<(
    bostrack_core::Image,
    bostrack_core::Mask,
    Vec<bostrack_core::Image>,
)> {
    use bostrack_io::read_image;
    let dir = bostrack_io::bos_sample_dir()?;
    let img = read_image(&dir.join("pair/reference.tif")).unwrap();
    let mask =
        bostrack_io::read_mask_for(&dir.join("mask.tif"), img.width(), img.height()).unwrap();
    let stack = (1..=10)
        .map(|k| read_image(&dir.join(format!("ref-stack/im_{k:04}.tif"))).unwrap())
        .collect();
    Some((img, mask, stack))
}
