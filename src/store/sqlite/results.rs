//! Results and artefacts on SQLite: written together with the job's final state in one
//! transaction; a main table from a file is copied in chunks (incremental BLOB I/O).

use std::io::{Read, Write};
use std::path::Path;

use rusqlite::{MAIN_DB, OptionalExtension, Transaction, params};
use serde_json::Value;

use super::Sqlite;
use super::jobs::log_tx;
use crate::jobs::Artefact;
use crate::lab::Decision;
use crate::store::backend::Results;
use crate::store::{ArtefactInfo, MainTableCsv, Run, StoreError, now};

/// Chunk of the copies between files and BLOBs, bytes.
pub(super) const CHUNK: usize = 1 << 16;

pub(super) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Insert job `id`'s result with the CSV file `path` as its main table, copied in chunks.
fn insert_result_with_file(
    tx: &Transaction<'_>,
    id: i64,
    result: &str,
    path: &Path,
) -> Result<(), StoreError> {
    let mut file = std::fs::File::open(path).map_err(io_err(path))?;
    let len = file.metadata().map_err(io_err(path))?.len();
    let len =
        i64::try_from(len).map_err(|_| StoreError::Conflict("main table too large".into()))?;
    tx.execute(
        "INSERT INTO results (job_id, result, main_table_csv) VALUES (?1, ?2, zeroblob(?3))",
        params![id, result, len],
    )?;
    // `results.job_id` is the INTEGER PRIMARY KEY: the row id is the job id.
    let mut blob = tx.blob_open(MAIN_DB, "results", "main_table_csv", id, false)?;
    let mut buf = vec![0u8; CHUNK];
    loop {
        let n = file.read(&mut buf).map_err(io_err(path))?;
        if n == 0 {
            break;
        }
        blob.write_all(&buf[..n]).map_err(io_err(path))?;
    }
    Ok(())
}

impl Results for Sqlite {
    fn finish_job(
        &self,
        run: Run,
        result: &Value,
        main_table_csv: Option<MainTableCsv<'_>>,
        artefacts: &[Artefact],
        decision: Option<&Decision>,
    ) -> Result<bool, StoreError> {
        let id = run.job;
        let text = serde_json::to_string(result)?;
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx
                .prepare_cached(
                    "UPDATE jobs SET state = 'succeeded', finished_at = ?2, progress = 1, error = NULL \
                     WHERE id = ?1 AND state = 'running' AND attempt = ?3",
                )?
                .execute(params![id, now(), run.attempt])?;
            if n != 1 {
                super::runs::check_run(&tx, run)?;
                return Ok(false);
            }
            match main_table_csv {
                Some(MainTableCsv::File(path)) => {
                    insert_result_with_file(&tx, id, &text, path)?;
                }
                Some(MainTableCsv::Text(csv)) => {
                    tx.prepare_cached(
                        "INSERT INTO results (job_id, result, main_table_csv) VALUES (?1, ?2, ?3)",
                    )?
                    .execute(params![id, text, csv])?;
                }
                None => {
                    tx.prepare_cached(
                        "INSERT INTO results (job_id, result, main_table_csv) VALUES (?1, ?2, NULL)",
                    )?
                    .execute(params![id, text])?;
                }
            }
            for a in artefacts {
                tx.prepare_cached(
                    "INSERT INTO artefacts (job_id, name, media_type, content) VALUES (?1, ?2, ?3, ?4)",
                )?
                .execute(params![id, a.name, a.media_type, a.content])?;
            }
            if let Some(d) = decision {
                super::campaigns::insert_cell_model(&tx, Some(id), d)?;
                let msg = format!(
                    "cell {}: model {}: {}",
                    d.cell,
                    if d.accepted { "accepted" } else { "rejected" },
                    d.reason
                );
                log_tx(&tx, Some(id), "info", &msg)?;
            }
            log_tx(&tx, Some(id), "info", "succeeded")?;
            tx.commit()?;
            Ok(true)
        })
    }

    fn result(&self, id: i64) -> Result<Option<Value>, StoreError> {
        self.read(|c| {
            let s: Option<String> = c
                .prepare_cached("SELECT result FROM results WHERE job_id = ?1")?
                .query_row([id], |r| r.get(0))
                .optional()?;
            Ok(s.map(|s| serde_json::from_str(&s)).transpose()?)
        })
    }

    fn main_table_csv(&self, id: i64) -> Result<Option<String>, StoreError> {
        self.read(|c| {
            // Text, or a BLOB when the table was copied in chunks from a file.
            let csv = c
                .prepare_cached("SELECT main_table_csv FROM results WHERE job_id = ?1")?
                .query_row([id], |r| {
                    Ok(match r.get_ref(0)? {
                        rusqlite::types::ValueRef::Text(t) | rusqlite::types::ValueRef::Blob(t) => {
                            Some(String::from_utf8_lossy(t).into_owned())
                        }
                        _ => None,
                    })
                })
                .optional()?
                .flatten();
            Ok(csv)
        })
    }

    fn artefacts(&self, id: i64) -> Result<Vec<ArtefactInfo>, StoreError> {
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

    fn artefact(&self, id: i64, name: &str) -> Result<Option<Artefact>, StoreError> {
        self.read(|c| {
            Ok(c.prepare_cached(
                "SELECT name, media_type, content FROM artefacts WHERE job_id = ?1 AND name = ?2",
            )?
            .query_row(params![id, name], |r| {
                Ok(Artefact {
                    name: r.get(0)?,
                    media_type: r.get(1)?,
                    content: r.get(2)?,
                })
            })
            .optional()?)
        })
    }
}
