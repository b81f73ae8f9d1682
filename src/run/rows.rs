//! Tables row by row: a CSV reader that yields one checked row at a time from any byte
//! stream, and a CSV writer that formats one row at a time into any sink. [`Table`] reads
//! and writes through these, so a streamed table and a whole one agree to the byte; jobs
//! whose tables can be large (`serial.fk` over a file) use them directly, with memory flat
//! in the number of rows.
//!
//! [`Table`]: super::Table

use std::io::{Read, Write};

use sha2::{Digest, Sha256};

use crate::run::JobError;

/// CSV rows read one at a time, each checked as [`super::Table::from_csv`] checks it: as
/// wide as the header, every cell a finite number (or a gap where admitted); errors name
/// the input, the row (from 1, the header not counted), the column and the value.
pub struct CsvRows<R: Read> {
    field: String,
    reader: csv::Reader<R>,
    columns: Vec<String>,
    gaps: Vec<bool>,
    record: csv::ByteRecord,
    row: usize,
}

impl<R: Read> std::fmt::Debug for CsvRows<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CsvRows")
            .field("field", &self.field)
            .field("columns", &self.columns)
            .field("row", &self.row)
            .finish()
    }
}

impl<R: Read> CsvRows<R> {
    /// Read the header of the CSV text `input` (named `field` in errors); in the columns
    /// `gaps` admits, an empty or `NaN` cell is a missing value (NaN).
    pub fn new(field: &str, input: R, gaps: &dyn Fn(&str) -> bool) -> Result<Self, JobError> {
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(true)
            .trim(csv::Trim::Headers)
            .flexible(true)
            .buffer_capacity(1 << 16)
            .from_reader(input);
        let columns: Vec<String> = reader
            .headers()
            .map_err(|e| JobError::invalid(field, format!("CSV header: {e}")))?
            .iter()
            .map(str::to_string)
            .collect();
        if columns.iter().any(String::is_empty) {
            return Err(JobError::invalid(
                field,
                "CSV header has an empty column name",
            ));
        }
        // A repeated name would make one of the two columns unreachable by name.
        for (i, c) in columns.iter().enumerate() {
            if let Some(j) = columns[..i].iter().position(|d| d == c) {
                return Err(JobError::invalid(
                    field,
                    format!(
                        "CSV header names column `{c}` twice (columns {} and {})",
                        j + 1,
                        i + 1
                    ),
                ));
            }
        }
        let gaps = columns.iter().map(|c| gaps(c)).collect();
        Ok(Self {
            field: field.to_string(),
            reader,
            columns,
            gaps,
            record: csv::ByteRecord::new(),
            row: 0,
        })
    }

    /// Column names, in order.
    pub fn columns(&self) -> &[String] {
        &self.columns
    }

    /// The byte stream, positioned at the end of what was read.
    pub fn into_inner(self) -> R {
        self.reader.into_inner()
    }

    /// Read the next row into `values` (cleared first); its number (from 1), or `None` at
    /// the end of the input.
    pub fn next_into(&mut self, values: &mut Vec<f64>) -> Result<Option<usize>, JobError> {
        let field = self.field.as_str();
        let row = self.row + 1;
        let more = self
            .reader
            .read_byte_record(&mut self.record)
            .map_err(|e| JobError::row(field, row, format!("CSV: {e}")))?;
        if !more {
            return Ok(None);
        }
        self.row = row;
        if self.record.len() != self.columns.len() {
            return Err(JobError::row(
                field,
                row,
                format!(
                    "{} values for {} columns",
                    self.record.len(),
                    self.columns.len()
                ),
            ));
        }
        values.clear();
        for (c, cell) in self.record.iter().enumerate() {
            let cell = trim(cell);
            if self.gaps[c] && (cell.is_empty() || cell.eq_ignore_ascii_case(b"nan")) {
                values.push(f64::NAN);
                continue;
            }
            // Cells are parsed from the record's bytes (no per-row text copy); a cell that
            // is not UTF-8 is not a number either.
            let parsed = std::str::from_utf8(cell)
                .ok()
                .and_then(|t| t.parse::<f64>().ok());
            let cell_text = || String::from_utf8_lossy(cell);
            let v = parsed.ok_or_else(|| {
                JobError::row(
                    field,
                    row,
                    format!(
                        "column `{}`: `{}` is not a number",
                        self.columns[c],
                        cell_text()
                    ),
                )
            })?;
            if !v.is_finite() {
                return Err(JobError::row(
                    field,
                    row,
                    format!(
                        "column `{}`: {} is not a finite number",
                        self.columns[c],
                        cell_text()
                    ),
                ));
            }
            values.push(v);
        }
        Ok(Some(row))
    }
}

