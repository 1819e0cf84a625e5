//! `bostrack synth`: a synthetic campaign (reference, no-flow stack, gradient frames) with its
//! exact truth, from a scene file and/or flags.

use crate::Outcome;
use crate::jobs::{JobsArg, up_to};
use anyhow::{Context as _, bail};
use bostrack_core::Image;
use bostrack_synth::{DisplacementField, FlowConfig, Scene, SceneConfig, stack, write_truth_csv};
use clap::Args;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

const SYNTH_LONG_ABOUT: &str = "\
Write a synthetic dot-target campaign with exact ground truth into DIR:

  reference.tif            the no-flow reference image
  stack/noflow_NN.tif      --stack further no-flow images (same dots, independent noise)
  gradient/frame_NN.tif    --frames gradient images: the dots moved and blurred by the flow,
                           independent noise per frame
  truth/reference.csv      per-dot truth of the reference (and of every stack image)
  truth/frame_NN.csv       per-dot truth of each gradient frame (same rows, same order)
  mask.png                 the region of interest, if the scene has one (white = keep)
  scene.toml, flow.toml    the resolved configurations (feed them back with --scene/--flow)

The scene starts from --scene FILE (a bostrack-synth SceneConfig TOML) or its defaults; the
flags below override single values. The flow starts from --flow FILE (a FlowConfig TOML) or no
flow; --field and --blur override it. Images with --bits 8, 12 or 16 are written as 16-bit TIFF,
32 or 64 as 32-bit float TIFF. Everything is deterministic for a given seed, whatever --jobs is.

The true displacement of a dot in frame NN is its x,y in truth/frame_NN.csv minus its x,y in
truth/reference.csv (same row).";

/// Write a synthetic campaign with its exact truth.
#[derive(Debug, Args)]
#[command(
    about = "Write a synthetic campaign (reference, no-flow stack, gradient frames) with exact truth",
    long_about = SYNTH_LONG_ABOUT
)]
pub(crate) struct SynthArgs {
    /// Output folder (created; must be empty or absent unless --force).
    #[arg(short = 'o', long = "out", value_name = "DIR")]
    out: PathBuf,
    /// Scene configuration file (TOML; unknown keys are errors).
    #[arg(long, value_name = "FILE")]
    scene: Option<PathBuf>,
    /// Flow configuration file (TOML: displacement field and blur).
    #[arg(long, value_name = "FILE")]
    flow: Option<PathBuf>,
    /// Image width (px).
    #[arg(long, value_name = "PX")]
    width: Option<usize>,
    /// Image height (px).
    #[arg(long, value_name = "PX")]
    height: Option<usize>,
    /// Lattice spacing: distance between neighbouring dots (px).
    #[arg(long, value_name = "PX")]
    spacing: Option<f64>,
    /// Dot standard deviation sigma, both axes (px; dot diameter d = 4 sigma).
    #[arg(long, value_name = "PX")]
    sigma: Option<f64>,
    /// Dot peak height above the background (counts).
    #[arg(long, value_name = "COUNTS")]
    amplitude: Option<f64>,
    /// Read-noise standard deviation (counts).
    #[arg(long, value_name = "COUNTS")]
    noise: Option<f64>,
    /// Shot noise: counts per photo-electron (0 = read noise only).
    #[arg(long, value_name = "COUNTS")]
    gain: Option<f64>,
    /// Bits per sample: 8, 12, 16 (quantised) or 32, 64 (float).
    #[arg(long, value_name = "BITS")]
    bits: Option<u16>,
    /// Master seed of the scene (layout and noise).
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Displacement field: zero | uniform:DX,DY | bump:AMPLITUDE,WIDTH | vortex:STRENGTH,CORE
    /// (bump and vortex centred on the image; bump: d = A grad exp(-r²/2w²), A in px², w in px;
    /// vortex: strength in px², core in px).
    #[arg(long, value_name = "SPEC", value_parser = parse_field)]
    field: Option<FieldSpec>,
    /// Blur footprint variance of the flow (px²): the gradient dot's covariance grows by
    /// blur · J Jᵀ, J the displacement Jacobian.
    #[arg(long, value_name = "PX2")]
    blur: Option<f64>,
    /// Number of gradient frames (same flow, independent noise).
    #[arg(long, value_name = "N", default_value_t = 3, value_parser = up_to::<10_000>)]
    frames: usize,
    /// Number of no-flow stack images.
    #[arg(long = "stack", value_name = "K", default_value_t = 5, value_parser = up_to::<1000>)]
    stack_size: usize,
    /// Write into DIR even if it is not empty (files of the same name are replaced).
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    jobs: JobsArg,
}

