//! Jobs on PostgreSQL: the same operations and rules as the SQLite `jobs` module.

use postgres::{GenericClient, Row};
use serde_json::Value;

use super::{Pg, now};
use crate::store::backend::{Jobs, Runs};
use crate::store::{
    JobFilter, JobRecord, JobState, LogLine, NewJob, ProgressPoint, Recovered, Run, StoreError,
};

/// The columns of a [`JobRecord`], in the order [`record`] reads them.
macro_rules! columns {
    () => {
        "id, kind, state, priority, devices, inputs_sha256, submitted_at, started_at, \
         finished_at, progress, stage, message, error, submitted_by, schedule_id, rerun_of, \
         resumed_at"
    };
}

pub(super) fn record(r: &Row) -> Result<JobRecord, StoreError> {
    let state: String = r.try_get(2)?;
    let devices: String = r.try_get(4)?;
    let hashes: String = r.try_get(5)?;
    Ok(JobRecord {
        id: r.try_get(0)?,
        kind: r.try_get(1)?,
        state: JobState::parse(&state).ok_or(StoreError::Corrupt {
            column: "jobs.state",
            value: state,
        })?,
        priority: r.try_get(3)?,
        devices: serde_json::from_str(&devices)?,
        inputs_sha256: serde_json::from_str(&hashes)?,
        submitted_at: r.try_get(6)?,
        started_at: r.try_get(7)?,
        resumed_at: r.try_get(16)?,
        finished_at: r.try_get(8)?,
        progress: r.try_get(9)?,
        stage: r.try_get(10)?,
        message: r.try_get(11)?,
        error: r.try_get(12)?,
        submitted_by: r.try_get(13)?,
        schedule_id: r.try_get(14)?,
        rerun_of: r.try_get(15)?,
    })
}

/// Append a log line within `c` (a transaction or a connection).
pub(super) fn log_tx(
    c: &mut impl GenericClient,
    job: Option<i64>,
    level: &str,
    message: &str,
) -> Result<(), StoreError> {
    c.execute(
        "INSERT INTO logs (job_id, at, level, message) VALUES ($1, $2, $3, $4)",
        &[&job, &now(), &level, &message],
    )?;
    Ok(())
}

/// After a write conditioned on `run` changed nothing: [`StoreError::Stale`] if the job was
/// taken from the run (queued again, or claimed by a later attempt), else `Ok` (it ended).
pub(super) fn check_run(c: &mut impl GenericClient, run: Run) -> Result<(), StoreError> {
    let row = c.query_opt("SELECT state, attempt FROM jobs WHERE id = $1", &[&run.job])?;
    if let Some(r) = row {
        let (state, attempt): (String, i64) = (r.try_get(0)?, r.try_get(1)?);
        if attempt != run.attempt || state == "queued" || state == "running" {
            return Err(StoreError::Stale {
                job: run.job,
                attempt: run.attempt,
            });
        }
    }
    Ok(())
}

