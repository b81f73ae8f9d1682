//! Runs of jobs: starting one (each start is a new attempt, the run's token), its progress
//! and its end. Writes of a run are conditioned on its attempt, so a run whose job was taken
//! from it cannot overwrite the work of the run that took it.

use super::{JobState, Run, Store, StoreError};

impl Store {
    /// Mark a queued job running; returns the run's token, none if it was no longer queued.
    /// A resumed job keeps the `started_at` of its first start.
    pub fn start_job(&self, id: i64) -> Result<Option<Run>, StoreError> {
        self.backend.start_job(id)
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
        self.backend
            .record_progress(run, fraction, stage, message, history)
    }

    /// End a job without result (`failed`, `cancelled`) whatever runs it; false if it was
    /// already final.
    pub fn end_job(
        &self,
        id: i64,
        state: JobState,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        debug_assert!(state.is_final());
        self.backend.end(id, None, state, error)
    }

    /// End run `run`'s job without result (`failed`, `cancelled`, `interrupted`); false if
    /// it already ended, [`StoreError::Stale`] if it was taken from the run.
    pub fn end_run(
        &self,
        run: Run,
        state: JobState,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        debug_assert!(state.is_final());
        self.backend.end(run.job, Some(run.attempt), state, error)
    }
}
