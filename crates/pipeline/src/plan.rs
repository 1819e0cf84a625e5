//! The validated plan: the second configuration level, with every path resolved and checked.

use crate::config::{
    ArVariant, ArrayFormat, DetectSection, Figure, FigureFormat, FitSection, MatchConfig,
    PipelineConfig, Quantities, ReferenceFrom, ReferencePosition, UncertaintyConfig,
};
use crate::error::ConfigError;
use crate::files::{PathKind, Want, list_inputs, output_dir_problem};
use crate::jobs::{MAX_JOBS, resolve_jobs};
use crate::load::load_config;
use crate::suggest::did_you_mean;
use bostrack_core::DotFlags;
use std::path::{Path, PathBuf};

/// Where the reference image of a run comes from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ReferenceImage {
    /// This file (checked to exist).
    File(PathBuf),
    /// The pixel-wise mean of [`Plan::stack`] (which is then not empty).
    StackMean,
}

/// The outputs a run writes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OutputPlan {
    /// Output folder (resolved; may not exist yet).
    pub dir: PathBuf,
    /// Figures to draw, without duplicates, in the order written.
    pub figures: Vec<Figure>,
    /// File formats of every figure, without duplicates.
    pub figure_formats: Vec<FigureFormat>,
    /// Lattice array formats, without duplicates.
    pub arrays: Vec<ArrayFormat>,
    pub overwrite: bool,
}

/// A validated campaign: resolved, existing input files in natural order, checked stage
/// configurations, and the number of worker threads.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// The configuration file the plan was built from.
    pub config_file: PathBuf,
    /// The configuration as parsed (for the run record).
    pub config: PipelineConfig,
    pub reference: ReferenceImage,
    /// No-flow stack files (natural order): the files of `input.stack_dir`, or the one
    /// multi-page file `input.stack`; every page of every file is a stack image. Empty when
    /// `input.stack = ""` and `input.stack_dir = ""`.
    pub stack: Vec<PathBuf>,
    /// Gradient images (natural order; at least one).
    pub gradients: Vec<PathBuf>,
    pub mask: Option<PathBuf>,
    pub detect: DetectSection,
    pub fit: FitSection,
    pub matching: MatchConfig,
    /// The flags that make a displacement invalid: the default set without `[match]
    /// keep_flagged` ([`MatchConfig::invalid_if`]).
    pub invalid_if: DotFlags,
    pub uncertainty: UncertaintyConfig,
    pub output: OutputPlan,
    /// The optical setup and density settings (`[optics]` ...); `None`: no densities.
    pub density: Option<crate::density::DensityPlan>,
    /// Worker threads (`run.jobs`, 0 resolved to the available CPUs).
    pub jobs: usize,
    /// Things that do not stop a run but are probably not meant (a pattern that also matches
    /// the reference image, a folder named like a frame), each naming the configuration file,
    /// the key and the file. `bostrack check` and `bostrack run` print them.
    pub warnings: Vec<String>,
}

impl Plan {
    /// Reads, parses and validates a configuration file.
    pub fn load(config_file: &Path) -> Result<Plan, ConfigError> {
        let cfg = load_config(config_file)?;
        Plan::from_config(cfg, config_file)
    }

