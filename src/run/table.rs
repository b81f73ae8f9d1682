//! Tables of numbers with named columns: read from CSV text or from JSON row objects, checked
//! column by column and row by row (missing columns, wrong width, non-numbers, NaN are
//! refused with the row and value), and written back as CSV or JSON rows.

use serde_json::{Map, Value};

use super::JobError;
use super::rows::{CsvRows, CsvSink};

/// A numeric table: column names and rows of finite numbers.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Table {
    /// Column names, in order.
    pub columns: Vec<String>,
    /// Rows, each as wide as `columns`.
    pub rows: Vec<Vec<f64>>,
}

impl Table {
    /// An empty table with these columns.
    pub fn new(columns: &[&str]) -> Self {
        Self {
            columns: columns.iter().map(|c| c.to_string()).collect(),
            rows: vec![],
        }
    }

    /// Parse CSV text with a header row; `field` names the input in errors.
    pub fn from_csv(field: &str, text: &str) -> Result<Self, JobError> {
        Self::from_csv_with_gaps(field, text, &|_: &str| false)
    }

    /// As [`Table::from_csv`], but in the columns `gaps` admits an empty or `NaN` cell is a
    /// missing value (kept as NaN), e.g. an occluded motion-capture marker.
    pub fn from_csv_with_gaps(
        field: &str,
        text: &str,
        gaps: &dyn Fn(&str) -> bool,
    ) -> Result<Self, JobError> {
        let mut reader = CsvRows::new(field, text.as_bytes(), gaps)?;
        let columns = reader.columns().to_vec();
        let mut rows = Vec::new();
        let mut values = Vec::with_capacity(columns.len());
        while reader.next_into(&mut values)?.is_some() {
            rows.push(values.clone());
        }
        Ok(Self { columns, rows })
    }

    /// Parse a JSON array of row objects keyed by column name (the form results use).
    pub fn from_json_rows(field: &str, v: &Value) -> Result<Self, JobError> {
        Self::from_json_rows_with_gaps(field, v, &|_: &str| false)
    }

    /// As [`Table::from_json_rows`], with `null` admitted as a missing value (NaN) in the
    /// columns `gaps` admits.
    pub fn from_json_rows_with_gaps(
        field: &str,
        v: &Value,
        gaps: &dyn Fn(&str) -> bool,
    ) -> Result<Self, JobError> {
        let arr = v.as_array().ok_or_else(|| {
            JobError::invalid(field, "expected an array of row objects or a file name")
        })?;
        let mut columns: Vec<String> = Vec::new();
        if let Some(first) = arr.first().and_then(Value::as_object) {
            columns = first.keys().cloned().collect();
        }
        let mut rows = Vec::with_capacity(arr.len());
        for (i, r) in arr.iter().enumerate() {
            let row = i + 1;
            let obj = r
                .as_object()
                .ok_or_else(|| JobError::row(field, row, "is not an object"))?;
            if obj.len() != columns.len() || obj.keys().any(|k| !columns.contains(k)) {
                return Err(JobError::row(
                    field,
                    row,
                    format!(
                        "has columns {:?}, the first row has {:?}",
                        obj.keys().collect::<Vec<_>>(),
                        columns
                    ),
                ));
            }
            let mut vals = Vec::with_capacity(columns.len());
            for c in &columns {
                if gaps(c) && obj.get(c).is_some_and(Value::is_null) {
                    vals.push(f64::NAN);
                    continue;
                }
                let v = obj.get(c).and_then(Value::as_f64).ok_or_else(|| {
                    JobError::row(
                        field,
                        row,
                        format!("column `{c}`: {} is not a number", obj[c]),
                    )
                })?;
                vals.push(v);
            }
            rows.push(vals);
        }
        Ok(Self { columns, rows })
    }

    /// Index of a column, or an error naming the missing column.
    pub fn col(&self, field: &str, name: &str) -> Result<usize, JobError> {
        self.columns.iter().position(|c| c == name).ok_or_else(|| {
            JobError::invalid(
                field,
                format!("missing column `{name}` (columns are {:?})", self.columns),
            )
        })
    }

    /// Whether a column exists.
    pub fn has(&self, name: &str) -> bool {
        self.columns.iter().any(|c| c == name)
    }

