//! Jobs on SQLite: submission, reads, logs, progress history, recovery.

use rusqlite::{OptionalExtension, Row, params};
use serde_json::Value;

use super::Sqlite;
use crate::store::backend::Jobs;
use crate::store::{
    JobFilter, JobRecord, JobState, LogLine, NewJob, ProgressPoint, Recovered, StoreError, now,
};

/// The columns of a [`JobRecord`], in the order [`record`] reads them.
macro_rules! columns {
    () => {
        "id, kind, state, priority, devices, inputs_sha256, submitted_at, started_at, \
         finished_at, progress, stage, message, error, submitted_by, schedule_id, rerun_of, \
         resumed_at"
    };
}

fn record(r: &Row<'_>) -> rusqlite::Result<(JobRecord, String, String, String)> {
    let state: String = r.get(2)?;
    let devices: String = r.get(4)?;
    let hashes: String = r.get(5)?;
    Ok((
        JobRecord {
            id: r.get(0)?,
            kind: r.get(1)?,
            state: JobState::Queued,
            priority: r.get(3)?,
            devices: vec![],
            inputs_sha256: Default::default(),
            submitted_at: r.get(6)?,
            started_at: r.get(7)?,
            resumed_at: r.get(16)?,
            finished_at: r.get(8)?,
            progress: r.get(9)?,
            stage: r.get(10)?,
            message: r.get(11)?,
            error: r.get(12)?,
            submitted_by: r.get(13)?,
            schedule_id: r.get(14)?,
            rerun_of: r.get(15)?,
        },
        state,
        devices,
        hashes,
    ))
}

fn finish(raw: (JobRecord, String, String, String)) -> Result<JobRecord, StoreError> {
    let (mut j, state, devices, hashes) = raw;
    j.state = JobState::parse(&state).ok_or(StoreError::Corrupt {
        column: "jobs.state",
        value: state,
    })?;
    j.devices = serde_json::from_str(&devices)?;
    j.inputs_sha256 = serde_json::from_str(&hashes)?;
    Ok(j)
}

/// Job `id` read on connection `c`.
fn job_on(c: &rusqlite::Connection, id: i64) -> Result<Option<JobRecord>, StoreError> {
    let mut st = c.prepare_cached(concat!("SELECT ", columns!(), " FROM jobs WHERE id = ?1"))?;
    let raw = st.query_row([id], record).optional()?;
    raw.map(finish).transpose()
}

impl Sqlite {
    /// Job `id` as kept since the last write, else by `read` (None: it could not read
    /// now), and kept for the next reads.
    fn job_kept(
        &self,
        id: i64,
        read: impl FnOnce() -> Option<Result<Option<JobRecord>, StoreError>>,
    ) -> Option<Result<Option<JobRecord>, StoreError>> {
        if let Some(rec) = self.recent.get(id) {
            return Some(Ok(Some(rec)));
        }
        let at = self.recent.now();
        let rec = read()?;
        if let Ok(Some(r)) = &rec {
            self.recent.keep(at, r);
        }
        Some(rec)
    }
}

/// Append a log line within `c` (a transaction or a connection).
pub(super) fn log_tx(
    c: &rusqlite::Connection,
    job: Option<i64>,
    level: &str,
    message: &str,
) -> rusqlite::Result<()> {
    c.prepare_cached("INSERT INTO logs (job_id, at, level, message) VALUES (?1, ?2, ?3, ?4)")?
        .execute(params![job, now(), level, message])?;
    Ok(())
}

impl Jobs for Sqlite {
    fn insert_job_once(&self, j: &NewJob) -> Result<(i64, bool), StoreError> {
        let doc = serde_json::to_string(&j.doc)?;
        let devices = serde_json::to_string(&j.devices)?;
        let hashes = serde_json::to_string(&j.inputs_sha256)?;
        let by = j.submitted_by.as_deref().unwrap_or("anonymous");
        self.write(|c| {
            let tx = c.transaction()?;
            if let Some(k) = &j.idempotency {
                let seen: Option<(i64, String)> = tx
                    .prepare_cached(
                        "SELECT job_id, request_sha256 FROM idempotency_keys \
                         WHERE submitted_by = ?1 AND key = ?2",
                    )?
                    .query_row(params![by, k.key], |r| Ok((r.get(0)?, r.get(1)?)))
                    .optional()?;
                match seen {
                    Some((id, sha)) if sha == k.request_sha256 => return Ok((id, false)),
                    Some((id, _)) => {
                        return Err(StoreError::Conflict(format!(
                            "Idempotency-Key `{}` for a different request (job {id})",
                            k.key
                        )));
                    }
                    None => {}
                }
            }
            tx.prepare_cached(
                "INSERT INTO jobs (kind, state, priority, devices, doc, inputs_sha256, submitted_at, \
                 submitted_by, schedule_id, rerun_of) VALUES (?1, 'queued', ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
            )?
            .execute(params![j.kind, j.priority, devices, doc, hashes, now(), j.submitted_by, j.schedule_id, j.rerun_of])?;
            let id = tx.last_insert_rowid();
            if let (Some(sid), Some((due, outcome, message))) = (j.schedule_id, &j.schedule_run) {
                super::schedules::record_run_tx(&tx, sid, due, outcome, Some(id), message.as_deref())?;
            }
            if let Some(k) = &j.idempotency {
                tx.prepare_cached(
                    "INSERT INTO idempotency_keys (submitted_by, key, request_sha256, job_id, at) \
                     VALUES (?1, ?2, ?3, ?4, ?5)",
                )?
                .execute(params![by, k.key, k.request_sha256, id, now()])?;
            }
            log_tx(&tx, Some(id), "info", &format!("submitted by {by}"))?;
            tx.commit()?;
            Ok((id, true))
        })
    }

