//! The operations every storage backend implements (SQLite in `sqlite/`, PostgreSQL in
//! `pg/`), grouped by area; [`super::Store`] holds one backend and documents each call.

use std::path::Path;
use std::time::Duration;

use serde_json::Value;

use super::{
    ArtefactInfo, CancelRequest, CellModel, Claimed, DatasetInfo, JobFilter, JobRecord, JobState,
    LogLine, MainTableCsv, NewJob, NewSchedule, ProgressPoint, Recovered, Run, ScheduleRecord,
    ScheduleRun, StoreError,
};
use crate::jobs::Artefact;
use crate::lab::Decision;
use crate::procedures::JournalEntry;

/// A storage backend: every area below, plus what only the store front needs.
pub(crate) trait Backend:
    Jobs + Runs + Results + Datasets + Campaigns + Schedules + Fleet + std::fmt::Debug + Send + Sync
{
    /// The database file, for a backend that has one.
    fn file(&self) -> Option<&Path>;
    /// The backend as `Any`, for the one operation that spans two backends (`copy_to`).
    fn as_any(&self) -> &dyn std::any::Any;
}

/// Jobs: submission, reads, logs, progress history, recovery.
pub(crate) trait Jobs {
    fn insert_job_once(&self, j: &NewJob) -> Result<(i64, bool), StoreError>;
    fn job(&self, id: i64) -> Result<Option<JobRecord>, StoreError>;
    /// Job `id` read at once, without waiting on a lock or the network; `None` when this
    /// backend (or its state right now) cannot: call [`Jobs::job`] off the runtime then.
    fn job_now(&self, _id: i64) -> Option<Result<Option<JobRecord>, StoreError>> {
        None
    }
    fn job_doc(&self, id: i64) -> Result<Option<Value>, StoreError>;
    fn jobs(&self, f: &JobFilter) -> Result<Vec<JobRecord>, StoreError>;
    fn count_by_state(&self) -> Result<Vec<(JobState, i64)>, StoreError>;
    fn log(&self, job: Option<i64>, level: &str, message: &str) -> Result<(), StoreError>;
    fn logs(&self, id: i64) -> Result<Vec<LogLine>, StoreError>;
    fn progress_history(&self, id: i64) -> Result<Vec<ProgressPoint>, StoreError>;
    fn recover(&self) -> Result<Recovered, StoreError>;
}

/// Runs of jobs: start, progress, end without result.
pub(crate) trait Runs {
    fn start_job(&self, id: i64) -> Result<Option<Run>, StoreError>;
    fn record_progress(
        &self,
        run: Run,
        fraction: f64,
        stage: &str,
        message: Option<&str>,
        history: bool,
    ) -> Result<(), StoreError>;
    /// End job `id` (any run of it when `attempt` is none, else only that run).
    fn end(
        &self,
        id: i64,
        attempt: Option<i64>,
        state: JobState,
        error: Option<&str>,
    ) -> Result<bool, StoreError>;
}

/// Results and artefacts.
pub(crate) trait Results {
    fn finish_job(
        &self,
        run: Run,
        result: &Value,
        main_table_csv: Option<MainTableCsv<'_>>,
        artefacts: &[Artefact],
        decision: Option<&Decision>,
    ) -> Result<bool, StoreError>;
    fn result(&self, id: i64) -> Result<Option<Value>, StoreError>;
    fn main_table_csv(&self, id: i64) -> Result<Option<String>, StoreError>;
    fn artefacts(&self, id: i64) -> Result<Vec<ArtefactInfo>, StoreError>;
    fn artefact(&self, id: i64, name: &str) -> Result<Option<Artefact>, StoreError>;
}

/// Content-addressed datasets.
pub(crate) trait Datasets {
    /// Insert dataset `id` unless it exists.
    fn insert_dataset(
        &self,
        id: &str,
        name: &str,
        media_type: &str,
        content: &[u8],
    ) -> Result<(), StoreError>;
    fn dataset_info(&self, id: &str) -> Result<Option<DatasetInfo>, StoreError>;
    fn dataset(&self, id: &str) -> Result<Option<Vec<u8>>, StoreError>;
    fn datasets(&self) -> Result<Vec<DatasetInfo>, StoreError>;
    /// Write dataset `id` to `out` (named `path` in errors); false if there is none.
    fn dataset_to_writer(
        &self,
        id: &str,
        out: &mut dyn std::io::Write,
        path: &Path,
    ) -> Result<bool, StoreError>;
}

