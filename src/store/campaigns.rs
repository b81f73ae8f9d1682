//! Campaign state in the store: each job's measurement journal (one row per configuration,
//! committed before the robot moves again), pausing and resuming, and each cell's model
//! history (the current model, accepted and rejected candidates, and why).

use serde::Serialize;
use serde_json::Value;

use super::{Run, Store, StoreError};
use crate::procedures::{Journal, JournalEntry, JournalError};

/// A cell model as stored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellModel {
    /// Row id.
    pub id: i64,
    /// Cell name.
    pub cell: String,
    /// The campaign job that produced it (none for a model set by hand).
    pub job_id: Option<i64>,
    /// `current`, `superseded` or `rejected`.
    pub state: String,
    /// Why it was accepted or rejected.
    pub reason: String,
    /// Validation figures the decision was made on.
    pub validation: Value,
    /// The model file.
    pub model: Value,
    /// When (RFC 3339).
    pub at: String,
}

impl Store {
    /// Append one journal entry of job `job`; an index already present is refused.
    pub fn append_measurement(&self, job: i64, e: &JournalEntry) -> Result<(), StoreError> {
        self.backend.append_measurement(job, e)
    }

    /// The journal of job `job`, in index order.
    pub fn measurements(&self, job: i64) -> Result<Vec<JournalEntry>, StoreError> {
        self.backend.measurements(job)
    }

    /// Run `run`'s job paused on device faults; false if it was not running,
    /// [`StoreError::Stale`] if it was taken from the run.
    pub fn pause_job(&self, run: Run, reason: &str) -> Result<bool, StoreError> {
        self.backend.pause_job(run, reason)
    }

    /// Queue a paused or interrupted job again and set its `resumed_at` (its `started_at`
    /// stays that of its first start); false if it is in neither state.
    pub fn resume_job(&self, id: i64, why: &str) -> Result<bool, StoreError> {
        self.backend.resume_job(id, why)
    }

    /// Replace the pause reason of paused job `id` (logged); false if it is not paused.
    pub fn note_pause(&self, id: i64, reason: &str) -> Result<bool, StoreError> {
        self.backend.note_pause(id, reason)
    }

    /// The current model of `cell`, if one was accepted.
    pub fn current_cell_model(&self, cell: &str) -> Result<Option<CellModel>, StoreError> {
        Ok(self
            .cell_models(cell)?
            .into_iter()
            .find(|m| m.state == "current"))
    }

    /// The model history of `cell`, newest first.
    pub fn cell_models(&self, cell: &str) -> Result<Vec<CellModel>, StoreError> {
        self.backend.cell_models(cell)
    }
}

/// The measurement journal of one job, in the store: an append returns once committed.
#[derive(Debug, Clone)]
pub struct StoreJournal {
    /// The store.
    pub store: Store,
    /// The job.
    pub job: i64,
}

impl Journal for StoreJournal {
    fn entries(&self) -> Result<Vec<JournalEntry>, JournalError> {
        self.store
            .measurements(self.job)
            .map_err(JournalError::storage)
    }

    fn append(&self, e: &JournalEntry) -> Result<(), JournalError> {
        self.store
            .append_measurement(self.job, e)
            .map_err(|err| match err {
                StoreError::Conflict(_) => JournalError::Duplicate { index: e.index },
                other => JournalError::storage(other),
            })
    }
}
