//! Storage: jobs, their input datasets (content-hashed), progress history, results and
//! artefacts, logs, schedules and campaign state, behind one [`Store`] handle whose calls
//! go to a backend (`backend.rs`: one trait per area): an embedded SQLite file
//! (`sqlite/`, the default) or a PostgreSQL database several daemons share (`pg/`). Every
//! call is blocking: async code reaches the store through the service's storage module
//! (`service::storage`), which runs calls on the blocking pool (a status read may run in
//! place: [`Store::job_now`]). A result is written in the same transaction that makes its
//! job final, so a crash either keeps the whole result or leaves the job `running`, which
//! [`Store::recover`] turns into `interrupted` on the next start.

mod backend;
mod campaigns;
mod copy;
mod datasets;
mod jobs;
mod location;
mod lock;
mod migrate;
mod pg;
mod records;
mod results;
mod runs;
mod schedules;
mod shared;
mod spool;
mod sqlite;
pub mod testpg;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use backend::Backend;

pub use campaigns::{CellModel, StoreJournal};
pub use copy::Copied;
pub use datasets::DatasetInfo;
pub use jobs::{
    IdempotencyKey, JobFilter, JobRecord, JobState, LogLine, NewJob, ProgressPoint, Recovered, Run,
};
pub use location::{Location, PgLocation};
pub use lock::DataLock;
pub use migrate::SCHEMA_VERSION;
pub use results::{ArtefactInfo, MainTableCsv};
pub use schedules::{MissedPolicy, NewSchedule, ScheduleRecord, ScheduleRun};
pub use shared::{CancelRequest, Claimed};

/// Why a storage operation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// SQLite refused or failed.
    #[error("store: database: {0}")]
    Sqlite(#[from] rusqlite::Error),
    /// PostgreSQL refused or failed (or could not be reached).
    #[error("store: PostgreSQL: {0}")]
    Postgres(#[from] postgres::Error),
    /// The `store` setting is not a `sqlite:PATH` or `postgres://` location.
    #[error("store: {0}")]
    Location(String),
    /// A stored JSON document could not be read or written.
    #[error("store: JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// The data folder could not be created.
    #[error("store: {path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// Another daemon serves this data folder (one daemon per SQLite store).
    #[error(
        "store: another calibd daemon (process {holder}) serves this data folder: it holds \
         {path}; stop it, or give this daemon its own data folder or a PostgreSQL store"
    )]
    InUse {
        /// The lock file.
        path: PathBuf,
        /// What the lock file says of its holder (its process id).
        holder: String,
    },
    /// The database was written by a newer calibd.
    #[error("store: database schema version {found} is newer than this calibd knows ({known})")]
    SchemaTooNew {
        /// Version found in the file.
        found: i64,
        /// Newest version this binary knows.
        known: i64,
    },
    /// A stored value is not one calibd writes (corrupted or edited by hand).
    #[error("store: unexpected stored value `{value}` in {column}")]
    Corrupt {
        /// Which column.
        column: &'static str,
        /// The value.
        value: String,
    },
    /// A record with this name or id already exists.
    #[error("store: {0} already exists")]
    Conflict(String),
    /// A run wrote after its job was taken from it: its lease expired and the job was
    /// queued again or started by a later run (on this daemon or another).
    #[error(
        "store: job {job} is no longer held by its run {attempt}: it was re-queued or claimed again"
    )]
    Stale {
        /// The job.
        job: i64,
        /// The stale run's attempt.
        attempt: i64,
    },
    /// The operation needs another backend.
    #[error("store: {0}")]
    Unsupported(&'static str),
    /// The task doing the storage failed (it panicked).
    #[error("store: internal error: {0}")]
    Internal(String),
}

/// Handle to the database; cheap to clone. Every call goes to its backend: the embedded
/// SQLite file (the default, `sqlite/`) or a PostgreSQL database shared by several daemons
/// (`pg/`).
#[derive(Debug, Clone)]
pub struct Store {
    backend: Arc<dyn Backend>,
}

/// The one timestamp format of the store (RFC 3339, UTC, milliseconds): strings in this
/// format sort like the instants they name.
pub use crate::util::format_time;

fn now() -> String {
    format_time(chrono::Utc::now())
}

impl Store {
    /// Open (or create) the database `calibd.sqlite3` in folder `dir` and migrate it.
    pub fn open(dir: &Path) -> Result<Store, StoreError> {
        Ok(Store {
            backend: Arc::new(sqlite::Sqlite::open(dir)?),
        })
    }

    /// Open the store at `location`: [`Location::Sqlite`] as [`Store::open`] does, or
    /// connect to PostgreSQL and migrate it. Blocking: from async code, use
    /// `service::open_store`.
    pub fn open_location(location: &Location) -> Result<Store, StoreError> {
        match location {
            Location::Sqlite(dir) => Store::open(dir),
            Location::Postgres(pg) => Ok(Store {
                backend: Arc::new(pg::Pg::connect(pg)?),
            }),
        }
    }

    /// The database file (empty for PostgreSQL).
    pub fn path(&self) -> &Path {
        self.backend.file().unwrap_or(Path::new(""))
    }
}

#[cfg(test)]
mod tests;
