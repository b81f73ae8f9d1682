//! Kinds that drive the lab's devices (`cell.*`): what each job document asks for, checked
//! before anything moves; the campaigns themselves are in [`crate::campaigns`], async tasks
//! over the cell's devices that journal every measurement before the next move.

use std::time::Duration;

use serde::Deserialize;

use crate::campaigns::engine::Retry;
use crate::lab::TricalCell;
use crate::procedures::CentringOptions;
use crate::run::JobError;

/// Bounds of the centring loop as a job gives them (units in the names).
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CentringSpec {
    /// Stop when |r| is below this (mm).
    pub epsilon_mm: f64,
    /// Most corrective moves.
    pub max_iterations: usize,
    /// A reading asking for a larger move means the ball is lost (mm).
    pub max_step_mm: f64,
    /// Wait after each move before reading (ms).
    pub settle_ms: u64,
    /// Longest wait for a reading (ms).
    pub reading_timeout_ms: u64,
}

impl Default for CentringSpec {
    fn default() -> Self {
        let d = CentringOptions::default();
        Self {
            epsilon_mm: d.epsilon_mm,
            max_iterations: d.max_iterations,
            max_step_mm: d.max_step_mm,
            settle_ms: d.settle.as_millis() as u64,
            reading_timeout_ms: d.reading_timeout.as_millis() as u64,
        }
    }
}

impl CentringSpec {
    /// Checked options; `field` names the spec in errors; the approach step is the cell's.
    pub fn options(&self, field: &str, cell: &TricalCell) -> Result<CentringOptions, JobError> {
        let bad = |k: &str, m: String| JobError::invalid(format!("{field}.{k}"), m);
        if !(self.epsilon_mm.is_finite() && self.epsilon_mm > 0.0) {
            return Err(bad(
                "epsilon_mm",
                format!("{} must be positive", self.epsilon_mm),
            ));
        }
        if !(self.max_step_mm.is_finite() && self.max_step_mm > 0.0) {
            return Err(bad(
                "max_step_mm",
                format!("{} must be positive", self.max_step_mm),
            ));
        }
        if self.max_step_mm > cell.envelope.max_tool_step_mm {
            return Err(bad(
                "max_step_mm",
                format!(
                    "{} mm is above the cell's tool-move limit {} mm",
                    self.max_step_mm, cell.envelope.max_tool_step_mm
                ),
            ));
        }
        if self.max_iterations == 0 || self.reading_timeout_ms == 0 {
            return Err(bad(
                "max_iterations",
                "max_iterations and reading_timeout_ms must be at least 1".into(),
            ));
        }
        Ok(CentringOptions {
            epsilon_mm: self.epsilon_mm,
            max_iterations: self.max_iterations,
            max_step_mm: self.max_step_mm,
            settle: Duration::from_millis(self.settle_ms),
            reading_timeout: Duration::from_millis(self.reading_timeout_ms),
            approach_step: cell.envelope.max_joint_step,
            ..CentringOptions::default()
        })
    }

    /// Check what can be checked without a cell.
    pub fn validate(&self, field: &str) -> Result<(), JobError> {
        if !(self.epsilon_mm.is_finite() && self.epsilon_mm > 0.0)
            || !(self.max_step_mm.is_finite() && self.max_step_mm > 0.0)
            || self.max_iterations == 0
            || self.reading_timeout_ms == 0
        {
            return Err(JobError::invalid(
                field,
                "epsilon_mm and max_step_mm must be positive, max_iterations and reading_timeout_ms at least 1",
            ));
        }
        Ok(())
    }
}

/// Devices of the TriCal cell `name` (queue locks: the campaign holds both).
pub fn trical_devices(name: &str) -> Vec<String> {
    vec![format!("{name}.rws"), format!("{name}.uwave")]
}

/// Retry policy of a campaign as a job gives it: attempts per configuration and the first
/// back-off delay (ms, doubled after each failure).
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RetrySpec {
    /// Attempts per configuration before the campaign pauses.
    pub attempts: usize,
    /// First back-off delay (ms).
    pub backoff_ms: u64,
}

impl Default for RetrySpec {
    fn default() -> Self {
        let r = Retry::default();
        Self {
            attempts: r.attempts,
            backoff_ms: r.backoff.as_millis() as u64,
        }
    }
}

impl RetrySpec {
    /// The engine's retry policy.
    pub fn retry(&self) -> Retry {
        Retry {
            attempts: self.attempts,
            backoff: Duration::from_millis(self.backoff_ms),
        }
    }
}

pub(crate) fn default_cell() -> String {
    "irb120".into()
}
