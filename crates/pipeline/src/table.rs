//! The one CSV writer of bostrack: `locate`'s table, a run's `<frame>/dots.csv` and
//! `campaign.csv` all go through [`CsvTable`]. Its float cells are formatted by
//! [`bostrack_core::table::number`] (fixed decimals; an unknown value is the empty field, never
//! `NaN`), so one convention holds in every file (docs/CONVENTIONS.md, "Tables").

use std::io::{self, Write};

/// A CSV table written row by row: a header, then rows of exactly as many cells (RFC 4180
/// quoting where a cell needs it, `\n` line ends). A row none of whose cells needs quotes (no
/// `,`, `"`, `\r` or `\n`: every row of numbers) is written directly, its cells joined by commas,
/// which is what the `csv` crate writes for it; any other row goes through the `csv` crate.
#[derive(Debug)]
pub struct CsvTable<W: Write> {
    out: io::BufWriter<W>,
    width: usize,
}

impl<W: Write> CsvTable<W> {
    /// Starts the table with its header row.
    pub fn new<S: AsRef<str>>(w: W, header: &[S]) -> io::Result<Self> {
        let mut t = CsvTable::body(w, header.len());
        t.row(header)?;
        Ok(t)
    }

    /// A table's rows without their header (`width` cells each): a part of a table that is
    /// written in parts (the parts joined after the header are the whole table).
    pub fn body(w: W, width: usize) -> Self {
        CsvTable {
            out: io::BufWriter::with_capacity(1 << 16, w),
            width,
        }
    }

    /// Writes one row; an error if it has not as many cells as the header.
    pub fn row<S: AsRef<str>>(&mut self, cells: &[S]) -> io::Result<()> {
        if cells.len() != self.width {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "a table row of {} cells under a header of {}",
                    cells.len(),
                    self.width
                ),
            ));
        }
        let plain = |c: &S| {
            !c.as_ref()
                .bytes()
                .any(|b| matches!(b, b',' | b'"' | b'\r' | b'\n'))
        };
        // (one cell: the `csv` crate quotes an empty one, so that the row is not a blank line)
        if self.width >= 2 && cells.iter().all(plain) {
            for (k, c) in cells.iter().enumerate() {
                if k > 0 {
                    self.out.write_all(b",")?;
                }
                self.out.write_all(c.as_ref().as_bytes())?;
            }
            return self.out.write_all(b"\n");
        }
        let mut quoted = csv::WriterBuilder::new()
            .terminator(csv::Terminator::Any(b'\n'))
            .from_writer(Vec::new());
        quoted.write_record(cells.iter().map(|s| s.as_ref()))?;
        let bytes = quoted.into_inner().map_err(|e| e.into_error())?;
        self.out.write_all(&bytes)
    }

    /// Flushes the table and gives back the writer.
    pub fn finish(self) -> io::Result<W> {
        self.out.into_inner().map_err(|e| e.into_error())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bostrack_core::table::number;

    #[test]
    fn rows_under_the_header_with_empty_unknowns_and_quoted_text() {
        let mut t = CsvTable::new(Vec::new(), &["a", "b", "c"]).unwrap();
        t.row(&[number(1.25), number(f64::NAN), "x,y".to_string()])
            .unwrap();
        t.row(&["", "", ""]).unwrap();
        assert!(t.row(&["1", "2"]).is_err());
        let text = String::from_utf8(t.finish().unwrap()).unwrap();
        assert_eq!(text, "a,b,c\n1.250000,,\"x,y\"\n,,\n");
    }

    /// Every row, written directly or through the `csv` crate, is the `csv` crate's row; a
    /// table written in parts ([`CsvTable::body`]) is the table written whole.
    #[test]
    fn rows_are_the_csv_crates_rows() {
        let cells = [
            "",
            "1.5",
            "-0.000001",
            "x,y",
            "say \"hi\"",
            "a\nb",
            "c\rd",
            " pad ",
            "ok|flag",
            "é",
        ];
        let mut rows: Vec<Vec<String>> = Vec::new();
        for width in 1..=4 {
            for start in 0..cells.len() {
                rows.push(
                    (0..width)
                        .map(|k| cells[(start + 3 * k) % cells.len()].to_string())
                        .collect(),
                );
            }
        }
        for width in 1..=4 {
            let rows: Vec<&Vec<String>> = rows.iter().filter(|r| r.len() == width).collect();
            let header: Vec<String> = (0..width).map(|k| format!("h{k}")).collect();
            let mut mine = CsvTable::new(Vec::new(), &header).unwrap();
            let mut theirs = csv::WriterBuilder::new()
                .terminator(csv::Terminator::Any(b'\n'))
                .from_writer(Vec::new());
            theirs.write_record(&header).unwrap();
            for r in &rows {
                mine.row(r).unwrap();
                theirs.write_record(r.iter()).unwrap();
            }
            let whole = mine.finish().unwrap();
            assert_eq!(whole, theirs.into_inner().unwrap(), "width {width}");
            // in parts: the header, then two bodies
            let mut parts = CsvTable::new(Vec::new(), &header)
                .unwrap()
                .finish()
                .unwrap();
            for half in rows.chunks(rows.len().div_ceil(2)) {
                let mut b = CsvTable::body(Vec::new(), width);
                for r in half {
                    b.row(r).unwrap();
                }
                parts.extend(b.finish().unwrap());
            }
            assert_eq!(parts, whole, "width {width} in parts");
        }
    }
}
