//! Results and artefacts: written together with the job's final state in one transaction.

use serde::Serialize;
use serde_json::Value;

use super::{Run, Store, StoreError};
use crate::jobs::Artefact;
use crate::lab::Decision;

/// A job's main table as it reaches the store: CSV text, or a CSV file written row by row
/// (a large table is copied into the database in chunks, never held whole in memory).
#[derive(Debug, Clone, Copy)]
pub enum MainTableCsv<'a> {
    /// The CSV text.
    Text(&'a str),
    /// A CSV file.
    File(&'a std::path::Path),
}

/// An artefact's description (no content).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArtefactInfo {
    /// File name.
    pub name: String,
    /// Media type.
    pub media_type: String,
    /// Size in bytes.
    pub size: i64,
}

impl Store {
    /// Store run `run`'s result, artefacts and its cell's model decision and mark the job
    /// `succeeded`, all in one transaction. False (and nothing written) if the job was no
    /// longer running (cancelled); [`StoreError::Stale`] if it was taken from the run.
    pub fn finish_job(
        &self,
        run: Run,
        result: &Value,
        main_table_csv: Option<MainTableCsv<'_>>,
        artefacts: &[Artefact],
        decision: Option<&Decision>,
    ) -> Result<bool, StoreError> {
        self.backend
            .finish_job(run, result, main_table_csv, artefacts, decision)
    }

    /// A job's result document.
    pub fn result(&self, id: i64) -> Result<Option<Value>, StoreError> {
        self.backend.result(id)
    }

    /// A job's main table as CSV.
    pub fn main_table_csv(&self, id: i64) -> Result<Option<String>, StoreError> {
        self.backend.main_table_csv(id)
    }

    /// A job's artefacts, by name.
    pub fn artefacts(&self, id: i64) -> Result<Vec<ArtefactInfo>, StoreError> {
        self.backend.artefacts(id)
    }

    /// One artefact with its content.
    pub fn artefact(&self, id: i64, name: &str) -> Result<Option<Artefact>, StoreError> {
        self.backend.artefact(id, name)
    }
}
