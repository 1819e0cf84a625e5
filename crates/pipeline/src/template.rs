//! The annotated `pipeline.toml` that `bostrack init` writes, generated from the defaults in code.
//!
//! The values come from serialising a [`PipelineConfig`] (so the defaults are written once, in the
//! `Default` impls); the comments come from [`SECTIONS`]. A key that has a value but no entry here
//! is still written (with a "no description" comment) and a test fails until it is described.

use crate::config::PipelineConfig;
use crate::error::ConfigError;
use std::fmt::Write as _;
use std::path::PathBuf;

/// Documentation of one key of a section.
#[derive(Clone, Copy, Debug)]
pub(crate) struct KeyDoc {
    pub key: &'static str,
    /// Comment lines (without `# `), separated by `\n`.
    pub doc: &'static str,
    /// For keys that are absent by default (optional values): a value to show commented out.
    pub example: Option<&'static str>,
}

/// Documentation of one section.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SectionDoc {
    pub name: &'static str,
    pub doc: &'static str,
    pub keys: &'static [KeyDoc],
}

const fn key(key: &'static str, doc: &'static str) -> KeyDoc {
    KeyDoc {
        key,
        doc,
        example: None,
    }
}

const HEADER: &str = "\
bostrack campaign configuration (pipeline.toml).

Written by `bostrack init`: every key is shown with its default value, so a key left out means
exactly what is written here. Unknown keys are errors. Relative paths are resolved against the
folder of this file. Conventions (pixel centres at integer coordinates, x right, y down, lengths
in px, displacement = gradient - reference): docs/CONVENTIONS.md.";

