//! The one door to storage. Every store call is blocking (SQLite, or the synchronous
//! `postgres` client), so it runs on tokio's blocking pool — and this module is the only
//! place that sends store work there (a job status read runs in place when the store can
//! answer it without waiting: [`job`]). The HTTP API and the scheduler read and write the
//! store only through the typed async methods below; the service's own modules (workers,
//! fleet, cells) use [`call`] and [`blocking`]. A campaign's journal is read and written
//! from inside the campaign's async task through a synchronous trait: [`RunJournal`] moves
//! those calls off the runtime's threads too.

use serde_json::Value;

use super::{Service, ServiceError};
use crate::jobs::Artefact;
use crate::procedures::{Journal, JournalEntry, JournalError};
use crate::store::{
    ArtefactInfo, CellModel, DatasetInfo, JobRecord, Location, LogLine, NewSchedule, ProgressPoint,
    ScheduleRecord, ScheduleRun, Store, StoreError, StoreJournal,
};

/// Run `f` on `store` on the blocking pool.
pub(super) async fn call<T: Send + 'static>(
    store: &Store,
    f: impl FnOnce(&Store) -> Result<T, StoreError> + Send + 'static,
) -> Result<T, StoreError> {
    let st = store.clone();
    tokio::task::spawn_blocking(move || f(&st))
        .await
        .map_err(|e| StoreError::Internal(e.to_string()))?
}

/// Job `id`, read in place when the store can without waiting (a free SQLite reader: a
/// status read then costs no hand-off to the blocking pool and back), else there.
pub(super) async fn job(store: &Store, id: i64) -> Result<Option<JobRecord>, StoreError> {
    match store.job_now(id) {
        Some(rec) => rec,
        None => call(store, move |s| s.job(id)).await,
    }
}

/// Run blocking work that reads the store (job preparation resolves datasets) on the
/// blocking pool.
pub(super) async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, ServiceError> + Send + 'static,
) -> Result<T, ServiceError> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| ServiceError::Internal(e.to_string()))?
}

/// Run blocking `f` from synchronous code that may be on a runtime thread: in place on a
/// multi-thread runtime (the worker thread is handed over first), on a scoped thread of its
/// own on a current-thread runtime, directly outside any runtime. The synchronous
/// PostgreSQL client panics if called on a runtime thread; SQLite would stall the runtime.
fn off_runtime<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    use tokio::runtime::{Handle, RuntimeFlavor};
    match Handle::try_current() {
        Ok(h) if h.runtime_flavor() == RuntimeFlavor::MultiThread => tokio::task::block_in_place(f),
        Ok(_) => std::thread::scope(|s| match s.spawn(f).join() {
            Ok(v) => v,
            Err(panic) => std::panic::resume_unwind(panic),
        }),
        Err(_) => f(),
    }
}

/// The measurement journal of a campaign run by the service: the store's journal, with
/// its blocking calls kept off the runtime's threads.
#[derive(Debug)]
pub(super) struct RunJournal(pub(super) StoreJournal);

impl Journal for RunJournal {
    fn entries(&self) -> Result<Vec<JournalEntry>, JournalError> {
        off_runtime(|| self.0.entries())
    }

    fn append(&self, e: &JournalEntry) -> Result<(), JournalError> {
        off_runtime(|| self.0.append(e))
    }
}

/// Open (or create) the store at `location` and migrate it, off the runtime.
pub async fn open(location: Location) -> Result<Store, StoreError> {
    tokio::task::spawn_blocking(move || Store::open_location(&location))
        .await
        .map_err(|e| StoreError::Internal(e.to_string()))?
}

