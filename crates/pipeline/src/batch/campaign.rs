//! The campaign files, built from the per-frame outputs on disk: `campaign.csv`,
//! `campaign.json`, `failures.json` and the campaign figures. The same code serves the end of
//! an unsharded run and `merge`, so both give the same files.
//!
//! One row per frame, in frame order: `frame` (from 1), `stem`, `file` (its name), `status`
//! (`ok` or `failed`), `reason` (of a failure), then every value of the frame's
//! `summary.json` flattened to dotted column names (`a.b`; a list of `[name, value]` pairs
//! becomes `a.name`), **timing columns last**: those whose name has a part containing `time`
//! or `seconds`. `campaign.json` holds the same rows as objects with the timings under
//! `"timings"`, and names the timing columns in `"timing_columns"`, so two campaigns can be
//! compared without them.

use super::fsx::AtomicFile;
use super::{BatchError, FrameFailure, FrameRef, Progress};
use crate::figures::{CampaignPoint, FigureSetup, FigureSpec, draw_campaign_figures};
use crate::pair::frame_is_complete;
use crate::table::CsvTable;
use bostrack_core::table;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use std::collections::HashMap;
use std::io::Write as _;
use std::path::Path;

pub(crate) const CAMPAIGN_CSV: &str = "campaign.csv";
pub(crate) const CAMPAIGN_JSON: &str = "campaign.json";
pub(crate) const FAILURES: &str = "failures.json";

/// `failures.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct FailuresFile {
    /// Frames of the campaign.
    pub frames: usize,
    /// Frames that failed.
    pub failed: usize,
    pub failures: Vec<FrameFailure>,
}

/// What the campaign files say.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Built {
    pub failures: Vec<FrameFailure>,
}

/// A summary value flattened: `(column, value)`.
type Flat = Vec<(String, Value)>;

/// Whether a flattened column holds a wall time.
pub(crate) fn is_timing(column: &str) -> bool {
    column
        .split('.')
        .any(|part| part.contains("time") || part.contains("seconds"))
}

fn flatten(prefix: &str, v: &Value, out: &mut Flat) {
    let join = |k: &str| {
        if prefix.is_empty() {
            k.to_string()
        } else {
            format!("{prefix}.{k}")
        }
    };
    match v {
        Value::Object(o) => {
            for (k, v) in o {
                flatten(&join(k), v, out);
            }
        }
        Value::Array(a)
            if !a.is_empty()
                && a.iter().all(|e| {
                    e.as_array()
                        .is_some_and(|p| p.len() == 2 && p[0].is_string() && !p[1].is_object())
                }) =>
        {
            for e in a {
                let p = e.as_array().expect("checked");
                flatten(&join(p[0].as_str().expect("checked")), &p[1], out);
            }
        }
        // Per-axis pairs `[x, y]` (the summaries' convention) and other lists of scalars.
        Value::Array(a) if a.iter().all(|e| !e.is_array() && !e.is_object()) => {
            for (k, e) in a.iter().enumerate() {
                let name = match (a.len(), k) {
                    (2, 0) => "x".to_string(),
                    (2, 1) => "y".to_string(),
                    _ => k.to_string(),
                };
                out.push((join(&name), e.clone()));
            }
        }
        Value::Array(_) => out.push((prefix.to_string(), Value::String(v.to_string()))),
        _ => out.push((prefix.to_string(), v.clone())),
    }
}

/// The keys of `summary.json` left out of the rows: the frame's path and the version (the
/// `file` column and the run record hold them).
const DROPPED: [&str; 2] = ["frame", "version"];

/// Reads and flattens `DIR/<stem>/summary.json`.
fn read_summary(out: &Path, stem: &str) -> Result<Flat, String> {
    let path = out.join(stem).join("summary.json");
    let bytes =
        std::fs::read(&path).map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let v: Value =
        serde_json::from_slice(&bytes).map_err(|e| format!("{}: not JSON: {e}", path.display()))?;
    let mut flat = Flat::new();
    flatten("", &v, &mut flat);
    flat.retain(|(k, _)| !DROPPED.contains(&k.as_str()));
    Ok(flat)
}

/// Finds a number in a flattened summary by the first matching column name.
fn number(flat: &Flat, names: &[&str]) -> f64 {
    names
        .iter()
        .find_map(|n| flat.iter().find(|(k, _)| k == n))
        .and_then(|(_, v)| v.as_f64())
        .unwrap_or(f64::NAN)
}