/// A displacement field given on the command line, centred on the image once its size is known.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum FieldSpec {
    Zero,
    Uniform { dx: f64, dy: f64 },
    Bump { amplitude: f64, width: f64 },
    Vortex { strength: f64, core: f64 },
}

fn parse_field(s: &str) -> Result<FieldSpec, String> {
    let (kind, args) = s.split_once(':').unwrap_or((s, ""));
    let nums: Vec<f64> = if args.is_empty() {
        Vec::new()
    } else {
        args.split(',')
            .map(|a| {
                a.trim()
                    .parse::<f64>()
                    .map_err(|_| format!("`{a}` is not a number"))
            })
            .collect::<Result<_, _>>()?
    };
    let two = |name: &str| -> Result<(f64, f64), String> {
        match nums.as_slice() {
            [a, b] => Ok((*a, *b)),
            _ => Err(format!("`{name}` takes two numbers, e.g. {name}:1.5,-0.5")),
        }
    };
    match kind {
        "zero" if nums.is_empty() => Ok(FieldSpec::Zero),
        "zero" => Err("`zero` takes no numbers".into()),
        "uniform" => two("uniform").map(|(dx, dy)| FieldSpec::Uniform { dx, dy }),
        "bump" => two("bump").map(|(amplitude, width)| FieldSpec::Bump { amplitude, width }),
        "vortex" => two("vortex").map(|(strength, core)| FieldSpec::Vortex { strength, core }),
        other => Err(format!(
            "unknown field `{other}` (expected zero, uniform:DX,DY, bump:A,W or vortex:S,C)"
        )),
    }
}

impl FieldSpec {
    fn field(self, centre: [f64; 2]) -> DisplacementField {
        match self {
            FieldSpec::Zero => DisplacementField::Zero,
            FieldSpec::Uniform { dx, dy } => DisplacementField::Uniform { dx, dy },
            FieldSpec::Bump { amplitude, width } => DisplacementField::GaussianBump {
                centre,
                amplitude,
                width,
            },
            FieldSpec::Vortex { strength, core } => DisplacementField::Vortex {
                centre,
                strength,
                core,
            },
        }
    }
}

/// The scene and flow of a synth run: the files (or defaults) with the flags applied, validated.
fn resolve(args: &SynthArgs) -> anyhow::Result<(SceneConfig, FlowConfig)> {
    let mut scene: SceneConfig = match &args.scene {
        Some(p) => bostrack_pipeline::load_toml(p)?,
        None => SceneConfig::default(),
    };
    let set = |v: Option<f64>, slot: &mut f64| {
        if let Some(v) = v {
            *slot = v;
        }
    };
    if let Some(w) = args.width {
        scene.width = w;
    }
    if let Some(h) = args.height {
        scene.height = h;
    }
    set(args.spacing, &mut scene.lattice.spacing);
    if let Some(s) = args.sigma {
        scene.dots.sigma_x = s;
        scene.dots.sigma_y = s;
    }
    set(args.amplitude, &mut scene.dots.amplitude);
    set(args.noise, &mut scene.noise.read_noise);
    set(args.gain, &mut scene.noise.gain);
    if let Some(b) = args.bits {
        scene.bits = b;
    }
    if let Some(s) = args.seed {
        scene.seed = s;
    }
    let what = |p: &Option<PathBuf>| {
        p.as_ref().map_or("options".to_string(), |p| {
            format!("{} and options", p.display())
        })
    };
    scene
        .validate()
        .with_context(|| format!("scene from {}", what(&args.scene)))?;

    let mut flow: FlowConfig = match &args.flow {
        Some(p) => bostrack_pipeline::load_toml(p)?,
        None => FlowConfig::default(),
    };
    if let Some(f) = args.field {
        let centre = [
            (scene.width as f64 - 1.0) / 2.0,
            (scene.height as f64 - 1.0) / 2.0,
        ];
        flow.displacement = f.field(centre);
    }
    set(args.blur, &mut flow.blur);
    flow.validate()
        .with_context(|| format!("flow from {}", what(&args.flow)))?;
    Ok((scene, flow))
}

/// One image or table to write.
enum Product {
    Reference(Scene),
    Stack(Vec<Image>),
    Frame(usize, Scene),
}