pub(crate) const SECTIONS: &[SectionDoc] = &[
    SectionDoc {
        name: "input",
        doc: "The images of the campaign. Every path in this section is relative to `dir`.",
        keys: &[
            key(
                "dir",
                "Campaign folder, relative to the folder of this file.",
            ),
            key(
                "reference_from",
                "Reference (no-flow) image: \"file\" reads `reference`; \"stack-mean\" uses the\n\
                 pixel-wise mean of the no-flow stack.",
            ),
            key(
                "reference",
                "Reference image file (read when reference_from = \"file\").",
            ),
            key(
                "stack",
                "The no-flow stack as one multi-page TIFF file (one page per image, as many cameras\n\
                 write it); \"\" to read the stack from stack_dir. When set, stack_dir and\n\
                 stack_glob are not used.",
            ),
            key(
                "stack_dir",
                "Folder of the no-flow stack: further images without flow, for the per-dot\n\
                 position noise. \"\" for none.",
            ),
            key(
                "stack_glob",
                "File-name pattern of the stack images (* any characters, ? one character,\n\
                 [a-z] one of a set); files are sorted naturally (im2 before im10).",
            ),
            key(
                "gradient_dir",
                "Folder of the gradient images (the target seen through the flow).",
            ),
            key(
                "gradient_glob",
                "File-name pattern of the gradient images, sorted naturally.",
            ),
            key(
                "mask",
                "Region-of-interest mask image: pixels displaying brighter than the midpoint of its\n\
                 darkest and brightest values are kept ({0,1}, {0,255}, {0,65535}, any photometric tag);\n\
                 \"\" for the whole image.",
            ),
            key(
                "saturation",
                "Clip level of the camera, counts: samples at or above it are left out of the fits\n\
                 and flag their dot \"saturated\". \"auto\" finds it in every image: the TIFF tag\n\
                 MaxSampleValue, else a pile-up of samples at the largest value, else the camera's\n\
                 significant bits (12-bit data in a 16-bit file clip at 4095), else the file's\n\
                 maximum 2^bits - 1; the run record and summary.json say what was found.",
            ),
        ],
    },
    SectionDoc {
        name: "detect",
        doc: "Dot detection on the lattice of the target (bostrack-detect). The lattice is always\n\
              measured from the image; spacing and diameter are only priors.",
        keys: &[
            KeyDoc {
                key: "spacing",
                doc: "Approximate dot spacing (nearest-neighbour distance), px. Left out: estimated.",
                example: Some("8.0"),
            },
            KeyDoc {
                key: "diameter",
                doc: "Approximate dot diameter d = 4 sigma, px; sizes the matched filter. Left out:\n\
                      estimated.",
                example: Some("6.5"),
            },
            key(
                "lattice",
                "\"square\" or \"hexagonal\" (the measured basis angle must agree within 15 degrees).",
            ),
            key(
                "polarity",
                "\"bright\" dots on a dark background, or \"dark\" dots on a bright one.",
            ),
            key(
                "min_snr",
                "A site holds a dot only if its filtered peak exceeds min_snr times the robust noise\n\
                 of the filtered image ...",
            ),
            key(
                "missing_ratio",
                "... and missing_ratio times its neighbours' median peak; otherwise it is \"missing\".",
            ),
            key(
                "faint_ratio",
                "A dot below faint_ratio times its neighbours' median peak is flagged \"faint\".",
            ),
            key(
                "map_degree",
                "Total degree of the polynomial grid-to-image map, 1 (affine) to 4; lowered\n\
                 automatically when too few dots support it.",
            ),
            KeyDoc {
                key: "window_half_width",
                doc: "Half-width of the square fit window, px. Left out:\n\
                      max(2, min(round(spacing / 2), ceil(1.5 d))).",
                example: Some("4"),
            },
            key(
                "search_radius",
                "Tracking into the other images: search radius around a dot's reference position,\n\
                 as a fraction of the spacing, (0, 0.5].",
            ),
        ],
    },
    SectionDoc {
        name: "fit",
        doc: "Per-dot fit of the elliptical Gaussian model (bostrack-fit).",
        keys: &[
            key(
                "model",
                "Free parameters: \"elliptical\" (7), \"axis_aligned\" (rho = 0) or \"circular\"\n\
                 (sigma_x = sigma_y, rho = 0).",
            ),
            key(
                "sampling",
                "\"auto\" (pixel-integrated; dots wider than 1 px evaluated as the pixel-blurred\n\
                 Gaussian, 4x faster and equal to 1e-4 px), \"integrated\" (the model's mean over\n\
                 each pixel, what a camera records, for every dot) or \"point\" (its value at the\n\
                 pixel centre).",
            ),
            key(
                "estimator",
                "\"lsg\" (least-squares Gaussian, all parameters), \"iwc\" (intensity-weighted\n\
                 centroid) or \"tpg\" (three-point Gaussian; rho not estimated).",
            ),
            key(
                "solver",
                "Least-squares solver: \"fast\" (specialised Levenberg-Marquardt) or \"lm_crate\"\n\
                 (the levenberg-marquardt crate).",
            ),
            key(
                "max_iterations",
                "Levenberg-Marquardt iterations, rejected steps included.",
            ),
            key(
                "tolerance",
                "Converged when the next step is below this many standard deviations of the\n\
                 parameters (the step is taken).",
            ),
            key(
                "neighbours",
                "\"subtract\": fit, subtract the fitted neighbours' tails from each window, fit again;\n\
                 \"none\": fit each window as it is.",
            ),
            key(
                "neighbour_passes",
                "With neighbours = \"subtract\": the largest number of neighbour passes (1 to 100).\n\
                 Each pass refits, with its neighbours' latest fits subtracted, every dot not yet\n\
                 converged with its neighbours; the passes stop as soon as every dot has converged.\n\
                 A dot still not converged after the last pass is flagged \"unconverged\".",
            ),
            key(
                "neighbour_tolerance",
                "A dot has converged with its neighbours when their latest changes can move its\n\
                 position by less than this, in units of its position bound (a bound on that move\n\
                 from the change of their models over its window); otherwise it is refitted in\n\
                 the next pass.",
            ),
            key(
                "ghosts",
                "With neighbours = \"subtract\": model the lattice sites just outside the image\n\
                 whose light reaches into it (a dot of the image's median shape at the position\n\
                 extrapolated along the lattice, amplitude and background fitted on its visible\n\
                 part; never reported), so that the windows along the image edge are explained.",
            ),
            key(
                "frame_map",
                "With neighbours = \"subtract\": solve the still part of each gradient frame (dots that,\n\
                 with their neighbours, moved like the whole frame) on the reference's linear coupling\n\
                 map instead of refitting them in every pass: ~20 % less CPU in the real sample's fit\n\
                 stage, the same joint solution. false: the passes alone.",
            ),
            key(
                "residual_false_alarm",
                "False-alarm rate of the per-dot chi-square test of the window's residual against\n\
                 the noise model: a dot above the test's threshold is flagged \"residual\" (an\n\
                 unmodelled neighbour, a defect, a speck: its bound does not describe it). 0: no test.",
            ),
            key(
                "bound",
                "Compute the per-dot Cramer-Rao bound (crlb_x, crlb_y) from the fitted parameters.",
            ),
        ],
    },
    SectionDoc {
        name: "match",
        doc: "Pairing every reference dot with its partner in each gradient image, and validation\n\
              with the normalised median test (Westerweel & Scarano 2005) over the 8 grid\n\
              neighbours: |d - median| / (median residual + epsilon) > threshold flags an outlier.",
        keys: &[
            key(
                "search_radius",
                "Largest distance to the partner, as a fraction of the dot spacing (0, 1].",
            ),
            key(
                "median_epsilon",
                "Median-test epsilon (px): the displacement noise floor.",
            ),
            key("median_threshold", "Median-test threshold (dimensionless)."),
            KeyDoc {
                key: "max_displacement",
                doc: "Displacements longer than this (px) are outliers, before the median test. Left\n\
                      out: no threshold.",
                example: Some("3.0"),
            },
            key(
                "min_matched_fraction",
                "A gradient image in which fewer than this fraction of the fitted reference dots\n\
                 are matched is an error (a wrong or empty image), not a result.",
            ),
            key(
                "keep_flagged",
                "Flags that leave a displacement valid although they make it invalid by default:\n\
                 \"unconverged\" and/or \"residual\" (the flags stay in the flags column; every\n\
                 flag and whether it invalidates: docs/CONVENTIONS.md).",
            ),
        ],
    },
    SectionDoc {
        name: "uncertainty",
        doc: "Per-dot displacement uncertainty: u_d = sqrt(u_refpos^2 + u_grad^2), u_grad = AR * u_ref\n\
              (docs/CONVENTIONS.md; the amplification ratio: docs/theory.md, Eq. 37).",
        keys: &[
            key(
                "common_mode",
                "Remove the common-mode shift of each no-flow stack image (the mean displacement of\n\
                 all its dots: camera or target vibration) before the per-dot scatter is computed.",
            ),
            key(
                "reference_position",
                "Reference dot position: \"image\" (the fit in the reference image) or \"stack-mean\"\n\
                 (the mean over the K stack images; its uncertainty is u_ref / sqrt(K)).",
            ),
            key(
                "ar_variant",
                "Amplification ratio: \"bounds\" (the ratio of the two fits' own Cramer-Rao bounds:\n\
                 right under shot noise too; needs [fit] bound = true), \"notes\" (the closed form\n\
                 of docs/theory.md, Eq. 37, from the fitted shapes: right under read noise alone) or\n\
                 \"published\" (the published reference code, only to reproduce published numbers).",
            ),
        ],
    },
    SectionDoc {
        name: "output",
        doc: "What a run writes.",
        keys: &[
            key("dir", "Output folder, relative to the folder of this file."),
            key(
                "quantities",
                "What is computed per dot, each level including the ones before it: \"displacement\",\n\
                 \"amplification\" (+ amplification ratio AR), \"uncertainty\" (+ u_ref from the\n\
                 no-flow stack, u_grad = AR * u_ref, u_d). Nothing more is computed than asked for:\n\
                 below \"uncertainty\" the stack is not fitted (it still gives the noise model).",
            ),
            key(
                "figures",
                "Figures to draw. Per frame, into DIR/<frame>/: \"displacement\" (arrows over |d|),\n\
                 \"uncertainty\" (map of |u_d|), \"amplification\" (map of max(AR_x, AR_y)),\n\
                 \"histograms\" (|u_ref| and |u_grad|, max(AR_x, AR_y)). Per campaign, into DIR/:\n\
                 \"campaign\" (median |d| and median |u_d| against the frame number),\n\
                 \"detections\" (the reference dots). Only with [optics], per frame: \"density\"\n\
                 (maps of the density rho and of its uncertainty u_rho).",
            ),
            key(
                "figure_formats",
                "File formats of the figures: \"png\" and/or \"svg\".",
            ),
            key(
                "arrays",
                "Lattice arrays per frame: \"npz\" (DIR/<frame>/fields.npz) and/or \"mat\"\n\
                 (fields.mat, MATLAB): every dots.csv quantity as a 2-D array, rows i, columns j,\n\
                 NaN where no dot, with a units record (README, \"Python, numpy and MATLAB\").",
            ),
            key(
                "overwrite",
                "Recompute every frame, even those whose outputs in `dir` are complete, and accept\n\
                 a `dir` written with another configuration (as `bostrack run --force`).\n\
                 Otherwise a rerun skips complete frames and refuses such a `dir`.",
            ),
        ],
    },
    SectionDoc {
        name: "run",
        doc: "How the work is run.",
        keys: &[
            key(
                "jobs",
                "Worker threads; 0 = every CPU available to the process (cgroup quota,\n\
                 SLURM_CPUS_PER_TASK). The command-line option --jobs overrides it.",
            ),
            key(
                "frames_in_flight",
                "Most frames processed at once; their stages share the worker threads. Each\n\
                 holds its image, fit canvas and records (~56 MB for a 1-MP frame), so this\n\
                 bounds the memory of a run. 0 = a third of the worker threads, rounded up,\n\
                 and at least 2 (16 jobs: 6 frames).",
            ),
        ],
    },
];

