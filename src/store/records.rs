//! The job records the store reads and writes: states, stored jobs, filters, history.

use serde::{Deserialize, Serialize};
use serde_json::Value;

/// Where a job is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    /// Accepted and waiting for a worker (or a device).
    Queued,
    /// Executing.
    Running,
    /// Finished with a result.
    Succeeded,
    /// Finished without a result.
    Failed,
    /// Stopped on request.
    Cancelled,
    /// Was running when the daemon stopped without finishing it.
    Interrupted,
    /// A campaign stopped on persistent device faults; the operator resumes or cancels it.
    Paused,
}

impl JobState {
    /// Every state, in life order.
    pub const ALL: [JobState; 7] = [
        JobState::Queued,
        JobState::Running,
        JobState::Succeeded,
        JobState::Failed,
        JobState::Cancelled,
        JobState::Interrupted,
        JobState::Paused,
    ];

    /// The name used in the API and the database.
    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
            JobState::Interrupted => "interrupted",
            JobState::Paused => "paused",
        }
    }

    /// Parse a state name.
    pub fn parse(s: &str) -> Option<JobState> {
        JobState::ALL.into_iter().find(|x| x.as_str() == s)
    }

    /// True once the job will not change any more.
    pub fn is_final(self) -> bool {
        !matches!(
            self,
            JobState::Queued | JobState::Running | JobState::Paused
        )
    }
}

/// A job as stored (without its document and result).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JobRecord {
    /// Job id.
    pub id: i64,
    /// Job kind.
    pub kind: String,
    /// State.
    pub state: JobState,
    /// Higher runs first.
    pub priority: i64,
    /// Devices the job holds while it runs.
    pub devices: Vec<String>,
    /// SHA-256 (hex) of the job document and of each input, by input name.
    pub inputs_sha256: std::collections::BTreeMap<String, String>,
    /// When it was accepted (RFC 3339, UTC).
    pub submitted_at: String,
    /// When it first started (a resumed job keeps its first start).
    pub started_at: Option<String>,
    /// When it was last resumed after a pause or an interruption (none if never).
    pub resumed_at: Option<String>,
    /// When it reached a final state.
    pub finished_at: Option<String>,
    /// Progress in [0, 1].
    pub progress: f64,
    /// Current stage name.
    pub stage: Option<String>,
    /// Last progress message.
    pub message: Option<String>,
    /// Why it failed.
    pub error: Option<String>,
    /// Name of the token that submitted it.
    pub submitted_by: Option<String>,
    /// The schedule that submitted it (absent, not null, for a job a person submitted: an
    /// id field is either a real id or missing).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub schedule_id: Option<i64>,
    /// The job this one re-runs (absent when it is not a re-run).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rerun_of: Option<i64>,
}

/// A job to insert.
#[derive(Debug, Clone)]
pub struct NewJob {
    /// Kind.
    pub kind: String,
    /// The job document as submitted.
    pub doc: Value,
    /// Priority (higher first).
    pub priority: i64,
    /// Devices it needs.
    pub devices: Vec<String>,
    /// SHA-256 (hex) of the job document and of each input, by input name.
    pub inputs_sha256: std::collections::BTreeMap<String, String>,
    /// Token name.
    pub submitted_by: Option<String>,
    /// Submitting schedule.
    pub schedule_id: Option<i64>,
    /// Re-run of.
    pub rerun_of: Option<i64>,
    /// For a scheduled job: the occurrence it stands for (RFC 3339), the outcome
    /// (`submitted`, `missed_run_once`) and a message. The schedule's run record and its
    /// `checked_until` are written in the same transaction as the job.
    pub schedule_run: Option<(String, String, Option<String>)>,
    /// The client's `Idempotency-Key` and the SHA-256 of the request it came with: a second
    /// submission with the same key (same token name) returns the first job.
    pub idempotency: Option<IdempotencyKey>,
}

/// An `Idempotency-Key` of a submission.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IdempotencyKey {
    /// The key the client sent.
    pub key: String,
    /// SHA-256 of the request (document and priority).
    pub request_sha256: String,
}

/// Filter and page for listing jobs (newest first).
#[derive(Debug, Clone, Default)]
pub struct JobFilter {
    /// Only this state.
    pub state: Option<JobState>,
    /// Only this kind.
    pub kind: Option<String>,
    /// Only ids below this (the cursor of the next page).
    pub before: Option<i64>,
    /// Page size.
    pub limit: usize,
}

/// One entry of a job's progress history.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProgressPoint {
    /// When.
    pub at: String,
    /// Fraction in [0, 1].
    pub fraction: f64,
    /// Stage.
    pub stage: String,
    /// Message.
    pub message: Option<String>,
}

/// One log line.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LogLine {
    /// When.
    pub at: String,
    /// `info`, `warn` or `error`.
    pub level: String,
    /// Text.
    pub message: String,
}

/// What [`Store::recover`] found at start-up.
#[derive(Debug, Clone, Default)]
pub struct Recovered {
    /// Jobs that were running and are now `interrupted`.
    pub interrupted: Vec<i64>,
    /// Jobs still queued, oldest first: (id, priority, document).
    pub queued: Vec<(i64, i64, Value)>,
}

/// The log line of a job that ended in `state` without result: (level, message).
pub(crate) fn end_log(state: JobState, error: Option<&str>) -> (&'static str, String) {
    let message = match error {
        Some(e) => format!("{}: {e}", state.as_str()),
        None => state.as_str().to_string(),
    };
    let level = if state == JobState::Failed {
        "error"
    } else {
        "info"
    };
    (level, message)
}

/// One run of a job: the token a worker got when it started (or claimed) the job. A run
/// records progress, its result and its end only while the job is still this attempt, so
/// a run whose job was taken from it (its lease expired and another daemon claimed the job)
/// cannot write over the new run's work.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Run {
    /// The job.
    pub job: i64,
    /// Which start of the job this run is (1 for the first).
    pub attempt: i64,
}
