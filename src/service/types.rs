//! The service's settings, errors, submitter and origin descriptions, device status and
//! the store-backed dataset resolver.

use serde::Serialize;

use crate::jobs::{JobError, Resolver};
use crate::store::{Store, StoreError};

/// Why the service refused or failed a request.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServiceError {
    /// The job document is invalid (names field, row and value).
    #[error("{0}")]
    Invalid(JobError),
    /// No such job.
    #[error("no job with id {0}")]
    NotFound(i64),
    /// The caller may not do this.
    #[error("{0}")]
    Forbidden(String),
    /// The request conflicts with the job's state.
    #[error("{0}")]
    Conflict(String),
    /// The queue is full.
    #[error("the queue is full ({0} jobs waiting); try again later")]
    QueueFull(usize),
    /// Storage failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// A background task failed.
    #[error("internal: {0}")]
    Internal(String),
}

impl From<JobError> for ServiceError {
    /// A job refused before it is queued: the job's own fault is [`ServiceError::Invalid`]
    /// (422, with field and value); anything else is the daemon's (500, details logged).
    fn from(e: JobError) -> Self {
        if e.is_invalid_input() {
            ServiceError::Invalid(e)
        } else {
            ServiceError::Internal(e.to_string())
        }
    }
}

/// Settings of the service.
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    /// Number of jobs executed at once (each on a blocking thread).
    pub workers: usize,
    /// Most jobs waiting in the queue; further submissions get [`ServiceError::QueueFull`].
    pub max_queued: usize,
    /// Devices of the lab (shown by the device panel even when idle).
    pub devices: Vec<String>,
}

impl Default for ServiceConfig {
    fn default() -> Self {
        Self {
            workers: std::thread::available_parallelism().map_or(2, |n| n.get()),
            max_queued: 10_000,
            devices: Vec::new(),
        }
    }
}

/// Who submits, as far as the service cares.
#[derive(Debug, Clone, Default)]
pub struct Submitter {
    /// Token name, recorded with the job.
    pub name: Option<String>,
    /// May submit jobs that drive devices (the operator role).
    pub may_drive_devices: bool,
}

/// The schedule occurrence a job stands for.
#[derive(Debug, Clone)]
pub struct ScheduleOrigin {
    /// Schedule id.
    pub id: i64,
    /// The (last) occurrence, RFC 3339.
    pub due: String,
    /// `submitted` or `missed_run_once`.
    pub outcome: String,
    /// Details (missed occurrences).
    pub message: Option<String>,
}

/// Where a submission comes from besides a client.
#[derive(Debug, Clone, Default)]
pub struct Origin {
    /// Submitted by a schedule.
    pub schedule: Option<ScheduleOrigin>,
    /// Re-run of this job.
    pub rerun_of: Option<i64>,
    /// The client's `Idempotency-Key`: a retry with the same key returns the first job.
    pub idempotency_key: Option<String>,
}

/// A device and who holds it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceStatus {
    /// Device name.
    pub name: String,
    /// `idle` or `busy`.
    pub state: &'static str,
    /// The running job that holds it.
    pub job: Option<i64>,
    /// Jobs waiting for it.
    pub waiting: usize,
}

/// Resolves dataset ids (the string inputs of a job over HTTP) from the store.
#[derive(Debug, Clone)]
pub struct StoreResolver(pub Store);

impl Resolver for StoreResolver {
    fn read(&self, field: &str, reference: &str) -> Result<Vec<u8>, JobError> {
        let input_err = |message: String| JobError::Input {
            field: field.into(),
            reference: reference.into(),
            message,
        };
        match self.0.dataset(reference) {
            Ok(Some(b)) => Ok(b),
            Ok(None) => Err(input_err(
                "no uploaded dataset has this id (upload it with POST /v1/datasets, or give the input inline)".into(),
            )),
            Err(e) => Err(input_err(e.to_string())),
        }
    }

    fn file(&self, reference: &str) -> Option<std::path::PathBuf> {
        match self.0.spooled_dataset(reference) {
            Ok(p) => p,
            Err(e) => {
                tracing::warn!(dataset = reference, error = %e, "spooling a dataset failed: read whole");
                None
            }
        }
    }
}
