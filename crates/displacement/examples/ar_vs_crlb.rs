//! Does the amplification ratio predict the ratio of the exact per-dot Cramér-Rao bounds
//! (gradient dot / reference dot, the same read noise in both images)? Sweeps reference sigma
//! 1, 1.5, 2 px (ρ_ref -0.4, 0, 0.4), gradient shapes stretched up to aspect 3 with
//! ρ_grad ∈ [-0.8, 0.8] and intensity ratios 0.3 / 0.6 / 1, and prints the worst relative
//! error per reference sigma for the NOTES formula on the fitted shapes, on the pixel-blurred
//! shapes, and for the published variant.
//!
//! `cargo run --release -p bostrack-displacement --example ar_vs_crlb [point]`
//! (`point`: point-sampled model instead of pixel-integrated)
use bostrack_core::{Gaussian2D, NoiseModel, Window};
use bostrack_displacement::pixel_blurred;
use bostrack_model::{ArVariant, ModelKind, Sampling, amplification_ratio, crlb};

fn bound(g: &Gaussian2D, half: usize, s: Sampling) -> [f64; 2] {
    let w = Window::centred(g.x0, g.y0, half);
    let b = crlb(g, w, &NoiseModel::read(20.0), s, ModelKind::Elliptical).expect("regular");
    [b.std[0], b.std[1]]
}

struct Worst(f64, String);

impl Worst {
    fn see(&mut self, e: f64, at: impl FnOnce() -> String) {
        if e.abs() > self.0.abs() {
            *self = Worst(e, at());
        }
    }
}

fn main() {
    let sampling = if std::env::args().any(|a| a == "point") {
        Sampling::Point
    } else {
        Sampling::Integrated
    };
    println!("sampling: {sampling:?}; error = AR / (crlb_grad / crlb_ref) - 1");
    for sr in [1.0, 1.5, 2.0] {
        let (mut notes, mut blurred, mut published) = (
            Worst(0.0, String::new()),
            Worst(0.0, String::new()),
            Worst(0.0, String::new()),
        );
        let mut n = 0;
        for rho_r in [-0.4, 0.0, 0.4] {
            let r = Gaussian2D {
                x0: 0.3,
                y0: -0.2,
                amplitude: 1000.0,
                sigma_x: sr,
                sigma_y: sr,
                rho: rho_r,
                background: 100.0,
            };
            for (fx, fy) in [
                (1.0, 1.0),
                (1.5, 1.0),
                (3.0, 1.0),
                (1.0, 3.0),
                (2.0, 2.0),
                (3.0, 1.5),
            ] {
                for rho_g in [-0.8, -0.4, 0.0, 0.4, 0.8] {
                    for ir in [0.3, 0.6, 1.0] {
                        let g = Gaussian2D {
                            sigma_x: sr * fx,
                            sigma_y: sr * fy,
                            rho: rho_g,
                            amplitude: 1000.0 * ir,
                            ..r
                        };
                        let half = (6.0 * g.sigma_x.max(g.sigma_y)).ceil() as usize;
                        let (br, bg) = (bound(&r, half, sampling), bound(&g, half, sampling));
                        let a_n = amplification_ratio(&r, &g, ArVariant::Notes);
                        let a_b = amplification_ratio(
                            &pixel_blurred(&r),
                            &pixel_blurred(&g),
                            ArVariant::Notes,
                        );
                        let a_p = amplification_ratio(&r, &g, ArVariant::Published);
                        for ax in 0..2 {
                            let ratio = bg[ax] / br[ax];
                            let at = || {
                                format!(
                                    "axis {ax}, rho_ref {rho_r:+.1}, grad sigmas ({:.2}, {:.2}) rho {rho_g:+.1}, I0 ratio {ir}",
                                    g.sigma_x, g.sigma_y
                                )
                            };
                            notes.see(a_n[ax] / ratio - 1.0, at);
                            blurred.see(a_b[ax] / ratio - 1.0, at);
                            published.see(a_p[ax] / ratio - 1.0, at);
                            n += 1;
                        }
                    }
                }
            }
        }
        println!("sigma_ref {sr} px ({n} cases x axes):");
        println!(
            "  NOTES, fitted shapes:        worst {:+.4} at {}",
            notes.0, notes.1
        );
        println!(
            "  NOTES, pixel-blurred shapes: worst {:+.4} at {}",
            blurred.0, blurred.1
        );
        println!(
            "  Published:                   worst {:+.4} at {}",
            published.0, published.1
        );
    }
}
