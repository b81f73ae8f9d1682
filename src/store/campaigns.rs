//! Campaign state in the store: each job's measurement journal (one row per configuration,
//! committed before the robot moves again), pausing and resuming, and each cell's model
//! history (the current model, accepted and rejected candidates, and why).

use rusqlite::params;
use serde::Serialize;
use serde_json::Value;

use super::jobs::log_tx;
use super::{Run, Store, StoreError, now};
use crate::lab::Decision;
use crate::procedures::{EntryStatus, Journal, JournalEntry};

/// A cell model as stored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellModel {
    /// Row id.
    pub id: i64,
    /// Cell name.
    pub cell: String,
    /// The campaign job that produced it (none for a model set by hand).
    pub job_id: Option<i64>,
    /// `current`, `superseded` or `rejected`.
    pub state: String,
    /// Why it was accepted or rejected.
    pub reason: String,
    /// Validation figures the decision was made on.
    pub validation: Value,
    /// The model file.
    pub model: Value,
    /// When (RFC 3339).
    pub at: String,
}

impl Store {
    /// Append one journal entry of job `job`; an index already present is refused.
    pub fn append_measurement(&self, job: i64, e: &JournalEntry) -> Result<(), StoreError> {
        if let Some(pg) = self.pg() {
            return pg.append_measurement(job, e);
        }
        let status = match e.status {
            EntryStatus::Measured => "measured",
            EntryStatus::Skipped => "skipped",
        };
        self.write(|c| {
            c.execute(
                "INSERT INTO measurements (job_id, idx, status, data, at) VALUES (?1, ?2, ?3, ?4, ?5)",
                params![job, e.index as i64, status, e.data.to_string(), now()],
            )?;
            Ok(())
        })
    }

    /// The journal of job `job`, in index order.
    pub fn measurements(&self, job: i64) -> Result<Vec<JournalEntry>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.measurements(job);
        }
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

    /// Run `run`'s job paused on device faults; false if it was not running,
    /// [`StoreError::Stale`] if it was taken from the run.
    pub fn pause_job(&self, run: Run, reason: &str) -> Result<bool, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.pause_job(run, reason);
        }
        let id = run.job;
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx.execute(
                "UPDATE jobs SET state = 'paused', error = ?2 \
                 WHERE id = ?1 AND state = 'running' AND attempt = ?3",
                params![id, reason, run.attempt],
            )?;
            if n == 1 {
                log_tx(&tx, Some(id), "warn", &format!("paused: {reason}"))?;
            } else {
                super::runs::check_run(&tx, run)?;
            }
            tx.commit()?;
            Ok(n == 1)
        })
    }

    /// Queue a paused or interrupted job again; false if it is in neither state.
    pub fn resume_job(&self, id: i64, why: &str) -> Result<bool, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.resume_job(id, why);
        }
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx.execute(
                "UPDATE jobs SET state = 'queued', error = NULL, finished_at = NULL \
                 WHERE id = ?1 AND state IN ('paused', 'interrupted')",
                params![id],
            )?;
            if n == 1 {
                log_tx(&tx, Some(id), "info", &format!("resumed: {why}"))?;
            }
            tx.commit()?;
            Ok(n == 1)
        })
    }

    /// The current model of `cell`, if one was accepted.
    pub fn current_cell_model(&self, cell: &str) -> Result<Option<CellModel>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.current_cell_model(cell);
        }
        Ok(self
            .cell_models(cell)?
            .into_iter()
            .find(|m| m.state == "current"))
    }

    /// The model history of `cell`, newest first.
    pub fn cell_models(&self, cell: &str) -> Result<Vec<CellModel>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.cell_models(cell);
        }
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

/// Insert a decision into the cell's model history within `tx`.
pub(super) fn insert_cell_model(
    tx: &rusqlite::Transaction<'_>,
    job_id: Option<i64>,
    d: &Decision,
) -> Result<i64, StoreError> {
    if d.accepted {
        tx.execute(
            "UPDATE cell_models SET state = 'superseded' WHERE cell = ?1 AND state = 'current'",
            [&d.cell],
        )?;
    }
    tx.execute(
        "INSERT INTO cell_models (cell, job_id, state, reason, validation, model, at) \
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
        params![
            d.cell,
            job_id,
            if d.accepted { "current" } else { "rejected" },
            d.reason,
            d.validation.to_string(),
            d.model.to_string(),
            now()
        ],
    )?;
    Ok(tx.last_insert_rowid())
}

/// The measurement journal of one job, in the store: an append returns once committed.
#[derive(Debug, Clone)]
pub struct StoreJournal {
    /// The store.
    pub store: Store,
    /// The job.
    pub job: i64,
}

impl Journal for StoreJournal {
    fn entries(&self) -> Result<Vec<JournalEntry>, String> {
        self.store.measurements(self.job).map_err(|e| e.to_string())
    }

    fn append(&self, e: &JournalEntry) -> Result<(), String> {
        self.store
            .append_measurement(self.job, e)
            .map_err(|e| e.to_string())
    }
}
