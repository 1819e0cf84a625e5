//! The run record: `DIR/run.toml` (a whole run, or one rebuilt by `merge`) and
//! `DIR/shards/shard-K-of-N.toml` (one shard): version, inputs and the fully resolved
//! configuration, so every output folder says what produced it.

use super::fsx::{read, write_atomic};
use super::inputs::Fingerprint;
use super::{BatchError, Shard};
use crate::config::{Figure, FigureFormat, PipelineConfig};
use crate::files::natural_cmp;
use crate::plan::{Plan, ReferenceImage};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Record file of a whole run.
pub(crate) const RUN_RECORD: &str = "run.toml";
/// Folder of the shard records.
pub(crate) const SHARDS_DIR: &str = "shards";

/// The sections of `config` that decide the per-frame results: outputs computed under one
/// record are reused by a run under another only when these, `output.quantities` and the
/// reference, stack and mask files agree.
const RESULT_SECTIONS: [&str; 5] = ["input", "detect", "fit", "match", "uncertainty"];

/// `K` and `N` of a shard record.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct ShardRecord {
    pub index: usize,
    pub count: usize,
}

/// The files of a run, resolved (absolute where they could be canonicalised).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct Inputs {
    /// The configuration file.
    pub config_file: PathBuf,
    /// `"file"` or `"stack-mean"`.
    pub reference_from: String,
    /// The reference image (with `reference_from = "file"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask: Option<PathBuf>,
    /// No-flow stack images, natural order.
    pub stack: Vec<PathBuf>,
    /// Gradient frames, natural order (frame 1 first).
    pub gradients: Vec<PathBuf>,
    /// Size, modification time and content hash of the reference image, the mask and the
    /// no-flow images, in that order: every frame's results depend on them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub reference_side: Vec<Fingerprint>,
    /// The same of the gradient frames of the run (of a shard: its own), natural order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frames: Vec<Fingerprint>,
}

/// Size of the images (px).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct ImageSize {
    pub width: usize,
    pub height: usize,
}

/// One run record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct RunRecord {
    /// `bostrack` version that wrote it.
    pub bostrack_version: String,
    /// `"run"`, `"shard"` or `"merge"`.
    pub kind: String,
    /// Worker threads of the run (0 for a merge).
    pub jobs: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<ShardRecord>,
    /// The shard records a merge was built from (file names under `shards/`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub merged_from: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<ImageSize>,
    pub inputs: Inputs,
    /// The whole configuration with every default filled in and `output.dir` the folder
    /// actually written.
    pub config: toml::Table,
    /// Reference-side facts of the run (dots found, noise model, stack), when it computed them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<toml::Table>,
}

/// `p` made absolute (symbolic links resolved) when it exists, else as given.
pub(crate) fn canonical(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf())
}

impl RunRecord {
    /// The record of a run of `plan` writing into `out_dir`.
    pub fn new(
        plan: &Plan,
        out_dir: &Path,
        shard: Option<Shard>,
        jobs: usize,
    ) -> Result<RunRecord, BatchError> {
        let mut cfg: PipelineConfig = plan.config.clone();
        cfg.output.dir = canonical(out_dir);
        cfg.run.jobs = jobs;
        let config = toml::Table::try_from(&cfg).map_err(|e| BatchError::Corrupt {
            path: plan.config_file.clone(),
            message: format!("cannot record the configuration: {e}"),
        })?;
        let (reference_from, reference) = match &plan.reference {
            ReferenceImage::File(p) => ("file", Some(canonical(p))),
            ReferenceImage::StackMean => ("stack-mean", None),
        };
        Ok(RunRecord {
            bostrack_version: env!("CARGO_PKG_VERSION").to_string(),
            kind: if shard.is_some() { "shard" } else { "run" }.to_string(),
            jobs,
            shard: shard.map(|s| ShardRecord {
                index: s.index(),
                count: s.count(),
            }),
            merged_from: Vec::new(),
            image: None,
            inputs: Inputs {
                config_file: canonical(&plan.config_file),
                reference_from: reference_from.to_string(),
                reference,
                mask: plan.mask.as_deref().map(canonical),
                stack: plan.stack.iter().map(|p| canonical(p)).collect(),
                gradients: plan.gradients.iter().map(|p| canonical(p)).collect(),
                reference_side: Vec::new(),
                frames: Vec::new(),
            },
            config,
            reference: None,
        })
    }

