//! The PostgreSQL backend: several daemons on one database. The synchronous `postgres`
//! client (over tokio-postgres, with its own small runtime per connection) keeps the
//! store's blocking shape, so async code reaches both backends alike through the
//! service's storage module (which runs calls on the blocking pool; never call this client
//! on a runtime thread: it panics there). A small pool of connections, each keeping the
//! hot statements it prepared ([`Statements`]); the schema is the SQLite schema translated
//! by [`translate`], plus a PostgreSQL-only step for the shared queue (leases, cells).

mod fleet;
mod jobs;
mod other;
mod schedules;

use std::collections::HashMap;
use std::sync::Mutex;

use postgres::{Client, GenericClient, NoTls, Statement};

use super::{PgLocation, StoreError, backend};

/// The PostgreSQL store: a pool of connections.
pub(crate) struct Pg {
    config: postgres::Config,
    idle: Mutex<Vec<(Client, Statements)>>,
}

/// The statements prepared on one connection, by their SQL: the hot calls (status reads,
/// progress) are parsed and planned once per connection, not once per call.
#[derive(Default)]
pub(crate) struct Statements(HashMap<&'static str, Statement>);

impl Statements {
    /// Statement `sql`, prepared on `c` (a connection or one of its transactions) the
    /// first time.
    pub(crate) fn get(
        &mut self,
        c: &mut impl GenericClient,
        sql: &'static str,
    ) -> Result<Statement, StoreError> {
        if let Some(s) = self.0.get(sql) {
            return Ok(s.clone());
        }
        let s = c.prepare(sql)?;
        self.0.insert(sql, s.clone());
        Ok(s)
    }
}

impl std::fmt::Debug for Pg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pg").finish_non_exhaustive()
    }
}

/// Connections kept idle at most.
const IDLE: usize = 8;

/// A pooled connection with its prepared statements, returned to the pool when dropped
/// (unless it broke).
pub(crate) struct Conn<'a> {
    pool: &'a Pg,
    client: Option<(Client, Statements)>,
}

impl std::ops::Deref for Conn<'_> {
    type Target = Client;
    fn deref(&self) -> &Client {
        &self.client.as_ref().expect("taken only on drop").0
    }
}

impl std::ops::DerefMut for Conn<'_> {
    fn deref_mut(&mut self) -> &mut Client {
        &mut self.client.as_mut().expect("taken only on drop").0
    }
}

impl Conn<'_> {
    /// The client and its statement cache, apart (a transaction borrows the client).
    pub(crate) fn split(&mut self) -> (&mut Client, &mut Statements) {
        let (c, s) = self.client.as_mut().expect("taken only on drop");
        (c, s)
    }

    /// At most one row of the cached statement `sql`.
    pub(crate) fn query_opt_cached(
        &mut self,
        sql: &'static str,
        params: &[&(dyn postgres::types::ToSql + Sync)],
    ) -> Result<Option<postgres::Row>, StoreError> {
        let (c, s) = self.split();
        let st = s.get(c, sql)?;
        Ok(c.query_opt(&st, params)?)
    }

    /// The rows of the cached statement `sql`.
    pub(crate) fn query_cached(
        &mut self,
        sql: &'static str,
        params: &[&(dyn postgres::types::ToSql + Sync)],
    ) -> Result<Vec<postgres::Row>, StoreError> {
        let (c, s) = self.split();
        let st = s.get(c, sql)?;
        Ok(c.query(&st, params)?)
    }
}

impl Drop for Conn<'_> {
    fn drop(&mut self) {
        if let Some((c, s)) = self.client.take()
            && !c.is_closed()
        {
            let mut idle = self.pool.idle.lock().unwrap_or_else(|p| p.into_inner());
            if idle.len() < IDLE {
                idle.push((c, s));
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
            Some((c, s)) if !c.is_closed() => (c, s),
            _ => (self.config.connect(NoTls)?, Statements::default()),
        };
        Ok(Conn {
            pool: self,
            client: Some(client),
        })
    }
}

impl backend::Backend for Pg {
    fn file(&self) -> Option<&std::path::Path> {
        None
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
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
