//! Results, artefacts, datasets and campaign state on PostgreSQL: the same operations and
//! rules as the SQLite modules.

use postgres::GenericClient;
use serde_json::Value;

use super::jobs::log_tx;
use super::{Pg, now};
use crate::jobs::Artefact;
use crate::lab::Decision;
use crate::procedures::{EntryStatus, JournalEntry};
use crate::store::backend::{Campaigns, Datasets, Results};
use crate::store::{ArtefactInfo, CellModel, DatasetInfo, MainTableCsv, Run, StoreError};

/// Record a schedule occurrence within `c` and move the schedule's `checked_until`.
pub(super) fn record_run_tx(
    c: &mut impl GenericClient,
    schedule: i64,
    due: &str,
    outcome: &str,
    job: Option<i64>,
    message: Option<&str>,
) -> Result<(), StoreError> {
    c.execute(
        "INSERT INTO schedule_runs (schedule_id, due_at, at, outcome, job_id, message) \
         VALUES ($1, $2, $3, $4, $5, $6)",
        &[&schedule, &due, &now(), &outcome, &job, &message],
    )?;
    c.execute(
        "UPDATE schedules SET checked_until = GREATEST(checked_until, $2) WHERE id = $1",
        &[&schedule, &due],
    )?;
    Ok(())
}

fn insert_cell_model(
    c: &mut impl GenericClient,
    job_id: Option<i64>,
    d: &Decision,
) -> Result<(), StoreError> {
    if d.accepted {
        c.execute(
            "UPDATE cell_models SET state = 'superseded' WHERE cell = $1 AND state = 'current'",
            &[&d.cell],
        )?;
    }
    c.execute(
        "INSERT INTO cell_models (cell, job_id, state, reason, validation, model, at) \
         VALUES ($1, $2, $3, $4, $5, $6, $7)",
        &[
            &d.cell,
            &job_id,
            &if d.accepted { "current" } else { "rejected" },
            &d.reason,
            &d.validation.to_string(),
            &d.model.to_string(),
            &now(),
        ],
    )?;
    Ok(())
}

impl Results for Pg {
    fn finish_job(
        &self,
        run: Run,
        result: &Value,
        main_table_csv: Option<MainTableCsv<'_>>,
        artefacts: &[Artefact],
        decision: Option<&Decision>,
    ) -> Result<bool, StoreError> {
        let text = serde_json::to_string(result)?;
        // PostgreSQL takes the table as one parameter: a file is read whole here.
        let from_file = match main_table_csv {
            Some(MainTableCsv::File(path)) => Some(std::fs::read_to_string(path).map_err(
                |source| StoreError::Io {
                    path: path.to_path_buf(),
                    source,
                },
            )?),
            _ => None,
        };
        let main_table_csv = match main_table_csv {
            Some(MainTableCsv::Text(t)) => Some(t),
            _ => from_file.as_deref(),
        };
        let id = run.job;
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let n = tx.execute(
            "UPDATE jobs SET state = 'succeeded', finished_at = $2, progress = 1, error = NULL, \
             owner = NULL, lease_until = NULL WHERE id = $1 AND state = 'running' AND attempt = $3",
            &[&id, &now(), &run.attempt],
        )?;
        if n != 1 {
            super::jobs::check_run(&mut tx, run)?;
            return Ok(false);
        }
        tx.execute(
            "INSERT INTO results (job_id, result, main_table_csv) VALUES ($1, $2, $3)",
            &[&id, &text, &main_table_csv],
        )?;
        for a in artefacts {
            tx.execute(
                "INSERT INTO artefacts (job_id, name, media_type, content) VALUES ($1, $2, $3, $4)",
                &[&id, &a.name, &a.media_type, &a.content],
            )?;
        }
        if let Some(d) = decision {
            insert_cell_model(&mut tx, Some(id), d)?;
            let msg = format!(
                "cell {}: model {}: {}",
                d.cell,
                if d.accepted { "accepted" } else { "rejected" },
                d.reason
            );
            log_tx(&mut tx, Some(id), "info", &msg)?;
        }
        log_tx(&mut tx, Some(id), "info", "succeeded")?;
        tx.commit()?;
        Ok(true)
    }

