//! A MATLAB Level 5 MAT-file writer for the lattice arrays: 2-D double, uint32 and logical
//! arrays, and scalar structs of char rows and doubles; little-endian, uncompressed (read by
//! MATLAB's and Octave's `load` and by `scipy.io.loadmat`).
//!
//! Written here rather than taken from a crate (docs/ARCHITECTURE.md, "Dependencies and why"):
//! `matfile` 0.5 only reads; `matrw` 0.1.4 writes, but its one writing function takes the path
//! as `&str` and returns `Ok` after a failed write (`let _ =` on the write and the flush), its
//! writing interface has no logical arrays, and it brings `binrw`, `chrono` and `paste`. The
//! subset needed is a few documented records (MathWorks, "MAT-File Format", Level 5): a
//! 128-byte header, then one `miMATRIX` element per variable holding its array flags,
//! dimensions, name and data, every element padded to 8 bytes. It is checked by reading the
//! files back with `matfile` (Rust tests) and with `scipy.io.loadmat` and Octave (Python tests).

use super::{FieldValues, LatticeFields, flag_bits};

// data types of the elements
const MI_INT8: u32 = 1;
const MI_UINT8: u32 = 2;
const MI_UINT16: u32 = 4;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;
const MI_DOUBLE: u32 = 9;
const MI_MATRIX: u32 = 14;
// array classes
const MX_STRUCT: u32 = 2;
const MX_CHAR: u32 = 4;
const MX_DOUBLE: u32 = 6;
const MX_UINT8: u32 = 9;
const MX_UINT32: u32 = 13;
/// The logical bit of the array flags (in the class word, bit 9).
const LOGICAL: u32 = 0x0200;
/// MATLAB's longest variable and field name.
const MAX_NAME: usize = 63;

/// The file: the header, then `i` (column), `j` (row), every field, `units`, `flag_bits`.
pub(super) fn write(f: &LatticeFields) -> Result<Vec<u8>, String> {
    let (rows, cols) = f.shape();
    let mut out = header();
    let index = |v: &[i32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<f64>>();
    out.extend(matrix("i", [f.i.len(), 1], &Data::Double(index(&f.i)))?);
    out.extend(matrix("j", [1, f.j.len()], &Data::Double(index(&f.j)))?);
    for field in &f.fields {
        let data = match &field.values {
            FieldValues::Float(v) => Data::Double(column_major(v, rows, cols)),
            FieldValues::Bool(v) => Data::Logical(column_major(v, rows, cols)),
            FieldValues::Bits(v) => Data::Uint32(column_major(v, rows, cols)),
        };
        out.extend(matrix(&field.name, [rows, cols], &data)?);
    }
    let units: Vec<(&str, Data)> = f
        .units()
        .into_iter()
        .map(|(name, unit)| (name, Data::Char(unit.to_string())))
        .collect();
    out.extend(matrix("units", [1, 1], &Data::Struct(units))?);
    let bits: Vec<(&str, Data)> = flag_bits()
        .into_iter()
        .map(|(name, bit)| (name, Data::Double(vec![f64::from(bit)])))
        .collect();
    out.extend(matrix("flag_bits", [1, 1], &Data::Struct(bits))?);
    Ok(out)
}

/// The values of one array, column-major.
enum Data<'a> {
    Double(Vec<f64>),
    Logical(Vec<bool>),
    Uint32(Vec<u32>),
    Char(String),
    /// A scalar struct: field names and values.
    Struct(Vec<(&'a str, Data<'a>)>),
}

fn column_major<T: Copy>(v: &[T], rows: usize, cols: usize) -> Vec<T> {
    let mut out = Vec::with_capacity(v.len());
    for c in 0..cols {
        for r in 0..rows {
            out.push(v[r * cols + c]);
        }
    }
    out
}

/// The 128-byte header: text, no subsystem data, version 0x0100, endian indicator "IM".
fn header() -> Vec<u8> {
    let text = format!(
        "MATLAB 5.0 MAT-file, Platform: {}, Created by: bostrack {} (lattice arrays)",
        std::env::consts::OS,
        env!("CARGO_PKG_VERSION")
    );
    let mut h = vec![b' '; 116];
    let n = text.len().min(116);
    h[..n].copy_from_slice(&text.as_bytes()[..n]);
    h.extend([0u8; 8]);
    h.extend(0x0100u16.to_le_bytes());
    h.extend(*b"IM");
    h
}

/// One data element: tag (type, byte count), the bytes, zeros to the next multiple of 8.
fn element(out: &mut Vec<u8>, ty: u32, bytes: &[u8]) -> Result<(), String> {
    let n = u32::try_from(bytes.len()).map_err(|_| "an array of more than 4 GiB".to_string())?;
    out.extend(ty.to_le_bytes());
    out.extend(n.to_le_bytes());
    out.extend(bytes);
    out.resize(out.len().next_multiple_of(8), 0);
    Ok(())
}

fn valid_name(name: &str) -> Result<(), String> {
    let mut chars = name.chars();
    let ok = chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && name.len() <= MAX_NAME;
    if ok {
        Ok(())
    } else {
        Err(format!("`{name}` is not a MATLAB variable name"))
    }
}