    fn job(&self, id: i64) -> Result<Option<JobRecord>, StoreError> {
        self.job_kept(id, || Some(self.read(|c| job_on(c, id))))
            .unwrap_or(Ok(None))
    }

    fn job_now(&self, id: i64) -> Option<Result<Option<JobRecord>, StoreError>> {
        // A read by primary key on a free WAL reader takes microseconds and waits on no
        // writer; with every reader busy, the caller waits off the runtime instead.
        self.job_kept(id, || self.try_read(|c| job_on(c, id)).ok())
    }

    fn job_doc(&self, id: i64) -> Result<Option<Value>, StoreError> {
        self.read(|c| {
            let s: Option<String> = c
                .prepare_cached("SELECT doc FROM jobs WHERE id = ?1")?
                .query_row([id], |r| r.get(0))
                .optional()?;
            Ok(s.map(|s| serde_json::from_str(&s)).transpose()?)
        })
    }

    fn jobs(&self, f: &JobFilter) -> Result<Vec<JobRecord>, StoreError> {
        self.read(|c| {
            let mut st = c.prepare_cached(concat!(
                "SELECT ",
                columns!(),
                " FROM jobs WHERE (?1 IS NULL OR state = ?1) AND (?2 IS NULL OR kind = ?2) \
                 AND (?3 IS NULL OR id < ?3) ORDER BY id DESC LIMIT ?4"
            ))?;
            let rows = st.query_map(
                params![
                    f.state.map(JobState::as_str),
                    f.kind,
                    f.before,
                    f.limit as i64
                ],
                record,
            )?;
            rows.map(|r| finish(r?)).collect()
        })
    }

    fn count_by_state(&self) -> Result<Vec<(JobState, i64)>, StoreError> {
        self.read(|c| {
            let mut st = c.prepare_cached("SELECT state, COUNT(*) FROM jobs GROUP BY state")?;
            let rows = st.query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, i64>(1)?)))?;
            let mut out = Vec::new();
            for r in rows {
                let (s, n) = r?;
                if let Some(s) = JobState::parse(&s) {
                    out.push((s, n));
                }
            }
            Ok(out)
        })
    }

    fn log(&self, job: Option<i64>, level: &str, message: &str) -> Result<(), StoreError> {
        self.write(|c| Ok(log_tx(c, job, level, message)?))
    }

    fn logs(&self, id: i64) -> Result<Vec<LogLine>, StoreError> {
        self.read(|c| {
            let mut st = c.prepare_cached(
                "SELECT at, level, message FROM logs WHERE job_id = ?1 ORDER BY id",
            )?;
            let rows = st.query_map([id], |r| {
                Ok(LogLine {
                    at: r.get(0)?,
                    level: r.get(1)?,
                    message: r.get(2)?,
                })
            })?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }

    fn progress_history(&self, id: i64) -> Result<Vec<ProgressPoint>, StoreError> {
        self.read(|c| {
            let mut st = c.prepare_cached(
                "SELECT at, fraction, stage, message FROM progress WHERE job_id = ?1 ORDER BY rowid",
            )?;
            let rows = st.query_map([id], |r| {
                Ok(ProgressPoint {
                    at: r.get(0)?,
                    fraction: r.get(1)?,
                    stage: r.get(2)?,
                    message: r.get(3)?,
                })
            })?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }

    fn recover(&self) -> Result<Recovered, StoreError> {
        self.write(|c| {
            let tx = c.transaction()?;
            let interrupted: Vec<i64> = {
                let mut st =
                    tx.prepare("SELECT id FROM jobs WHERE state = 'running' ORDER BY id")?;
                st.query_map([], |r| r.get(0))?.collect::<Result<_, _>>()?
            };
            for id in &interrupted {
                tx.execute(
                    "UPDATE jobs SET state = 'interrupted', finished_at = ?2, \
                     error = 'the daemon stopped while the job was running' WHERE id = ?1",
                    params![id, now()],
                )?;
                log_tx(
                    &tx,
                    Some(*id),
                    "warn",
                    "interrupted: the daemon stopped while the job was running",
                )?;
            }
            let queued: Vec<(i64, i64, String)> = {
                let mut st = tx.prepare(
                    "SELECT id, priority, doc FROM jobs WHERE state = 'queued' ORDER BY id",
                )?;
                st.query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))?
                    .collect::<Result<_, _>>()?
            };
            tx.commit()?;
            let queued = queued
                .into_iter()
                .map(|(id, p, d)| Ok((id, p, serde_json::from_str(&d)?)))
                .collect::<Result<_, StoreError>>()?;
            Ok(Recovered {
                interrupted,
                queued,
            })
        })
    }
}