    /// Validates a parsed configuration; relative paths are resolved against the folder of
    /// `config_file` (which is not read).
    pub fn from_config(cfg: PipelineConfig, config_file: &Path) -> Result<Plan, ConfigError> {
        let mut v = Validator {
            file: config_file,
            warnings: Vec::new(),
        };
        v.check_values(&cfg)?;
        let invalid_if = v.invalid_if(&cfg.matching)?;

        let base = config_file.parent().unwrap_or(Path::new(""));
        let input_dir = base.join(&cfg.input.dir);
        v.require_dir("input.dir", &input_dir)?;

        let stack = if !cfg.input.stack.as_os_str().is_empty() {
            let p = input_dir.join(&cfg.input.stack);
            v.require_file("input.stack", &p)?;
            vec![p]
        } else if cfg.input.stack_dir.as_os_str().is_empty() {
            Vec::new()
        } else {
            v.list(
                "input.stack_dir",
                "input.stack_glob",
                &input_dir.join(&cfg.input.stack_dir),
                &cfg.input.stack_glob,
            )?
        };
        if stack.len() > MAX_STACK_FILES {
            return Err(v.invalid(
                "input.stack_glob",
                format!(
                    "matches {} files; a stack may have at most {MAX_STACK_FILES}",
                    stack.len()
                ),
            ));
        }
        let gradients = v.list(
            "input.gradient_dir",
            "input.gradient_glob",
            &input_dir.join(&cfg.input.gradient_dir),
            &cfg.input.gradient_glob,
        )?;

        let reference = match cfg.input.reference_from {
            ReferenceFrom::File => {
                let p = input_dir.join(&cfg.input.reference);
                v.require_file("input.reference", &p)?;
                ReferenceImage::File(p)
            }
            ReferenceFrom::StackMean => {
                if stack.is_empty() {
                    return Err(v.invalid(
                        "input.reference_from",
                        "\"stack-mean\" needs a no-flow stack (input.stack and input.stack_dir are \"\")",
                    ));
                }
                ReferenceImage::StackMean
            }
        };
        if cfg.uncertainty.reference_position == ReferencePosition::StackMean && stack.is_empty() {
            return Err(v.invalid(
                "uncertainty.reference_position",
                "\"stack-mean\" needs a no-flow stack (input.stack and input.stack_dir are \"\"); use \"image\"",
            ));
        }

        let mask = if cfg.input.mask.as_os_str().is_empty() {
            None
        } else {
            let p = input_dir.join(&cfg.input.mask);
            v.require_file("input.mask", &p)?;
            Some(p)
        };

        v.warn_overlaps(&reference, mask.as_deref(), &stack, &gradients, &cfg);

        let mut density = crate::density::plan(&cfg).map_err(|(key, m)| v.invalid(&key, m))?;
        if let Some(d) = density.as_mut()
            && let Some(m) = d.reference_mask.as_mut()
        {
            *m = input_dir.join(&*m);
            v.require_file("density.reference_mask", m)?;
        }

        let out_dir = base.join(&cfg.output.dir);
        if let Some(problem) = output_dir_problem(&out_dir) {
            return Err(v.bad_path("output.dir", &out_dir, problem));
        }
        let output = OutputPlan {
            dir: out_dir,
            // the density maps only with an optical setup
            figures: (cfg.output.figures.iter().copied())
                .filter(|f| density.is_some() || *f != Figure::Density)
                .collect(),
            figure_formats: cfg.output.figure_formats.clone(),
            arrays: cfg.output.arrays.clone(),
            overwrite: cfg.output.overwrite,
        };

        Ok(Plan {
            config_file: config_file.to_path_buf(),
            reference,
            stack,
            gradients,
            mask,
            detect: cfg.detect.clone(),
            fit: cfg.fit.clone(),
            matching: cfg.matching.clone(),
            invalid_if,
            uncertainty: cfg.uncertainty.clone(),
            output,
            density,
            jobs: resolve_jobs(cfg.run.jobs),
            config: cfg,
            warnings: v.warnings,
        })
    }
}

/// Most no-flow stack files a plan accepts (every stack image is held in memory).
pub const MAX_STACK_FILES: usize = 1000;

/// Most iterations per fit `[fit] max_iterations` may ask for ([`bostrack_fit::MAX_ITERATIONS`]).
pub const MAX_FIT_ITERATIONS: u32 = bostrack_fit::MAX_ITERATIONS;

struct Validator<'a> {
    file: &'a Path,
    warnings: Vec<String>,
}