impl Service {
    async fn on_store<T: Send + 'static>(
        &self,
        f: impl FnOnce(&Store) -> Result<T, StoreError> + Send + 'static,
    ) -> Result<T, StoreError> {
        call(&self.shared.store, f).await
    }

    /// The stored result document of job `id` (none until it succeeded).
    pub async fn result(&self, id: i64) -> Result<Option<Value>, StoreError> {
        self.on_store(move |s| s.result(id)).await
    }

    /// The main table of job `id`'s result as CSV, if it has one.
    pub async fn main_table_csv(&self, id: i64) -> Result<Option<String>, StoreError> {
        self.on_store(move |s| s.main_table_csv(id)).await
    }

    /// The artefacts (plots, files) stored with job `id`'s result.
    pub async fn artefacts(&self, id: i64) -> Result<Vec<ArtefactInfo>, StoreError> {
        self.on_store(move |s| s.artefacts(id)).await
    }

    /// One artefact of job `id`, with its content.
    pub async fn artefact(&self, id: i64, name: String) -> Result<Option<Artefact>, StoreError> {
        self.on_store(move |s| s.artefact(id, &name)).await
    }

    /// The SVG artefacts of job `id`, with their content (for its report).
    pub async fn svg_artefacts(&self, id: i64) -> Result<Vec<Artefact>, StoreError> {
        self.on_store(move |s| {
            let mut out = Vec::new();
            for a in s.artefacts(id)? {
                if a.media_type == "image/svg+xml" {
                    out.extend(s.artefact(id, &a.name)?);
                }
            }
            Ok(out)
        })
        .await
    }

    /// Job `id`'s log lines and progress history, oldest first.
    pub async fn logs(&self, id: i64) -> Result<(Vec<LogLine>, Vec<ProgressPoint>), StoreError> {
        self.on_store(move |s| Ok((s.logs(id)?, s.progress_history(id)?)))
            .await
    }

    /// Job `id`'s measurement journal, in index order (empty for jobs that measure nothing).
    pub async fn journal(&self, id: i64) -> Result<Vec<JournalEntry>, StoreError> {
        self.on_store(move |s| s.measurements(id)).await
    }

    /// The model history of cell `cell`, newest first.
    pub async fn cell_models(&self, cell: String) -> Result<Vec<CellModel>, StoreError> {
        self.on_store(move |s| s.cell_models(&cell)).await
    }

    /// Store a dataset (content-addressed: the same bytes are stored once).
    pub async fn put_dataset(
        &self,
        name: String,
        media_type: String,
        content: Vec<u8>,
    ) -> Result<DatasetInfo, StoreError> {
        self.on_store(move |s| s.put_dataset(&name, &media_type, &content))
            .await
    }

    /// Every dataset's description.
    pub async fn datasets(&self) -> Result<Vec<DatasetInfo>, StoreError> {
        self.on_store(|s| s.datasets()).await
    }

    /// A dataset's description and content (none if either is missing).
    pub async fn dataset(&self, id: String) -> Result<Option<(DatasetInfo, Vec<u8>)>, StoreError> {
        self.on_store(move |s| Ok(s.dataset_info(&id)?.zip(s.dataset(&id)?)))
            .await
    }

    /// Create a schedule whose occurrences count from `checked_until`; returns its id.
    pub async fn insert_schedule(
        &self,
        spec: NewSchedule,
        created_by: Option<String>,
        checked_until: String,
    ) -> Result<i64, StoreError> {
        self.on_store(move |s| s.insert_schedule(&spec, created_by.as_deref(), &checked_until))
            .await
    }

    /// Replace schedule `id`'s definition; false if there is none.
    pub async fn update_schedule(
        &self,
        id: i64,
        spec: NewSchedule,
        checked_until: String,
    ) -> Result<bool, StoreError> {
        self.on_store(move |s| s.update_schedule(id, &spec, &checked_until))
            .await
    }

    /// Delete schedule `id`; false if there is none.
    pub async fn delete_schedule(&self, id: i64) -> Result<bool, StoreError> {
        self.on_store(move |s| s.delete_schedule(id)).await
    }

    /// One schedule.
    pub async fn schedule(&self, id: i64) -> Result<Option<ScheduleRecord>, StoreError> {
        self.on_store(move |s| s.schedule(id)).await
    }

    /// Every schedule.
    pub async fn schedules(&self) -> Result<Vec<ScheduleRecord>, StoreError> {
        self.on_store(|s| s.schedules()).await
    }

    /// Schedule `id`'s latest `limit` occurrences, newest first.
    pub async fn schedule_runs(
        &self,
        id: i64,
        limit: usize,
    ) -> Result<Vec<ScheduleRun>, StoreError> {
        self.on_store(move |s| s.schedule_runs(id, limit)).await
    }

    /// Record an occurrence of schedule `id` that submitted no job (skipped or refused).
    pub async fn record_schedule_run(
        &self,
        id: i64,
        due: String,
        outcome: &'static str,
        message: Option<String>,
    ) -> Result<(), StoreError> {
        self.on_store(move |s| s.record_schedule_run(id, &due, outcome, message.as_deref()))
            .await
    }
}
