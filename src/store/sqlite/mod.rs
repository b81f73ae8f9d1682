//! The SQLite backend: one file (bundled SQLite, WAL mode, `synchronous = FULL`). Writes go
//! through one connection; reads use a small pool of connections that WAL lets run beside
//! the writer. Statements are prepared once per connection and cached (`prepare_cached`).
//! One daemon owns the file (its in-memory queue is the queue), so a job record read since
//! the last write is answered from memory ([`recent`]).

mod campaigns;
mod datasets;
mod jobs;
mod recent;
mod results;
mod runs;
mod schedules;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard};

use rusqlite::{Connection, OpenFlags};

use super::{SCHEMA_VERSION, StoreError, backend};

/// The SQLite store.
#[derive(Debug)]
pub(crate) struct Sqlite {
    /// The only connection that writes: SQLite serialises writers anyway, and one
    /// connection keeps "busy" errors impossible.
    writer: Mutex<Connection>,
    /// Read-only connections; WAL lets them read while the writer commits.
    readers: Vec<Mutex<Connection>>,
    next_reader: AtomicUsize,
    path: PathBuf,
    /// Job records read since the last write (status reads from memory).
    recent: recent::Recent,
}

/// Number of read connections.
const READERS: usize = 3;

/// Prepared statements kept per connection: every statement the store runs fits, so none
/// is parsed twice.
const STATEMENT_CACHE: usize = 96;

pub(crate) fn lock(m: &Mutex<Connection>) -> MutexGuard<'_, Connection> {
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

/// Bring the schema to [`SCHEMA_VERSION`] (`PRAGMA user_version`) in one transaction;
/// returns the version found before.
fn migrate(conn: &mut Connection) -> Result<i64, StoreError> {
    let tx = conn.transaction()?;
    let found: i64 = tx.query_row("PRAGMA user_version", [], |r| r.get(0))?;
    if found > SCHEMA_VERSION {
        return Err(StoreError::SchemaTooNew {
            found,
            known: SCHEMA_VERSION,
        });
    }
    for step in &super::migrate::steps()[found as usize..] {
        tx.execute_batch(step)?;
    }
    tx.pragma_update(None, "user_version", SCHEMA_VERSION)?;
    tx.commit()?;
    Ok(found)
}

impl Sqlite {
    /// Open (or create) the database `calibd.sqlite3` in folder `dir` and migrate it.
    pub(crate) fn open(dir: &Path) -> Result<Sqlite, StoreError> {
        let path = dir.join("calibd.sqlite3");
        private_files(dir, &path).map_err(|(path, source)| StoreError::Io { path, source })?;
        let mut writer = Connection::open(&path)?;
        writer.pragma_update(None, "journal_mode", "WAL")?;
        writer.pragma_update(None, "synchronous", "FULL")?;
        writer.pragma_update(None, "foreign_keys", "ON")?;
        writer.busy_timeout(std::time::Duration::from_secs(5))?;
        writer.set_prepared_statement_cache_capacity(STATEMENT_CACHE);
        migrate(&mut writer)?;
        let mut readers = Vec::new();
        for _ in 0..READERS {
            let r = Connection::open_with_flags(
                &path,
                OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
            )?;
            r.busy_timeout(std::time::Duration::from_secs(5))?;
            r.set_prepared_statement_cache_capacity(STATEMENT_CACHE);
            readers.push(Mutex::new(r));
        }
        Ok(Sqlite {
            writer: Mutex::new(writer),
            readers,
            next_reader: AtomicUsize::new(0),
            path,
            recent: recent::Recent::default(),
        })
    }

    /// The writer connection, locked (for a copy that must see no write meanwhile; it only
    /// reads: writes go through [`Sqlite::write`], which the kept job records rely on).
    pub(crate) fn writer(&self) -> MutexGuard<'_, Connection> {
        lock(&self.writer)
    }

    /// Run `f` on the writer connection.
    fn write<T>(
        &self,
        f: impl FnOnce(&mut Connection) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let mut c = lock(&self.writer);
        let out = f(&mut c);
        // After the commit (or the rollback): a record read from here on is fresh.
        self.recent.wrote();
        out
    }

    /// Run `f` on a free read connection; `f` back, not run, when all are busy.
    fn try_read<T, F: FnOnce(&Connection) -> T>(&self, f: F) -> Result<T, F> {
        let n = self.readers.len();
        let start = self.next_reader.fetch_add(1, Ordering::Relaxed);
        for k in 0..n {
            if let Ok(c) = self.readers[(start + k) % n].try_lock() {
                return Ok(f(&c));
            }
        }
        Err(f)
    }

    /// Run `f` on a read connection (a free one if any, else wait for one).
    fn read<T>(
        &self,
        f: impl FnOnce(&Connection) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        match self.try_read(f) {
            Ok(out) => out,
            Err(f) => {
                let start = self.next_reader.load(Ordering::Relaxed);
                let c = lock(&self.readers[start % self.readers.len()]);
                f(&c)
            }
        }
    }
}

impl backend::Backend for Sqlite {
    fn file(&self) -> Option<&Path> {
        Some(&self.path)
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// One daemon owns the file: no shared queue.
impl backend::Fleet for Sqlite {}
