//! Lattice arrays: a frame's `dots.csv` regridded onto its (i, j) lattice, one 2-D array per
//! quantity (rows i, columns j), and their files `fields.npz` (numpy) and `fields.mat` (MATLAB
//! Level 5).
//!
//! The arrays are built from the **text of `dots.csv`** (every number parsed from its field: six
//! decimals, the SI columns in scientific notation, docs/CONVENTIONS.md), so `fields.npz`, `fields.mat`, the Python package's `bostrack.load` and the CSV hold
//! the same values, bit for bit. What a file holds:
//!
//! | name | shape, type | meaning |
//! |---|---|---|
//! | `i`, `j` | (n_i,), (n_j,) | the grid index of each row and column (int64 in `.npz`, double in `.mat`) |
//! | `present` | (n_i, n_j) bool | whether `dots.csv` has a row for the site |
//! | every numeric column (`x_ref`, `dx`, `u_dx`, ...) | (n_i, n_j) float64 | NaN where no dot or the field is empty |
//! | `valid` | (n_i, n_j) bool | false where no dot |
//! | `flags` | (n_i, n_j) uint32 | bit mask of the `flags` column, 0 where no dot |
//! | units | `.npz`: `variables`, `units` (string arrays, same order); `.mat`: struct `units` (`units.dx = 'px'`) | the unit of every array above |
//! | flag bits | `.npz`: `flag_names`, `flag_bits` (uint32); `.mat`: struct `flag_bits` (`flag_bits.outlier`) | the bit of every flag |
//!
//! Row `r`, column `c` is the site `i = i[r]`, `j = j[c]`; `i` grows along the lattice vector
//! closest to +x and `j` along the one closest to +y (docs/CONVENTIONS.md), so on an unrotated
//! target an array shows the image transposed: plot with the `x_ref`, `y_ref` arrays as
//! coordinates (e.g. `pcolormesh(x_ref, y_ref, dx)`), or transpose.

mod mat;

use bostrack_core::DotFlags;
use std::path::Path;

/// The values of one lattice array, row-major (row i, column j).
#[derive(Clone, Debug, PartialEq)]
pub enum FieldValues {
    /// A numeric column; NaN where no dot or an empty field.
    Float(Vec<f64>),
    /// `present` and `valid`; false where no dot.
    Bool(Vec<bool>),
    /// `flags` as a bit mask ([`DotFlags::bits`]); 0 where no dot.
    Bits(Vec<u32>),
}

/// One lattice array: its name (the `dots.csv` column), unit and values.
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    pub name: String,
    /// `px`, `counts`, `1` (dimensionless), `bool`, `bitmask`, `m`, `kg/m^4`; empty when the
    /// column is not known to this version.
    pub unit: &'static str,
    pub values: FieldValues,
}

/// A frame's dots on their lattice: every `dots.csv` quantity as a 2-D array of
/// `i.len()` rows and `j.len()` columns (module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct LatticeFields {
    /// Grid index `i` of each row, consecutive from the smallest to the largest in the file.
    pub i: Vec<i32>,
    /// Grid index `j` of each column.
    pub j: Vec<i32>,
    /// `present`, then the columns of `dots.csv` other than `i, j`, in file order.
    pub fields: Vec<Field>,
}

/// The unit of a `dots.csv` column (also of the columns #15 appends); empty when unknown.
pub fn unit_of(column: &str) -> &'static str {
    match column {
        "i" | "j" => "index",
        "present" | "valid" => "bool",
        "flags" => "bitmask",
        "rho_ref" | "rho_grad" | "ar_x" | "ar_y" => "1",
        "amp_ref" | "amp_grad" => "counts",
        "x_m" | "y_m" => "m",
        "grad_rho_x" | "grad_rho_y" | "u_grad_rho_x" | "u_grad_rho_y" => "kg/m^4",
        c if c.starts_with("x_")
            || c.starts_with("y_")
            || c.starts_with("sigma_")
            || c.starts_with("crlb_")
            || c.starts_with("u_")
            || c == "dx"
            || c == "dy" =>
        {
            "px"
        }
        _ => "",
    }
}

/// Most lattice sites per dot row: a file whose grid indices span more is not one lattice (a
/// masked or rotated target fills at least a quarter of its index box).
const MAX_SITES_PER_ROW: usize = 16;

impl LatticeFields {
    /// Rows in the arrays (`i.len()`) and columns (`j.len()`).
    pub fn shape(&self) -> (usize, usize) {
        (self.i.len(), self.j.len())
    }

    /// The array called `name`.
    pub fn get(&self, name: &str) -> Option<&Field> {
        self.fields.iter().find(|f| f.name == name)
    }