    /// `(section, value)` of every part that decides the per-frame results.
    fn result_key(&self) -> Vec<(String, Option<toml::Value>)> {
        let mut key: Vec<(String, Option<toml::Value>)> = RESULT_SECTIONS
            .iter()
            .map(|s| (format!("config.{s}"), self.config.get(*s).cloned()))
            .collect();
        let i = &self.inputs;
        let paths = |v: &[PathBuf]| {
            toml::Value::Array(
                v.iter()
                    .map(|p| toml::Value::String(p.display().to_string()))
                    .collect(),
            )
        };
        let opt = |p: &Option<PathBuf>| {
            p.as_ref()
                .map(|p| toml::Value::String(p.display().to_string()))
        };
        // What is computed per dot also decides the results.
        key.push((
            "config.output.quantities".into(),
            self.config
                .get("output")
                .and_then(|o| o.get("quantities"))
                .cloned(),
        ));
        key.push((
            "inputs.reference_from".into(),
            Some(toml::Value::String(i.reference_from.clone())),
        ));
        key.push(("inputs.reference".into(), opt(&i.reference)));
        key.push(("inputs.mask".into(), opt(&i.mask)));
        key.push(("inputs.stack".into(), Some(paths(&i.stack))));
        key
    }

    /// The first part of the result-deciding configuration in which `self` and `other` differ
    /// (`None` when the per-frame outputs of one are valid for the other). The list of
    /// gradient frames may differ: frames added to a campaign are computed by the next run.
    pub fn differs_from(&self, other: &RunRecord) -> Option<String> {
        self.result_key()
            .into_iter()
            .zip(other.result_key())
            .find(|(a, b)| a != b)
            .map(|(a, _)| a.0)
    }

    /// Fingerprints the reference side (reference image, mask, no-flow images) into
    /// `inputs.reference_side`, taking over the hash of a file that `known` records with the
    /// same size and modification time.
    pub fn fingerprint_reference_side(&mut self, known: &[&RunRecord]) -> Result<(), BatchError> {
        let i = &self.inputs;
        let files: Vec<PathBuf> = i
            .reference
            .iter()
            .chain(&i.mask)
            .chain(&i.stack)
            .cloned()
            .collect();
        self.inputs.reference_side = files
            .iter()
            .map(|p| {
                let old = known
                    .iter()
                    .flat_map(|r| &r.inputs.reference_side)
                    .find(|f| &f.path == p);
                Fingerprint::of(p, old).map_err(|source| BatchError::Read {
                    path: p.clone(),
                    source,
                })
            })
            .collect::<Result<_, _>>()?;
        Ok(())
    }

    /// The reference-side files whose content differs between `self` and `old`, each named
    /// with what changed (files that only one of them records are not compared: a changed
    /// list of files is a [`RunRecord::differs_from`] difference).
    pub fn changed_inputs(&self, old: &RunRecord) -> Vec<String> {
        self.inputs
            .reference_side
            .iter()
            .filter_map(|now| {
                let before = old
                    .inputs
                    .reference_side
                    .iter()
                    .find(|f| f.path == now.path)?;
                (!now.same_content(before)).then(|| now.change_from(before))
            })
            .collect()
    }

    /// Digest of what decides every frame's results on the reference side: the
    /// result-deciding configuration and files ([`RunRecord::differs_from`]) and the content
    /// hashes of the reference-side files. Recorded in each frame's `inputs.json`.
    pub fn reference_side_key(&self) -> String {
        let hashes: Vec<(&Path, &str)> = self
            .inputs
            .reference_side
            .iter()
            .map(|f| (f.path.as_path(), f.xxh3_128.as_str()))
            .collect();
        let text = serde_json::to_string(&(self.result_key(), hashes)).unwrap_or_default();
        format!("{:032x}", xxhash_rust::xxh3::xxh3_128(text.as_bytes()))
    }

    /// The figures and formats recorded in `config.output`.
    pub fn figures(&self) -> (Vec<Figure>, Vec<FigureFormat>) {
        let out = self.config.get("output").and_then(|v| v.as_table());
        let get = |key: &str| out.and_then(|t| t.get(key)).cloned();
        let optics = self.config.contains_key("optics");
        let figures = get("figures")
            .and_then(|v| v.try_into::<Vec<Figure>>().ok())
            .unwrap_or_default()
            .into_iter()
            .filter(|f| optics || *f != Figure::Density) // as Plan::from_config
            .collect();
        let formats = get("figure_formats")
            .and_then(|v| v.try_into::<Vec<FigureFormat>>().ok())
            .unwrap_or_else(|| vec![FigureFormat::Png]);
        (figures, formats)
    }

    /// The lattice array formats of the recorded configuration (`[output] arrays`).
    pub fn arrays(&self) -> Vec<crate::config::ArrayFormat> {
        self.config
            .get("output")
            .and_then(|v| v.as_table())
            .and_then(|t| t.get("arrays"))
            .and_then(|v| v.clone().try_into().ok())
            .unwrap_or_default()
    }

    /// Writes the record to `path` atomically.
    pub fn write(&self, path: &Path) -> Result<(), BatchError> {
        let text = toml::to_string(self).map_err(|e| BatchError::Corrupt {
            path: path.to_path_buf(),
            message: format!("cannot serialise the run record: {e}"),
        })?;
        let header = "# Run record written by bostrack: version, inputs and the fully resolved \
                      configuration.\n";
        write_atomic(path, format!("{header}{text}").as_bytes())
    }