impl Validator<'_> {
    fn invalid(&self, key: &str, message: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            path: self.file.to_path_buf(),
            key: key.into(),
            message: message.into(),
        }
    }

    fn not_found(&self, key: &str, file: &Path) -> ConfigError {
        ConfigError::NotFound {
            path: self.file.to_path_buf(),
            key: key.into(),
            file: file.to_path_buf(),
        }
    }

    fn bad_path(&self, key: &str, file: &Path, problem: String) -> ConfigError {
        ConfigError::BadPath {
            path: self.file.to_path_buf(),
            key: key.into(),
            file: file.to_path_buf(),
            problem,
        }
    }

    /// Warns about a stack or gradient pattern that also matches the reference image, the mask
    /// or (gradients) a no-flow image: such a file would be processed as a frame of the other
    /// kind.
    fn warn_overlaps(
        &mut self,
        reference: &ReferenceImage,
        mask: Option<&Path>,
        stack: &[PathBuf],
        gradients: &[PathBuf],
        cfg: &PipelineConfig,
    ) {
        let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
            (Ok(a), Ok(b)) => a == b,
            _ => a == b,
        };
        let mut others: Vec<(&str, &Path)> = Vec::new();
        if let ReferenceImage::File(p) = reference {
            others.push(("the reference image", p));
        }
        if let Some(m) = mask {
            others.push(("the mask", m));
        }
        let lists = [
            (
                "input.stack_glob",
                &cfg.input.stack_glob,
                stack,
                "no-flow image",
            ),
            (
                "input.gradient_glob",
                &cfg.input.gradient_glob,
                gradients,
                "gradient frame",
            ),
        ];
        for (key, glob, list, kind) in lists {
            for p in list {
                let hit = others.iter().find(|(_, o)| same(p, o)).map(|(w, _)| *w);
                let hit = hit.or_else(|| {
                    (kind == "gradient frame" && stack.iter().any(|s| same(p, s)))
                        .then_some("a no-flow stack image")
                });
                if let Some(what) = hit {
                    self.warnings.push(format!(
                        "{}: {key}: `{glob}` also matches {what} {}, which will be processed \
                         as a {kind} too; narrow the pattern or move the file",
                        self.file.display(),
                        p.display()
                    ));
                }
            }
        }
    }

    fn check_values(&self, cfg: &PipelineConfig) -> Result<(), ConfigError> {
        if let Err(e) = cfg.detect.validate() {
            let key = match &e {
                bostrack_detect::DetectError::InvalidConfig { field, .. } => {
                    format!("detect.{field}")
                }
                _ => "detect".into(),
            };
            return Err(self.invalid(&key, e.to_string()));
        }
        // every value that scales the work is bounded (the [fit] bounds are in
        // FitConfig::validate; this one named with its key)
        if cfg.fit.max_iterations > MAX_FIT_ITERATIONS {
            return Err(self.invalid(
                "fit.max_iterations",
                format!(
                    "must be 1 to {MAX_FIT_ITERATIONS}, got {}",
                    cfg.fit.max_iterations
                ),
            ));
        }
        cfg.fit
            .validate()
            .map_err(|e| self.invalid("fit", e.to_string()))?;
        for (key, value, zero) in [
            ("run.jobs", cfg.run.jobs, "every available CPU"),
            (
                "run.frames_in_flight",
                cfg.run.frames_in_flight,
                "automatic",
            ),
        ] {
            if value > MAX_JOBS {
                return Err(self.invalid(
                    key,
                    format!("must be 0 ({zero}) to {MAX_JOBS}, got {value}"),
                ));
            }
        }
        if cfg.uncertainty.ar_variant == ArVariant::Bounds
            && !cfg.fit.bound
            && cfg.output.quantities >= Quantities::Amplification
        {
            return Err(self.invalid(
                "uncertainty.ar_variant",
                "\"bounds\" (the default) takes the amplification ratio from the fits' \
                 Cramer-Rao bounds, but [fit] bound = false: set [fit] bound = true, or choose \
                 [uncertainty] ar_variant = \"notes\" (the closed form from the fitted shapes)",
            ));
        }
        let m = &cfg.matching;
        if !(m.search_radius > 0.0 && m.search_radius <= 1.0) {
            return Err(self.invalid(
                "match.search_radius",
                format!("{} is not in (0, 1]", m.search_radius),
            ));
        }
        if !(m.median_epsilon.is_finite() && m.median_epsilon >= 0.0) {
            return Err(self.invalid(
                "match.median_epsilon",
                format!("{} is not a finite value >= 0", m.median_epsilon),
            ));
        }
        if !(m.median_threshold.is_finite() && m.median_threshold > 0.0) {
            return Err(self.invalid(
                "match.median_threshold",
                format!("{} is not a finite value > 0", m.median_threshold),
            ));
        }
        if !(0.0..=1.0).contains(&m.min_matched_fraction) {
            return Err(self.invalid(
                "match.min_matched_fraction",
                format!("{} is not in [0, 1]", m.min_matched_fraction),
            ));
        }
        if let Some(t) = m.max_displacement
            && !(t.is_finite() && t > 0.0)
        {
            return Err(self.invalid(
                "match.max_displacement",
                format!("{t} is not a finite value > 0"),
            ));
        }
        for (key, glob) in [
            ("input.stack_glob", &cfg.input.stack_glob),
            ("input.gradient_glob", &cfg.input.gradient_glob),
        ] {
            if glob.is_empty() || glob.contains(['/', '\\']) {
                return Err(self.invalid(key, format!("`{glob}` is not a file-name pattern (no folders; put those in the _dir key)")));
            }
        }
        let figs = &cfg.output.figures;
        for (k, f) in figs.iter().enumerate() {
            if figs[..k].contains(f) {
                return Err(self.invalid(
                    "output.figures",
                    format!("\"{}\" is listed twice", f.name()),
                ));
            }
        }
        let formats = &cfg.output.figure_formats;
        for (k, f) in formats.iter().enumerate() {
            if formats[..k].contains(f) {
                return Err(self.invalid(
                    "output.figure_formats",
                    format!("\"{}\" is listed twice", f.extension()),
                ));
            }
        }
        let arrays = &cfg.output.arrays;
        if let Some(k) = (1..arrays.len()).find(|&k| arrays[..k].contains(&arrays[k])) {
            return Err(self.invalid(
                "output.arrays",
                format!("\"{}\" is listed twice", arrays[k].file_name()),
            ));
        }
        if formats.is_empty() && !figs.is_empty() {
            return Err(self.invalid(
                "output.figure_formats",
                "is empty but figures are requested (use [\"png\"], or figures = [])",
            ));
        }
        Ok(())
    }

    /// `[match] keep_flagged`: only the names of [`MatchConfig::KEEPABLE`], each once.
    fn invalid_if(&self, m: &MatchConfig) -> Result<DotFlags, ConfigError> {
        const KEY: &str = "match.keep_flagged";
        let valid: Vec<String> = MatchConfig::KEEPABLE.map(|f| f.to_string()).into();
        let candidates: Vec<&str> = valid.iter().map(String::as_str).collect();
        for (k, name) in m.keep_flagged.iter().enumerate() {
            if m.keep_flagged[..k].contains(name) {
                return Err(self.invalid(KEY, format!("\"{name}\" is listed twice")));
            }
        }
        m.invalid_if().map_err(|name| {
            let what = if DotFlags::parse(&name).is_ok_and(|f| !f.is_empty()) {
                "cannot be kept valid"
            } else {
                "is not a flag that can be kept valid"
            };
            let hint = did_you_mean(&name, &candidates)
                .map(|s| format!("did you mean \"{s}\"? "))
                .unwrap_or_default();
            self.invalid(
                KEY,
                format!(
                    "\"{name}\" {what} ({hint}valid names: {})",
                    valid.join(", ")
                ),
            )
        })
    }

    fn require_file(&self, key: &str, p: &Path) -> Result<(), ConfigError> {
        self.require(key, p, Want::File)
    }

    fn require_dir(&self, key: &str, p: &Path) -> Result<(), ConfigError> {
        self.require(key, p, Want::Dir)
    }

    /// `p` is a `want`: else "not found" when nothing is there, or what it is instead.
    fn require(&self, key: &str, p: &Path, want: Want) -> Result<(), ConfigError> {
        let kind = PathKind::of(p);
        if let PathKind::Missing = kind {
            return Err(self.not_found(key, p));
        }
        match kind.problem(want) {
            None => Ok(()),
            Some(problem) => Err(self.bad_path(key, p, problem)),
        }
    }

    /// The files of `dir` matching `glob`: folders that match are skipped with a warning, and
    /// a match that is neither a file nor a folder (a broken link, a link loop) is an error.
    fn list(
        &mut self,
        dir_key: &str,
        glob_key: &str,
        dir: &Path,
        glob: &str,
    ) -> Result<Vec<PathBuf>, ConfigError> {
        self.require_dir(dir_key, dir)?;
        let listing = list_inputs(dir, glob).map_err(|source| ConfigError::ListDir {
            path: self.file.to_path_buf(),
            key: dir_key.into(),
            dir: dir.to_path_buf(),
            source,
        })?;
        if let Some((p, problem)) = listing.unusable.into_iter().next() {
            return Err(self.bad_path(
                glob_key,
                &p,
                format!(
                    "matches `{glob}` but {problem}; repair or remove it, or narrow {glob_key}"
                ),
            ));
        }
        for p in &listing.folders {
            self.warnings.push(format!(
                "{}: {glob_key}: `{glob}` matches the folder {}, which is skipped (only files are \
                 inputs)",
                self.file.display(),
                p.display()
            ));
        }
        let files = listing.files;
        if files.is_empty() {
            return Err(ConfigError::NoMatch {
                path: self.file.to_path_buf(),
                key: glob_key.into(),
                dir: dir.to_path_buf(),
                pattern: glob.into(),
            });
        }
        Ok(files)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load::parse_config;
    use std::fs;

    /// A campaign folder `camp/` beside `cfg/pipeline.toml`, with frames named to need natural order.
    fn campaign() -> tempfile::TempDir {
        let root = tempfile::tempdir().unwrap();
        let camp = root.path().join("camp");
        fs::create_dir_all(camp.join("stack")).unwrap();
        fs::create_dir_all(camp.join("grad")).unwrap();
        fs::create_dir_all(root.path().join("cfg")).unwrap();
        fs::write(camp.join("reference.tif"), b"x").unwrap();
        fs::write(camp.join("mask.png"), b"x").unwrap();
        for k in [1, 2, 3] {
            fs::write(camp.join(format!("stack/s{k}.tif")), b"x").unwrap();
        }
        for k in [10, 9, 1, 2] {
            fs::write(camp.join(format!("grad/frame{k}.tif")), b"x").unwrap();
        }
        fs::write(camp.join("grad/readme.txt"), b"x").unwrap();
        root
    }

    fn plan(root: &Path, text: &str) -> Result<Plan, ConfigError> {
        let file = root.join("cfg/pipeline.toml");
        fs::write(&file, text).unwrap();
        Plan::load(&file)
    }

    /// The file names of a plan's gradient frames, in order.
    fn frame_names(p: &Plan) -> Vec<&str> {
        p.gradients
            .iter()
            .map(|g| g.file_name().unwrap().to_str().unwrap())
            .collect()
    }

    const BASE: &str = "[input]\ndir = \"../camp\"\ngradient_dir = \"grad\"\n";

    #[test]
    fn resolves_relative_to_the_config_file_and_sorts_naturally() {
        let root = campaign();
        let p = plan(
            root.path(),
            &format!("{BASE}mask = \"mask.png\"\n[run]\njobs = 3\n"),
        )
        .unwrap();
        let camp = root.path().join("cfg/../camp");
        assert_eq!(
            p.reference,
            ReferenceImage::File(camp.join("reference.tif"))
        );
        let names = frame_names(&p);
        assert_eq!(
            names,
            ["frame1.tif", "frame2.tif", "frame9.tif", "frame10.tif"]
        );
        assert_eq!(p.stack.len(), 3);
        assert_eq!(p.mask, Some(camp.join("mask.png")));
        assert_eq!(p.output.dir, root.path().join("cfg/out"));
        assert_eq!(p.jobs, 3);
        assert_eq!(p.matching, MatchConfig::default());
    }

    #[test]
    fn every_value_that_scales_the_work_is_bounded() {
        let root = campaign();
        for (text, key, says) in [
            (
                "[fit]\nmax_iterations = 1001\n",
                "fit.max_iterations",
                "1 to 1000",
            ),
            ("[fit]\nneighbour_passes = 1000000\n", "fit", "1..=100"),
            (
                "[run]\njobs = 5000\n",
                "run.jobs",
                "0 (every available CPU) to 1024",
            ),
            (
                "[run]\nframes_in_flight = 5000\n",
                "run.frames_in_flight",
                "0 (automatic) to 1024",
            ),
            (
                "[detect]\nspacing = 0.001\n",
                "detect.spacing",
                "[2, 1024] px",
            ),
            (
                "[detect]\ndiameter = 1e9\n",
                "detect.diameter",
                "[0.5, 256] px",
            ),
            (
                "[detect]\nwindow_half_width = 100000\n",
                "detect.window_half_width",
                "1 to 256",
            ),
        ] {
            let e = plan(root.path(), &format!("{BASE}{text}")).unwrap_err();
            match &e {
                ConfigError::Invalid {
                    key: k, message, ..
                } => {
                    assert_eq!(k, key, "{e}");
                    assert!(message.contains(says), "{e}");
                }
                other => panic!("{text}: {other:?}"),
            }
        }
        // the limits themselves are accepted
        let ok = "[fit]\nmax_iterations = 1000\n[run]\njobs = 1024\n[detect]\nspacing = 1024.0\n";
        assert!(plan(root.path(), &format!("{BASE}{ok}")).is_ok());
        // a stack folder of more than MAX_STACK_FILES files
        let many = root.path().join("camp/many");
        fs::create_dir_all(&many).unwrap();
        for k in 0..=MAX_STACK_FILES {
            fs::write(many.join(format!("s{k}.tif")), b"x").unwrap();
        }
        let e = plan(root.path(), &format!("{BASE}stack_dir = \"many\"\n")).unwrap_err();
        assert!(
            e.to_string()
                .contains("matches 1001 files; a stack may have at most 1000"),
            "{e}"
        );
    }

    #[test]
    fn missing_files_are_named() {
        let root = campaign();
        let e = plan(root.path(), &format!("{BASE}reference = \"nope.tif\"\n")).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("pipeline.toml: input.reference:") && msg.contains("nope.tif not found"),
            "{msg}"
        );

        let e = plan(root.path(), &format!("{BASE}gradient_glob = \"*.png\"\n")).unwrap_err();
        assert!(
            matches!(&e, ConfigError::NoMatch { key, .. } if key == "input.gradient_glob"),
            "{e}"
        );

        let e = plan(root.path(), "[input]\ndir = \"../elsewhere\"\n").unwrap_err();
        assert!(
            matches!(&e, ConfigError::NotFound { key, .. } if key == "input.dir"),
            "{e}"
        );
    }

    /// The `ConfigError::BadPath` of `key` that `extra` after [`BASE`] gives: (file, problem).
    fn bad_path(root: &Path, extra: &str, key: &str) -> (PathBuf, String) {
        match plan(root, &format!("{BASE}{extra}")) {
            Err(ConfigError::BadPath {
                key: k,
                file,
                problem,
                ..
            }) if k == key => (file, problem),
            other => panic!("{extra}: not a bad path for {key}: {other:?}"),
        }
    }

    #[test]
    fn folders_files_and_link_loops_are_not_reported_as_missing() {
        let root = campaign();
        let camp = root.path().join("camp");
        // A folder where a file is needed, a file where a folder is needed.
        fs::create_dir(camp.join("ref.tif")).unwrap();
        let (file, problem) = bad_path(root.path(), "reference = \"ref.tif\"\n", "input.reference");
        assert!(
            file.ends_with("ref.tif") && problem == "is a folder, not a file",
            "{problem}"
        );
        let (_, problem) = bad_path(root.path(), "mask = \"grad\"\n", "input.mask");
        assert_eq!(problem, "is a folder, not a file");
        let (_, problem) = bad_path(root.path(), "stack_dir = \"mask.png\"\n", "input.stack_dir");
        assert_eq!(problem, "is a file, not a folder");
        let e = plan(root.path(), &format!("{BASE}reference = \"ref.tif\"\n")).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("pipeline.toml: input.reference: ")
                && msg.contains("ref.tif: is a folder, not a file")
                && !msg.contains("not found"),
            "{msg}"
        );

        // An output folder that is a file, or lies under one.
        let (file, problem) = bad_path(
            root.path(),
            "[output]\ndir = \"../camp/mask.png\"\n",
            "output.dir",
        );
        assert!(
            file.ends_with("mask.png") && problem == "is a file, not a folder",
            "{problem}"
        );
        bad_path(
            root.path(),
            "[output]\ndir = \"../camp/mask.png/out\"\n",
            "output.dir",
        );
        plan(root.path(), &format!("{BASE}[output]\ndir = \"new/out\"\n")).unwrap();

        #[cfg(unix)]
        {
            use std::os::unix::fs::symlink;
            symlink("loop.tif", camp.join("loop.tif")).unwrap();
            let (_, problem) =
                bad_path(root.path(), "reference = \"loop.tif\"\n", "input.reference");
            assert!(problem.starts_with("cannot be examined: "), "{problem}");
            symlink("gone.tif", camp.join("dangling.tif")).unwrap();
            let (_, problem) = bad_path(
                root.path(),
                "reference = \"dangling.tif\"\n",
                "input.reference",
            );
            assert_eq!(problem, "is a symbolic link whose target does not exist");
            symlink("frame11.tif", camp.join("grad/frame11.tif")).unwrap();
            let (file, problem) = bad_path(root.path(), "", "input.gradient_glob");
            assert!(file.ends_with("grad/frame11.tif"), "{}", file.display());
            assert!(
                problem.starts_with("matches `*.tif` but cannot be examined: ")
                    && problem.ends_with("narrow input.gradient_glob"),
                "{problem}"
            );
            fs::remove_file(camp.join("grad/frame11.tif")).unwrap();
            let (_, problem) = bad_path(
                root.path(),
                "[output]\ndir = \"../camp/loop.tif\"\n",
                "output.dir",
            );
            assert!(problem.starts_with("cannot be examined: "), "{problem}");
        }
    }

    #[test]
    fn overlapping_patterns_and_matching_folders_are_warned_about() {
        let root = campaign();
        let camp = root.path().join("camp");
        let p = plan(root.path(), BASE).unwrap();
        assert!(p.warnings.is_empty(), "{:?}", p.warnings);
        // The reference and the mask beside the frames, a folder named like a frame.
        fs::copy(camp.join("reference.tif"), camp.join("grad/reference.tif")).unwrap();
        fs::create_dir(camp.join("grad/frame0.tif")).unwrap();
        let text = format!(
            "{BASE}reference = \"grad/reference.tif\"\nmask = \"grad/readme.txt\"\n\
             gradient_glob = \"*\"\n"
        );
        let p = plan(root.path(), &text).unwrap();
        let names = frame_names(&p);
        assert_eq!(
            names,
            [
                "frame1.tif",
                "frame2.tif",
                "frame9.tif",
                "frame10.tif",
                "readme.txt",
                "reference.tif"
            ],
            "warned, not changed"
        );
        assert_eq!(p.warnings.len(), 3, "{:#?}", p.warnings);
        let has = |parts: &[&str]| {
            p.warnings
                .iter()
                .any(|w| parts.iter().all(|x| w.contains(x)))
        };
        assert!(
            has(&[
                "pipeline.toml: input.gradient_glob: `*` also matches the reference image",
                "grad/reference.tif",
                "as a gradient frame"
            ]),
            "{:#?}",
            p.warnings
        );
        assert!(
            has(&["also matches the mask", "readme.txt"]),
            "{:#?}",
            p.warnings
        );
        assert!(
            has(&["matches the folder", "frame0.tif", "skipped"]),
            "{:#?}",
            p.warnings
        );
        // A stack pattern that takes in the reference.
        fs::remove_dir(camp.join("grad/frame0.tif")).unwrap();
        let text = format!("{BASE}reference = \"stack/s1.tif\"\n");
        let p = plan(root.path(), &text).unwrap();
        assert_eq!(p.warnings.len(), 1, "{:#?}", p.warnings);
        assert!(
            p.warnings[0].contains("input.stack_glob") && p.warnings[0].contains("no-flow image"),
            "{}",
            p.warnings[0]
        );
    }

    #[test]
    fn stack_mean_needs_a_stack() {
        let root = campaign();
        let text = format!("{BASE}stack_dir = \"\"\nreference_from = \"stack-mean\"\n");
        let e = plan(root.path(), &text).unwrap_err();
        assert!(
            matches!(&e, ConfigError::Invalid { key, .. } if key == "input.reference_from"),
            "{e}"
        );

        let text =
            format!("{BASE}stack_dir = \"\"\n[uncertainty]\nreference_position = \"stack-mean\"\n");
        let e = plan(root.path(), &text).unwrap_err();
        assert!(
            matches!(&e, ConfigError::Invalid { key, .. } if key == "uncertainty.reference_position"),
            "{e}"
        );

        let text = format!("{BASE}stack_dir = \"\"\n");
        let p = plan(root.path(), &text).unwrap();
        assert!(p.stack.is_empty());

        let text = format!("{BASE}reference_from = \"stack-mean\"\nreference = \"absent.tif\"\n");
        assert_eq!(
            plan(root.path(), &text).unwrap().reference,
            ReferenceImage::StackMean
        );
    }

    #[test]
    fn values_out_of_range_are_rejected() {
        let root = campaign();
        for (extra, key) in [
            ("[match]\nsearch_radius = 0.0\n", "match.search_radius"),
            ("[match]\nsearch_radius = 1.5\n", "match.search_radius"),
            ("[match]\nmedian_epsilon = -0.1\n", "match.median_epsilon"),
            (
                "[match]\nmedian_threshold = nan\n",
                "match.median_threshold",
            ),
            (
                "[output]\nfigures = [\"uncertainty\", \"uncertainty\"]\n",
                "output.figures",
            ),
            (
                "[output]\nfigure_formats = [\"svg\", \"svg\"]\n",
                "output.figure_formats",
            ),
            ("[output]\nfigure_formats = []\n", "output.figure_formats"),
            ("[detect]\nmin_snr = -1.0\n", "detect.min_snr"),
            ("[fit]\nmax_iterations = 0\n", "fit"),
            (
                "[fit]\nbound = false\n[uncertainty]\nar_variant = \"bounds\"\n",
                "uncertainty.ar_variant",
            ),
            (
                "[match]\nmax_displacement = -1.0\n",
                "match.max_displacement",
            ),
            (
                "[match]\nmin_matched_fraction = 1.5\n",
                "match.min_matched_fraction",
            ),
        ] {
            let e = plan(root.path(), &format!("{BASE}{extra}")).unwrap_err();
            assert!(
                matches!(&e, ConfigError::Invalid { key: k, .. } if k == key),
                "{extra}: {e}"
            );
        }
        let e = plan(
            root.path(),
            "[input]\ndir = \"../camp\"\ngradient_glob = \"grad/*.tif\"\n",
        )
        .unwrap_err();
        assert!(
            matches!(&e, ConfigError::Invalid { key, .. } if key == "input.gradient_glob"),
            "{e}"
        );
    }

    /// The message of the `ConfigError::Invalid` of `key` that `extra` after [`BASE`] gives.
    fn invalid_message(root: &Path, extra: &str, key: &str) -> String {
        match plan(root, &format!("{BASE}{extra}")) {
            Err(ConfigError::Invalid {
                key: k, message, ..
            }) if k == key => message,
            other => panic!("{extra}: not an invalid {key}: {other:?}"),
        }
    }

    #[test]
    fn default_bounds_ar_needs_the_fit_bound() {
        let root = campaign();
        // the default ar_variant ("bounds") with the bound switched off: both keys and the
        // ways out are named
        let key = "uncertainty.ar_variant";
        let msg = invalid_message(root.path(), "[fit]\nbound = false\n", key);
        for part in [
            "\"bounds\" (the default)",
            "[fit] bound = false",
            "set [fit] bound = true",
            "ar_variant = \"notes\"",
        ] {
            assert!(msg.contains(part), "{part}: {msg}");
        }
        let amplification = "[fit]\nbound = false\n[output]\nquantities = \"amplification\"\n";
        invalid_message(root.path(), amplification, key);
        // either way out works; without an amplification ratio the bound is not needed
        for extra in [
            "[fit]\nbound = false\n[uncertainty]\nar_variant = \"notes\"\n",
            "[fit]\nbound = false\n[uncertainty]\nar_variant = \"published\"\n",
            "[fit]\nbound = true\n",
            "[fit]\nbound = false\n[output]\nquantities = \"displacement\"\n",
        ] {
            if let Err(e) = plan(root.path(), &format!("{BASE}{extra}")) {
                panic!("{extra}: {e}");
            }
        }
    }

    #[test]
    fn keep_flagged_takes_unconverged_and_residual_out_of_invalid_if() {
        let root = campaign();
        let default = bostrack_displacement::DisplacementConfig::DEFAULT_INVALID_IF;
        assert!(default.contains(DotFlags::UNCONVERGED | DotFlags::RESIDUAL));
        let invalid_if = |names: &str| {
            let extra = format!("[match]\nkeep_flagged = [{names}]\n");
            plan(root.path(), &format!("{BASE}{extra}"))
                .unwrap()
                .invalid_if
        };
        assert_eq!(plan(root.path(), BASE).unwrap().invalid_if, default);
        assert_eq!(invalid_if(""), default);
        let p = invalid_if("\"residual\"");
        assert!(p.contains(DotFlags::UNCONVERGED) && !p.intersects(DotFlags::RESIDUAL));
        let mut want = default;
        want.remove(DotFlags::UNCONVERGED | DotFlags::RESIDUAL);
        assert_eq!(invalid_if("\"residual\", \"unconverged\""), want);
        assert!(want.contains(DotFlags::OUTLIER | DotFlags::UNMATCHED));

        for (names, says) in [
            ("\"outlier\"", "\"outlier\" cannot be kept valid"),
            ("\"residuals\"", "did you mean \"residual\"?"),
            (
                "\"bogus\"",
                "\"bogus\" is not a flag that can be kept valid",
            ),
            ("\"residual\", \"residual\"", "\"residual\" is listed twice"),
        ] {
            let extra = format!("[match]\nkeep_flagged = [{names}]\n");
            let msg = invalid_message(root.path(), &extra, "match.keep_flagged");
            assert!(msg.contains(says), "{says}: {msg}");
            if !says.contains("twice") {
                assert!(msg.contains("valid names: unconverged, residual"), "{msg}");
            }
        }
    }

    #[test]
    fn absolute_paths_stay_absolute() {
        let root = campaign();
        let camp = root.path().join("camp");
        let text = format!(
            "[input]\ndir = {:?}\ngradient_dir = \"grad\"\n",
            camp.to_str().unwrap()
        );
        let cfg = parse_config(&text, Path::new("x.toml")).unwrap();
        let p = Plan::from_config(cfg, Path::new("/nonexistent/x.toml")).unwrap();
        assert_eq!(
            p.reference,
            ReferenceImage::File(camp.join("reference.tif"))
        );
    }
}
