//! `bostrack crlb`: the paper as code for one experiment: the predicted shift, dot shape,
//! Cramér-Rao bound and amplification ratio of a setup (bostrack-theory), and the design sweeps
//! of the paper's Sec. 2.3 as CSV tables and figures.

use crate::Outcome;
use anyhow::Context as _;
use bostrack_figures::{AxisScale, RefLine, SeriesStyle, XyPlot, XySeries, xy_panels};
use bostrack_theory::{
    ExposureScaling, Geometry, Prediction, Setup, SweepRow, TheoryFlags, ZdHold, predict,
    sweep_f_number, sweep_z_d,
};
use clap::Args;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

const CRLB_LONG_ABOUT: &str = "\
Predict what a BOS (or volumetric PTV) experiment will measure for one dot, from a setup file
(TOML, the bostrack-theory Setup: [optics], [geometry], [flow], [view], [camera], [constants];
testdata/crlb-setup.toml is a commented example; unknown keys are errors):

  shift_x, shift_y      centroid shift -S grad(rho), px (paper Eq. 6, 18)
  sigma_x, sigma_y, rho the effective (blurred) gradient dot, px (Eq. 25-26 and the cross term);
                        diameters d = 4 sigma
  crlb_x, crlb_y        exact Cramér-Rao bound of the gradient dot's position (pixel-integrated,
                        7 free parameters, 1 sigma, px); crlb_ref_* that of the reference dot
  eq35_x, eq35_y        the closed form (Eq. 35 with rho, docs/theory.md)
  ar_x, ar_y            amplification ratio (docs/theory.md, Eq. 37); ar_exact_* the ratio of exact bounds
  u_d_x, u_d_y          displacement uncertainty of one pair, sqrt(crlb_ref² + crlb²), px
  flags                 where the model's assumptions are strained (cone_clamped,
                        cone_corrected, wide_cone, non_gaussian, undersampled, lensing,
                        bound_singular, window_capped)

--json prints the whole prediction as one JSON object (NaN as null). --sweep --out DIR writes
the design sweeps of the paper's Sec. 2.3: the bound against the f-number (at fixed exposure
and at fixed illumination), and against Z_D, the distance from the target to the density field,
at fixed shift sensitivity M·Z_D and at fixed magnification (BOS setups only), as
crlb-vs-f-number.csv / .png / .svg and crlb-vs-z_d.csv / .png / .svg.";

/// Predict the shift, dot shape, Cramér-Rao bound and amplification ratio of a setup.
#[derive(Debug, Args)]
#[command(
    about = "Predict shift, dot size, Cramér-Rao bound and amplification ratio of a setup (--sweep: design plots)",
    long_about = CRLB_LONG_ABOUT
)]
pub(crate) struct CrlbArgs {
    /// Setup file (TOML; see testdata/crlb-setup.toml).
    #[arg(value_name = "SETUP")]
    setup: PathBuf,
    /// Print the prediction as one JSON object.
    #[arg(long)]
    json: bool,
    /// Write the design sweeps (bound against f-number and against Z_D) into --out.
    #[arg(long, requires = "out")]
    sweep: bool,
    /// Output folder of --sweep (created; files of the same name are replaced).
    #[arg(short = 'o', long = "out", value_name = "DIR", requires = "sweep")]
    out: Option<PathBuf>,
    /// f-numbers of the sweep, comma-separated [default: third stops from 2.8 to 32].
    #[arg(long, value_name = "LIST", value_delimiter = ',', requires = "sweep")]
    f_numbers: Vec<f64>,
    /// Z_D values of the sweep (m), comma-separated [default: 25 values from Z_D/5 to 3 Z_D,
    /// kept between the target and the lens].
    #[arg(
        long = "z-d",
        value_name = "LIST",
        value_delimiter = ',',
        requires = "sweep"
    )]
    z_d: Vec<f64>,
}

