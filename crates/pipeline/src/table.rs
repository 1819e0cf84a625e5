//! The one CSV writer of bostrack: `locate`'s table, a run's `<frame>/dots.csv` and
//! `campaign.csv` all go through [`CsvTable`]. Its float cells are formatted by
//! [`bostrack_core::table::number`] (fixed decimals; an unknown value is the empty field, never
//! `NaN`), so one convention holds in every file (docs/CONVENTIONS.md, "Tables").

use std::io::{self, Write};

/// A CSV table written row by row: a header, then rows of exactly as many cells (RFC 4180
/// quoting where a cell needs it, `\n` line ends).
#[derive(Debug)]
pub struct CsvTable<W: Write> {
    out: csv::Writer<W>,
    width: usize,
}

impl<W: Write> CsvTable<W> {
    /// Starts the table with its header row.
    pub fn new<S: AsRef<str>>(w: W, header: &[S]) -> io::Result<Self> {
        let mut out = csv::WriterBuilder::new()
            .terminator(csv::Terminator::Any(b'\n'))
            .from_writer(w);
        out.write_record(header.iter().map(|s| s.as_ref()))?;
        Ok(CsvTable {
            out,
            width: header.len(),
        })
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
        self.out.write_record(cells.iter().map(|s| s.as_ref()))?;
        Ok(())
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
}
