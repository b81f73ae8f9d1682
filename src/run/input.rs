//! Inputs of a job: a string is a reference (a path relative to the job file for
//! `calibd run`, a dataset id over HTTP) unless it is inline URDF text; objects and arrays
//! are inline. Every input read is hashed (SHA-256) for the result envelope.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::PathBuf;

use serde_json::Value;
use sha2::{Digest, Sha256};

use super::{JobError, Table};

/// Resolves a reference to bytes.
pub trait Resolver: Sync {
    /// The bytes `reference` names, for input `field`.
    fn read(&self, field: &str, reference: &str) -> Result<Vec<u8>, JobError>;

    /// The file `reference` names, when references are files that a job may read again,
    /// row by row, while it runs (a table too large to hold); `None` (the default) when
    /// references are read whole only.
    fn file(&self, _reference: &str) -> Option<PathBuf> {
        None
    }
}

/// References are paths relative to a folder (the job file's).
#[derive(Debug, Clone)]
pub struct DirResolver {
    /// The folder.
    pub dir: PathBuf,
}

impl Resolver for DirResolver {
    fn read(&self, field: &str, reference: &str) -> Result<Vec<u8>, JobError> {
        let p = self.dir.join(reference);
        std::fs::read(&p).map_err(|e| JobError::Input {
            field: field.into(),
            reference: p.display().to_string(),
            message: e.to_string(),
        })
    }

    fn file(&self, reference: &str) -> Option<PathBuf> {
        Some(self.dir.join(reference))
    }
}

/// Refuses every reference (jobs must be fully inline).
#[derive(Debug, Clone, Copy)]
pub struct NoReferences;

impl Resolver for NoReferences {
    fn read(&self, field: &str, reference: &str) -> Result<Vec<u8>, JobError> {
        Err(JobError::Input {
            field: field.into(),
            reference: reference.into(),
            message: "references are not allowed here: give the input inline".into(),
        })
    }
}

/// Hex SHA-256 of bytes.
pub fn sha256_hex(b: &[u8]) -> String {
    let d = Sha256::digest(b);
    d.iter().map(|x| format!("{x:02x}")).collect()
}

/// Reads a job's inputs through a resolver and remembers their hashes.
pub struct Inputs<'a> {
    resolver: &'a dyn Resolver,
    hashes: RefCell<BTreeMap<String, String>>,
}

impl std::fmt::Debug for Inputs<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Inputs")
            .field("hashes", &self.hashes)
            .finish()
    }
}

impl<'a> Inputs<'a> {
    /// Inputs read through `resolver`.
    pub fn new(resolver: &'a dyn Resolver) -> Self {
        Self {
            resolver,
            hashes: RefCell::new(BTreeMap::new()),
        }
    }

    /// The hashes of everything read, by field.
    pub fn into_hashes(self) -> BTreeMap<String, String> {
        self.hashes.into_inner()
    }

    fn record(&self, field: &str, bytes: &[u8]) {
        self.record_sha256(field, sha256_hex(bytes));
    }

    /// Record the hex SHA-256 of input `field` when it was read other than through these
    /// methods (a table streamed from its file).
    pub fn record_sha256(&self, field: &str, hex: String) {
        self.hashes.borrow_mut().insert(field.to_string(), hex);
    }

    /// The file a table input names, when it is a reference the resolver maps to a file
    /// (see [`Resolver::file`]); `None` for inline rows and for other references.
    pub fn table_file(&self, v: &Value) -> Option<PathBuf> {
        v.as_str().and_then(|s| self.resolver.file(s))
    }

    /// Text of an input given as a reference, or inline text (URDF) as is.
    pub fn text(&self, field: &str, v: &Value) -> Result<String, JobError> {
        let s = v.as_str().ok_or_else(|| {
            JobError::invalid(field, "expected a string (file name or inline text)")
        })?;
        let bytes = if s.trim_start().starts_with('<') {
            s.as_bytes().to_vec()
        } else {
            self.resolver.read(field, s)?
        };
        self.record(field, &bytes);
        String::from_utf8(bytes).map_err(|_| JobError::invalid(field, "is not UTF-8 text"))
    }

    /// Text given inline (a string of several lines is the text itself) or a reference to
    /// a file (a RAPID module).
    pub fn text_or_inline(&self, field: &str, v: &Value) -> Result<String, JobError> {
        match v.as_str() {
            Some(s) if s.contains('\n') => {
                self.record(field, s.as_bytes());
                Ok(s.to_string())
            }
            _ => self.text(field, v),
        }
    }

    /// The bytes of a binary input given as a reference (an image file or dataset id).
    pub fn bytes(&self, field: &str, v: &Value) -> Result<Vec<u8>, JobError> {
        let s = v
            .as_str()
            .ok_or_else(|| JobError::invalid(field, "expected a file name or dataset id"))?;
        let bytes = self.resolver.read(field, s)?;
        self.record(field, &bytes);
        Ok(bytes)
    }

    /// A JSON document: inline object, or a reference to a JSON file.
    pub fn json(&self, field: &str, v: &Value) -> Result<Value, JobError> {
        match v {
            Value::String(s) => {
                let bytes = self.resolver.read(field, s)?;
                self.record(field, &bytes);
                serde_json::from_slice(&bytes)
                    .map_err(|e| JobError::invalid(field, format!("`{s}` is not valid JSON: {e}")))
            }
            Value::Object(_) => {
                self.record(field, &serde_json::to_vec(v).unwrap_or_default());
                Ok(v.clone())
            }
            _ => Err(JobError::invalid(
                field,
                "expected an object or a file name",
            )),
        }
    }

    /// A table: inline rows, or a reference to a CSV file.
    pub fn table(&self, field: &str, v: &Value) -> Result<Table, JobError> {
        self.table_with_gaps(field, v, &|_: &str| false)
    }

    /// As [`Inputs::table`], with missing values (empty, `NaN` or `null`) admitted in the
    /// columns `gaps` admits.
    pub fn table_with_gaps(
        &self,
        field: &str,
        v: &Value,
        gaps: &dyn Fn(&str) -> bool,
    ) -> Result<Table, JobError> {
        match v {
            Value::String(s) => {
                let bytes = self.resolver.read(field, s)?;
                self.record(field, &bytes);
                let text = String::from_utf8(bytes)
                    .map_err(|_| JobError::invalid(field, format!("`{s}` is not UTF-8 text")))?;
                Table::from_csv_with_gaps(field, &text, gaps)
            }
            Value::Array(_) => {
                self.record(field, &serde_json::to_vec(v).unwrap_or_default());
                Table::from_json_rows_with_gaps(field, v, gaps)
            }
            _ => Err(JobError::invalid(
                field,
                "expected an array of row objects or a CSV file name",
            )),
        }
    }
}