/// The sections of a `pipeline.toml` that are not the setup's: a `pipeline.toml` with the
/// optical setup (`[optics]`, `[geometry]`, `[constants]`, issue 15) is also a setup file.
const PIPELINE_SECTIONS: [&str; 8] = [
    "input",
    "detect",
    "fit",
    "match",
    "uncertainty",
    "output",
    "run",
    "density",
];

/// Reads and validates a setup file (or a `pipeline.toml`, whose pipeline sections are left
/// out); errors name the file and the offending key.
fn load_setup(path: &Path) -> anyhow::Result<Setup> {
    let mut text = bostrack_pipeline::read_config_text(path)?;
    if let Ok(table) = text.parse::<toml::Table>()
        && table
            .keys()
            .any(|k| PIPELINE_SECTIONS.contains(&k.as_str()))
    {
        let setup: toml::Table = table
            .into_iter()
            .filter(|(k, _)| !PIPELINE_SECTIONS.contains(&k.as_str()))
            .collect();
        text = toml::to_string(&setup)?;
    }
    Setup::from_toml(&text).with_context(|| format!("{}", path.display()))
}

pub(crate) fn run(args: CrlbArgs) -> anyhow::Result<Outcome> {
    let setup = load_setup(&args.setup)?;
    let p = predict(&setup).with_context(|| format!("{}", args.setup.display()))?;
    // the sweeps first: a sweep that fails leaves nothing on stdout
    let written = match (&args.out, args.sweep) {
        (Some(out), true) => {
            std::fs::create_dir_all(out)
                .with_context(|| format!("cannot create {}", out.display()))?;
            Some((write_sweeps(&setup, &args, out)?, out))
        }
        _ => None,
    };
    if args.json {
        println!("{}", prediction_json(&p, &args.setup)?);
    } else {
        print!("{}", prediction_text(&setup, &p, &args.setup));
    }
    if let Some((n, out)) = written {
        eprintln!("wrote {n} files to {}", out.display());
    }
    Ok(Outcome::Done)
}

/// The prediction as one JSON object ([`bostrack_theory::prediction_json`]).
fn prediction_json(p: &Prediction, path: &Path) -> anyhow::Result<String> {
    let v = bostrack_theory::prediction_json(p, path).context("serialising the prediction")?;
    serde_json::to_string(&v).context("serialising the prediction")
}

fn flags_text(f: TheoryFlags) -> String {
    if f.is_empty() {
        "none".to_string()
    } else {
        f.to_string()
    }
}