/// A `miMATRIX` element: array flags, dimensions, name, data.
fn matrix(name: &str, dims: [usize; 2], data: &Data<'_>) -> Result<Vec<u8>, String> {
    if !name.is_empty() {
        valid_name(name)?;
    }
    let (class, dims) = match data {
        Data::Double(_) => (MX_DOUBLE, dims),
        Data::Logical(_) => (MX_UINT8 | LOGICAL, dims),
        Data::Uint32(_) => (MX_UINT32, dims),
        Data::Char(s) if s.is_empty() => (MX_CHAR, [0, 0]),
        Data::Char(s) => (MX_CHAR, [1, s.encode_utf16().count()]),
        Data::Struct(_) => (MX_STRUCT, [1, 1]),
    };
    let mut body = Vec::new();
    let mut flags = class.to_le_bytes().to_vec();
    flags.extend(0u32.to_le_bytes());
    element(&mut body, MI_UINT32, &flags)?;
    let mut d = Vec::new();
    for n in dims {
        let n = i32::try_from(n).map_err(|_| format!("`{name}`: dimension {n} too large"))?;
        d.extend(n.to_le_bytes());
    }
    element(&mut body, MI_INT32, &d)?;
    element(&mut body, MI_INT8, name.as_bytes())?;
    match data {
        Data::Double(v) => {
            element(&mut body, MI_DOUBLE, &bytes(v, |x| x.to_le_bytes()))?;
        }
        Data::Logical(v) => {
            let b: Vec<u8> = v.iter().map(|&x| u8::from(x)).collect();
            element(&mut body, MI_UINT8, &b)?;
        }
        Data::Uint32(v) => {
            element(&mut body, MI_UINT32, &bytes(v, |x| x.to_le_bytes()))?;
        }
        Data::Char(s) => {
            let units: Vec<u16> = s.encode_utf16().collect();
            element(&mut body, MI_UINT16, &bytes(&units, |x| x.to_le_bytes()))?;
        }
        Data::Struct(fields) => {
            let width = fields.iter().map(|(n, _)| n.len()).max().unwrap_or(0) + 1;
            // the field name length in the small data element format (type and byte count in
            // one word, then the value): Octave reads it only in that form
            body.extend(((4u32 << 16) | MI_INT32).to_le_bytes());
            body.extend((width as i32).to_le_bytes());
            let mut names = vec![0u8; width * fields.len()];
            for (k, (n, _)) in fields.iter().enumerate() {
                valid_name(n)?;
                names[k * width..k * width + n.len()].copy_from_slice(n.as_bytes());
            }
            element(&mut body, MI_INT8, &names)?;
            for (_, value) in fields {
                let dims = match value {
                    Data::Double(v) => [1, v.len()],
                    _ => [1, 1],
                };
                body.extend(matrix("", dims, value)?);
            }
        }
    }
    let mut out = Vec::with_capacity(body.len() + 8);
    element(&mut out, MI_MATRIX, &body)?;
    Ok(out)
}

fn bytes<T: Copy, const N: usize>(v: &[T], le: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    let mut out = Vec::with_capacity(v.len() * N);
    for &x in v {
        out.extend(le(x));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_back_with_the_matfile_crate() {
        let csv = "i,j,x_ref,dx,valid,flags\n\
                   2,5,10.500000,0.250000,true,\n\
                   3,7,20.000000,,false,outlier\n";
        let f = LatticeFields::from_dots_csv(csv.as_bytes()).unwrap();
        let bytes = f.to_mat().unwrap();
        assert_eq!(&bytes[126..128], b"IM");
        let m = matfile::MatFile::parse(std::io::Cursor::new(bytes)).unwrap();
        let get = |name: &str| m.find_by_name(name).unwrap_or_else(|| panic!("{name}"));
        let dx = get("dx");
        assert_eq!(dx.size(), &[2, 3]);
        let matfile::NumericData::Double { real, .. } = dx.data() else {
            panic!("dx is not double")
        };
        // column-major: (0,0), (1,0), (0,1), ...; (1,2) = site (3,7) has an empty dx
        assert_eq!(real[0], 0.25);
        assert!(real[1..].iter().all(|v| v.is_nan()));
        let matfile::NumericData::Double { real: x, .. } = get("x_ref").data() else {
            panic!()
        };
        assert_eq!((x[0], x[5]), (10.5, 20.0));
        assert_eq!(get("i").size(), &[2, 1]);
        assert_eq!(get("j").size(), &[1, 3]);
        let matfile::NumericData::UInt32 { real: flags, .. } = get("flags").data() else {
            panic!("flags is not uint32")
        };
        assert_eq!(flags[5], bostrack_core::DotFlags::OUTLIER.bits());
        let matfile::NumericData::UInt8 { real: valid, .. } = get("valid").data() else {
            panic!("valid is not logical (uint8)")
        };
        assert_eq!(valid, &vec![1, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn names_matlab_cannot_hold_are_errors() {
        assert!(matrix("2x", [1, 1], &Data::Double(vec![1.0])).is_err());
        assert!(matrix("a-b", [1, 1], &Data::Double(vec![1.0])).is_err());
        assert!(matrix(&"a".repeat(64), [1, 1], &Data::Double(vec![1.0])).is_err());
        assert!(matrix("ok_1", [1, 1], &Data::Double(vec![1.0])).is_ok());
    }
}
