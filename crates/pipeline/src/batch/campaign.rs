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

use super::fsx::write_atomic;
use super::{BatchError, FrameFailure, FrameRef, Progress};
use crate::figures::{CampaignPoint, FigureSetup, FigureSpec, draw_campaign_figures};
use crate::pair::frame_is_complete;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use std::collections::HashMap;
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
    let bytes = std::fs::read(&path).map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let v: Value = serde_json::from_slice(&bytes)
        .map_err(|e| format!("{}: not JSON: {e}", path.display()))?;
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

/// Column names of the median |d| and median |u_d| in `summary.json` (the first present).
const MEDIAN_D: [&str; 3] = ["median_d", "median.d", "medians.d"];
const MEDIAN_U: [&str; 3] = ["median_u_d", "median.u_d", "medians.u_d"];

/// Builds and writes the campaign files of `frames` in `out`. `reasons` gives the failure
/// reason of frames known to have failed; frames without complete outputs and without a
/// reason are "not processed".
pub(crate) fn build(
    out: &Path,
    frames: &[FrameRef],
    reasons: &HashMap<String, String>,
    spec: &FigureSpec,
    setup: Option<&FigureSetup>,
    title: &str,
    progress: &dyn Progress,
) -> Result<Built, BatchError> {
    struct Row {
        frame: usize,
        stem: String,
        file: String,
        reason: Option<String>,
        values: Flat,
    }
    let mut rows = Vec::with_capacity(frames.len());
    let mut failures = Vec::new();
    for f in frames {
        let complete = frame_is_complete(out, &f.stem) && spec.frame_complete(&out.join(&f.stem));
        let read = if complete {
            read_summary(out, &f.stem)
        } else {
            Err(reasons.get(&f.stem).cloned().unwrap_or_else(|| {
                format!(
                    "not processed: no complete output in {} (a shard not run or not finished?)",
                    out.join(&f.stem).display()
                )
            }))
        };
        let (values, reason) = match read {
            Ok(v) => (v, None),
            Err(reason) => {
                failures.push(FrameFailure {
                    frame: f.number,
                    stem: f.stem.clone(),
                    file: f.path.clone(),
                    reason: reason.clone(),
                });
                (Flat::new(), Some(reason))
            }
        };
        rows.push(Row {
            frame: f.number,
            stem: f.stem.clone(),
            file: f
                .path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            reason,
            values,
        });
    }

    // Columns: the union of the summaries' keys in first-seen order, timings last.
    let mut columns: Vec<String> = Vec::new();
    for r in &rows {
        for (k, _) in &r.values {
            if !columns.contains(k) {
                columns.push(k.clone());
            }
        }
    }
    let (mut data_cols, timing_cols): (Vec<String>, Vec<String>) =
        columns.into_iter().partition(|c| !is_timing(c));
    data_cols.extend(timing_cols.iter().cloned());
    let all_cols = data_cols;

    // campaign.csv
    let csv_err = |e: csv::Error| BatchError::Corrupt {
        path: out.join(CAMPAIGN_CSV),
        message: e.to_string(),
    };
    let mut w = csv::Writer::from_writer(Vec::new());
    let mut header = vec!["frame", "stem", "file", "status", "reason"];
    header.extend(all_cols.iter().map(String::as_str));
    w.write_record(&header).map_err(csv_err)?;
    let cell = |v: Option<&Value>| match v {
        None | Some(Value::Null) => String::new(),
        Some(Value::String(s)) => s.clone(),
        Some(v) => v.to_string(),
    };
    for r in &rows {
        let lookup: HashMap<&str, &Value> =
            r.values.iter().map(|(k, v)| (k.as_str(), v)).collect();
        let mut rec = vec![
            r.frame.to_string(),
            r.stem.clone(),
            r.file.clone(),
            if r.reason.is_none() { "ok" } else { "failed" }.to_string(),
            r.reason.clone().unwrap_or_default(),
        ];
        rec.extend(all_cols.iter().map(|c| cell(lookup.get(c.as_str()).copied())));
        w.write_record(&rec).map_err(csv_err)?;
    }
    let csv_bytes = w
        .into_inner()
        .map_err(|e| BatchError::Corrupt {
            path: out.join(CAMPAIGN_CSV),
            message: e.to_string(),
        })?;
    write_atomic(&out.join(CAMPAIGN_CSV), &csv_bytes)?;

    // campaign.json
    let json_rows: Vec<Value> = rows
        .iter()
        .map(|r| {
            let mut o = Map::new();
            o.insert("frame".into(), r.frame.into());
            o.insert("stem".into(), r.stem.clone().into());
            o.insert("file".into(), r.file.clone().into());
            o.insert(
                "status".into(),
                if r.reason.is_none() { "ok" } else { "failed" }.into(),
            );
            if let Some(reason) = &r.reason {
                o.insert("reason".into(), reason.clone().into());
            }
            let mut timings = Map::new();
            for (k, v) in &r.values {
                if is_timing(k) {
                    timings.insert(k.clone(), v.clone());
                } else {
                    o.insert(k.clone(), v.clone());
                }
            }
            if !timings.is_empty() {
                o.insert("timings".into(), Value::Object(timings));
            }
            Value::Object(o)
        })
        .collect();
    let doc = serde_json::json!({
        "bostrack_version": env!("CARGO_PKG_VERSION"),
        "frames": rows.len(),
        "complete": rows.len() - failures.len(),
        "failed": failures.len(),
        "timing_columns": timing_cols,
        "rows": json_rows,
    });
    super::write_json(&out.join(CAMPAIGN_JSON), &doc)?;
    super::write_json(
        &out.join(FAILURES),
        &FailuresFile {
            frames: rows.len(),
            failed: failures.len(),
            failures: failures.clone(),
        },
    )?;

    if let Some(setup) = setup {
        let points: Vec<CampaignPoint> = rows
            .iter()
            .map(|r| CampaignPoint {
                frame: r.frame,
                median_d: number(&r.values, &MEDIAN_D),
                median_u: number(&r.values, &MEDIAN_U),
            })
            .collect();
        let first_complete = frames
            .iter()
            .zip(&rows)
            .find(|(_, r)| r.reason.is_none())
            .map(|(f, _)| (out.join(&f.stem), f.title(frames.len())));
        let notes = draw_campaign_figures(
            out,
            title,
            &points,
            first_complete
                .as_ref()
                .map(|(dir, t)| (dir.as_path(), t.as_str())),
            setup,
        )?;
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
            "median_d": 0.5,
            "times": {"stages": [["detect", 0.25], ["fit", 1.5]]},
            "wall_seconds": 2.0,
            "list": [1, 2],
        });
        let mut flat = Flat::new();
        flatten("", &v, &mut flat);
        let keys: Vec<&str> = flat.iter().map(|(k, _)| k.as_str()).collect();
        for k in [
            "counts.found",
            "counts.valid",
            "median_d",
            "times.stages.detect",
            "times.stages.fit",
            "wall_seconds",
            "list",
        ] {
            assert!(keys.contains(&k), "{k} not in {keys:?}");
        }
        assert!(is_timing("times.stages.fit") && is_timing("wall_seconds"));
        assert!(!is_timing("counts.valid") && !is_timing("median_d"));
        assert_eq!(number(&flat, &MEDIAN_D), 0.5);
        assert!(number(&flat, &MEDIAN_U).is_nan());
    }
}