    /// Builds the arrays from the text of a `dots.csv` (columns `i`, `j`, numeric columns,
    /// `valid`, `flags`; any other column is numeric). `Err` names the row and column of the
    /// first problem.
    pub fn from_dots_csv(bytes: &[u8]) -> Result<LatticeFields, String> {
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(true)
            .from_reader(bytes);
        let headers: Vec<String> = rdr
            .headers()
            .map_err(|e| e.to_string())?
            .iter()
            .map(str::to_string)
            .collect();
        let col = |name: &str| {
            headers
                .iter()
                .position(|h| h == name)
                .ok_or_else(|| format!("no column `{name}`"))
        };
        let (ci, cj) = (col("i")?, col("j")?);
        let mut index: Vec<(i32, i32)> = Vec::new();
        let mut cells: Vec<Vec<String>> = vec![Vec::new(); headers.len()];
        for (k, rec) in rdr.records().enumerate() {
            let rec = rec.map_err(|e| e.to_string())?;
            let int = |c: usize| -> Result<i32, String> {
                let s = rec.get(c).unwrap_or("");
                s.parse().map_err(|_| {
                    format!(
                        "row {}: `{s}` in column `{}` is not an integer",
                        k + 2,
                        headers[c]
                    )
                })
            };
            index.push((int(ci)?, int(cj)?));
            for (c, cell) in cells.iter_mut().enumerate() {
                if c != ci && c != cj {
                    cell.push(rec.get(c).unwrap_or("").to_string());
                }
            }
        }
        // the index box, checked before anything of its size is allocated
        let range = |k: fn(&(i32, i32)) -> i32| {
            let lo = index.iter().map(k).min().unwrap_or(0);
            let hi = index.iter().map(k).max().unwrap_or(-1);
            (lo, (i64::from(hi) - i64::from(lo) + 1).max(0) as u64)
        };
        let ((i0, ni), (j0, nj)) = (range(|p| p.0), range(|p| p.1));
        if ni.saturating_mul(nj) > (MAX_SITES_PER_ROW * index.len() + 4096) as u64 {
            return Err(format!(
                "the grid indices span {ni} x {nj} sites for {} rows: not the dots of one lattice",
                index.len()
            ));
        }
        let i: Vec<i32> = (0..ni as i32).map(|k| i0 + k).collect();
        let j: Vec<i32> = (0..nj as i32).map(|k| j0 + k).collect();
        let sites = i.len() * j.len();
        let mut at = Vec::with_capacity(index.len());
        let mut present = vec![false; sites];
        for (k, &(ii, jj)) in index.iter().enumerate() {
            let cell = (ii - i[0]) as usize * j.len() + (jj - j[0]) as usize;
            if present[cell] {
                return Err(format!("row {}: site ({ii}, {jj}) appears twice", k + 2));
            }
            present[cell] = true;
            at.push(cell);
        }
        let mut fields = vec![Field {
            name: "present".into(),
            unit: unit_of("present"),
            values: FieldValues::Bool(present),
        }];
        for (c, name) in headers.iter().enumerate() {
            if c == ci || c == cj {
                continue;
            }
            let bad = |k: usize, s: &str, what: &str| {
                format!("row {}: `{s}` in column `{name}` is not {what}", k + 2)
            };
            let values = match name.as_str() {
                "valid" => {
                    let mut v = vec![false; sites];
                    for (k, s) in cells[c].iter().enumerate() {
                        v[at[k]] = match s.as_str() {
                            "true" => true,
                            "false" => false,
                            _ => return Err(bad(k, s, "true/false")),
                        };
                    }
                    FieldValues::Bool(v)
                }
                "flags" => {
                    let mut v = vec![0u32; sites];
                    for (k, s) in cells[c].iter().enumerate() {
                        v[at[k]] = DotFlags::parse(s)
                            .map_err(|e| format!("row {}: column `flags`: {e}", k + 2))?
                            .bits();
                    }
                    FieldValues::Bits(v)
                }
                _ => {
                    let mut v = vec![f64::NAN; sites];
                    for (k, s) in cells[c].iter().enumerate() {
                        if !s.is_empty() {
                            v[at[k]] = s.parse().map_err(|_| bad(k, s, "a number"))?;
                        }
                    }
                    FieldValues::Float(v)
                }
            };
            fields.push(Field {
                name: name.clone(),
                unit: unit_of(name),
                values,
            });
        }
        Ok(LatticeFields { i, j, fields })
    }