/// Campaign state: measurement journals, pause and resume, cell models.
pub(crate) trait Campaigns {
    fn append_measurement(&self, job: i64, e: &JournalEntry) -> Result<(), StoreError>;
    fn measurements(&self, job: i64) -> Result<Vec<JournalEntry>, StoreError>;
    fn pause_job(&self, run: Run, reason: &str) -> Result<bool, StoreError>;
    fn resume_job(&self, id: i64, why: &str) -> Result<bool, StoreError>;
    fn note_pause(&self, id: i64, reason: &str) -> Result<bool, StoreError>;
    fn cell_models(&self, cell: &str) -> Result<Vec<CellModel>, StoreError>;
}

/// Schedules and their occurrences.
pub(crate) trait Schedules {
    fn insert_schedule(
        &self,
        s: &NewSchedule,
        created_by: Option<&str>,
        checked_until: &str,
    ) -> Result<i64, StoreError>;
    fn update_schedule(
        &self,
        id: i64,
        s: &NewSchedule,
        checked_until: &str,
    ) -> Result<bool, StoreError>;
    fn delete_schedule(&self, id: i64) -> Result<bool, StoreError>;
    fn schedule(&self, id: i64) -> Result<Option<ScheduleRecord>, StoreError>;
    fn schedules(&self) -> Result<Vec<ScheduleRecord>, StoreError>;
    fn record_schedule_run(
        &self,
        schedule: i64,
        due: &str,
        outcome: &str,
        message: Option<&str>,
    ) -> Result<(), StoreError>;
    fn schedule_runs(&self, id: i64, limit: usize) -> Result<Vec<ScheduleRun>, StoreError>;
}

/// Why a backend without a shared queue refuses the fleet calls.
const NOT_SHARED: StoreError = StoreError::Unsupported("several daemons need a PostgreSQL store");

/// Several daemons on one database; a backend that cannot share refuses every call.
pub(crate) trait Fleet {
    fn is_shared(&self) -> bool {
        false
    }
    fn register_daemon(
        &self,
        _name: &str,
        _cells: &[String],
        _stale: Duration,
    ) -> Result<(), StoreError> {
        Err(NOT_SHARED)
    }
    fn cell_owners(&self) -> Result<Vec<(String, String)>, StoreError> {
        Err(NOT_SHARED)
    }
    fn claim(
        &self,
        _owner: &str,
        _devices: &[String],
        _lease: Duration,
    ) -> Result<Option<Claimed>, StoreError> {
        Err(NOT_SHARED)
    }
    fn heartbeat(&self, _owner: &str, _lease: Duration) -> Result<u64, StoreError> {
        Err(NOT_SHARED)
    }
    fn requeue_expired(&self) -> Result<Vec<i64>, StoreError> {
        Err(NOT_SHARED)
    }
    fn job_owner(&self, _id: i64) -> Result<Option<String>, StoreError> {
        Err(NOT_SHARED)
    }
    fn release_owned(&self, _owner: &str) -> Result<Vec<i64>, StoreError> {
        Err(NOT_SHARED)
    }
    fn request_cancel(&self, _id: i64) -> Result<CancelRequest, StoreError> {
        Err(NOT_SHARED)
    }
    fn cancel_requests(&self, _owner: &str) -> Result<Vec<i64>, StoreError> {
        Err(NOT_SHARED)
    }
    fn notify(&self, _channel: &str, _payload: &str) -> Result<(), StoreError> {
        Err(NOT_SHARED)
    }
    fn listen(
        &self,
        _channels: &[&str],
        _tick: Duration,
        _stop: &dyn Fn() -> bool,
        _on: &mut dyn FnMut(&str, &str),
    ) -> Result<(), StoreError> {
        Err(NOT_SHARED)
    }
}
