//! The per-frame outputs: `DIR/<stem>/dots.csv` and `DIR/<stem>/summary.json`, written
//! atomically.

use super::FrameResult;
use crate::error::PipelineError;
use crate::table::CsvTable;
use bostrack_displacement::{COLUMNS, write_row};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

const DOTS: &str = "dots.csv";
const SUMMARY: &str = "summary.json";

/// Writes `out_dir/<stem>/dots.csv` (columns [`bostrack_displacement::COLUMNS`], one row per
/// reference dot, `to_row` formatting) and `out_dir/<stem>/summary.json`, atomically: both go
/// into `out_dir/.<stem>.tmp-<pid>/` first (summary.json last), which is then renamed to
/// `out_dir/<stem>` (an older `out_dir/<stem>` is removed just before). So a folder
/// `out_dir/<stem>` with a `summary.json` is always a complete frame ([`frame_is_complete`]),
/// and a failure leaves no half-written `out_dir/<stem>`.
pub fn write_frame(out_dir: &Path, result: &FrameResult) -> Result<(), PipelineError> {
    let stem = &result.stem;
    if stem.is_empty()
        || stem.starts_with('.')
        || stem.contains(['/', '\\'])
        || Path::new(stem).components().count() != 1
    {
        return Err(PipelineError::Output {
            path: out_dir.join(stem),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("`{stem}` is not a usable frame name"),
            ),
        });
    }
    let out = |path: PathBuf| move |source| PipelineError::Output { path, source };
    fs::create_dir_all(out_dir).map_err(out(out_dir.to_path_buf()))?;
    let tmp = out_dir.join(format!(".{stem}.tmp-{}", std::process::id()));
    if tmp.exists() {
        fs::remove_dir_all(&tmp).map_err(out(tmp.clone()))?;
    }
    let result = write_into(&tmp, result).and_then(|()| {
        let dest = out_dir.join(stem);
        if dest.exists() {
            fs::remove_dir_all(&dest).map_err(out(dest.clone()))?;
        }
        fs::rename(&tmp, &dest).map_err(out(dest.clone()))
    });
    if result.is_err() {
        let _ = fs::remove_dir_all(&tmp);
    }
    result
}

fn write_into(dir: &Path, result: &FrameResult) -> Result<(), PipelineError> {
    let out = |path: PathBuf| move |source| PipelineError::Output { path, source };
    fs::create_dir(dir).map_err(out(dir.to_path_buf()))?;
    let csv = dots_csv(&result.dots).map_err(out(dir.join(DOTS)))?;
    write_synced(&dir.join(DOTS), &csv).map_err(out(dir.join(DOTS)))?;
    let mut json =
        serde_json::to_vec_pretty(&result.summary).map_err(|e| PipelineError::Output {
            path: dir.join(SUMMARY),
            source: std::io::Error::other(e),
        })?;
    json.push(b'\n');
    write_synced(&dir.join(SUMMARY), &json).map_err(out(dir.join(SUMMARY)))
}

/// The text of `dots.csv`: [`COLUMNS`], then one row per dot ([`write_row`], the cells of
/// `to_row` reused from row to row), by the one table writer.
fn dots_csv(dots: &[bostrack_displacement::PairDot]) -> std::io::Result<Vec<u8>> {
    let mut t = CsvTable::new(Vec::with_capacity(200 * (dots.len() + 1)), &COLUMNS)?;
    let mut cells: [String; COLUMNS.len()] = Default::default();
    for d in dots {
        write_row(d, &mut cells);
        t.row(&cells)?;
    }
    t.finish()
}

fn write_synced(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut f = fs::File::create(path)?;
    f.write_all(bytes)?;
    f.sync_all()
}

/// Whether `out_dir/<stem>/summary.json` exists. `summary.json` is written last and the frame
/// folder appears by a rename, so this means the frame is complete.
pub fn frame_is_complete(out_dir: &Path, stem: &str) -> bool {
    out_dir.join(stem).join(SUMMARY).is_file()
}
