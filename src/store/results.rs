//! Results and artefacts: written together with the job's final state in one transaction.

use rusqlite::{OptionalExtension, params};
use serde::Serialize;
use serde_json::Value;

use super::{Run, Store, StoreError, jobs::JobState, now};
use crate::jobs::Artefact;
use crate::lab::Decision;

/// A job's main table as it reaches the store: CSV text, or a CSV file written row by row
/// (a large table is copied into the database in chunks, never held whole in memory).
#[derive(Debug, Clone, Copy)]
pub enum MainTableCsv<'a> {
    /// The CSV text.
    Text(&'a str),
    /// A CSV file.
    File(&'a std::path::Path),
}

/// An artefact's description (no content).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArtefactInfo {
    /// File name.
    pub name: String,
    /// Media type.
    pub media_type: String,
    /// Size in bytes.
    pub size: i64,
}

impl Store {
    /// Store run `run`'s result, artefacts and its cell's model decision and mark the job
    /// `succeeded`, all in one transaction. False (and nothing written) if the job was no
    /// longer running (cancelled); [`StoreError::Stale`] if it was taken from the run.
    pub fn finish_job(
        &self,
        run: Run,
        result: &Value,
        main_table_csv: Option<MainTableCsv<'_>>,
        artefacts: &[Artefact],
        decision: Option<&Decision>,
    ) -> Result<bool, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.finish_job(run, result, main_table_csv, artefacts, decision);
        }
        let id = run.job;
        let text = serde_json::to_string(result)?;
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx.execute(
                "UPDATE jobs SET state = ?2, finished_at = ?3, progress = 1, error = NULL \
                 WHERE id = ?1 AND state = 'running' AND attempt = ?4",
                params![id, JobState::Succeeded.as_str(), now(), run.attempt],
            )?;
            if n != 1 {
                super::runs::check_run(&tx, run)?;
                return Ok(false);
            }
            match main_table_csv {
                Some(MainTableCsv::File(path)) => {
                    super::spool::insert_result_with_file(&tx, id, &text, path)?;
                }
                Some(MainTableCsv::Text(csv)) => {
                    tx.execute(
                        "INSERT INTO results (job_id, result, main_table_csv) VALUES (?1, ?2, ?3)",
                        params![id, text, csv],
                    )?;
                }
                None => {
                    tx.execute(
                        "INSERT INTO results (job_id, result, main_table_csv) VALUES (?1, ?2, NULL)",
                        params![id, text],
                    )?;
                }
            }
            for a in artefacts {
                tx.execute(
                    "INSERT INTO artefacts (job_id, name, media_type, content) VALUES (?1, ?2, ?3, ?4)",
                    params![id, a.name, a.media_type, a.content],
                )?;
            }
            if let Some(d) = decision {
                super::campaigns::insert_cell_model(&tx, Some(id), d)?;
                tx.execute(
                    "INSERT INTO logs (job_id, at, level, message) VALUES (?1, ?2, 'info', ?3)",
                    params![
                        id,
                        now(),
                        format!(
                            "cell {}: model {}: {}",
                            d.cell,
                            if d.accepted { "accepted" } else { "rejected" },
                            d.reason
                        )
                    ],
                )?;
            }
            tx.execute(
                "INSERT INTO logs (job_id, at, level, message) VALUES (?1, ?2, 'info', 'succeeded')",
                params![id, now()],
            )?;
            tx.commit()?;
            Ok(true)
        })
    }

    /// A job's result document.
    pub fn result(&self, id: i64) -> Result<Option<Value>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.result(id);
        }
        self.read(|c| {
            let s: Option<String> = c
                .query_row("SELECT result FROM results WHERE job_id = ?1", [id], |r| {
                    r.get(0)
                })
                .optional()?;
            Ok(s.map(|s| serde_json::from_str(&s)).transpose()?)
        })
    }

    /// A job's main table as CSV.
    pub fn main_table_csv(&self, id: i64) -> Result<Option<String>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.main_table_csv(id);
        }
        self.read(|c| {
            // Text, or a BLOB when the table was copied in chunks from a file.
            let csv = c
                .query_row(
                    "SELECT main_table_csv FROM results WHERE job_id = ?1",
                    [id],
                    |r| {
                        Ok(match r.get_ref(0)? {
                            rusqlite::types::ValueRef::Text(t)
                            | rusqlite::types::ValueRef::Blob(t) => {
                                Some(String::from_utf8_lossy(t).into_owned())
                            }
                            _ => None,
                        })
                    },
                )
                .optional()?
                .flatten();
            Ok(csv)
        })
    }

    /// A job's artefacts, by name.
    pub fn artefacts(&self, id: i64) -> Result<Vec<ArtefactInfo>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.artefacts(id);
        }
        self.read(|c| {
            let mut st = c.prepare_cached(
                "SELECT name, media_type, length(content) FROM artefacts WHERE job_id = ?1 ORDER BY name",
            )?;
            let rows = st.query_map([id], |r| {
                Ok(ArtefactInfo {
                    name: r.get(0)?,
                    media_type: r.get(1)?,
                    size: r.get(2)?,
                })
            })?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }

    /// One artefact with its content.
    pub fn artefact(&self, id: i64, name: &str) -> Result<Option<Artefact>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.artefact(id, name);
        }
        self.read(|c| {
            Ok(c.query_row(
                "SELECT name, media_type, content FROM artefacts WHERE job_id = ?1 AND name = ?2",
                params![id, name],
                |r| {
                    Ok(Artefact {
                        name: r.get(0)?,
                        media_type: r.get(1)?,
                        content: r.get(2)?,
                    })
                },
            )
            .optional()?)
        })
    }
}
