//! The per-frame outputs: `DIR/<stem>/dots.csv` and `DIR/<stem>/summary.json`, written
//! atomically.

use super::FrameResult;
use crate::density::{DENSITY_COLUMNS, PHYSICAL_COLUMNS};
use crate::error::PipelineError;
use crate::table::CsvTable;
use bostrack_core::table::optional_scientific as si;
use bostrack_displacement::{COLUMNS, write_row};
use rayon::prelude::*;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

const DOTS: &str = "dots.csv";
const DENSITY: &str = "density.csv";
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
    let csv = dots_csv(result).map_err(out(dir.join(DOTS)))?;
    write_synced(&dir.join(DOTS), &csv).map_err(out(dir.join(DOTS)))?;
    if let Some(csv) = density_csv(result).map_err(out(dir.join(DENSITY)))? {
        write_synced(&dir.join(DENSITY), &csv).map_err(out(dir.join(DENSITY)))?;
    }
    let mut json =
        serde_json::to_vec_pretty(&result.summary).map_err(|e| PipelineError::Output {
            path: dir.join(SUMMARY),
            source: std::io::Error::other(e),
        })?;
    json.push(b'\n');
    write_synced(&dir.join(SUMMARY), &json).map_err(out(dir.join(SUMMARY)))
}

/// The text of `dots.csv`: [`COLUMNS`], then one row per dot ([`write_row`], the cells reused
/// from row to row), by the one table writer; with `[optics]` the columns
/// [`PHYSICAL_COLUMNS`] after them (SI units: scientific notation, `table::scientific`).
fn dots_csv(result: &FrameResult) -> std::io::Result<Vec<u8>> {
    let dots = &result.dots;
    let mut columns: Vec<&str> = COLUMNS.to_vec();
    if result.physical.is_some() {
        columns.extend(PHYSICAL_COLUMNS);
    }
    let width = columns.len();
    // the rows in blocks of dots formatted in parallel, joined in dot order after the header
    // (one thread formatted a real frame's 12,236 rows in ~14 ms, all of it serial)
    const BLOCK: usize = 1024;
    let blocks: Vec<std::io::Result<Vec<u8>>> = dots
        .par_chunks(BLOCK)
        .enumerate()
        .map(|(b, block)| {
            let mut t = CsvTable::body(Vec::with_capacity(250 * block.len()), width);
            let mut cells: [String; COLUMNS.len()] = Default::default();
            let mut row: Vec<String> = Vec::with_capacity(width);
            for (k, d) in block.iter().enumerate() {
                write_row(d, &mut cells);
                let Some(p) = result.physical.as_ref().map(|v| v[b * BLOCK + k]) else {
                    t.row(&cells)?;
                    continue;
                };
                let pair = |v: Option<[f64; 2]>| [si(v.map(|a| a[0])), si(v.map(|a| a[1]))];
                row.clear();
                row.extend(cells.iter().cloned());
                row.extend(pair(p.position_m));
                row.extend(pair(p.gradient));
                row.extend(pair(p.u_gradient));
                t.row(&row)?;
            }
            t.finish()
        })
        .collect();
    let mut out = CsvTable::new(Vec::with_capacity(250 * (dots.len() + 1)), &columns)?.finish()?;
    for b in blocks {
        out.extend_from_slice(&b?);
    }
    Ok(out)
}

/// The text of `density.csv` ([`DENSITY_COLUMNS`], one row per dot of `dots.csv`), or `None`
/// without `[optics]`. Positions and densities in scientific notation (`table::scientific`,
/// docs/CONVENTIONS.md). `valid` is true where ρ is known; `status` is `solved`, `reference` (a
/// Dirichlet node), `no_reference` (an island without one) or `hole` (not a valid dot).
fn density_csv(result: &FrameResult) -> std::io::Result<Option<Vec<u8>>> {
    let (Some(field), Some(physical)) = (&result.density, &result.physical) else {
        return Ok(None);
    };
    let mut t = CsvTable::new(
        Vec::with_capacity(80 * (result.dots.len() + 1)),
        &DENSITY_COLUMNS,
    )?;
    for ((d, p), (rho, u, status)) in result.dots.iter().zip(physical).zip(&field.nodes) {
        let [x, y] = p
            .position_m
            .map_or([None, None], |v| [Some(v[0]), Some(v[1])]);
        t.row(&[
            d.index.i.to_string(),
            d.index.j.to_string(),
            si(x),
            si(y),
            si(*rho),
            si(*u),
            rho.is_some().to_string(),
            status.map_or("hole", |s| s.name()).to_string(),
        ])?;
    }
    t.finish().map(Some)
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
