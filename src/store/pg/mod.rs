//! The PostgreSQL backend: several daemons on one database. The synchronous `postgres`
//! client (over tokio-postgres, with its own small runtime per connection) keeps the
//! store's blocking shape, so async code reaches both backends alike through the
//! service's storage module (which runs calls on the blocking pool; never call this client
//! on a runtime thread: it panics there). A
//! small pool of connections; the schema is the SQLite schema translated by
//! [`translate`], plus a PostgreSQL-only step for the shared queue (leases, cells).

mod fleet;
mod jobs;
mod other;
mod schedules;

pub use fleet::{CancelRequest, Claimed};

use std::sync::Mutex;

use postgres::{Client, NoTls};

use super::StoreError;

/// Where the store lives: the `store` setting.
#[derive(Clone, PartialEq, Eq)]
pub enum Location {
    /// `sqlite:PATH`: the embedded SQLite file `calibd.sqlite3` in folder PATH.
    Sqlite(std::path::PathBuf),
    /// `postgres://…`: a PostgreSQL database.
    Postgres(PgLocation),
}

/// A PostgreSQL location: the URL without a password, and the password from a file or an
/// environment variable (kept out of `Debug` and of every message).
#[derive(Clone, PartialEq, Eq)]
pub struct PgLocation {
    url: String,
    password: Option<String>,
}

impl std::fmt::Debug for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Location::Sqlite(p) => write!(f, "sqlite:{}", p.display()),
            Location::Postgres(p) => p.fmt(f),
        }
    }
}

impl std::fmt::Debug for PgLocation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pw = if self.password.is_some() {
            " (password set)"
        } else {
            ""
        };
        write!(f, "{}{pw}", self.url)
    }
}

impl Location {
    /// Parse a `store` setting: `sqlite:PATH` or a `postgres://` / `postgresql://` URL. A
    /// password inside the URL is refused (it would end up in config files and logs): give
    /// it as `password` (read from `password_file` or an environment variable).
    pub fn parse(s: &str, password: Option<String>) -> Result<Location, StoreError> {
        if let Some(path) = s.strip_prefix("sqlite:") {
            if path.is_empty() {
                return Err(StoreError::Location("`sqlite:` needs a folder".into()));
            }
            return Ok(Location::Sqlite(path.into()));
        }
        if !(s.starts_with("postgres://") || s.starts_with("postgresql://")) {
            return Err(StoreError::Location(
                "`store` must be `sqlite:FOLDER` or a `postgres://` URL".into(),
            ));
        }
        let cfg: postgres::Config = s
            .parse()
            .map_err(|_| StoreError::Location("the PostgreSQL URL does not parse".into()))?;
        if cfg.get_password().is_some() {
            return Err(StoreError::Location(
                "no password in the PostgreSQL URL: use `password_file` or CALIBD_STORE_PASSWORD"
                    .into(),
            ));
        }
        Ok(Location::Postgres(PgLocation {
            url: s.to_string(),
            password,
        }))
    }

    /// The location with its password never shown (for logs).
    pub fn display(&self) -> String {
        format!("{self:?}")
    }
}

/// The PostgreSQL store: a pool of connections.
pub(crate) struct Pg {
    config: postgres::Config,
    idle: Mutex<Vec<Client>>,
}

impl std::fmt::Debug for Pg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pg").finish_non_exhaustive()
    }
}

/// Connections kept idle at most.
const IDLE: usize = 8;

/// A pooled connection, returned to the pool when dropped (unless it broke).
pub(crate) struct Conn<'a> {
    pool: &'a Pg,
    client: Option<Client>,
}

impl std::ops::Deref for Conn<'_> {
    type Target = Client;
    fn deref(&self) -> &Client {
        self.client.as_ref().expect("taken only on drop")
    }
}

impl std::ops::DerefMut for Conn<'_> {
    fn deref_mut(&mut self) -> &mut Client {
        self.client.as_mut().expect("taken only on drop")
    }
}

impl Drop for Conn<'_> {
    fn drop(&mut self) {
        if let Some(c) = self.client.take()
            && !c.is_closed()
        {
            let mut idle = self.pool.idle.lock().unwrap_or_else(|p| p.into_inner());
            if idle.len() < IDLE {
                idle.push(c);
            }
        }
    }
}

