//! Renders every figure of bostrack-figures from synthetic data, as PNG and SVG, into the
//! folder given on the command line (e.g. `/tmp/figs`), and prints the rendering times.
//!
//! `cargo run --release -p bostrack-figures --example gallery -- /tmp/figs`
//!
//! Data: a 1024×1024 image with dots on an 9.3 px square lattice (~12k dots); displacement is a
//! Gaussian bump of the gradient of a Gaussian refractive-index field (peak about 1.2 px),
//! a band y ∈ [600, 680) is masked out, 1 % of the dots are invalid; |AR| peaks in the bump and
//! the uncertainties are log-normal.

use std::time::Instant;

use bostrack_core::Mask;
use bostrack_figures::{
    AxisScale, CampaignRow, MapFrame, MapOptions, MapPoint, RefLine, SeriesStyle,
    UncertaintyComponent, XyPlot, XySeries, ar_histogram, ar_map, campaign_figure,
    displacement_map, uncertainty_histogram, uncertainty_map, xy_panels, xy_plot,
};

/// Small deterministic generator (xorshift64*), so the example needs no rand dependency.
struct Rng(u64);
impl Rng {
    fn next_f64(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Standard normal (Box–Muller).
    fn normal(&mut self) -> f64 {
        let u1 = self.next_f64().max(1e-300);
        let u2 = self.next_f64();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .ok_or("usage: gallery <output folder>")?;
    let out = std::path::PathBuf::from(out);
    std::fs::create_dir_all(&out)?;

    let (w, h) = (1024usize, 1024usize);
    let pitch = 9.3;
    let band = 600.0..680.0;
    let mask = Mask::from_fn(w, h, |_, y| !band.contains(&(y as f64)));
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (cx, cy, s) = (430.0, 380.0, 150.0);

    let mut disp = Vec::new();
    let mut ar = Vec::new();
    let mut ud = Vec::new();
    let (mut u_ref, mut u_grad, mut ar_vals) = (Vec::new(), Vec::new(), Vec::new());
    let n = (w as f64 / pitch) as usize;
    for j in 0..n {
        for i in 0..n {
            let x = 4.0 + i as f64 * pitch + 0.3 * rng.normal();
            let y = 4.0 + j as f64 * pitch + 0.3 * rng.normal();
            let (rx, ry) = (x - cx, y - cy);
            let g = (-(rx * rx + ry * ry) / (2.0 * s * s)).exp();
            // displacement = gradient of a Gaussian bump (a lens-like deflection)
            let amp = 1.2 * std::f64::consts::E.sqrt() / s;
            let (dx, dy) = (
                -amp * rx * g + 0.01 * rng.normal(),
                -amp * ry * g + 0.01 * rng.normal(),
            );
            let in_mask = mask.keeps(
                x.round().clamp(0.0, 1023.0) as usize,
                y.round().clamp(0.0, 1023.0) as usize,
            );
            let valid = rng.next_f64() > 0.01;
            let arx = 1.0 + 1.6 * g + 0.05 * rng.normal();
            let ary = 1.0 + 1.1 * g + 0.05 * rng.normal();
            let ar_mag = arx.hypot(ary);
            let ur = 0.012 * (0.25 * rng.normal()).exp();
            let ug = ur * arx;
            let u = (ur * ur + ug * ug).sqrt() * std::f64::consts::SQRT_2;
            disp.push(MapPoint::vector(x, y, dx, dy, valid, in_mask));
            ar.push(MapPoint::scalar(x, y, ar_mag, valid, in_mask));
            ud.push(MapPoint::scalar(x, y, u, valid, in_mask));
            if valid && in_mask {
                u_ref.push(ur);
                u_grad.push(ug);
                ar_vals.push(ar_mag);
            }
        }
    }
    println!("{} dots", disp.len());

    let frame = MapFrame {
        width: w,
        height: h,
        title: "frame 3 (synthetic, grad_0003.tif)",
        mask: Some(&mask),
    };
    let opts = MapOptions::default();

    let mut figs = Vec::new();
    let t = Instant::now();
    figs.push(("displacement", displacement_map(&disp, &frame, &opts)?));
    figs.push(("ar_map", ar_map(&ar, &frame, &opts)?));
    figs.push((
        "uncertainty_map",
        uncertainty_map(&ud, &frame, UncertaintyComponent::Magnitude, &opts)?,
    ));
    figs.push((
        "uncertainty_hist",
        uncertainty_histogram(&u_ref, &u_grad, frame.title)?,
    ));
    figs.push(("ar_hist", ar_histogram(&ar_vals, frame.title)?));
    println!(
        "built 5 per-frame figures in {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );

    // campaign: 40 frames, the flow switches on at frame 10
    let rows: Vec<CampaignRow> = (0..40)
        .map(|k| {
            let on = 1.0 / (1.0 + (-(k as f64 - 10.0) / 1.5).exp());
            CampaignRow {
                frame: k,
                median_d: 0.02 + 0.35 * on + 0.01 * rng.normal(),
                median_u: if k == 25 {
                    f64::NAN
                } else {
                    0.017 + 0.006 * on + 0.0005 * rng.normal()
                },
            }
        })
        .collect();
    figs.push((
        "campaign",
        campaign_figure("Campaign run-2024-05 (40 frames)", &rows)?,
    ));

    // benchmark: error vs time per dot, log x
    let est = |label: &str, pts: &[(f64, f64)], style| XySeries {
        label: label.to_string(),
        points: pts.to_vec(),
        style,
    };
    figs.push((
        "error_vs_time",
        xy_plot(&XyPlot {
            title: "Position error against fit time (σ = 1.5 px, SNR 30)".to_string(),
            x_label: "time per dot (µs)".to_string(),
            y_label: "RMS error / CRLB".to_string(),
            x_scale: AxisScale::Log10,
            y_scale: AxisScale::Linear,
            series: vec![
                est(
                    "centroid",
                    &[(0.4, 2.9), (0.6, 2.4), (0.9, 2.2)],
                    SeriesStyle::LinePoints,
                ),
                est(
                    "3-point Gaussian",
                    &[(0.8, 1.6), (1.1, 1.45)],
                    SeriesStyle::LinePoints,
                ),
                est(
                    "LM (crate), elliptical",
                    &[(75.0, 1.01), (90.0, 1.0), (106.0, 1.0)],
                    SeriesStyle::LinePoints,
                ),
                est(
                    "hand LM, elliptical",
                    &[(18.0, 1.0), (19.5, 0.99), (21.0, 1.0)],
                    SeriesStyle::Points,
                ),
            ],
            ref_lines: vec![RefLine {
                y: 1.0,
                label: "Cramér–Rao bound".to_string(),
            }],
        })?,
    ));
    // theory: two panels
    let fnum: Vec<(f64, f64)> = (0..30)
        .map(|k| {
            let f = 2.0 + 0.5 * k as f64;
            (f, 0.004 * (1.0 + (f / 8.0).powi(2)))
        })
        .collect();
    let zd: Vec<(f64, f64)> = (0..30)
        .map(|k| {
            let z = 0.05 + 0.05 * k as f64;
            (z, 0.006 + 0.01 * z * z)
        })
        .collect();
    figs.push((
        "theory_panels",
        xy_panels(
            "Predicted uncertainty (theory)",
            &[
                XyPlot {
                    title: "CRLB against f-number".to_string(),
                    x_label: "f-number".to_string(),
                    y_label: "CRLB σ_x (px)".to_string(),
                    y_scale: AxisScale::Log10,
                    series: vec![est("CRLB σ_x", &fnum, SeriesStyle::Line)],
                    ..XyPlot::default()
                },
                XyPlot {
                    title: "CRLB against Z_D".to_string(),
                    x_label: "Z_D (m)".to_string(),
                    y_label: "CRLB σ_x (px)".to_string(),
                    series: vec![est("CRLB σ_x", &zd, SeriesStyle::Line)],
                    ..XyPlot::default()
                },
            ],
        )?,
    ));

    // edge cases: a small non-square frame, a frame whose dots are all invalid, a flat field
    let small_mask = Mask::from_fn(200, 150, |_, y| !(60..80).contains(&y));
    let small: Vec<MapPoint> = (0..300)
        .map(|k| {
            let (x, y) = (5.0 + 10.0 * (k % 20) as f64, 5.0 + 10.0 * (k / 20) as f64);
            let keep = small_mask.keeps(x as usize, y as usize);
            MapPoint::vector(
                x,
                y,
                0.01 * (y - 75.0),
                -0.01 * (x - 100.0),
                k % 17 != 0,
                keep,
            )
        })
        .collect();
    let small_frame = MapFrame {
        width: 200,
        height: 150,
        title: "frame 1 (200×150 test)",
        mask: Some(&small_mask),
    };
    figs.push((
        "edge_small_rect",
        displacement_map(&small, &small_frame, &opts)?,
    ));
    let none: Vec<MapPoint> = small
        .iter()
        .map(|p| MapPoint {
            value: f64::NAN,
            ..*p
        })
        .collect();
    figs.push(("edge_all_invalid", ar_map(&none, &small_frame, &opts)?));
    let flat: Vec<MapPoint> = small
        .iter()
        .map(|p| MapPoint { value: 0.02, ..*p })
        .collect();
    figs.push((
        "edge_flat",
        uncertainty_map(&flat, &small_frame, UncertaintyComponent::X, &opts)?
            .with_size(700, 520)?,
    ));

    for (name, fig) in &figs {
        let t = Instant::now();
        let png = fig.to_png()?;
        let t_png = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let svg = fig.to_svg()?;
        let t_svg = t.elapsed().as_secs_f64() * 1e3;
        std::fs::write(out.join(format!("{name}.png")), &png)?;
        std::fs::write(out.join(format!("{name}.svg")), &svg)?;
        let (fw, fh) = fig.size();
        println!(
            "{name:18} {fw}x{fh}  PNG {t_png:7.1} ms ({:6} kB)  SVG {t_svg:7.1} ms ({:6} kB)",
            png.len() / 1024,
            svg.len() / 1024
        );
    }
    Ok(())
}