/// The optional sections (absent by default): name, comment, and the example shown commented
/// out when the section is absent.
const OPTIONAL: &[(&str, &str, &str)] = &[
    (
        "optics",
        "Optional: the optical setup, with the keys and meaning of `bostrack crlb`'s setup file
         (testdata/crlb-setup.toml; keys only the prediction needs are accepted and not used).
         With it, dots.csv gains x_m, y_m, grad_rho_x/y and u_grad_rho_x/y (SI units) and each
         frame a density.csv (the density field and its 1 sigma uncertainty, kg/m^3):
         docs/theory.md, \"From displacements to density\". Required: pixel_pitch_um, and
         magnification or focal_length_mm with target_distance_m (the dot target).",
        "pixel_pitch_um = 6.5
focal_length_mm = 105.0
target_distance_m = 1.5",
    ),
    (
        "geometry",
        "With [optics]: the density field, a slab delta_z_m thick whose middle lies z_d_m in
         front of the dot target (both required).",
        "kind = \"bos\"
z_d_m = 0.5
delta_z_m = 0.05",
    ),
    (
        "constants",
        "With [optics]: Gladstone-Dale constant (m^3/kg) and ambient refractive index [air].",
        "gladstone_dale_m3_kg = 0.000225
n0 = 1.000278",
    ),
    (
        "density",
        "With [optics]: the density field on the dot lattice. method: \"wls\" (weighted by the
         per-dot uncertainties) or \"poisson\"; the density of the quiescent gas and its 1 sigma
         uncertainty hold on the Dirichlet nodes: the outer ring of the valid dots, or the valid
         dots inside reference_mask (a mask image of the quiescent gas, relative to
         [input] dir); Neumann elsewhere, holes included.",
        "method = \"wls\"
reference_density_kg_m3 = 1.204
         reference_density_uncertainty_kg_m3 = 0.0
reference_mask = \"\"",
    ),
    (
        "flow",
        "Accepted (from a `bostrack crlb` setup file) and not used by run.",
        "",
    ),
    ("view", "Accepted and not used by run.", ""),
    ("camera", "Accepted and not used by run.", ""),
];

