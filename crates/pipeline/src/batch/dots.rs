//! Reading a frame's `dots.csv` back (the columns of `bostrack_displacement::COLUMNS`) into the
//! numbers the figures need. Figures are always drawn from the file on disk, so a figure drawn
//! right after a frame was computed, on a rerun, or by `bostrack merge` is the same.

use super::BatchError;
use std::path::Path;

/// The per-dot values of one frame that the figures use. Empty CSV fields read as NaN.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct FrameDots {
    pub x_ref: Vec<f64>,
    pub y_ref: Vec<f64>,
    pub dx: Vec<f64>,
    pub dy: Vec<f64>,
    /// Reference fit usable (its shape columns are filled).
    pub ref_fitted: Vec<bool>,
    pub crlb_x_ref: Vec<f64>,
    pub crlb_y_ref: Vec<f64>,
    pub ar_x: Vec<f64>,
    pub ar_y: Vec<f64>,
    pub u_ref_x: Vec<f64>,
    pub u_ref_y: Vec<f64>,
    pub u_grad_x: Vec<f64>,
    pub u_grad_y: Vec<f64>,
    pub u_dx: Vec<f64>,
    pub u_dy: Vec<f64>,
    pub valid: Vec<bool>,
    /// From `density.csv` (same rows), when read: ρ and u_ρ (kg/m³).
    pub rho: Vec<f64>,
    pub u_rho: Vec<f64>,
}

impl FrameDots {
    pub fn len(&self) -> usize {
        self.x_ref.len()
    }
}

/// Reads `path` (a `dots.csv`).
pub(crate) fn read_dots(path: &Path) -> Result<FrameDots, BatchError> {
    let bytes = super::fsx::read(path)?;
    parse_dots(&bytes).map_err(|message| BatchError::Corrupt {
        path: path.to_path_buf(),
        message,
    })
}

fn parse_dots(bytes: &[u8]) -> Result<FrameDots, String> {
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_reader(bytes);
    let headers = rdr.headers().map_err(|e| e.to_string())?.clone();
    let col = |name: &str| -> Result<usize, String> {
        headers
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| format!("no column `{name}`"))
    };
    let names = [
        "x_ref",
        "y_ref",
        "dx",
        "dy",
        "sigma_x_ref",
        "crlb_x_ref",
        "crlb_y_ref",
        "ar_x",
        "ar_y",
        "u_ref_x",
        "u_ref_y",
        "u_grad_x",
        "u_grad_y",
        "u_dx",
        "u_dy",
        "valid",
    ];
    let idx: Vec<usize> = names.iter().map(|n| col(n)).collect::<Result<_, _>>()?;
    let mut d = FrameDots::default();
    for (line, rec) in rdr.records().enumerate() {
        let rec = rec.map_err(|e| e.to_string())?;
        let field = |k: usize| rec.get(idx[k]).unwrap_or("");
        let num = |k: usize| -> Result<f64, String> {
            let s = field(k);
            if s.is_empty() {
                Ok(f64::NAN)
            } else {
                s.parse::<f64>().map_err(|_| {
                    format!(
                        "row {}: `{s}` in column `{}` is not a number",
                        line + 2,
                        names[k]
                    )
                })
            }
        };
        d.x_ref.push(num(0)?);
        d.y_ref.push(num(1)?);
        d.dx.push(num(2)?);
        d.dy.push(num(3)?);
        d.ref_fitted.push(!field(4).is_empty());
        d.crlb_x_ref.push(num(5)?);
        d.crlb_y_ref.push(num(6)?);
        d.ar_x.push(num(7)?);
        d.ar_y.push(num(8)?);
        d.u_ref_x.push(num(9)?);
        d.u_ref_y.push(num(10)?);
        d.u_grad_x.push(num(11)?);
        d.u_grad_y.push(num(12)?);
        d.u_dx.push(num(13)?);
        d.u_dy.push(num(14)?);
        d.valid.push(match field(15) {
            "true" => true,
            "false" => false,
            other => {
                return Err(format!(
                    "row {}: `{other}` in column `valid` is not true/false",
                    line + 2
                ));
            }
        });
    }
    Ok(d)
}