    /// Reads a `dots.csv` ([`LatticeFields::from_dots_csv`]); errors name the file.
    pub fn read(path: &Path) -> Result<LatticeFields, crate::BatchError> {
        let bytes = crate::batch::fsx::read(path)?;
        Self::from_dots_csv(&bytes).map_err(|message| crate::BatchError::Corrupt {
            path: path.to_path_buf(),
            message,
        })
    }

    /// `(name, unit)` of every array of the files: `i`, `j`, then [`LatticeFields::fields`].
    pub fn units(&self) -> Vec<(&str, &'static str)> {
        let mut out = vec![("i", unit_of("i")), ("j", unit_of("j"))];
        out.extend(self.fields.iter().map(|f| (f.name.as_str(), f.unit)));
        out
    }

    /// The `.npz` file (numpy; arrays stored uncompressed): the module documentation's arrays.
    pub fn to_npz(&self) -> Result<Vec<u8>, String> {
        use ndarray::{Array1, Array2};
        use ndarray_npy::NpzWriter;
        let err = |e: ndarray_npy::WriteNpzError| e.to_string();
        let (rows, cols) = self.shape();
        let mut npz = NpzWriter::new(std::io::Cursor::new(Vec::new()));
        let index = |v: &[i32]| Array1::from_iter(v.iter().map(|&x| i64::from(x)));
        npz.add_array("i", &index(&self.i)).map_err(err)?;
        npz.add_array("j", &index(&self.j)).map_err(err)?;
        let shape = |e: ndarray::ShapeError| e.to_string();
        for f in &self.fields {
            match &f.values {
                FieldValues::Float(v) => npz.add_array(
                    f.name.as_str(),
                    &Array2::from_shape_vec((rows, cols), v.clone()).map_err(shape)?,
                ),
                FieldValues::Bool(v) => npz.add_array(
                    f.name.as_str(),
                    &Array2::from_shape_vec((rows, cols), v.clone()).map_err(shape)?,
                ),
                FieldValues::Bits(v) => npz.add_array(
                    f.name.as_str(),
                    &Array2::from_shape_vec((rows, cols), v.clone()).map_err(shape)?,
                ),
            }
            .map_err(err)?;
        }
        let strings = |v: Vec<&str>| -> Result<Array1<NpyStr>, String> {
            v.into_iter().map(NpyStr::new).collect::<Result<_, _>>()
        };
        let units = self.units();
        npz.add_array("variables", &strings(units.iter().map(|u| u.0).collect())?)
            .map_err(err)?;
        npz.add_array("units", &strings(units.iter().map(|u| u.1).collect())?)
            .map_err(err)?;
        let flags = flag_bits();
        npz.add_array("flag_names", &strings(flags.iter().map(|f| f.0).collect())?)
            .map_err(err)?;
        npz.add_array("flag_bits", &Array1::from_iter(flags.iter().map(|f| f.1)))
            .map_err(err)?;
        Ok(npz.finish().map_err(err)?.into_inner())
    }

    /// The `.mat` file (MATLAB Level 5, uncompressed): the module documentation's arrays.
    pub fn to_mat(&self) -> Result<Vec<u8>, String> {
        mat::write(self)
    }
}

/// `(name, bit)` of every [`DotFlags`] flag, in bit order.
pub fn flag_bits() -> Vec<(&'static str, u32)> {
    DotFlags::from_bits(u32::MAX)
        .names()
        .map(|n| (n, DotFlags::parse(n).map_or(0, DotFlags::bits)))
        .collect()
}

/// A numpy fixed-width unicode string (`<U64`): the names and units of the `.npz` file.
#[derive(Clone, Debug, PartialEq)]
struct NpyStr(Vec<char>);

/// Characters of an [`NpyStr`]: MATLAB's longest variable name (63) and one more.
const NPY_STR_CHARS: usize = 64;

impl NpyStr {
    fn new(s: &str) -> Result<NpyStr, String> {
        let chars: Vec<char> = s.chars().collect();
        if chars.len() > NPY_STR_CHARS {
            return Err(format!("`{s}` is longer than {NPY_STR_CHARS} characters"));
        }
        Ok(NpyStr(chars))
    }
}

impl ndarray_npy::WritableElement for NpyStr {
    fn type_descriptor() -> py_literal::Value {
        py_literal::Value::String(format!("<U{NPY_STR_CHARS}"))
    }

    fn write<W: std::io::Write>(&self, mut writer: W) -> Result<(), ndarray_npy::WriteDataError> {
        let mut buf = [0u8; 4 * NPY_STR_CHARS];
        for (k, c) in self.0.iter().enumerate() {
            buf[4 * k..4 * k + 4].copy_from_slice(&u32::from(*c).to_le_bytes());
        }
        writer.write_all(&buf)?;
        Ok(())
    }