/// The prediction as an aligned human-readable table.
fn prediction_text(setup: &Setup, p: &Prediction, path: &Path) -> String {
    let geometry = match setup.geometry {
        Geometry::Bos { z_d_m, delta_z_m } => {
            format!("BOS, slab {delta_z_m} m thick, Z_D = {z_d_m} m")
        }
        Geometry::Volumetric { depth_m } => format!("volumetric, depth {depth_m} m"),
    };
    let mut t = String::new();
    let mut line = |k: &str, v: String| {
        let _ = writeln!(t, "{k:<34} {v}");
    };
    line("setup", format!("{} ({geometry})", path.display()));
    line("magnification |M|", format!("{:.5}", p.magnification));
    line("f-number", format!("{}", p.f_number));
    line(
        "shift sensitivity S",
        format!("{:.5} px per kg/m⁴", p.sensitivity_px),
    );
    line(
        "cone angle: geometric / used",
        format!(
            "{:.3} / {:.3} mrad",
            1e3 * p.cone_angle_geometric_rad,
            1e3 * p.cone_angle_rad
        ),
    );
    line(
        "diffraction diameter",
        format!("{:.3} px", p.diffraction_diameter_px),
    );
    line(
        "reference dot",
        format!(
            "d = {:.3} px (sigma {:.4}), peak {:.1} counts",
            p.reference_diameter_px, p.reference.sigma_x, p.reference.amplitude
        ),
    );
    line(
        "shift (x, y)",
        format!("{:+.4}, {:+.4} px", p.shift_x + 0.0, p.shift_y + 0.0),
    );
    line(
        "gradient dot diameters d = 4 sigma",
        format!(
            "{:.3}, {:.3} px (sigma {:.4}, {:.4})",
            p.diameter_x, p.diameter_y, p.sigma_x, p.sigma_y
        ),
    );
    line("gradient dot rho", format!("{:.4}", p.rho));
    line("gradient dot peak", format!("{:.1} counts", p.peak));
    line(
        "CRLB gradient dot (x, y)",
        format!("{:.5}, {:.5} px (exact, 1 sigma)", p.crlb_x, p.crlb_y),
    );
    line(
        "CRLB reference dot (x, y)",
        format!("{:.5}, {:.5} px", p.crlb_ref_x, p.crlb_ref_y),
    );
    line(
        "Eq. 35 with rho (x, y)",
        format!("{:.5}, {:.5} px", p.eq35_x, p.eq35_y),
    );
    line(
        "AR (x, y), closed form (Eq. 37)",
        format!("{:.4}, {:.4}", p.ar_x, p.ar_y),
    );
    line(
        "AR (x, y), ratio of exact bounds",
        format!("{:.4}, {:.4}", p.ar_exact_x, p.ar_exact_y),
    );
    line(
        "u_d = sqrt(crlb_ref² + crlb²)",
        format!(
            "{:.5}, {:.5} px",
            p.crlb_ref_x.hypot(p.crlb_x),
            p.crlb_ref_y.hypot(p.crlb_y)
        ),
    );
    let g = p.displacement_gradient;
    line(
        "displacement gradient",
        format!(
            "[[{:+.4}, {:+.4}], [{:+.4}, {:+.4}]] px/px",
            g[0][0] + 0.0,
            g[0][1] + 0.0,
            g[1][0] + 0.0,
            g[1][1] + 0.0
        ),
    );
    line(
        "bound window",
        format!("{}x{} px", p.window.width, p.window.height),
    );
    line("flags", flags_text(p.flags));
    t
}

/// Height of one panel of the sweep figures (px): room for the legends.
const PANEL_HEIGHT: u32 = 420;

/// Third stops from f/2.8 to f/32: `2^(k/6)`, k = 9..=30.
fn default_f_numbers() -> Vec<f64> {
    (9..=30).map(|k| 2f64.powf(f64::from(k) / 6.0)).collect()
}

/// 25 values from Z_D/5 to 3 Z_D, kept inside `(Δz/2, Z_T − Δz/2)` (with a 2 % margin) when
/// the target distance is known.
fn default_z_d(setup: &Setup) -> Option<Vec<f64>> {
    let Geometry::Bos { z_d_m, delta_z_m } = setup.geometry else {
        return None;
    };
    let mut lo = 0.2 * z_d_m;
    let mut hi = 3.0 * z_d_m;
    lo = lo.max(0.5 * delta_z_m * 1.02);
    if setup.optics.magnification.is_none() {
        hi = hi.min(0.98 * (setup.optics.target_distance_m - 0.5 * delta_z_m));
    }
    if hi <= lo {
        return Some(vec![z_d_m]);
    }
    let n = 25;
    Some(
        (0..n)
            .map(|k| lo + (hi - lo) * k as f64 / (n - 1) as f64)
            .collect(),
    )
}

/// Columns of the sweep CSV files after the first (`exposure` or `hold`).
const SWEEP_COLUMNS: &str = "f_number,magnification,z_d_m,m_z_d_m,sensitivity_px,cone_angle_rad,exposure_counts,reference_diameter_px,shift_x,shift_y,sigma_x,sigma_y,rho,crlb_x,crlb_y,crlb_ref_x,crlb_ref_y,eq35_x,eq35_y,eq35_ref,ar_x,ar_y,ar_exact_x,ar_exact_y,u_d_x,u_d_y,snr_x,snr_y,flags";