pub(crate) fn run(args: SynthArgs) -> anyhow::Result<Outcome> {
    let (scene_cfg, flow) = resolve(&args)?;
    let out = &args.out;
    if out.exists() && !args.force {
        let non_empty = std::fs::read_dir(out)
            .with_context(|| format!("cannot list {}", out.display()))?
            .next()
            .is_some();
        if non_empty {
            bail!(
                "{} is not empty (use --force to write into it)",
                out.display()
            );
        }
    }
    for sub in ["", "stack", "gradient", "truth"] {
        let d = out.join(sub);
        std::fs::create_dir_all(&d).with_context(|| format!("cannot create {}", d.display()))?;
    }

    let pool = args.jobs.pool(0)?;
    // Independent tasks (each seeded on its own), computed in parallel, written in order.
    let n_tasks = 2 + args.frames;
    let products: Vec<anyhow::Result<Option<Product>>> = pool.install(|| {
        (0..n_tasks)
            .into_par_iter()
            .map(|t| -> anyhow::Result<Option<Product>> {
                Ok(match t {
                    0 => Some(Product::Reference(Scene::reference(&scene_cfg)?)),
                    1 if args.stack_size == 0 => None,
                    1 => Some(Product::Stack(stack(&scene_cfg, args.stack_size)?)),
                    _ => {
                        let n = t - 1;
                        Some(Product::Frame(n, Scene::frame(&scene_cfg, &flow, n)?))
                    }
                })
            })
            .collect()
    });

    let write_image = |path: &Path, img: &Image| -> anyhow::Result<()> {
        if scene_cfg.bits <= 16 {
            bostrack_io::write_tiff_u16(path, img)?;
        } else {
            bostrack_io::write_tiff_f32(path, img)?;
        }
        Ok(())
    };
    let width = args.frames.max(args.stack_size).to_string().len().max(2);
    let mut files = 0usize;
    let mut inside = 0usize;
    for p in products {
        match p? {
            None => {}
            Some(Product::Reference(s)) => {
                write_image(&out.join("reference.tif"), &s.image)?;
                write_truth(&out.join("truth/reference.csv"), &s)?;
                inside = s
                    .truth
                    .iter()
                    .filter(|t| t.centre_inside(scene_cfg.width, scene_cfg.height))
                    .count();
                files += 2;
                if let Some(mask) = &s.mask {
                    let img = Image::from_fn(mask.width(), mask.height(), |x, y| {
                        if mask.keeps(x, y) { 255.0 } else { 0.0 }
                    });
                    bostrack_io::write_png_u8(&out.join("mask.png"), &img)?;
                    files += 1;
                }
            }
            Some(Product::Stack(images)) => {
                for (k, img) in images.iter().enumerate() {
                    write_image(
                        &out.join(format!("stack/noflow_{:0width$}.tif", k + 1)),
                        img,
                    )?;
                    files += 1;
                }
            }
            Some(Product::Frame(n, s)) => {
                write_image(
                    &out.join(format!("gradient/frame_{n:0width$}.tif")),
                    &s.image,
                )?;
                write_truth(&out.join(format!("truth/frame_{n:0width$}.csv")), &s)?;
                files += 2;
            }
        }
    }
    write_toml(&out.join("scene.toml"), &scene_cfg)?;
    write_toml(&out.join("flow.toml"), &flow)?;
    files += 2;
    eprintln!(
        "wrote {files} files to {} ({}x{} px, {inside} dots centred in the image, {} stack images, {} gradient frames)",
        out.display(),
        scene_cfg.width,
        scene_cfg.height,
        args.stack_size,
        args.frames
    );
    Ok(Outcome::Done)
}

fn write_truth(path: &Path, scene: &Scene) -> anyhow::Result<()> {
    let mut buf = Vec::new();
    write_truth_csv(&mut buf, &scene.truth)
        .with_context(|| format!("writing {}", path.display()))?;
    std::fs::write(path, buf).with_context(|| format!("cannot write {}", path.display()))
}

fn write_toml<T: serde::Serialize>(path: &Path, value: &T) -> anyhow::Result<()> {
    let text = toml::to_string(value).with_context(|| format!("serialising {}", path.display()))?;
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_specs() {
        assert_eq!(parse_field("zero"), Ok(FieldSpec::Zero));
        assert_eq!(
            parse_field("uniform:0.5,-1"),
            Ok(FieldSpec::Uniform { dx: 0.5, dy: -1.0 })
        );
        assert_eq!(
            parse_field("bump:60, 24"),
            Ok(FieldSpec::Bump {
                amplitude: 60.0,
                width: 24.0
            })
        );
        assert_eq!(
            parse_field("vortex:40,10"),
            Ok(FieldSpec::Vortex {
                strength: 40.0,
                core: 10.0
            })
        );
        assert!(parse_field("bump:60").unwrap_err().contains("two numbers"));
        assert!(
            parse_field("uniform:a,1")
                .unwrap_err()
                .contains("`a` is not a number")
        );
        assert!(
            parse_field("swirl:1,2")
                .unwrap_err()
                .contains("unknown field `swirl`")
        );
        assert!(parse_field("zero:1").is_err());
    }
}
