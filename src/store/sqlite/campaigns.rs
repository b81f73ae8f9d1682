//! Campaign state on SQLite: measurement journals, pause and resume, cell models.

use rusqlite::params;

use super::Sqlite;
use super::jobs::log_tx;
use crate::lab::Decision;
use crate::procedures::{EntryStatus, JournalEntry};
use crate::store::backend::Campaigns;
use crate::store::{CellModel, Run, StoreError, now};

/// Insert a decision into the cell's model history within `tx`.
pub(super) fn insert_cell_model(
    tx: &rusqlite::Transaction<'_>,
    job_id: Option<i64>,
    d: &Decision,
) -> Result<i64, StoreError> {
    if d.accepted {
        tx.prepare_cached(
            "UPDATE cell_models SET state = 'superseded' WHERE cell = ?1 AND state = 'current'",
        )?
        .execute([&d.cell])?;
    }
    tx.prepare_cached(
        "INSERT INTO cell_models (cell, job_id, state, reason, validation, model, at) \
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
    )?
    .execute(params![
        d.cell,
        job_id,
        if d.accepted { "current" } else { "rejected" },
        d.reason,
        d.validation.to_string(),
        d.model.to_string(),
        now()
    ])?;
    Ok(tx.last_insert_rowid())
}

impl Campaigns for Sqlite {
    fn append_measurement(&self, job: i64, e: &JournalEntry) -> Result<(), StoreError> {
        let status = match e.status {
            EntryStatus::Measured => "measured",
            EntryStatus::Skipped => "skipped",
        };
        self.write(|c| {
            c.prepare_cached(
                "INSERT INTO measurements (job_id, idx, status, data, at) VALUES (?1, ?2, ?3, ?4, ?5)",
            )?
            .execute(params![job, e.index as i64, status, e.data.to_string(), now()])
            .map_err(|err| match err {
                rusqlite::Error::SqliteFailure(f, _)
                    if f.extended_code == rusqlite::ffi::SQLITE_CONSTRAINT_PRIMARYKEY =>
                {
                    StoreError::Conflict(format!("configuration {} of job {job}", e.index))
                }
                other => StoreError::Sqlite(other),
            })?;
            Ok(())
        })
    }

    fn measurements(&self, job: i64) -> Result<Vec<JournalEntry>, StoreError> {
        self.read(|c| {
            let mut st = c.prepare_cached(
                "SELECT idx, status, data FROM measurements WHERE job_id = ?1 ORDER BY idx",
            )?;
            let rows = st.query_map([job], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                ))
            })?;
            let mut out = Vec::new();
            for row in rows {
                let (idx, status, data) = row?;
                out.push(JournalEntry {
                    index: idx as usize,
                    status: if status == "skipped" {
                        EntryStatus::Skipped
                    } else {
                        EntryStatus::Measured
                    },
                    data: serde_json::from_str(&data)?,
                });
            }
            Ok(out)
        })
    }

    fn pause_job(&self, run: Run, reason: &str) -> Result<bool, StoreError> {
        let id = run.job;
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx
                .prepare_cached(
                    "UPDATE jobs SET state = 'paused', error = ?2 \
                     WHERE id = ?1 AND state = 'running' AND attempt = ?3",
                )?
                .execute(params![id, reason, run.attempt])?;
            if n == 1 {
                log_tx(&tx, Some(id), "warn", &format!("paused: {reason}"))?;
            } else {
                super::runs::check_run(&tx, run)?;
            }
            tx.commit()?;
            Ok(n == 1)
        })
    }

    fn resume_job(&self, id: i64, why: &str) -> Result<bool, StoreError> {
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx
                .prepare_cached(
                    "UPDATE jobs SET state = 'queued', error = NULL, finished_at = NULL, \
                     resumed_at = ?2 WHERE id = ?1 AND state IN ('paused', 'interrupted')",
                )?
                .execute(params![id, now()])?;
            if n == 1 {
                log_tx(&tx, Some(id), "info", &format!("resumed: {why}"))?;
            }
            tx.commit()?;
            Ok(n == 1)
        })
    }

    fn note_pause(&self, id: i64, reason: &str) -> Result<bool, StoreError> {
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx
                .prepare_cached("UPDATE jobs SET error = ?2 WHERE id = ?1 AND state = 'paused'")?
                .execute(params![id, reason])?;
            if n == 1 {
                log_tx(&tx, Some(id), "warn", &format!("paused: {reason}"))?;
            }
            tx.commit()?;
            Ok(n == 1)
        })
    }

    fn cell_models(&self, cell: &str) -> Result<Vec<CellModel>, StoreError> {
        self.read(|c| {
            let mut st = c.prepare_cached(
                "SELECT id, cell, job_id, state, reason, validation, model, at FROM cell_models \
                 WHERE cell = ?1 ORDER BY id DESC",
            )?;
            let rows = st.query_map([cell], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, Option<i64>>(2)?,
                    r.get::<_, String>(3)?,
                    r.get::<_, String>(4)?,
                    r.get::<_, String>(5)?,
                    r.get::<_, String>(6)?,
                    r.get::<_, String>(7)?,
                ))
            })?;
            let mut out = Vec::new();
            for row in rows {
                let (id, cell, job_id, state, reason, validation, model, at) = row?;
                out.push(CellModel {
                    id,
                    cell,
                    job_id,
                    state,
                    reason,
                    validation: serde_json::from_str(&validation)?,
                    model: serde_json::from_str(&model)?,
                    at,
                });
            }
            Ok(out)
        })
    }
}