    /// Reads a record.
    pub fn read(path: &Path) -> Result<RunRecord, BatchError> {
        let bytes = read(path)?;
        let text = String::from_utf8_lossy(&bytes);
        toml::from_str(&text).map_err(|e| BatchError::Corrupt {
            path: path.to_path_buf(),
            message: format!("not a run record: {}", e.message()),
        })
    }
}

/// The record files present in `out_dir`: `run.toml` first, then `shards/*.toml` in natural
/// order.
pub(crate) fn record_files(out_dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let run = out_dir.join(RUN_RECORD);
    if run.is_file() {
        out.push(run);
    }
    if let Ok(files) = crate::files::list_matching(&out_dir.join(SHARDS_DIR), "shard-*-of-*.toml") {
        out.extend(files);
    }
    out
}

/// Every record in `out_dir`, with its path.
pub(crate) fn read_records(out_dir: &Path) -> Result<Vec<(PathBuf, RunRecord)>, BatchError> {
    record_files(out_dir)
        .into_iter()
        .map(|p| RunRecord::read(&p).map(|r| (p, r)))
        .collect()
}

/// The gradient frames of several records: their union, in natural order of the file names
/// (ties by the full path), each once.
pub(crate) fn union_of_frames<'a>(records: impl Iterator<Item = &'a RunRecord>) -> Vec<PathBuf> {
    let mut all: Vec<PathBuf> = records
        .flat_map(|r| r.inputs.gradients.iter().cloned())
        .collect();
    let name = |p: &PathBuf| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    all.sort_by(|a, b| natural_cmp(&name(a), &name(b)).then_with(|| a.cmp(b)));
    all.dedup();
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(dir: &Path) -> RunRecord {
        let camp = dir.join("camp");
        std::fs::create_dir_all(camp.join("g")).unwrap();
        std::fs::write(camp.join("reference.tif"), b"x").unwrap();
        for n in [1, 2, 10] {
            std::fs::write(camp.join(format!("g/f{n}.tif")), b"x").unwrap();
        }
        let text = "[input]\ndir = \"camp\"\nstack_dir = \"\"\ngradient_dir = \"g\"\n";
        let cfg = crate::parse_config(text, Path::new("p.toml")).unwrap();
        let plan = Plan::from_config(cfg, &dir.join("p.toml")).unwrap();
        RunRecord::new(&plan, &dir.join("out"), None, 3).unwrap()
    }

    #[test]
    fn round_trips_and_compares() {
        let dir = tempfile::tempdir().unwrap();
        let r = record(dir.path());
        assert_eq!(r.kind, "run");
        assert_eq!(r.inputs.gradients.len(), 3);
        assert!(r.inputs.gradients[2].ends_with("f10.tif"));
        let p = dir.path().join("run.toml");
        r.write(&p).unwrap();
        let back = RunRecord::read(&p).unwrap();
        assert_eq!(back, r);
        assert_eq!(back.differs_from(&r), None);
        let (figures, formats) = back.figures();
        // the density maps only with [optics]
        let mut expected = PipelineConfig::default().output.figures;
        expected.retain(|f| *f != Figure::Density);
        assert_eq!(figures, expected);
        assert_eq!(formats, [FigureFormat::Png]);

        // More frames, other jobs or figures: the results still apply.
        let mut other = r.clone();
        other.inputs.gradients.pop();
        other.jobs = 1;
        other.config["output"]["figures"] = toml::Value::Array(Vec::new());
        assert_eq!(other.differs_from(&r), None);
        // Another fit setting or reference: they do not.
        let mut other = r.clone();
        other.config["fit"]["max_iterations"] = toml::Value::Integer(7);
        assert_eq!(other.differs_from(&r).as_deref(), Some("config.fit"));
        let mut other = r.clone();
        other.config["output"]["quantities"] = toml::Value::String("displacement".into());
        assert_eq!(
            other.differs_from(&r).as_deref(),
            Some("config.output.quantities")
        );
        let mut other = r.clone();
        other.inputs.reference = Some(PathBuf::from("/else.tif"));
        assert_eq!(other.differs_from(&r).as_deref(), Some("inputs.reference"));

        std::fs::write(&p, "bostrack_version = 3\n").unwrap();
        let e = RunRecord::read(&p).unwrap_err();
        assert!(e.to_string().contains("run.toml") && e.to_string().contains("not a run record"));
    }

    #[test]
    fn union_is_natural_and_unique() {
        let dir = tempfile::tempdir().unwrap();
        let r = record(dir.path());
        let mut s = r.clone();
        s.inputs.gradients.remove(0);
        let u = union_of_frames([&s, &r].into_iter());
        assert_eq!(u, r.inputs.gradients);
    }
}
