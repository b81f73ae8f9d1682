//! Runs of jobs: starting one (each start is a new attempt, the run's token), its progress
//! and its end. Writes of a run are conditioned on its attempt, so a run whose job was taken
//! from it cannot overwrite the work of the run that took it.

use rusqlite::{OptionalExtension, params};

use super::jobs::log_tx;
use super::{JobState, Run, Store, StoreError, now};

/// After a write conditioned on `run` changed nothing: [`StoreError::Stale`] if the job was
/// taken from the run (queued again, or started by a later attempt), else `Ok` (it ended,
/// e.g. cancelled by an operator).
pub(super) fn check_run(c: &rusqlite::Connection, run: Run) -> Result<(), StoreError> {
    let now: Option<(String, i64)> = c
        .query_row(
            "SELECT state, attempt FROM jobs WHERE id = ?1",
            [run.job],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
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

impl Store {
    /// Mark a queued job running; returns the run's token, none if it was no longer queued.
    pub fn start_job(&self, id: i64) -> Result<Option<Run>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.start_job(id);
        }
        self.write(|c| {
            let tx = c.transaction()?;
            let attempt: Option<i64> = tx
                .query_row(
                    "UPDATE jobs SET state = 'running', started_at = ?2, progress = 0, \
                     attempt = attempt + 1 WHERE id = ?1 AND state = 'queued' RETURNING attempt",
                    params![id, now()],
                    |r| r.get(0),
                )
                .optional()?;
            if attempt.is_some() {
                log_tx(&tx, Some(id), "info", "started")?;
            }
            tx.commit()?;
            Ok(attempt.map(|attempt| Run { job: id, attempt }))
        })
    }

    /// Record progress of run `run`; `history` also appends it to the job's history. A run
    /// whose job was taken from it gets [`StoreError::Stale`].
    pub fn record_progress(
        &self,
        run: Run,
        fraction: f64,
        stage: &str,
        message: Option<&str>,
        history: bool,
    ) -> Result<(), StoreError> {
        if let Some(pg) = self.pg() {
            return pg.record_progress(run, fraction, stage, message, history);
        }
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx.execute(
                "UPDATE jobs SET progress = ?2, stage = ?3, message = ?4 \
                 WHERE id = ?1 AND state = 'running' AND attempt = ?5",
                params![run.job, fraction, stage, message, run.attempt],
            )?;
            if n == 0 {
                return check_run(&tx, run);
            }
            if history {
                tx.execute(
                    "INSERT INTO progress (job_id, at, fraction, stage, message) VALUES (?1, ?2, ?3, ?4, ?5)",
                    params![run.job, now(), fraction, stage, message],
                )?;
            }
            tx.commit()?;
            Ok(())
        })
    }

    /// End a job without result (`failed`, `cancelled`) whatever runs it; false if it was
    /// already final.
    pub fn end_job(
        &self,
        id: i64,
        state: JobState,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        self.end(id, None, state, error)
    }

    /// End run `run`'s job without result (`failed`, `cancelled`, `interrupted`); false if
    /// it already ended, [`StoreError::Stale`] if it was taken from the run.
    pub fn end_run(
        &self,
        run: Run,
        state: JobState,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        self.end(run.job, Some(run.attempt), state, error)
    }

    fn end(
        &self,
        id: i64,
        attempt: Option<i64>,
        state: JobState,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.end_job(id, attempt, state, error);
        }
        debug_assert!(state.is_final());
        self.write(|c| {
            let tx = c.transaction()?;
            let n = tx.execute(
                "UPDATE jobs SET state = ?2, finished_at = ?3, error = ?4 WHERE id = ?1 \
                 AND ((?5 IS NULL AND state IN ('queued', 'running', 'paused')) \
                      OR (state = 'running' AND attempt = ?5))",
                params![id, state.as_str(), now(), error, attempt],
            )?;
            if n == 1 {
                let (level, msg) = super::records::end_log(state, error);
                log_tx(&tx, Some(id), level, &msg)?;
            } else if let Some(attempt) = attempt {
                check_run(&tx, Run { job: id, attempt })?;
            }
            tx.commit()?;
            Ok(n == 1)
        })
    }
}