impl Jobs for Pg {
    fn insert_job_once(&self, j: &NewJob) -> Result<(i64, bool), StoreError> {
        let doc = serde_json::to_string(&j.doc)?;
        let devices = serde_json::to_string(&j.devices)?;
        let hashes = serde_json::to_string(&j.inputs_sha256)?;
        let by = j.submitted_by.as_deref().unwrap_or("anonymous");
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        if let Some(k) = &j.idempotency {
            // Two daemons may get the same key at once: serialise on it.
            tx.execute(
                "SELECT pg_advisory_xact_lock(hashtext($1::TEXT || '/' || $2::TEXT))",
                &[&by, &k.key],
            )?;
            let seen = tx.query_opt(
                "SELECT job_id, request_sha256 FROM idempotency_keys WHERE submitted_by = $1 AND key = $2",
                &[&by, &k.key],
            )?;
            if let Some(r) = seen {
                let (id, sha): (i64, String) = (r.try_get(0)?, r.try_get(1)?);
                if sha == k.request_sha256 {
                    return Ok((id, false));
                }
                return Err(StoreError::Conflict(format!(
                    "Idempotency-Key `{}` for a different request (job {id})",
                    k.key
                )));
            }
        }
        let id: i64 = tx
            .query_one(
                "INSERT INTO jobs (kind, state, priority, devices, doc, inputs_sha256, submitted_at, \
                 submitted_by, schedule_id, rerun_of) VALUES ($1, 'queued', $2, $3, $4, $5, $6, $7, $8, $9) \
                 RETURNING id",
                &[&j.kind, &j.priority, &devices, &doc, &hashes, &now(), &j.submitted_by, &j.schedule_id, &j.rerun_of],
            )?
            .try_get(0)?;
        if let (Some(sid), Some((due, outcome, message))) = (j.schedule_id, &j.schedule_run) {
            super::other::record_run_tx(&mut tx, sid, due, outcome, Some(id), message.as_deref())?;
        }
        if let Some(k) = &j.idempotency {
            tx.execute(
                "INSERT INTO idempotency_keys (submitted_by, key, request_sha256, job_id, at) \
                 VALUES ($1, $2, $3, $4, $5)",
                &[&by, &k.key, &k.request_sha256, &id, &now()],
            )?;
        }
        log_tx(&mut tx, Some(id), "info", &format!("submitted by {by}"))?;
        // Wake the queue of every daemon.
        tx.execute("SELECT pg_notify('calibd_queue', $1)", &[&id.to_string()])?;
        tx.commit()?;
        Ok((id, true))
    }

    fn job(&self, id: i64) -> Result<Option<JobRecord>, StoreError> {
        let row = self.conn()?.query_opt_cached(
            concat!("SELECT ", columns!(), " FROM jobs WHERE id = $1"),
            &[&id],
        )?;
        row.as_ref().map(record).transpose()
    }

    fn job_doc(&self, id: i64) -> Result<Option<Value>, StoreError> {
        let row = self
            .conn()?
            .query_opt_cached("SELECT doc FROM jobs WHERE id = $1", &[&id])?;
        match row {
            Some(r) => Ok(Some(serde_json::from_str(r.try_get::<_, &str>(0)?)?)),
            None => Ok(None),
        }
    }

    fn jobs(&self, f: &JobFilter) -> Result<Vec<JobRecord>, StoreError> {
        let rows = self.conn()?.query(
            concat!(
                "SELECT ",
                columns!(),
                " FROM jobs WHERE ($1::TEXT IS NULL OR state = $1) \
                 AND ($2::TEXT IS NULL OR kind = $2) AND ($3::BIGINT IS NULL OR id < $3) \
                 ORDER BY id DESC LIMIT $4"
            ),
            &[
                &f.state.map(JobState::as_str),
                &f.kind,
                &f.before,
                &(f.limit as i64),
            ],
        )?;
        rows.iter().map(record).collect()
    }

    fn count_by_state(&self) -> Result<Vec<(JobState, i64)>, StoreError> {
        let rows = self
            .conn()?
            .query_cached("SELECT state, COUNT(*) FROM jobs GROUP BY state", &[])?;
        let mut out = Vec::new();
        for r in rows {
            if let Some(s) = JobState::parse(r.try_get(0)?) {
                out.push((s, r.try_get(1)?));
            }
        }
        Ok(out)
    }

    fn log(&self, job: Option<i64>, level: &str, message: &str) -> Result<(), StoreError> {
        log_tx(&mut *self.conn()?, job, level, message)
    }

    fn logs(&self, id: i64) -> Result<Vec<LogLine>, StoreError> {
        let rows = self.conn()?.query_cached(
            "SELECT at, level, message FROM logs WHERE job_id = $1 ORDER BY id",
            &[&id],
        )?;
        rows.iter()
            .map(|r| {
                Ok(LogLine {
                    at: r.try_get(0)?,
                    level: r.try_get(1)?,
                    message: r.try_get(2)?,
                })
            })
            .collect()
    }

    fn progress_history(&self, id: i64) -> Result<Vec<ProgressPoint>, StoreError> {
        let rows = self.conn()?.query_cached(
            "SELECT at, fraction, stage, message FROM progress WHERE job_id = $1 ORDER BY seq",
            &[&id],
        )?;
        rows.iter()
            .map(|r| {
                Ok(ProgressPoint {
                    at: r.try_get(0)?,
                    fraction: r.try_get(1)?,
                    stage: r.try_get(2)?,
                    message: r.try_get(3)?,
                })
            })
            .collect()
    }

