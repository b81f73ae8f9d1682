//! `calibd store copy`: move a lab's history from its SQLite file into an empty
//! PostgreSQL database, table by table, ids kept, in one PostgreSQL transaction (a copy
//! cut short leaves the target empty).

use postgres::types::{ToSql, Type};

use super::pg::Pg;
use super::sqlite::Sqlite;
use super::{Store, StoreError};

/// The tables, parents before children; each copied in its stored order.
const TABLES: &[(&str, &str)] = &[
    ("jobs", "id"),
    ("datasets", "id"),
    ("progress", "rowid"),
    ("results", "job_id"),
    ("artefacts", "job_id, name"),
    ("logs", "id"),
    ("schedules", "id"),
    ("schedule_runs", "id"),
    ("measurements", "job_id, idx"),
    ("cell_models", "id"),
    ("idempotency_keys", "submitted_by, key"),
];

/// Tables whose `id` comes from a sequence in PostgreSQL.
const SERIAL: &[&str] = &["jobs", "logs", "schedules", "schedule_runs", "cell_models"];

/// How many rows of each table were copied.
pub type Copied = Vec<(&'static str, u64)>;

/// One SQLite value as a parameter of the PostgreSQL column type `ty`.
fn param(v: rusqlite::types::Value, ty: &Type) -> Result<Box<dyn ToSql + Sync>, StoreError> {
    use rusqlite::types::Value as V;
    let bad = |v: &V| StoreError::Corrupt {
        column: "(copy)",
        value: format!("{v:?} for a {ty} column"),
    };
    Ok(match (v, ty) {
        (V::Null, t) if *t == Type::INT8 => Box::new(None::<i64>),
        (V::Null, t) if *t == Type::FLOAT8 => Box::new(None::<f64>),
        (V::Null, t) if *t == Type::BYTEA => Box::new(None::<Vec<u8>>),
        (V::Null, _) => Box::new(None::<String>),
        (V::Integer(i), t) if *t == Type::INT8 => Box::new(i),
        (V::Integer(i), t) if *t == Type::FLOAT8 => Box::new(i as f64),
        (V::Real(x), t) if *t == Type::FLOAT8 => Box::new(x),
        (V::Text(s), t) if *t == Type::TEXT => Box::new(s),
        (V::Integer(i), t) if *t == Type::TEXT => Box::new(i.to_string()),
        (V::Blob(b), t) if *t == Type::BYTEA => Box::new(b),
        (V::Text(s), t) if *t == Type::BYTEA => Box::new(s.into_bytes()),
        (v, _) => return Err(bad(&v)),
    })
}

impl Store {
    /// Copy everything in this (SQLite) store into `to` (PostgreSQL), which must hold no
    /// job yet. Returns the rows copied per table.
    pub fn copy_to(&self, to: &Store) -> Result<Copied, StoreError> {
        let Some(pg) = to.backend.as_any().downcast_ref::<Pg>() else {
            return Err(StoreError::Unsupported("copy goes to a PostgreSQL store"));
        };
        let Some(src) = self.backend.as_any().downcast_ref::<Sqlite>() else {
            return Err(StoreError::Unsupported("copy comes from a SQLite store"));
        };
        // The writer, held: nothing is written to the source while it is copied.
        let sq = src.writer();
        let mut c = pg.conn()?;
        let mut tx = c.transaction()?;
        let jobs: i64 = tx.query_one("SELECT COUNT(*) FROM jobs", &[])?.try_get(0)?;
        if jobs > 0 {
            return Err(StoreError::Conflict(format!(
                "the target database already holds {jobs} jobs"
            )));
        }
        let mut copied = Vec::new();
        for (table, order) in TABLES {
            let mut st = sq.prepare(&format!("SELECT * FROM {table} ORDER BY {order}"))?;
            let cols: Vec<String> = st.column_names().map(|s| s.to_string()).collect();
            let marks: Vec<String> = (1..=cols.len()).map(|i| format!("${i}")).collect();
            let insert = tx.prepare(&format!(
                "INSERT INTO {table} ({}) VALUES ({})",
                cols.join(", "),
                marks.join(", ")
            ))?;
            let types = insert.params().to_vec();
            let mut rows = st.query([])?;
            let mut n = 0;
            while let Some(r) = rows.next()? {
                let mut ps = Vec::with_capacity(cols.len());
                for (i, ty) in types.iter().enumerate() {
                    ps.push(param(r.get::<_, rusqlite::types::Value>(i)?, ty)?);
                }
                let refs: Vec<&(dyn ToSql + Sync)> = ps.iter().map(|p| p.as_ref()).collect();
                tx.execute(&insert, &refs)?;
                n += 1;
            }
            copied.push((*table, n));
        }
        for table in SERIAL {
            tx.execute(
                &format!(
                    "SELECT setval(pg_get_serial_sequence('{table}', 'id'), \
                     COALESCE((SELECT MAX(id) FROM {table}), 0) + 1, false)"
                ),
                &[],
            )?;
        }
        tx.commit()?;
        Ok(copied)
    }
}