    /// Indices of the given columns, erroring on the first missing one.
    pub fn cols(&self, field: &str, names: &[String]) -> Result<Vec<usize>, JobError> {
        names.iter().map(|n| self.col(field, n)).collect()
    }

    /// The table without column `name` (the same table if it has none).
    pub fn without(&self, name: &str) -> Table {
        let keep: Vec<usize> = (0..self.columns.len())
            .filter(|&k| self.columns[k] != name)
            .collect();
        Table {
            columns: keep.iter().map(|&k| self.columns[k].clone()).collect(),
            rows: self
                .rows
                .iter()
                .map(|r| keep.iter().map(|&k| r[k]).collect())
                .collect(),
        }
    }

    /// Append a row.
    pub fn push(&mut self, row: Vec<f64>) {
        debug_assert_eq!(row.len(), self.columns.len());
        self.rows.push(row);
    }

    /// The table as JSON row objects.
    pub fn to_json_rows(&self) -> Value {
        Value::Array(
            self.rows
                .iter()
                .map(|r| {
                    let mut m = Map::new();
                    for (c, v) in self.columns.iter().zip(r) {
                        m.insert(
                            c.clone(),
                            serde_json::Number::from_f64(*v).map_or(Value::Null, Value::Number),
                        );
                    }
                    Value::Object(m)
                })
                .collect(),
        )
    }

    /// The first cell that is not a finite number: (row from 1, column, value).
    pub fn first_non_finite(&self) -> Option<(usize, &str, f64)> {
        self.rows.iter().enumerate().find_map(|(i, r)| {
            r.iter()
                .zip(&self.columns)
                .find(|(v, _)| !v.is_finite())
                .map(|(v, c)| (i + 1, c.as_str(), *v))
        })
    }

    /// The table as CSV text with a header row (written as [`CsvSink`] streams it).
    pub fn to_csv(&self) -> String {
        let mut bytes = Vec::new();
        self.write_csv(&mut bytes)
            .expect("writing to a Vec<u8> cannot fail");
        // CsvSink writes column names (UTF-8 strings) and formatted numbers only.
        String::from_utf8(bytes).unwrap_or_default()
    }

    /// Write the table as CSV to `out`, row by row.
    pub fn write_csv<W: std::io::Write>(&self, out: W) -> std::io::Result<()> {
        let mut sink = CsvSink::new(out, &self.columns)?;
        for r in &self.rows {
            sink.row(r)?;
        }
        sink.finish().map(drop)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_round_trip_and_errors_name_row_and_value() {
        let t = Table::from_csv("joints", "q1,q2\n1.5,2\n-3,4e-3\n").unwrap();
        assert_eq!(t.rows, vec![vec![1.5, 2.0], vec![-3.0, 4e-3]]);
        assert_eq!(Table::from_csv("joints", &t.to_csv()).unwrap(), t);
        assert_eq!(
            Table::from_json_rows("joints", &t.to_json_rows()).unwrap(),
            t
        );
        let e = Table::from_csv("joints", "q1,q2\n1,2\n3,NaN\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("joints") && e.contains("row 2") && e.contains("q2") && e.contains("NaN"),
            "{e}"
        );
        let e = Table::from_csv("joints", "q1,q2\n1,2,3\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("row 1") && e.contains("3 values for 2 columns"),
            "{e}"
        );
        let e = Table::from_csv("joints", "q1,q2\n1,abc\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`abc` is not a number"), "{e}");
        let e = t.col("joints", "q3").unwrap_err().to_string();
        assert!(e.contains("missing column `q3`"), "{e}");
        // Gaps only where admitted.
        let g = Table::from_csv_with_gaps("s", "q1,m_x\n1,\n2,NaN\n3,4\n", &|c: &str| {
            c.ends_with("_x")
        })
        .unwrap();
        assert!(g.rows[0][1].is_nan() && g.rows[1][1].is_nan() && g.rows[2][1] == 4.0);
        let e = Table::from_csv_with_gaps("s", "q1,m_x\n,1\n", &|c: &str| c.ends_with("_x"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("row 1") && e.contains("q1"), "{e}");
    }
}
