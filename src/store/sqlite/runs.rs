//! Runs of jobs on SQLite: start, progress, end without result.

use rusqlite::{OptionalExtension, params};

use super::Sqlite;
use super::jobs::log_tx;
use crate::store::backend::Runs;
use crate::store::{JobState, Run, StoreError, now};

/// After a write conditioned on `run` changed nothing: [`StoreError::Stale`] if the job was
/// taken from the run (queued again, or started by a later attempt), else `Ok` (it ended,
/// e.g. cancelled by an operator).
pub(super) fn check_run(c: &rusqlite::Connection, run: Run) -> Result<(), StoreError> {
    let now: Option<(String, i64)> = c
        .prepare_cached("SELECT state, attempt FROM jobs WHERE id = ?1")?
        .query_row([run.job], |r| Ok((r.get(0)?, r.get(1)?)))
        .optional()?;
    match now {
        Some((state, attempt))
            if attempt != run.attempt || state == "queued" || state == "running" =>
        {
            Err(StoreError::Stale {
                job: run.job,
                attempt: run.attempt,
            })
        }
        _ => Ok(()),
    }
}

impl Runs for Sqlite {
    fn start_job(&self, id: i64) -> Result<Option<Run>, StoreError> {
        self.write(|c| {
            let tx = c.transaction()?;
            // A resumed job keeps its first start (`resumed_at` tells when it went on).
            let attempt: Option<i64> = tx
                .prepare_cached(
                    "UPDATE jobs SET state = 'running', started_at = COALESCE(started_at, ?2), \
                     progress = 0, attempt = attempt + 1 WHERE id = ?1 AND state = 'queued' \
                     RETURNING attempt",
                )?
                .query_row(params![id, now()], |r| r.get(0))
                .optional()?;
            if attempt.is_some() {
                log_tx(&tx, Some(id), "info", "started")?;
            }
            tx.commit()?;
            Ok(attempt.map(|attempt| Run { job: id, attempt }))
        })
    }

    fn record_progress(
        &self,
        run: Run,
        fraction: f64,
        stage: &str,
        message: Option<&str>,
        history: bool,
    ) -> Result<(), StoreError> {
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx
                .prepare_cached(
                    "UPDATE jobs SET progress = ?2, stage = ?3, message = ?4 \
                     WHERE id = ?1 AND state = 'running' AND attempt = ?5",
                )?
                .execute(params![run.job, fraction, stage, message, run.attempt])?;
            if n == 0 {
                return check_run(&tx, run);
            }
            if history {
                tx.prepare_cached(
                    "INSERT INTO progress (job_id, at, fraction, stage, message) VALUES (?1, ?2, ?3, ?4, ?5)",
                )?
                .execute(params![run.job, now(), fraction, stage, message])?;
            }
            tx.commit()?;
            Ok(())
        })
    }

    fn end(
        &self,
        id: i64,
        attempt: Option<i64>,
        state: JobState,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx
                .prepare_cached(
                    "UPDATE jobs SET state = ?2, finished_at = ?3, error = ?4 WHERE id = ?1 \
                     AND ((?5 IS NULL AND state IN ('queued', 'running', 'paused')) \
                          OR (state = 'running' AND attempt = ?5))",
                )?
                .execute(params![id, state.as_str(), now(), error, attempt])?;
            if n == 1 {
                let (level, msg) = crate::store::records::end_log(state, error);
                log_tx(&tx, Some(id), level, &msg)?;
            } else if let Some(attempt) = attempt {
                check_run(&tx, Run { job: id, attempt })?;
            }
            tx.commit()?;
            Ok(n == 1)
        })
    }
}