/// Reads the `rho` and `u_rho` columns of `path` (a `density.csv`, the rows of `dots.csv`)
/// into `d`.
pub(crate) fn read_density(path: &Path, d: &mut FrameDots) -> Result<(), BatchError> {
    let bytes = super::fsx::read(path)?;
    let corrupt = |message: String| BatchError::Corrupt {
        path: path.to_path_buf(),
        message,
    };
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_reader(&bytes[..]);
    let headers = rdr.headers().map_err(|e| corrupt(e.to_string()))?.clone();
    let col = |name: &str| {
        headers
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| corrupt(format!("no column `{name}`")))
    };
    let (cr, cu) = (col("rho")?, col("u_rho")?);
    let (mut rho, mut u_rho) = (Vec::new(), Vec::new());
    for rec in rdr.records() {
        let rec = rec.map_err(|e| corrupt(e.to_string()))?;
        let num = |c: usize| {
            rec.get(c)
                .and_then(|s| s.parse::<f64>().ok())
                .unwrap_or(f64::NAN)
        };
        rho.push(num(cr));
        u_rho.push(num(cu));
    }
    if rho.len() != d.len() {
        return Err(corrupt(format!(
            "{} rows, but dots.csv has {}",
            rho.len(),
            d.len()
        )));
    }
    d.rho = rho;
    d.u_rho = u_rho;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use bostrack_core::{DotFit, DotFlags, FitStatus, Gaussian2D, GridIndex};
    use bostrack_displacement::{
        COLUMNS, DisplacementConfig, PairInput, ReferenceStats, pair_dot, to_row,
    };

    #[test]
    fn reads_back_what_the_displacement_crate_writes() {
        let fit = |x0: f64, amplitude: f64| DotFit {
            index: GridIndex::new(1, 2),
            params: Gaussian2D::circular(x0, 20.0, amplitude, 1.5, 100.0),
            crlb_x: 0.01,
            crlb_y: 0.02,
            rms: 5.0,
            iterations: 6,
            status: FitStatus::Converged,
            flags: DotFlags::NONE,
        };
        // half as bright: twice the bound, AR = 2 by the default ratio of the bounds
        let (r, g) = (
            fit(10.0, 1000.0),
            DotFit {
                crlb_x: 0.02,
                crlb_y: 0.04,
                ..fit(10.25, 500.0)
            },
        );
        let stack = ReferenceStats {
            images: 10,
            mean: Some([10.0, 20.0]),
            u: Some([0.02, 0.03]),
        };
        let with = PairInput {
            reference: Some(&r),
            gradient: Some(&g),
            stack: Some(stack),
            flags: DotFlags::NONE,
        };
        let without = PairInput {
            reference: Some(&r),
            gradient: None,
            stack: None,
            flags: DotFlags::NONE,
        };
        let cfg = DisplacementConfig::default();
        let mut text = COLUMNS.join(",") + "\n";
        for input in [with, without] {
            text += &(to_row(&pair_dot(&input, &cfg).unwrap()).join(",") + "\n");
        }
        let d = parse_dots(text.as_bytes()).unwrap();
        assert_eq!(d.len(), 2);
        assert_eq!((d.x_ref[0], d.dx[0], d.dy[0]), (10.0, 0.25, 0.0));
        assert_eq!((d.ar_x[0], d.u_ref_y[0], d.u_grad_x[0]), (2.0, 0.03, 0.04));
        assert_eq!((d.crlb_x_ref[0], d.crlb_y_ref[0]), (0.01, 0.02));
        assert!(d.valid[0] && !d.valid[1]);
        assert!(d.ref_fitted[0] && d.ref_fitted[1]);
        assert!(d.dx[1].is_nan() && d.ar_x[1].is_nan() && d.u_dx[1].is_nan());

        assert!(
            parse_dots(b"i,j\n1,2\n")
                .unwrap_err()
                .contains("no column `x_ref`")
        );
        let bad = text.replace("true", "maybe");
        assert!(parse_dots(bad.as_bytes()).unwrap_err().contains("row 2"));
    }
}