/// A cell without its leading and trailing whitespace (Unicode's, as `str::trim`: the
/// ASCII fast path, and the full trim only where a non-ASCII byte or a vertical tab is at an
/// end). Trimming the borrowed bytes here saves the csv reader's copy of every record.
fn trim(cell: &[u8]) -> &[u8] {
    let t = cell.trim_ascii();
    let odd = |b: Option<&u8>| b.is_some_and(|&b| b >= 0x80 || b == 0x0b);
    if !odd(t.first()) && !odd(t.last()) {
        return t;
    }
    match std::str::from_utf8(t) {
        Ok(s) => s.trim().as_bytes(),
        Err(_) => t,
    }
}

/// CSV written one row at a time: a header row (names quoted by `csv::Writer` where they
/// need it), then each number as Rust's shortest round-trip decimal (the text of `{}`), one
/// `\n`-terminated line per row. Rows are formatted into one buffer and handed to `out` in
/// blocks of about [`BLOCK`] bytes (numbers never need quoting).
#[derive(Debug)]
pub struct CsvSink<W: Write> {
    out: W,
    columns: usize,
    rows: usize,
    buf: Vec<u8>,
}

/// Bytes gathered before a write to the sink.
const BLOCK: usize = 1 << 16;

impl<W: Write> CsvSink<W> {
    /// Start a table with `columns` on `out` (the header row is written with the first block).
    pub fn new<S: AsRef<str>>(out: W, columns: &[S]) -> std::io::Result<Self> {
        let mut header = csv::WriterBuilder::new()
            .terminator(csv::Terminator::Any(b'\n'))
            .from_writer(Vec::new());
        header.write_record(columns.iter().map(|c| c.as_ref()))?;
        let mut buf = header.into_inner().map_err(|e| e.into_error())?;
        buf.reserve(BLOCK + 1024);
        Ok(Self {
            out,
            columns: columns.len(),
            rows: 0,
            buf,
        })
    }

    /// Append one row; a row as wide as the header, or an `InvalidInput` error.
    pub fn row(&mut self, values: &[f64]) -> std::io::Result<()> {
        if values.len() != self.columns {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "CSV row {} has {} values for {} columns",
                    self.rows + 1,
                    values.len(),
                    self.columns
                ),
            ));
        }
        for (k, v) in values.iter().enumerate() {
            if k > 0 {
                self.buf.push(b',');
            }
            crate::util::decimal::push_f64_bytes(&mut self.buf, *v);
        }
        self.buf.push(b'\n');
        self.rows += 1;
        if self.buf.len() >= BLOCK {
            self.out.write_all(&self.buf)?;
            self.buf.clear();
        }
        Ok(())
    }

    /// Rows written so far.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// The sink, with every row written and flushed.
    pub fn finish(mut self) -> std::io::Result<W> {
        self.out.write_all(&self.buf)?;
        self.buf.clear();
        self.out.flush()?;
        Ok(self.out)
    }
}

/// A reader that hashes (SHA-256) every byte read through it, so a streamed input gets the
/// same hash in the result envelope as one read whole.
#[derive(Debug)]
pub struct HashingReader<R: Read> {
    inner: R,
    hasher: Sha256,
}

impl<R: Read> HashingReader<R> {
    /// Hash what is read from `inner`.
    pub fn new(inner: R) -> Self {
        Self {
            inner,
            hasher: Sha256::new(),
        }
    }

    /// Hex SHA-256 of every byte read so far.
    pub fn hex(&self) -> String {
        self.hasher
            .clone()
            .finalize()
            .iter()
            .map(|x| format!("{x:02x}"))
            .collect()
    }
}