impl Pg {
    /// Connect, check the server answers, and migrate (under an advisory lock, so daemons
    /// starting together migrate once).
    pub(crate) fn connect(loc: &PgLocation) -> Result<Pg, StoreError> {
        let mut config: postgres::Config = loc
            .url
            .parse()
            .map_err(|_| StoreError::Location("the PostgreSQL URL does not parse".into()))?;
        if let Some(p) = &loc.password {
            config.password(p);
        }
        if config.get_application_name().is_none() {
            config.application_name("calibd");
        }
        config.connect_timeout(std::time::Duration::from_secs(10));
        let pg = Pg {
            config,
            idle: Mutex::new(Vec::new()),
        };
        let mut c = pg.conn()?;
        migrate(&mut c)?;
        drop(c);
        Ok(pg)
    }

    /// A connection from the pool (or a new one).
    pub(crate) fn conn(&self) -> Result<Conn<'_>, StoreError> {
        let pooled = self.idle.lock().unwrap_or_else(|p| p.into_inner()).pop();
        let client = match pooled {
            Some(c) if !c.is_closed() => c,
            _ => self.config.connect(NoTls)?,
        };
        Ok(Conn {
            pool: self,
            client: Some(client),
        })
    }
}

/// The SQLite schema step `sql` in PostgreSQL's types: the same tables, columns and
/// indexes (ids are `BIGSERIAL`, integers `BIGINT`, reals `DOUBLE PRECISION`, blobs `BYTEA`).
pub(crate) fn translate(sql: &str) -> String {
    sql.replace("INTEGER PRIMARY KEY AUTOINCREMENT", "BIGSERIAL PRIMARY KEY")
        .replace("INTEGER", "BIGINT")
        .replace("REAL", "DOUBLE PRECISION")
        .replace("BLOB", "BYTEA")
}

/// How many SQLite schema steps existed when the PostgreSQL backend came; later SQLite
/// steps follow [`PG_STEPS`] in a PostgreSQL database.
const SQLITE_STEPS_BEFORE_PG: usize = 3;

/// PostgreSQL-only steps after the translated SQLite ones: what several daemons need.
const PG_STEPS: &[&str] = &[
    // Progress history in insertion order (SQLite uses its rowid); the shared queue's claims:
    // which daemon holds a running job and until when (renewed by its heartbeat); which
    // daemon holds each cell; the daemons' heartbeats.
    "ALTER TABLE progress ADD COLUMN seq BIGSERIAL;
    ALTER TABLE jobs ADD COLUMN owner TEXT;
    ALTER TABLE jobs ADD COLUMN lease_until TIMESTAMPTZ;
    ALTER TABLE jobs ADD COLUMN cell TEXT;
    CREATE INDEX jobs_queue ON jobs(state, priority DESC, id) WHERE state = 'queued';
    CREATE TABLE daemons (
        name TEXT PRIMARY KEY,
        started_at TIMESTAMPTZ NOT NULL,
        heartbeat TIMESTAMPTZ NOT NULL
    );
    CREATE TABLE cells (
        name TEXT PRIMARY KEY,
        owner TEXT NOT NULL,
        since TIMESTAMPTZ NOT NULL
    );",
];

/// Bring the schema up to date; returns the version found before.
fn migrate(c: &mut Client) -> Result<i64, StoreError> {
    // SQLite's steps up to the first PostgreSQL store, then PostgreSQL's own, then SQLite's
    // later steps: a database keeps its version numbers as both lists grow.
    let sqlite = super::migrate::steps();
    let (before, after) = sqlite.split_at(SQLITE_STEPS_BEFORE_PG.min(sqlite.len()));
    let steps: Vec<String> = before
        .iter()
        .map(|s| translate(s))
        .chain(PG_STEPS.iter().map(|s| s.to_string()))
        .chain(after.iter().map(|s| translate(s)))
        .collect();
    let known = steps.len() as i64;
    let mut tx = c.transaction()?;
    // One migrator at a time across daemons.
    tx.execute("SELECT pg_advisory_xact_lock(7106601)", &[])?;
    tx.batch_execute("CREATE TABLE IF NOT EXISTS calibd_schema (version BIGINT NOT NULL)")?;
    let found: i64 = match tx.query_opt("SELECT version FROM calibd_schema", &[])? {
        Some(r) => r.get(0),
        None => {
            tx.execute("INSERT INTO calibd_schema (version) VALUES (0)", &[])?;
            0
        }
    };
    if found > known {
        return Err(StoreError::SchemaTooNew { found, known });
    }
    for step in &steps[found as usize..] {
        tx.batch_execute(step)?;
    }
    tx.execute("UPDATE calibd_schema SET version = $1", &[&known])?;
    tx.commit()?;
    Ok(found)
}

/// The current instant in the store's text format.
fn now() -> String {
    super::now()
}