fn sweep_csv_row(first: &str, r: &SweepRow) -> String {
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
    let nums = [
        r.f_number,
        r.magnification,
        f64::NAN, // placeholders replaced below
        f64::NAN,
        r.sensitivity_px,
        r.cone_angle_rad,
        r.exposure,
        r.reference_diameter_px,
        r.shift_x,
        r.shift_y,
        r.sigma_x,
        r.sigma_y,
        r.rho,
        r.crlb_x,
        r.crlb_y,
        r.crlb_ref_x,
        r.crlb_ref_y,
        r.eq35_x,
        r.eq35_y,
        r.eq35_ref,
        r.ar_x,
        r.ar_y,
        r.ar_exact_x,
        r.ar_exact_y,
        r.u_d_x,
        r.u_d_y,
        r.snr_x,
        r.snr_y,
    ];
    let mut s = String::from(first);
    for (k, v) in nums.iter().enumerate() {
        s.push(',');
        match k {
            2 => s.push_str(&opt(r.z_d_m)),
            3 => s.push_str(&opt(r.m_z_d_m)),
            // (an unknown value is the empty field, as in every table)
            _ if v.is_finite() => s.push_str(&v.to_string()),
            _ => {}
        }
    }
    s.push(',');
    s.push_str(&r.flags.to_string());
    s
}

fn line(
    label: &str,
    rows: &[SweepRow],
    x: fn(&SweepRow) -> f64,
    y: fn(&SweepRow) -> f64,
) -> XySeries {
    XySeries {
        label: label.to_string(),
        points: rows.iter().map(|r| (x(r), y(r))).collect(),
        style: SeriesStyle::LinePoints,
    }
}

/// Markers on the rows whose dot is flagged `non_gaussian` (its Gaussian bound is optimistic).
fn non_gaussian(
    rows: &[&[SweepRow]],
    x: fn(&SweepRow) -> f64,
    y: fn(&SweepRow) -> f64,
) -> Option<XySeries> {
    let points: Vec<(f64, f64)> = rows
        .iter()
        .flat_map(|rs| rs.iter())
        .filter(|r| r.flags.contains(TheoryFlags::NON_GAUSSIAN))
        .map(|r| (x(r), y(r)))
        .collect();
    (!points.is_empty()).then(|| XySeries {
        label: "flagged non_gaussian: blur > reference dot, bound optimistic".to_string(),
        points,
        style: SeriesStyle::Points,
    })
}