impl<R: Read> Read for HashingReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.hasher.update(&buf[..n]);
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `Table::to_csv` as it was before tables were streamed: the reference output.
    fn joined(columns: &[&str], rows: &[Vec<f64>]) -> String {
        let mut s = columns.join(",");
        s.push('\n');
        for r in rows {
            let cells: Vec<String> = r.iter().map(|v| format!("{v}")).collect();
            s.push_str(&cells.join(","));
            s.push('\n');
        }
        s
    }

    #[test]
    fn a_column_named_twice_is_refused_by_name() {
        let e = CsvRows::new("joints", &b"q1,q2,q1\n1,2,3\n"[..], &|_: &str| false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("joints") && e.contains("`q1` twice"), "{e}");
        assert!(e.contains("columns 1 and 3"), "{e}");
        assert!(CsvRows::new("joints", &b"q1,q2\n1,2\n"[..], &|_: &str| false).is_ok());
    }

    #[test]
    fn streamed_csv_equals_the_joined_strings_to_the_byte() {
        let rows = [
            vec![0.1 + 0.2, -0.0, 1e-300, 123456789.125],
            vec![f64::MAX, f64::MIN_POSITIVE, -3.5, 1.0 / 3.0],
        ];
        let rows = &rows[..];
        let cols = ["x", "y", "z", "a"];
        let mut sink = CsvSink::new(Vec::new(), &cols).unwrap();
        for r in rows {
            sink.row(r).unwrap();
        }
        assert_eq!(sink.rows(), 2);
        let bytes = sink.finish().unwrap();
        assert_eq!(String::from_utf8(bytes).unwrap(), joined(&cols, rows));
    }

    /// A row narrower or wider than the header is refused, naming its number and widths,
    /// and rows are gathered past the block size without losing or reordering any.
    #[test]
    fn rows_of_another_width_are_refused_and_blocks_keep_every_row() {
        let mut sink = CsvSink::new(Vec::new(), &["a", "b"]).unwrap();
        sink.row(&[1.0, 2.0]).unwrap();
        let e = sink.row(&[1.0]).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
        assert!(
            e.to_string().contains("row 2 has 1 values for 2 columns"),
            "{e}"
        );
        let rows: Vec<Vec<f64>> = (0..20_000)
            .map(|k| vec![k as f64 * 0.37, -(k as f64) / 7.0])
            .collect();
        for r in &rows {
            sink.row(r).unwrap();
        }
        let text = String::from_utf8(sink.finish().unwrap()).unwrap();
        let mut all = vec![vec![1.0, 2.0]];
        all.extend(rows);
        assert!(text.len() > 2 * BLOCK);
        // Read back by the csv reader (the second method): every number, bit for bit.
        let mut back = CsvRows::new("t", text.as_bytes(), &|_: &str| false).unwrap();
        assert_eq!(back.columns(), ["a", "b"]);
        let mut v = Vec::new();
        for want in &all {
            back.next_into(&mut v).unwrap().unwrap();
            let bits = |x: &[f64]| x.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&v), bits(want));
        }
        assert_eq!(back.next_into(&mut v).unwrap(), None);
    }

    /// A column name with a comma, quote or space is quoted as RFC 4180 says, so the header
    /// reads back (through the csv reader, the second method) as the names written.
    #[test]
    fn header_names_that_need_quotes_are_quoted_and_read_back() {
        let cols = ["x, mm", "say \"y\"", "plain"];
        let mut sink = CsvSink::new(Vec::new(), &cols).unwrap();
        sink.row(&[1.0, 2.5, -0.0]).unwrap();
        let text = String::from_utf8(sink.finish().unwrap()).unwrap();
        assert_eq!(text, "\"x, mm\",\"say \"\"y\"\"\",plain\n1,2.5,-0\n");
        let r = CsvRows::new("t", text.as_bytes(), &|_: &str| false).unwrap();
        assert_eq!(r.columns(), cols);
    }

    #[test]
    fn rows_come_one_at_a_time_and_errors_name_row_column_and_value() {
        let text = "q1, q2\n1.5,2\n-3,4e-3\n7,x\n";
        let mut r = CsvRows::new("joints", text.as_bytes(), &|_: &str| false).unwrap();
        assert_eq!(r.columns(), ["q1", "q2"]);
        let mut v = Vec::new();
        assert_eq!(r.next_into(&mut v).unwrap(), Some(1));
        assert_eq!(v, [1.5, 2.0]);
        assert_eq!(r.next_into(&mut v).unwrap(), Some(2));
        assert_eq!(v, [-3.0, 4e-3]);
        let e = r.next_into(&mut v).unwrap_err().to_string();
        assert!(
            e.contains("joints") && e.contains("row 3") && e.contains("`q2`: `x`"),
            "{e}"
        );
        let mut r = CsvRows::new("joints", "q1\n1\n".as_bytes(), &|_: &str| false).unwrap();
        assert_eq!(r.next_into(&mut v).unwrap(), Some(1));
        assert_eq!(r.next_into(&mut v).unwrap(), None);
    }

    /// Cells are trimmed as `str::trim` trims them (ASCII and Unicode whitespace, vertical
    /// tab included); header names too.
    #[test]
    fn cells_are_trimmed_of_unicode_whitespace() {
        let text = " q1 ,q2\n \t1.5\u{a0}, \u{b}-2 \r\n\u{2003}3,4e1\u{3000}\n";
        let mut r = CsvRows::new("t", text.as_bytes(), &|_: &str| false).unwrap();
        assert_eq!(r.columns(), ["q1", "q2"]);
        let mut v = Vec::new();
        r.next_into(&mut v).unwrap();
        assert_eq!(v, [1.5, -2.0]);
        r.next_into(&mut v).unwrap();
        assert_eq!(v, [3.0, 40.0]);
        for cell in [" 1 ", "\u{a0}\u{a0}", "\u{b}x\u{85}", "a\u{a0}b", ""] {
            assert_eq!(trim(cell.as_bytes()), cell.trim().as_bytes(), "{cell:?}");
        }
    }

    #[test]
    fn hashing_reader_hashes_what_passes_through() {
        let text = b"q1,q2\n1,2\n";
        let mut h = HashingReader::new(&text[..]);
        let mut sink = Vec::new();
        h.read_to_end(&mut sink).unwrap();
        assert_eq!(sink, text);
        assert_eq!(h.hex(), crate::run::input::sha256_hex(text));
    }
}
