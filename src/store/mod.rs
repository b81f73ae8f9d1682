//! Storage: one SQLite file (bundled SQLite, WAL mode, `synchronous = FULL`) holding jobs,
//! their input datasets (content-hashed), progress history, results and artefacts, logs and
//! schedules. Writes go through one connection; reads use a small pool of connections that
//! WAL lets run beside the writer. Every call is blocking: async code reaches the store
//! through the service's storage module (`service::storage`), which runs calls on the
//! blocking pool. A result is written in the same transaction that makes its job final,
//! so a crash either keeps the whole result or leaves the job `running`, which
//! [`Store::recover`] turns into `interrupted` on the next start.

mod campaigns;
mod copy;
mod datasets;
mod jobs;
mod migrate;
mod pg;
mod records;
mod results;
mod runs;
mod schedules;
mod shared;
mod spool;
pub mod testpg;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use rusqlite::{Connection, OpenFlags};

pub use campaigns::{CellModel, StoreJournal};
pub use copy::Copied;
pub use datasets::DatasetInfo;
pub use jobs::{
    IdempotencyKey, JobFilter, JobRecord, JobState, LogLine, NewJob, ProgressPoint, Recovered, Run,
};
pub use migrate::SCHEMA_VERSION;
pub use pg::{Location, PgLocation};
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

/// Handle to the database; cheap to clone.
#[derive(Debug, Clone)]
pub struct Store {
    inner: Arc<Inner>,
}

#[derive(Debug)]
enum Inner {
    /// The embedded SQLite file (the default).
    Sqlite(Sqlite),
    /// A PostgreSQL database shared by several daemons.
    Postgres(pg::Pg),
}

#[derive(Debug)]
struct Sqlite {
    /// The only connection that writes: SQLite serialises writers anyway, and one
    /// connection keeps "busy" errors impossible.
    writer: Mutex<Connection>,
    /// Read-only connections; WAL lets them read while the writer commits.
    readers: Vec<Mutex<Connection>>,
    next_reader: AtomicUsize,
    path: PathBuf,
}

/// Number of read connections.
const READERS: usize = 3;

/// The one timestamp format of the store (RFC 3339, UTC, milliseconds): strings in this
/// format sort like the instants they name.
pub use crate::util::format_time;

fn now() -> String {
    format_time(chrono::Utc::now())
}

fn lock(m: &Mutex<Connection>) -> MutexGuard<'_, Connection> {
    // A panic while holding the lock cannot leave a half-done transaction behind (rusqlite
    // rolls back on drop), so the connection stays usable.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Create (or tighten) the data folder to 0700 and the database file to 0600 before SQLite
/// opens it: SQLite gives its `-wal` and `-shm` files the database file's mode, so results,
/// datasets and journals are readable by the daemon's user only, whatever the umask.
fn private_files(dir: &Path, db: &Path) -> Result<(), (PathBuf, std::io::Error)> {
    fn at(p: &Path) -> impl FnOnce(std::io::Error) -> (PathBuf, std::io::Error) + '_ {
        move |e| (p.to_path_buf(), e)
    }
    std::fs::create_dir_all(dir).map_err(at(dir))?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700)).map_err(at(dir))?;
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .mode(0o600)
            .open(db)
            .map_err(at(db))?;
        for suffix in ["", "-wal", "-shm"] {
            let f = PathBuf::from(format!("{}{suffix}", db.display()));
            match std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o600)) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err((f, e)),
                _ => {}
            }
        }
    }
    Ok(())
}

impl Store {
    /// Open (or create) the database `calibd.sqlite3` in folder `dir` and migrate it.
    pub fn open(dir: &Path) -> Result<Store, StoreError> {
        let path = dir.join("calibd.sqlite3");
        private_files(dir, &path).map_err(|(path, source)| StoreError::Io { path, source })?;
        let mut writer = Connection::open(&path)?;
        writer.pragma_update(None, "journal_mode", "WAL")?;
        writer.pragma_update(None, "synchronous", "FULL")?;
        writer.pragma_update(None, "foreign_keys", "ON")?;
        writer.busy_timeout(std::time::Duration::from_secs(5))?;
        migrate::migrate(&mut writer)?;
        let mut readers = Vec::new();
        for _ in 0..READERS {
            let r = Connection::open_with_flags(
                &path,
                OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
            )?;
            r.busy_timeout(std::time::Duration::from_secs(5))?;
            readers.push(Mutex::new(r));
        }
        Ok(Store {
            inner: Arc::new(Inner::Sqlite(Sqlite {
                writer: Mutex::new(writer),
                readers,
                next_reader: AtomicUsize::new(0),
                path,
            })),
        })
    }

    /// Open the store at `location`: [`Location::Sqlite`] as [`Store::open`] does, or
    /// connect to PostgreSQL and migrate it. Blocking: from async code, use
    /// `service::open_store`.
    pub fn open_location(location: &Location) -> Result<Store, StoreError> {
        match location {
            Location::Sqlite(dir) => Store::open(dir),
            Location::Postgres(pg) => Ok(Store {
                inner: Arc::new(Inner::Postgres(pg::Pg::connect(pg)?)),
            }),
        }
    }

    /// The database file (empty for PostgreSQL).
    pub fn path(&self) -> &Path {
        match &*self.inner {
            Inner::Sqlite(s) => &s.path,
            Inner::Postgres(_) => Path::new(""),
        }
    }

    /// The PostgreSQL backend, if this store is one.
    fn pg(&self) -> Option<&pg::Pg> {
        match &*self.inner {
            Inner::Postgres(p) => Some(p),
            Inner::Sqlite(_) => None,
        }
    }

    /// The SQLite backend; every public method sends PostgreSQL stores elsewhere first.
    fn sqlite(&self) -> Result<&Sqlite, StoreError> {
        match &*self.inner {
            Inner::Sqlite(s) => Ok(s),
            Inner::Postgres(_) => Err(StoreError::Internal(
                "SQLite call on a PostgreSQL store".into(),
            )),
        }
    }

    /// Run `f` on the writer connection.
    fn write<T>(
        &self,
        f: impl FnOnce(&mut Connection) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let mut c = lock(&self.sqlite()?.writer);
        f(&mut c)
    }

    /// Run `f` on a read connection (a free one if any).
    fn read<T>(
        &self,
        f: impl FnOnce(&Connection) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let db = self.sqlite()?;
        let n = db.readers.len();
        let start = db.next_reader.fetch_add(1, Ordering::Relaxed);
        for k in 0..n {
            if let Ok(c) = db.readers[(start + k) % n].try_lock() {
                return f(&c);
            }
        }
        let c = lock(&db.readers[start % n]);
        f(&c)
    }
}

#[cfg(test)]
mod tests;