fn write_sweeps(setup: &Setup, args: &CrlbArgs, out: &Path) -> anyhow::Result<usize> {
    let what = || format!("{}", args.setup.display());
    let f_numbers = if args.f_numbers.is_empty() {
        default_f_numbers()
    } else {
        args.f_numbers.clone()
    };
    let fixed = sweep_f_number(setup, &f_numbers, ExposureScaling::Fixed).with_context(what)?;
    let lit = sweep_f_number(setup, &f_numbers, ExposureScaling::Aperture).with_context(what)?;
    let mut files = 0;

    // f-number: CSV
    let mut csv = format!("exposure,{SWEEP_COLUMNS}\n");
    for r in &fixed {
        csv.push_str(&sweep_csv_row("fixed", r));
        csv.push('\n');
    }
    for r in &lit {
        csv.push_str(&sweep_csv_row("aperture", r));
        csv.push('\n');
    }
    write(out, "crlb-vs-f-number.csv", csv.as_bytes())?;
    files += 1;

    // f-number: figure
    let f = |r: &SweepRow| r.f_number;
    let mut bound_fixed = vec![
        line("gradient dot x", &fixed, f, |r| r.crlb_x),
        line("gradient dot y", &fixed, f, |r| r.crlb_y),
        line("reference dot", &fixed, f, |r| r.crlb_ref_x),
    ];
    bound_fixed.extend(non_gaussian(&[&fixed], f, |r| r.crlb_x));
    let mut bound_lit = vec![
        line("gradient dot x", &lit, f, |r| r.crlb_x),
        line("gradient dot y", &lit, f, |r| r.crlb_y),
        line("reference dot", &lit, f, |r| r.crlb_ref_x),
    ];
    bound_lit.extend(non_gaussian(&[&lit], f, |r| r.crlb_x));
    let panels = [
        XyPlot {
            title: "Exact Cramér-Rao bound at fixed exposure (illumination raised to compensate)"
                .into(),
            x_label: "f-number".into(),
            y_label: "CRLB (px, 1σ)".into(),
            x_scale: AxisScale::Log10,
            y_scale: AxisScale::Log10,
            series: bound_fixed,
            ref_lines: Vec::new(),
        },
        XyPlot {
            title: "Exact Cramér-Rao bound at fixed illumination (exposure ∝ 1/(f#² (1+M)²))"
                .into(),
            x_label: "f-number".into(),
            y_label: "CRLB (px, 1σ)".into(),
            x_scale: AxisScale::Log10,
            y_scale: AxisScale::Log10,
            series: bound_lit,
            ref_lines: Vec::new(),
        },
        XyPlot {
            title: "Amplification ratio (closed form, Eq. 37)".into(),
            x_label: "f-number".into(),
            y_label: "AR".into(),
            x_scale: AxisScale::Log10,
            y_scale: AxisScale::Linear,
            series: vec![
                line("AR x", &fixed, f, |r| r.ar_x),
                line("AR y", &fixed, f, |r| r.ar_y),
            ],
            ref_lines: vec![RefLine {
                y: 1.0,
                label: "no amplification".into(),
            }],
        },
        XyPlot {
            title: "Dot size".into(),
            x_label: "f-number".into(),
            y_label: "σ (px)".into(),
            x_scale: AxisScale::Log10,
            y_scale: AxisScale::Linear,
            series: vec![
                line("gradient dot σx", &fixed, f, |r| r.sigma_x),
                line("gradient dot σy", &fixed, f, |r| r.sigma_y),
                line("reference dot σ", &fixed, f, |r| {
                    r.reference_diameter_px / 4.0
                }),
            ],
            ref_lines: Vec::new(),
        },
    ];
    let fig = xy_panels(
        &format!("Bound against f-number: {}", file_name(&args.setup)),
        &panels,
    )
    .and_then(|f| f.with_size(900, 80 + 4 * PANEL_HEIGHT))
    .context("drawing the f-number sweep")?;
    write(
        out,
        "crlb-vs-f-number.png",
        &fig.to_png().context("rendering the PNG")?,
    )?;
    write(
        out,
        "crlb-vs-f-number.svg",
        fig.to_svg().context("rendering the SVG")?.as_bytes(),
    )?;
    files += 2;

    // Z_D: BOS only
    let z_d = if args.z_d.is_empty() {
        default_z_d(setup)
    } else {
        Some(args.z_d.clone())
    };
    let Some(z_d) = z_d else {
        eprintln!(
            "{}: not a BOS setup (geometry.kind = \"volumetric\"): no Z_D sweep",
            args.setup.display()
        );
        return Ok(files);
    };
    let sens =
        sweep_z_d(setup, &z_d, ZdHold::Sensitivity, ExposureScaling::Fixed).with_context(what)?;
    let mag =
        sweep_z_d(setup, &z_d, ZdHold::Magnification, ExposureScaling::Fixed).with_context(what)?;
    let mut csv = format!("hold,{SWEEP_COLUMNS}\n");
    for r in &sens {
        csv.push_str(&sweep_csv_row("sensitivity", r));
        csv.push('\n');
    }
    for r in &mag {
        csv.push_str(&sweep_csv_row("magnification", r));
        csv.push('\n');
    }
    write(out, "crlb-vs-z_d.csv", csv.as_bytes())?;
    files += 1;

    let z = |r: &SweepRow| r.z_d_m.unwrap_or(f64::NAN);
    let m_z = sens.first().and_then(|r| r.m_z_d_m).unwrap_or(f64::NAN);
    let m0 = mag.first().map_or(f64::NAN, |r| r.magnification);
    let mut sens_series = vec![
        line("gradient dot x", &sens, z, |r| r.crlb_x),
        line("gradient dot y", &sens, z, |r| r.crlb_y),
        line("reference dot", &sens, z, |r| r.crlb_ref_x),
    ];
    sens_series.extend(non_gaussian(&[&sens], z, |r| r.crlb_x));
    let mut mag_series = vec![
        line("gradient dot x", &mag, z, |r| r.crlb_x),
        line("gradient dot y", &mag, z, |r| r.crlb_y),
        line("u_d x (pair)", &mag, z, |r| r.u_d_x),
        line("u_d y (pair)", &mag, z, |r| r.u_d_y),
    ];
    mag_series.extend(non_gaussian(&[&mag], z, |r| r.crlb_x));
    let panels = [
        XyPlot {
            title: format!(
                "Bound at fixed shift sensitivity M·Z_D = {:.4} m (shift fixed, M = M·Z_D / Z_D)",
                m_z
            ),
            x_label: "Z_D, target to density field (m)".into(),
            y_label: "CRLB (px, 1σ)".into(),
            x_scale: AxisScale::Linear,
            y_scale: AxisScale::Linear,
            series: sens_series,
            ref_lines: Vec::new(),
        },
        XyPlot {
            title: format!("Bound at fixed magnification M = {m0:.4} (shift ∝ Z_D, blur ∝ Z_D²)"),
            x_label: "Z_D, target to density field (m)".into(),
            y_label: "CRLB (px, 1σ)".into(),
            x_scale: AxisScale::Linear,
            y_scale: AxisScale::Log10,
            series: mag_series,
            ref_lines: Vec::new(),
        },
        XyPlot {
            title: format!("Shift over its uncertainty at fixed magnification M = {m0:.4}"),
            x_label: "Z_D, target to density field (m)".into(),
            y_label: "|shift| / u_d".into(),
            x_scale: AxisScale::Linear,
            y_scale: AxisScale::Linear,
            series: vec![
                line("x", &mag, z, |r| r.snr_x),
                line("y", &mag, z, |r| r.snr_y),
            ],
            ref_lines: Vec::new(),
        },
    ];
    let fig = xy_panels(
        &format!("Bound against Z_D: {}", file_name(&args.setup)),
        &panels,
    )
    .and_then(|f| f.with_size(900, 80 + 3 * PANEL_HEIGHT))
    .context("drawing the Z_D sweep")?;
    write(
        out,
        "crlb-vs-z_d.png",
        &fig.to_png().context("rendering the PNG")?,
    )?;
    write(
        out,
        "crlb-vs-z_d.svg",
        fig.to_svg().context("rendering the SVG")?.as_bytes(),
    )?;
    files += 2;
    Ok(files)
}

fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> anyhow::Result<()> {
    let p = dir.join(name);
    std::fs::write(&p, bytes).with_context(|| format!("cannot write {}", p.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_sweeps() {
        let f = default_f_numbers();
        assert!((f[0] - 2.828).abs() < 1e-3 && (f[f.len() - 1] - 32.0).abs() < 1e-9);
        // third stops: three steps make a full stop, a factor √2
        assert!((f[3] / f[0] - 2f64.sqrt()).abs() < 1e-12);
        let s = Setup::default(); // Z_D 0.5 m, slab 0.05 m, target 1.5 m
        let z = default_z_d(&s).unwrap();
        assert_eq!(z.len(), 25);
        assert!((z[0] - 0.1).abs() < 1e-12);
        assert!(z[24] < 1.5 - 0.025 && z[24] > 1.4);
        let v = Setup {
            geometry: Geometry::Volumetric { depth_m: 0.001 },
            ..Setup::default()
        };
        assert!(default_z_d(&v).is_none());
    }

    #[test]
    fn csv_rows_have_every_column() {
        let s = Setup::default();
        let rows = sweep_f_number(&s, &[8.0, 11.0], ExposureScaling::Fixed).unwrap();
        let n = SWEEP_COLUMNS.split(',').count() + 1;
        for r in &rows {
            assert_eq!(sweep_csv_row("fixed", r).split(',').count(), n);
        }
    }
}
