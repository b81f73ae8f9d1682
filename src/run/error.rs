//! The error of the jobs layer: what was wrong with a job (field, row, value) or why it
//! failed while running.

use crate::identify::IdentifyError;
use crate::measure::MeasureError;
use crate::model::ModelError;

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
    /// The job ran but could not produce a result.
    #[error("{0}")]
    Failed(String),
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

impl From<crate::lab::LabError> for JobError {
    fn from(e: crate::lab::LabError) -> Self {
        match e {
            crate::lab::LabError::NoCell { .. } => JobError::invalid("cell", e.to_string()),
            other => JobError::Failed(other.to_string()),
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

    /// An invalid table row.
    pub fn row(field: impl Into<String>, row: usize, message: impl Into<String>) -> Self {
        JobError::Row {
            field: field.into(),
            row,
            message: message.into(),
        }
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
