//! The synthetic bump campaign of issue 15's density acceptance, shared by `#[path]` by the test
//! `tests/density.rs` and the study `examples/density_coverage.rs`: a 576 × 576 px dot target
//! (12 px pitch rotated by 15°, σ = 1.6 px, read and shot noise), a dim band over the left
//! third, and a flow that is the gradient of a Gaussian density bump (synth's `GaussianBump`)
//! 60 px (5 lattice steps) wide with at most 1 px of displacement, blurred so that AR grows
//! from 1 at the edge to about 2 at the centre; seen through a plausible BOS setup.

#![allow(dead_code)]

use bostrack_pipeline::{DensitySection, PipelineConfig};
use bostrack_synth::{DisplacementField, FlowConfig, SceneConfig};

pub const CENTRE: [f64; 2] = [288.0, 288.0];
pub const WIDTH: f64 = 60.0;
/// `A` of synth's bump: at most `A e^(-1/2) / s` = 1 px of displacement.
pub const AMPLITUDE: f64 = 60.0 / 0.606_530_659_712_633_4;

/// The pipeline configuration: 12 px spacing, the optical setup, `[density]` (WLS, outer ring,
/// exact reference density).
pub fn config() -> PipelineConfig {
    let mut cfg = PipelineConfig::default();
    cfg.detect.spacing = Some(12.0);
    cfg.optics = Some(bostrack_theory::Optics {
        pixel_pitch_um: 6.5,
        focal_length_mm: 105.0,
        target_distance_m: 1.5,
        ..Default::default()
    });
    cfg.geometry = Some(bostrack_theory::Geometry::Bos {
        z_d_m: 0.5,
        delta_z_m: 0.05,
    });
    cfg.density = Some(DensitySection {
        reference_density_uncertainty_kg_m3: 0.0,
        ..DensitySection::default()
    });
    cfg
}

/// The scene of campaign `seed` (its own reference, stack and frame noise).
pub fn scene(seed: u64) -> SceneConfig {
    let mut sc = SceneConfig {
        width: 576,
        height: 576,
        seed: 100 + seed,
        ..Default::default()
    };
    sc.lattice.spacing = 12.0;
    sc.lattice.angle_deg = 15.0;
    // a dim band over the left third: dots there 3× fainter, u_d larger
    sc.background.dark = vec![bostrack_synth::DarkRegion {
        x: Some([-100.0, 192.0]),
        y: None,
        factor: 0.45,
        edge: 20.0,
    }];
    sc
}

/// The flow: the bump's displacement field and its blur.
pub fn flow() -> FlowConfig {
    FlowConfig {
        displacement: DisplacementField::GaussianBump {
            centre: CENTRE,
            amplitude: AMPLITUDE,
            width: WIDTH,
        },
        blur: 5000.0,
        conserve_intensity: true,
    }
}

/// The exact displacement (px) of a dot at `p` (px).
pub fn displacement(p: [f64; 2]) -> [f64; 2] {
    let (x, y) = (p[0] - CENTRE[0], p[1] - CENTRE[1]);
    let k = -AMPLITUDE / (WIDTH * WIDTH) * (-(x * x + y * y) / (2.0 * WIDTH * WIDTH)).exp();
    [k * x, k * y]
}

/// `ρ_true − ρ_ref` at `p` (px) for a bump whose density deficit at the centre is `peak`.
pub fn density_deficit(p: [f64; 2], peak: f64) -> f64 {
    let r2 = (p[0] - CENTRE[0]).powi(2) + (p[1] - CENTRE[1]).powi(2);
    -peak * (-r2 / (2.0 * WIDTH * WIDTH)).exp()
}

/// Campaign `seed` through the pipeline: its reference and 10-image no-flow stack prepared,
/// its frame processed (the images handed over in memory).
pub fn run(plan: &bostrack_pipeline::Plan, seed: u64) -> bostrack_pipeline::FrameResult {
    use bostrack_synth::{Scene, stack};
    let sc = scene(seed);
    let reference = Scene::reference(&sc).unwrap().image;
    let stack = stack(&sc, 10).unwrap();
    let ctx =
        bostrack_pipeline::ReferenceContext::from_images(plan, reference, None, stack).unwrap();
    let frame = Scene::frame(&sc, &flow(), 1).unwrap().image;
    bostrack_pipeline::process_image(&ctx, plan, &frame, std::path::Path::new("g.tif")).unwrap()
}
