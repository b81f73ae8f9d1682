//! Jobs in the store: submission, state changes, progress history, logs, recovery.

use rusqlite::{OptionalExtension, Row, params};
use serde_json::Value;

pub use super::records::{
    IdempotencyKey, JobFilter, JobRecord, JobState, LogLine, NewJob, ProgressPoint, Recovered, Run,
};
use super::{Store, StoreError, now};

const COLUMNS: &str = "id, kind, state, priority, devices, inputs_sha256, submitted_at, started_at, \
     finished_at, progress, stage, message, error, submitted_by, schedule_id, rerun_of";

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
            inputs_sha256: Value::Null,
            submitted_at: r.get(6)?,
            started_at: r.get(7)?,
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

pub(super) fn log_tx(
    c: &rusqlite::Connection,
    job: Option<i64>,
    level: &str,
    message: &str,
) -> rusqlite::Result<()> {
    c.execute(
        "INSERT INTO logs (job_id, at, level, message) VALUES (?1, ?2, ?3, ?4)",
        params![job, now(), level, message],
    )?;
    Ok(())
}

impl Store {
    /// Persist a new job as `queued`; returns its id.
    pub fn insert_job(&self, j: &NewJob) -> Result<i64, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.insert_job(j);
        }
        self.insert_job_once(j).map(|(id, _)| id)
    }

    /// Insert a job unless its idempotency key was used before by the same submitter:
    /// returns the job id and whether it is new. The key is written in the job's own
    /// transaction, so a submission cut by a crash either left both or neither. The same
    /// key with a different request is a conflict.
    pub fn insert_job_once(&self, j: &NewJob) -> Result<(i64, bool), StoreError> {
        if let Some(pg) = self.pg() {
            return pg.insert_job_once(j);
        }
        let doc = serde_json::to_string(&j.doc)?;
        let devices = serde_json::to_string(&j.devices)?;
        let hashes = serde_json::to_string(&j.inputs_sha256)?;
        let by = j.submitted_by.as_deref().unwrap_or("anonymous");
        self.write(|c| {
            let tx = c.transaction()?;
            if let Some(k) = &j.idempotency {
                let seen: Option<(i64, String)> = tx
                    .query_row(
                        "SELECT job_id, request_sha256 FROM idempotency_keys \
                         WHERE submitted_by = ?1 AND key = ?2",
                        params![by, k.key],
                        |r| Ok((r.get(0)?, r.get(1)?)),
                    )
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
            tx.execute(
                "INSERT INTO jobs (kind, state, priority, devices, doc, inputs_sha256, submitted_at, \
                 submitted_by, schedule_id, rerun_of) VALUES (?1, 'queued', ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
                params![j.kind, j.priority, devices, doc, hashes, now(), j.submitted_by, j.schedule_id, j.rerun_of],
            )?;
            let id = tx.last_insert_rowid();
            if let (Some(sid), Some((due, outcome, message))) = (j.schedule_id, &j.schedule_run) {
                super::schedules::record_run_tx(&tx, sid, due, outcome, Some(id), message.as_deref())?;
            }
            if let Some(k) = &j.idempotency {
                tx.execute(
                    "INSERT INTO idempotency_keys (submitted_by, key, request_sha256, job_id, at) \
                     VALUES (?1, ?2, ?3, ?4, ?5)",
                    params![by, k.key, k.request_sha256, id, now()],
                )?;
            }
            log_tx(&tx, Some(id), "info", &format!("submitted by {by}"))?;
            tx.commit()?;
            Ok((id, true))
        })
    }

    /// One job.
    pub fn job(&self, id: i64) -> Result<Option<JobRecord>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.job(id);
        }
        self.read(|c| {
            let raw = c
                .query_row(
                    &format!("SELECT {COLUMNS} FROM jobs WHERE id = ?1"),
                    [id],
                    record,
                )
                .optional()?;
            raw.map(finish).transpose()
        })
    }

    /// The document a job was submitted with.
    pub fn job_doc(&self, id: i64) -> Result<Option<Value>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.job_doc(id);
        }
        self.read(|c| {
            let s: Option<String> = c
                .query_row("SELECT doc FROM jobs WHERE id = ?1", [id], |r| r.get(0))
                .optional()?;
            Ok(s.map(|s| serde_json::from_str(&s)).transpose()?)
        })
    }

    /// Jobs matching `f`, newest first.
    pub fn jobs(&self, f: &JobFilter) -> Result<Vec<JobRecord>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.jobs(f);
        }
        self.read(|c| {
            let mut st = c.prepare_cached(&format!(
                "SELECT {COLUMNS} FROM jobs WHERE (?1 IS NULL OR state = ?1) AND (?2 IS NULL OR kind = ?2) \
                 AND (?3 IS NULL OR id < ?3) ORDER BY id DESC LIMIT ?4"
            ))?;
            let rows = st.query_map(
                params![f.state.map(JobState::as_str), f.kind, f.before, f.limit as i64],
                record,
            )?;
            rows.map(|r| finish(r?)).collect()
        })
    }

    /// Number of jobs in each state.
    pub fn count_by_state(&self) -> Result<Vec<(JobState, i64)>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.count_by_state();
        }
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

    /// Append a log line (job-specific or daemon-wide).
    pub fn log(&self, job: Option<i64>, level: &str, message: &str) -> Result<(), StoreError> {
        if let Some(pg) = self.pg() {
            return pg.log(job, level, message);
        }
        self.write(|c| Ok(log_tx(c, job, level, message)?))
    }

    /// A job's log lines, oldest first.
    pub fn logs(&self, id: i64) -> Result<Vec<LogLine>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.logs(id);
        }
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

    /// A job's progress history, oldest first.
    pub fn progress_history(&self, id: i64) -> Result<Vec<ProgressPoint>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.progress_history(id);
        }
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

    /// At start-up: mark jobs that were running `interrupted` and return the queued ones.
    pub fn recover(&self) -> Result<Recovered, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.recover();
        }
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