/// Column of the median |d| in `summary.json`.
const MEDIAN_D: [&str; 1] = ["medians.abs_d"];
/// Column of the median |u_d| in `summary.json`.
const MEDIAN_U: [&str; 1] = ["medians.abs_u_d"];

/// A frame's state in the campaign: its flattened summary, or why it has none.
fn frame_values(
    out: &Path,
    f: &FrameRef,
    spec: &FigureSpec,
    reasons: &HashMap<String, String>,
) -> Result<Flat, String> {
    if frame_is_complete(out, &f.stem) && spec.frame_complete(&out.join(&f.stem)) {
        read_summary(out, &f.stem)
    } else {
        Err(reasons.get(&f.stem).cloned().unwrap_or_else(|| {
            format!(
                "not processed: no complete output in {} (a shard not run or not finished?)",
                out.join(&f.stem).display()
            )
        }))
    }
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Builds and writes the campaign files of `frames` in `out`. `reasons` gives the failure
/// reason of frames known to have failed; frames without complete outputs and without a
/// reason are "not processed".
///
/// Streams: a first pass over the summaries finds the columns, the second writes one row at a
/// time, so memory does not grow with the number of frames (beyond three numbers per frame for
/// the campaign figure).
pub(crate) fn build(
    out: &Path,
    frames: &[FrameRef],
    reasons: &HashMap<String, String>,
    spec: &FigureSpec,
    setup: Option<&FigureSetup>,
    title: &str,
    progress: &dyn Progress,
) -> Result<Built, BatchError> {
    // Temporaries of campaign files a killed run was writing.
    super::fsx::remove_stale_files(out);

    // Pass 1: columns (the union of the summaries' keys in first-seen order, timings last),
    // failures and the campaign figure's points.
    let mut columns: Vec<String> = Vec::new();
    let mut failures = Vec::new();
    let mut points = Vec::with_capacity(frames.len());
    let mut first_complete: Option<&FrameRef> = None;
    for f in frames {
        let (median_d, median_u) = match frame_values(out, f, spec, reasons) {
            Ok(values) => {
                first_complete.get_or_insert(f);
                for (k, _) in &values {
                    if !columns.contains(k) {
                        columns.push(k.clone());
                    }
                }
                (number(&values, &MEDIAN_D), number(&values, &MEDIAN_U))
            }
            Err(reason) => {
                failures.push(FrameFailure {
                    frame: f.number,
                    stem: f.stem.clone(),
                    file: f.path.clone(),
                    reason,
                });
                (f64::NAN, f64::NAN)
            }
        };
        points.push(CampaignPoint {
            frame: f.number,
            median_d,
            median_u,
        });
    }
    let (mut all_cols, timing_cols): (Vec<String>, Vec<String>) =
        columns.into_iter().partition(|c| !is_timing(c));
    all_cols.extend(timing_cols.iter().cloned());

    // Pass 2: one row per frame into campaign.csv and campaign.json.
    let csv_path = out.join(CAMPAIGN_CSV);
    let json_path = out.join(CAMPAIGN_JSON);
    let mut csv_file = AtomicFile::create(&csv_path)?;
    let mut json_file = AtomicFile::create(&json_path)?;
    let csv_err = |e: std::io::Error| BatchError::Write {
        path: csv_path.clone(),
        source: e,
    };
    let json_err = |e: std::io::Error| BatchError::Write {
        path: json_path.clone(),
        source: e,
    };
    {
        let mut header = vec!["frame", "stem", "file", "status", "reason"];
        header.extend(all_cols.iter().map(String::as_str));
        let mut w = CsvTable::new(csv_file.writer(), &header).map_err(csv_err)?;
        let head = serde_json::json!({
            "bostrack_version": env!("CARGO_PKG_VERSION"),
            "frames": frames.len(),
            "complete": frames.len() - failures.len(),
            "failed": failures.len(),
            "timing_columns": timing_cols,
        });
        // The header object, its closing brace replaced by the rows array.
        let head = serde_json::to_string_pretty(&head).map_err(|e| BatchError::Corrupt {
            path: json_path.clone(),
            message: e.to_string(),
        })?;
        let head = head.trim_end().trim_end_matches('}').trim_end();
        let jw = json_file.writer();
        write!(jw, "{head},\n  \"rows\": [").map_err(json_err)?;

        let cell = |col: &str, v: Option<&Value>| match v {
            None | Some(Value::Null) => String::new(),
            Some(Value::String(s)) => s.clone(),
            // counts as integers, measurements by the float conventions of every table: the
            // density's SI values in scientific notation, the others with fixed decimals
            Some(Value::Number(n)) if n.is_f64() => {
                let v = n.as_f64().unwrap_or(f64::NAN);
                if col.starts_with("density.") {
                    table::scientific(v)
                } else {
                    table::number(v)
                }
            }
            Some(v) => v.to_string(),
        };
        let mut failed = failures.iter().peekable();
        for (k, f) in frames.iter().enumerate() {
            let (values, reason) = if failed.peek().is_some_and(|x| x.frame == f.number) {
                (Flat::new(), failed.next().map(|x| x.reason.clone()))
            } else {
                match frame_values(out, f, spec, reasons) {
                    Ok(v) => (v, None),
                    // Changed between the passes (another process): report it as failed.
                    Err(reason) => (Flat::new(), Some(reason)),
                }
            };
            let status = if reason.is_none() { "ok" } else { "failed" };
            let lookup: HashMap<&str, &Value> =
                values.iter().map(|(k, v)| (k.as_str(), v)).collect();
            let mut rec = vec![
                f.number.to_string(),
                f.stem.clone(),
                file_name(&f.path),
                status.to_string(),
                reason.clone().unwrap_or_default(),
            ];
            rec.extend(
                all_cols
                    .iter()
                    .map(|c| cell(c, lookup.get(c.as_str()).copied())),
            );
            w.row(&rec).map_err(csv_err)?;

            let mut o = Map::new();
            o.insert("frame".into(), f.number.into());
            o.insert("stem".into(), f.stem.clone().into());
            o.insert("file".into(), file_name(&f.path).into());
            o.insert("status".into(), status.into());
            if let Some(reason) = reason {
                o.insert("reason".into(), reason.into());
            }
            let mut timings = Map::new();
            for (key, v) in values {
                if is_timing(&key) {
                    timings.insert(key, v);
                } else {
                    o.insert(key, v);
                }
            }
            if !timings.is_empty() {
                o.insert("timings".into(), Value::Object(timings));
            }
            let row =
                serde_json::to_string(&Value::Object(o)).map_err(|e| BatchError::Corrupt {
                    path: json_path.clone(),
                    message: e.to_string(),
                })?;
            let sep = if k == 0 { "" } else { "," };
            write!(jw, "{sep}\n    {row}").map_err(json_err)?;
        }
        writeln!(jw, "\n  ]\n}}").map_err(json_err)?;
        w.finish().map_err(csv_err)?;
    }
    csv_file.commit()?;
    json_file.commit()?;
    super::write_json(
        &out.join(FAILURES),
        &FailuresFile {
            frames: frames.len(),
            failed: failures.len(),
            failures: failures.clone(),
        },
    )?;

    if let Some(setup) = setup {
        let detections_from = first_complete.map(|f| out.join(&f.stem));
        let notes = draw_campaign_figures(out, title, &points, detections_from.as_deref(), setup)?;
        for n in notes {
            progress.note(&n);
        }
    }
    Ok(Built { failures })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flattening_and_timing_columns() {
        let v = serde_json::json!({
            "frame": "/x/f1.tif",
            "counts": {"found": 10, "valid": 9},
            "medians": {"abs_d": 0.5, "u_d": [0.01, null]},
            "times": {"stages": [["detect", 0.25], ["fit", 1.5]]},
            "wall_seconds": 2.0,
            "list": [1, 2, 3],
        });
        let mut flat = Flat::new();
        flatten("", &v, &mut flat);
        let keys: Vec<&str> = flat.iter().map(|(k, _)| k.as_str()).collect();
        for k in [
            "counts.found",
            "counts.valid",
            "medians.abs_d",
            "medians.u_d.x",
            "medians.u_d.y",
            "times.stages.detect",
            "times.stages.fit",
            "wall_seconds",
            "list.2",
        ] {
            assert!(keys.contains(&k), "{k} not in {keys:?}");
        }
        assert!(is_timing("times.stages.fit") && is_timing("wall_seconds"));
        assert!(!is_timing("counts.valid") && !is_timing("medians.abs_d"));
        assert_eq!(number(&flat, &MEDIAN_D), 0.5);
        assert!(number(&flat, &MEDIAN_U).is_nan());
    }
}