    /// At start-up of a single daemon: as SQLite does, running jobs become `interrupted`
    /// — but only those no other live daemon holds (no owner, or a lease that expired).
    fn recover(&self) -> Result<Recovered, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let interrupted: Vec<i64> = tx
            .query(
                "SELECT id FROM jobs WHERE state = 'running' \
                 AND (owner IS NULL OR lease_until IS NULL OR lease_until < now()) ORDER BY id FOR UPDATE",
                &[],
            )?
            .iter()
            .map(|r| r.try_get(0))
            .collect::<Result<_, _>>()?;
        for id in &interrupted {
            tx.execute(
                "UPDATE jobs SET state = 'interrupted', finished_at = $2, owner = NULL, lease_until = NULL, \
                 error = 'the daemon stopped while the job was running' WHERE id = $1",
                &[id, &now()],
            )?;
            log_tx(
                &mut tx,
                Some(*id),
                "warn",
                "interrupted: the daemon stopped while the job was running",
            )?;
        }
        let queued = tx
            .query(
                "SELECT id, priority, doc FROM jobs WHERE state = 'queued' ORDER BY id",
                &[],
            )?
            .iter()
            .map(|r| {
                Ok((
                    r.try_get(0)?,
                    r.try_get(1)?,
                    serde_json::from_str(r.try_get::<_, &str>(2)?)?,
                ))
            })
            .collect::<Result<_, StoreError>>()?;
        tx.commit()?;
        Ok(Recovered {
            interrupted,
            queued,
        })
    }
}

impl Runs for Pg {
    fn start_job(&self, id: i64) -> Result<Option<Run>, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let row = tx.query_opt(
            "UPDATE jobs SET state = 'running', started_at = COALESCE(started_at, $2), progress = 0, \
             attempt = attempt + 1 WHERE id = $1 AND state = 'queued' RETURNING attempt",
            &[&id, &now()],
        )?;
        let run = match row {
            Some(r) => Some(Run {
                job: id,
                attempt: r.try_get(0)?,
            }),
            None => None,
        };
        if run.is_some() {
            log_tx(&mut tx, Some(id), "info", "started")?;
        }
        tx.commit()?;
        Ok(run)
    }

    fn record_progress(
        &self,
        run: Run,
        fraction: f64,
        stage: &str,
        message: Option<&str>,
        history: bool,
    ) -> Result<(), StoreError> {
        let mut c = self.conn()?;
        let (c, cache) = c.split();
        let mut tx = c.transaction()?;
        let update = cache.get(
            &mut tx,
            "UPDATE jobs SET progress = $2, stage = $3, message = $4 \
             WHERE id = $1 AND state = 'running' AND attempt = $5",
        )?;
        let n = tx.execute(
            &update,
            &[&run.job, &fraction, &stage, &message, &run.attempt],
        )?;
        if n == 0 {
            return check_run(&mut tx, run);
        }
        if history {
            let insert = cache.get(
                &mut tx,
                "INSERT INTO progress (job_id, at, fraction, stage, message) VALUES ($1, $2, $3, $4, $5)",
            )?;
            tx.execute(&insert, &[&run.job, &now(), &fraction, &stage, &message])?;
        }
        tx.commit()?;
        Ok(())
    }

    /// End job `id` (any run of it when `attempt` is none, else only that run).
    fn end(
        &self,
        id: i64,
        attempt: Option<i64>,
        state: JobState,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let n = tx.execute(
            "UPDATE jobs SET state = $2, finished_at = $3, error = $4, owner = NULL, lease_until = NULL \
             WHERE id = $1 AND (($5::BIGINT IS NULL AND state IN ('queued', 'running', 'paused')) \
                                OR (state = 'running' AND attempt = $5))",
            &[&id, &state.as_str(), &now(), &error, &attempt],
        )?;
        if n == 1 {
            let (level, msg) = crate::store::records::end_log(state, error);
            log_tx(&mut tx, Some(id), level, &msg)?;
        } else if let Some(attempt) = attempt {
            check_run(&mut tx, Run { job: id, attempt })?;
        }
        tx.commit()?;
        Ok(n == 1)
    }
}