/// The annotated configuration file for `cfg`: every key with its value and a comment.
///
/// `template(&PipelineConfig::default())` is the file `bostrack init` writes; parsing the result
/// gives `cfg` back.
pub fn template(cfg: &PipelineConfig) -> Result<String, ConfigError> {
    let value = toml::Table::try_from(cfg).map_err(|e| ConfigError::Invalid {
        path: PathBuf::from("<template>"),
        key: "(configuration)".into(),
        message: e.to_string(),
    })?;
    let mut out = String::new();
    comment(&mut out, HEADER);
    let mut seen_sections = Vec::new();
    for section in SECTIONS {
        seen_sections.push(section.name);
        let table = value.get(section.name).and_then(toml::Value::as_table);
        write_section(&mut out, section.name, section.doc, section.keys, table);
    }
    for &(name, doc, example) in OPTIONAL {
        seen_sections.push(name);
        match value.get(name).and_then(toml::Value::as_table) {
            Some(table) => {
                out.push('\n');
                comment(&mut out, doc);
                let _ = writeln!(out, "[{name}]");
                for (k, v) in table {
                    let _ = writeln!(out, "{k} = {v}");
                }
            }
            None if !example.is_empty() => {
                out.push('\n');
                comment(&mut out, doc);
                let _ = writeln!(out, "# [{name}]");
                for line in example.lines() {
                    let _ = writeln!(out, "# {}", line.trim());
                }
            }
            None => {}
        }
    }
    for (name, v) in &value {
        if !seen_sections.contains(&name.as_str()) {
            write_section(&mut out, name, "(no description)", &[], v.as_table());
        }
    }
    Ok(out)
}

