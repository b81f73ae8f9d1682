//! Jobs in the store: submission, state changes, progress history, logs, recovery.

use serde_json::Value;

pub use super::records::{
    IdempotencyKey, JobFilter, JobRecord, JobState, LogLine, NewJob, ProgressPoint, Recovered, Run,
};
use super::{Store, StoreError};

impl Store {
    /// Persist a new job as `queued`; returns its id.
    pub fn insert_job(&self, j: &NewJob) -> Result<i64, StoreError> {
        self.insert_job_once(j).map(|(id, _)| id)
    }

    /// Insert a job unless its idempotency key was used before by the same submitter:
    /// returns the job id and whether it is new. The key is written in the job's own
    /// transaction, so a submission cut by a crash either left both or neither. The same
    /// key with a different request is a conflict.
    pub fn insert_job_once(&self, j: &NewJob) -> Result<(i64, bool), StoreError> {
        self.backend.insert_job_once(j)
    }

    /// One job.
    pub fn job(&self, id: i64) -> Result<Option<JobRecord>, StoreError> {
        self.backend.job(id)
    }

    /// One job, read at once when the backend can without waiting (a free SQLite reader):
    /// safe on an async runtime thread. `None` when it cannot: call [`Store::job`] off the
    /// runtime then.
    pub fn job_now(&self, id: i64) -> Option<Result<Option<JobRecord>, StoreError>> {
        self.backend.job_now(id)
    }

    /// The document a job was submitted with.
    pub fn job_doc(&self, id: i64) -> Result<Option<Value>, StoreError> {
        self.backend.job_doc(id)
    }

    /// Jobs matching `f`, newest first.
    pub fn jobs(&self, f: &JobFilter) -> Result<Vec<JobRecord>, StoreError> {
        self.backend.jobs(f)
    }

    /// Number of jobs in each state.
    pub fn count_by_state(&self) -> Result<Vec<(JobState, i64)>, StoreError> {
        self.backend.count_by_state()
    }

    /// Append a log line (job-specific or daemon-wide).
    pub fn log(&self, job: Option<i64>, level: &str, message: &str) -> Result<(), StoreError> {
        self.backend.log(job, level, message)
    }

    /// A job's log lines, oldest first.
    pub fn logs(&self, id: i64) -> Result<Vec<LogLine>, StoreError> {
        self.backend.logs(id)
    }

    /// A job's progress history, oldest first.
    pub fn progress_history(&self, id: i64) -> Result<Vec<ProgressPoint>, StoreError> {
        self.backend.progress_history(id)
    }

    /// At start-up: mark jobs that were running `interrupted` and return the queued ones.
    /// On a shared (PostgreSQL) store, only those no other live daemon holds.
    pub fn recover(&self) -> Result<Recovered, StoreError> {
        self.backend.recover()
    }
}