    fn write_slice<W: std::io::Write>(
        slice: &[Self],
        mut writer: W,
    ) -> Result<(), ndarray_npy::WriteDataError> {
        for s in slice {
            s.write(&mut writer)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bostrack_displacement::COLUMNS;

    const CSV: &str = "i,j,x_ref,dx,valid,flags\n\
                       2,5,10.500000,0.250000,true,\n\
                       3,7,20.000000,,false,outlier|saturated\n";

    #[test]
    fn rows_go_to_their_sites_and_holes_are_nan() {
        let f = LatticeFields::from_dots_csv(CSV.as_bytes()).unwrap();
        assert_eq!(f.i, vec![2, 3]);
        assert_eq!(f.j, vec![5, 6, 7]);
        let FieldValues::Float(dx) = &f.get("dx").unwrap().values else {
            panic!()
        };
        assert_eq!(dx[0], 0.25);
        assert!(
            dx[1].is_nan() && dx[5].is_nan(),
            "hole and empty field are NaN"
        );
        let FieldValues::Float(x) = &f.get("x_ref").unwrap().values else {
            panic!()
        };
        assert_eq!((x[0], x[5]), (10.5, 20.0));
        assert_eq!(
            f.get("present").unwrap().values,
            FieldValues::Bool(vec![true, false, false, false, false, true])
        );
        assert_eq!(
            f.get("valid").unwrap().values,
            FieldValues::Bool(vec![true, false, false, false, false, false])
        );
        let want = (DotFlags::OUTLIER | DotFlags::SATURATED).bits();
        assert_eq!(
            f.get("flags").unwrap().values,
            FieldValues::Bits(vec![0, 0, 0, 0, 0, want])
        );
        assert_eq!(f.get("dx").unwrap().unit, "px");
    }

    #[test]
    fn bad_files_are_errors_naming_the_row() {
        let e = LatticeFields::from_dots_csv(b"i,j,dx\n1,1,x\n").unwrap_err();
        assert!(e.contains("row 2") && e.contains("`dx`"), "{e}");
        let e = LatticeFields::from_dots_csv(b"i,j,dx\n1,1,0\n1,1,0\n").unwrap_err();
        assert!(e.contains("appears twice"), "{e}");
        let e = LatticeFields::from_dots_csv(b"i,j\n0,0\n100000,100000\n").unwrap_err();
        assert!(e.contains("not the dots of one lattice"), "{e}");
        let e = LatticeFields::from_dots_csv(b"x,j\n").unwrap_err();
        assert!(e.contains("no column `i`"), "{e}");
        let e = LatticeFields::from_dots_csv(b"i,j,flags\n1,1,bogus\n").unwrap_err();
        assert!(e.contains("unknown flag"), "{e}");
    }

    #[test]
    fn every_dots_csv_column_has_a_unit() {
        for c in COLUMNS {
            assert!(!unit_of(c).is_empty(), "column `{c}` has no unit");
        }
        assert_eq!(unit_of("amp_ref"), "counts");
        assert_eq!(unit_of("u_grad_x"), "px");
        assert_eq!(unit_of("ar_y"), "1");
    }

    #[test]
    fn npz_reads_back_with_the_same_values() {
        use ndarray::{Array1, Array2};
        use ndarray_npy::NpzReader;
        let f = LatticeFields::from_dots_csv(CSV.as_bytes()).unwrap();
        let bytes = f.to_npz().unwrap();
        let mut r = NpzReader::new(std::io::Cursor::new(bytes)).unwrap();
        let i: Array1<i64> = r.by_name("i").unwrap();
        assert_eq!(i.to_vec(), vec![2, 3]);
        let dx: Array2<f64> = r.by_name("dx").unwrap();
        assert_eq!(dx.dim(), (2, 3));
        assert_eq!(dx[[0, 0]], 0.25);
        assert!(dx[[1, 2]].is_nan());
        let valid: Array2<bool> = r.by_name("valid").unwrap();
        assert!(valid[[0, 0]] && !valid[[1, 2]]);
        let flags: Array2<u32> = r.by_name("flags").unwrap();
        assert_eq!(
            flags[[1, 2]],
            (DotFlags::OUTLIER | DotFlags::SATURATED).bits()
        );
        let bits: Array1<u32> = r.by_name("flag_bits").unwrap();
        assert_eq!(bits.len(), flag_bits().len());
        let mut names = r.names().unwrap();
        names.sort();
        for want in ["variables", "units", "flag_names", "present"] {
            assert!(names.iter().any(|n| n == want), "{want} in {names:?}");
        }
    }
}
