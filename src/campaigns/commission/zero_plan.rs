//! `cell.zero_check`: the indicators read 0.000 mm within a tolerance on the mated
//! coupling; the job document, checked before anything moves (the campaign is
//! [`crate::campaigns::commission::zero`]).

use serde::Deserialize;
use serde_json::Value;

use super::plan::{check_retry, positive};
use crate::campaigns::spec::{RetrySpec, default_cell};
use crate::run::{Inputs, JobError, parse_spec};

/// Options of `cell.zero_check`.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ZeroOptions {
    /// Largest |reading| accepted as zero (mm).
    pub tolerance_mm: f64,
    /// Wait before each reading (ms).
    pub settle_ms: u64,
    /// Longest wait for a reading (ms).
    pub reading_timeout_ms: u64,
    /// Retry of device faults.
    pub retry: RetrySpec,
}

impl Default for ZeroOptions {
    fn default() -> Self {
        Self {
            tolerance_mm: 0.005,
            settle_ms: 200,
            reading_timeout_ms: 2000,
            retry: RetrySpec::default(),
        }
    }
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct ZeroSpec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    #[serde(default = "five")]
    readings: usize,
    #[serde(default)]
    options: ZeroOptions,
}

fn five() -> usize {
    5
}

/// A validated `cell.zero_check` job.
#[derive(Debug)]
pub struct ZeroCheckJob {
    /// The cell.
    pub cell: String,
    /// Readings of the three indicators to take.
    pub readings: usize,
    /// Options.
    pub options: ZeroOptions,
}

/// Validate a `cell.zero_check` job.
pub fn prepare_zero(doc: &Value, _: &Inputs<'_>) -> Result<ZeroCheckJob, JobError> {
    let s: ZeroSpec = parse_spec(doc)?;
    if !(1..=1000).contains(&s.readings) {
        return Err(JobError::invalid(
            "readings",
            format!("{} is not in 1..=1000", s.readings),
        ));
    }
    positive("options.tolerance_mm", s.options.tolerance_mm)?;
    if s.options.reading_timeout_ms == 0 {
        return Err(JobError::invalid(
            "options.reading_timeout_ms",
            "must be at least 1",
        ));
    }
    check_retry(&s.options.retry)?;
    Ok(ZeroCheckJob {
        cell: s.cell,
        readings: s.readings,
        options: s.options,
    })
}