    fn result(&self, id: i64) -> Result<Option<Value>, StoreError> {
        let row = self
            .conn()?
            .query_opt_cached("SELECT result FROM results WHERE job_id = $1", &[&id])?;
        match row {
            Some(r) => Ok(Some(serde_json::from_str(r.try_get::<_, &str>(0)?)?)),
            None => Ok(None),
        }
    }

    fn main_table_csv(&self, id: i64) -> Result<Option<String>, StoreError> {
        let row = self.conn()?.query_opt(
            "SELECT main_table_csv FROM results WHERE job_id = $1",
            &[&id],
        )?;
        Ok(match row {
            Some(r) => r.try_get(0)?,
            None => None,
        })
    }

    fn artefacts(&self, id: i64) -> Result<Vec<ArtefactInfo>, StoreError> {
        let rows = self.conn()?.query(
            "SELECT name, media_type, octet_length(content)::BIGINT FROM artefacts WHERE job_id = $1 ORDER BY name",
            &[&id],
        )?;
        rows.iter()
            .map(|r| {
                Ok(ArtefactInfo {
                    name: r.try_get(0)?,
                    media_type: r.try_get(1)?,
                    size: r.try_get(2)?,
                })
            })
            .collect()
    }

    fn artefact(&self, id: i64, name: &str) -> Result<Option<Artefact>, StoreError> {
        let row = self.conn()?.query_opt(
            "SELECT name, media_type, content FROM artefacts WHERE job_id = $1 AND name = $2",
            &[&id, &name],
        )?;
        row.map(|r| {
            Ok(Artefact {
                name: r.try_get(0)?,
                media_type: r.try_get(1)?,
                content: r.try_get(2)?,
            })
        })
        .transpose()
    }
}

impl Pg {
    fn dataset_rows(&self, one: Option<&str>) -> Result<Vec<DatasetInfo>, StoreError> {
        let rows = self.conn()?.query(
            "SELECT id, name, media_type, size, created_at FROM datasets \
             WHERE ($1::TEXT IS NULL OR id = $1) ORDER BY created_at DESC, id",
            &[&one],
        )?;
        rows.iter()
            .map(|r| {
                Ok(DatasetInfo {
                    id: r.try_get(0)?,
                    name: r.try_get(1)?,
                    media_type: r.try_get(2)?,
                    size: r.try_get(3)?,
                    created_at: r.try_get(4)?,
                })
            })
            .collect()
    }
}

impl Datasets for Pg {
    fn insert_dataset(
        &self,
        id: &str,
        name: &str,
        media_type: &str,
        content: &[u8],
    ) -> Result<(), StoreError> {
        self.conn()?.execute(
            "INSERT INTO datasets (id, name, media_type, size, created_at, content) \
             VALUES ($1, $2, $3, $4, $5, $6) ON CONFLICT (id) DO NOTHING",
            &[
                &id,
                &name,
                &media_type,
                &(content.len() as i64),
                &now(),
                &content,
            ],
        )?;
        Ok(())
    }

    fn dataset_info(&self, id: &str) -> Result<Option<DatasetInfo>, StoreError> {
        Ok(self.dataset_rows(Some(id))?.into_iter().next())
    }

    fn dataset(&self, id: &str) -> Result<Option<Vec<u8>>, StoreError> {
        let row = self
            .conn()?
            .query_opt("SELECT content FROM datasets WHERE id = $1", &[&id])?;
        Ok(row.map(|r| r.try_get(0)).transpose()?)
    }

    fn datasets(&self) -> Result<Vec<DatasetInfo>, StoreError> {
        self.dataset_rows(None)
    }

    fn dataset_to_writer(
        &self,
        id: &str,
        out: &mut dyn std::io::Write,
        path: &std::path::Path,
    ) -> Result<bool, StoreError> {
        // PostgreSQL reads the value whole.
        match self.dataset(id)? {
            Some(bytes) => {
                out.write_all(&bytes).map_err(|source| StoreError::Io {
                    path: path.to_path_buf(),
                    source,
                })?;
                Ok(true)
            }
            None => Ok(false),
        }
    }
}

