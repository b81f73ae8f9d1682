//! The error of the jobs layer: what was wrong with a job (field, row, value) or why it
//! failed while running.

use std::path::PathBuf;

use crate::identify::IdentifyError;
use crate::lab::LabError;
use crate::measure::MeasureError;
use crate::model::ModelError;
use crate::procedures::{CentringError, DeviceError, JournalError};

/// Why a job was refused or failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JobError {
    /// A field of the job is invalid.
    #[error("`{field}`: {message}")]
    Invalid {
        /// Field path.
        field: String,
        /// What is wrong, with the value.
        message: String,
    },
    /// A row of a table is invalid.
    #[error("`{field}` row {row}: {message}")]
    Row {
        /// Table field.
        field: String,
        /// 1-based data row.
        row: usize,
        /// What is wrong, with the value.
        message: String,
    },
    /// The kind is not one calibd knows.
    #[error("unknown job kind `{kind}`; the kinds are: {known}")]
    UnknownKind {
        /// The `kind` the document named.
        kind: String,
        /// The kinds calibd runs, comma-separated (from the registry).
        known: String,
    },
    /// A model file is invalid.
    #[error("`model`: {0}")]
    Model(#[from] ModelError),
    /// Measurement data are inconsistent.
    #[error("{0}")]
    Measure(#[from] MeasureError),
    /// The computation failed.
    #[error("{0}")]
    Identify(IdentifyError),
    /// A referenced input could not be read.
    #[error("`{field}`: cannot read `{reference}`: {message}")]
    Input {
        /// Field that referenced it.
        field: String,
        /// Path or dataset id.
        reference: String,
        /// Why.
        message: String,
    },
    /// The job was cancelled.
    #[error("cancelled")]
    Cancelled,
    /// A campaign stopped on persistent device faults; it can be resumed from its journal.
    #[error("paused at configuration {index}: {reason}")]
    Paused {
        /// First configuration not measured.
        index: usize,
        /// The last fault.
        reason: String,
    },
    /// A campaign waits for the operator (jog, mate, confirm): paused; resuming it is the
    /// operator's confirmation. The text starts with `waiting for the operator:` (the page
    /// shows it as a prompt with a "continue" button).
    #[error("waiting for the operator: {prompt}")]
    Waiting {
        /// The step that waits (journal index).
        index: usize,
        /// What the operator must do before continuing.
        prompt: String,
    },
    /// A device-driven kind run without a lab.
    #[error(
        "`{kind}` drives devices: run it in the daemon (`calibd serve` + `calibd submit`), or with `calibd run JOB`, which drives the simulated lab"
    )]
    NeedsLab {
        /// The kind.
        kind: String,
    },
    /// The job ran but its data gave no result (too few measurements, nothing reachable):
    /// nothing more specific distinguishes the case.
    #[error("{0}")]
    Failed(String),
    /// A fault of calibd itself or its host (a result that does not serialise, a panicked
    /// computation, no runtime): not the job's fault; the details are for the log.
    #[error("internal error: {context}: {message}")]
    Internal {
        /// What calibd was doing.
        context: String,
        /// The underlying error.
        message: String,
    },
    /// Reading or writing a file (or a stream) failed.
    #[error("{what}{}: {source}", path.as_ref().map(|p| format!(" {}", p.display())).unwrap_or_default())]
    Io {
        /// What was being done (`writing the main table`).
        what: String,
        /// The file, when there is one.
        path: Option<PathBuf>,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The campaign's measurement journal failed (storage) or holds an entry it cannot read.
    #[error("{}", journal_message(.0))]
    Journal(#[from] JournalError),
    /// A device call failed outside a campaign's retry loop (a one-shot job).
    #[error("{0}")]
    Device(#[from] DeviceError),
    /// A device procedure (centring, a jog) stopped on a fault, not by cancellation.
    #[error("{procedure}: {source}")]
    Procedure {
        /// The procedure, as the message starts (`centring aborted`, `jog`).
        procedure: &'static str,
        /// Why it stopped.
        source: CentringError,
    },
    /// A robot controller refused an upload (program executing, no write access).
    #[error("upload to cell {cell}: {message}")]
    Upload {
        /// The cell whose controller refused.
        cell: String,
        /// The controller's reason.
        message: String,
    },
    /// The cell's stored model or plate does not fit the job (found while running).
    #[error("{message}")]
    CellMismatch {
        /// The cell's setting at fault (`model`, `plate`).
        what: &'static str,
        /// What does not fit, with the values.
        message: String,
    },
    /// The lab could not provide what the job needs (other than an unknown cell).
    #[error("{0}")]
    Lab(LabError),
    /// The computation overflowed: a result is not a finite number (an input far outside
    /// the model's range). Never stored as a result with `null`s or `NaN`s.
    #[error(
        "the result `{table}` is {value} at row {row}, column `{column}`: the inputs give no \
         finite result (check parameters and inputs for values far outside the model's range)"
    )]
    NonFinite {
        /// The result table.
        table: String,
        /// Row, from 1.
        row: usize,
        /// Column.
        column: String,
        /// The value (NaN or an infinity).
        value: f64,
    },
}

/// A journal fault's message: an unreadable entry as itself, a storage fault as the end of
/// the measuring.
fn journal_message(e: &JournalError) -> String {
    match e {
        JournalError::Unreadable { .. } => e.to_string(),
        other => format!("the measurement journal failed: {other}; nothing more is measured"),
    }
}

impl From<LabError> for JobError {
    fn from(e: LabError) -> Self {
        match e {
            LabError::NoCell { .. } => JobError::invalid("cell", e.to_string()),
            other => JobError::Lab(other),
        }
    }
}

impl From<IdentifyError> for JobError {
    fn from(e: IdentifyError) -> Self {
        match e {
            IdentifyError::Cancelled => JobError::Cancelled,
            other => JobError::Identify(other),
        }
    }
}

impl JobError {
    /// An invalid field.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        JobError::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// An internal fault while doing `context`.
    pub fn internal(context: impl Into<String>, message: impl std::fmt::Display) -> Self {
        JobError::Internal {
            context: context.into(),
            message: message.to_string(),
        }
    }

    /// An I/O fault while doing `what` on `path` (none for a stream).
    pub fn io(what: impl Into<String>, path: Option<&std::path::Path>, e: std::io::Error) -> Self {
        JobError::Io {
            what: what.into(),
            path: path.map(PathBuf::from),
            source: e,
        }
    }

    /// An invalid table row.
    pub fn row(field: impl Into<String>, row: usize, message: impl Into<String>) -> Self {
        JobError::Row {
            field: field.into(),
            row,
            message: message.into(),
        }
    }

    /// True if calibd or its host is at fault (a bug, a file or the journal's storage), not
    /// the job, the lab or a device: the daemon logs these for the administrator.
    pub fn is_internal(&self) -> bool {
        matches!(
            self,
            JobError::Internal { .. }
                | JobError::Io { .. }
                | JobError::Journal(JournalError::Storage { .. } | JournalError::Unwritable { .. })
        )
    }

    /// True if the job itself is at fault (a client error), not the execution.
    pub fn is_invalid_input(&self) -> bool {
        matches!(
            self,
            JobError::Invalid { .. }
                | JobError::Row { .. }
                | JobError::UnknownKind { .. }
                | JobError::Model(_)
                | JobError::Measure(_)
                | JobError::Input { .. }
        )
    }
}