fn write_section(
    out: &mut String,
    name: &str,
    doc: &str,
    keys: &[KeyDoc],
    table: Option<&toml::Table>,
) {
    out.push('\n');
    comment(out, doc);
    let _ = writeln!(out, "[{name}]");
    let empty = toml::Table::new();
    let table = table.unwrap_or(&empty);
    let mut written = 0;
    for k in keys {
        match (table.get(k.key), k.example) {
            (Some(v), _) => {
                comment(out, k.doc);
                key_value(out, k.key, v);
            }
            (None, Some(example)) => {
                comment(out, k.doc);
                let _ = writeln!(out, "# {} = {}", k.key, example);
            }
            (None, None) => continue,
        }
        written += 1;
    }
    for (k, v) in table {
        if !keys.iter().any(|d| d.key == k) {
            comment(out, "(no description)");
            let _ = writeln!(out, "{k} = {v}");
            written += 1;
        }
    }
    if written == 0 {
        comment(out, "(no keys yet)");
    }
}

/// `key = value`; an array too long for one line of 100 characters gets one item per line.
fn key_value(out: &mut String, key: &str, v: &toml::Value) {
    let line = format!("{key} = {v}");
    match v.as_array() {
        Some(items) if line.len() > 100 => {
            let _ = writeln!(out, "{key} = [");
            for item in items {
                let _ = writeln!(out, "    {item},");
            }
            out.push_str("]\n");
        }
        _ => {
            let _ = writeln!(out, "{line}");
        }
    }
}

fn comment(out: &mut String, text: &str) {
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() {
            out.push_str("#\n");
        } else {
            let _ = writeln!(out, "# {line}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load::parse_config;
    use std::path::Path;

    #[test]
    fn template_parses_back_to_the_defaults() {
        let text = template(&PipelineConfig::default()).unwrap();
        assert_eq!(
            parse_config(&text, Path::new("t.toml")).unwrap(),
            PipelineConfig::default()
        );
    }

    #[test]
    fn template_round_trips_a_changed_config() {
        let mut cfg = PipelineConfig::with_input_dir("some/where");
        cfg.matching.median_threshold = 3.5;
        cfg.output.figures.clear();
        let text = template(&cfg).unwrap();
        assert!(text.contains("dir = \"some/where\""));
        assert_eq!(parse_config(&text, Path::new("t.toml")).unwrap(), cfg);
    }

    #[test]
    fn every_key_and_section_is_documented() {
        let text = template(&PipelineConfig::default()).unwrap();
        assert!(
            !text.contains("(no description)"),
            "a key lacks a description in SECTIONS:\n{text}"
        );
        let value = toml::Table::try_from(PipelineConfig::default()).unwrap();
        for s in SECTIONS {
            let table = value[s.name].as_table().unwrap();
            for k in s.keys {
                assert!(
                    table.contains_key(k.key) || k.example.is_some(),
                    "[{}] {} is documented but is not a key",
                    s.name,
                    k.key
                );
            }
        }
        assert_eq!(value.len(), SECTIONS.len());
    }

    #[test]
    fn every_line_is_a_comment_a_header_a_key_or_blank() {
        let text = template(&PipelineConfig::default()).unwrap();
        for line in text.lines() {
            let ok = line.is_empty()
                || line.starts_with('#')
                || (line.starts_with('[') && line.ends_with(']'))
                || line.contains(" = ")
                || (line.starts_with("    ") && line.ends_with(','))
                || line == "]";
            assert!(ok, "odd line: {line:?}");
            assert!(line.len() <= 100, "line too long: {line:?}");
        }
    }
}