impl Campaigns for Pg {
    fn append_measurement(&self, job: i64, e: &JournalEntry) -> Result<(), StoreError> {
        let status = match e.status {
            EntryStatus::Measured => "measured",
            EntryStatus::Skipped => "skipped",
        };
        self.conn()?.execute(
            "INSERT INTO measurements (job_id, idx, status, data, at) VALUES ($1, $2, $3, $4, $5)",
            &[
                &job,
                &(e.index as i64),
                &status,
                &e.data.to_string(),
                &now(),
            ],
        )
        .map_err(|err| {
            if err.code() == Some(&postgres::error::SqlState::UNIQUE_VIOLATION) {
                StoreError::Conflict(format!("configuration {} of job {job}", e.index))
            } else {
                StoreError::Postgres(err)
            }
        })?;
        Ok(())
    }

    fn measurements(&self, job: i64) -> Result<Vec<JournalEntry>, StoreError> {
        let rows = self.conn()?.query(
            "SELECT idx, status, data FROM measurements WHERE job_id = $1 ORDER BY idx",
            &[&job],
        )?;
        rows.iter()
            .map(|r| {
                let idx: i64 = r.try_get(0)?;
                let status: &str = r.try_get(1)?;
                Ok(JournalEntry {
                    index: usize::try_from(idx).map_err(|_| StoreError::Corrupt {
                        column: "measurements.idx",
                        value: idx.to_string(),
                    })?,
                    status: if status == "skipped" {
                        EntryStatus::Skipped
                    } else {
                        EntryStatus::Measured
                    },
                    data: serde_json::from_str(r.try_get(2)?)?,
                })
            })
            .collect()
    }

    fn pause_job(&self, run: Run, reason: &str) -> Result<bool, StoreError> {
        let id = run.job;
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let n = tx.execute(
            "UPDATE jobs SET state = 'paused', error = $2, owner = NULL, lease_until = NULL \
             WHERE id = $1 AND state = 'running' AND attempt = $3",
            &[&id, &reason, &run.attempt],
        )?;
        if n == 1 {
            log_tx(&mut tx, Some(id), "warn", &format!("paused: {reason}"))?;
        } else {
            super::jobs::check_run(&mut tx, run)?;
        }
        tx.commit()?;
        Ok(n == 1)
    }

    fn resume_job(&self, id: i64, why: &str) -> Result<bool, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let n = tx.execute(
            "UPDATE jobs SET state = 'queued', error = NULL, finished_at = NULL, resumed_at = $2 \
             WHERE id = $1 AND state IN ('paused', 'interrupted')",
            &[&id, &now()],
        )?;
        if n == 1 {
            log_tx(&mut tx, Some(id), "info", &format!("resumed: {why}"))?;
            tx.execute("SELECT pg_notify('calibd_queue', $1)", &[&id.to_string()])?;
        }
        tx.commit()?;
        Ok(n == 1)
    }

    fn note_pause(&self, id: i64, reason: &str) -> Result<bool, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let n = tx.execute(
            "UPDATE jobs SET error = $2 WHERE id = $1 AND state = 'paused'",
            &[&id, &reason],
        )?;
        if n == 1 {
            log_tx(&mut tx, Some(id), "warn", &format!("paused: {reason}"))?;
        }
        tx.commit()?;
        Ok(n == 1)
    }

    fn cell_models(&self, cell: &str) -> Result<Vec<CellModel>, StoreError> {
        let rows = self.conn()?.query(
            "SELECT id, cell, job_id, state, reason, validation, model, at FROM cell_models \
             WHERE cell = $1 ORDER BY id DESC",
            &[&cell],
        )?;
        rows.iter()
            .map(|r| {
                Ok(CellModel {
                    id: r.try_get(0)?,
                    cell: r.try_get(1)?,
                    job_id: r.try_get(2)?,
                    state: r.try_get(3)?,
                    reason: r.try_get(4)?,
                    validation: serde_json::from_str(r.try_get(5)?)?,
                    model: serde_json::from_str(r.try_get(6)?)?,
                    at: r.try_get(7)?,
                })
            })
            .collect()
    }
}
