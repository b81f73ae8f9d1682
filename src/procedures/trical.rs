//! The TriCal measurement campaign: centre the device on a ball in each planned
//! configuration and record the joints, each measurement made durable through a
//! [`Journal`] before the next move; resume skips what is already recorded; device faults
//! are retried with back-off and then pause the campaign with the reason.

use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::centring::{CentringError, CentringOptions, centre};
use super::devices::{DeviceError, Indicators, Robot};
use crate::util::Monitor;

/// One planned configuration: where to start and which ball (0-based) it aims at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Planned {
    /// Start joint values (rad).
    pub q: Vec<f64>,
    /// Ball index (0-based).
    pub ball: usize,
}

/// One recorded measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Recorded {
    /// Index in the plan.
    pub index: usize,
    /// Ball (0-based).
    pub ball: usize,
    /// Joint values at the end of centring (rad).
    pub q: Vec<f64>,
    /// Final |r| (mm).
    pub residual_mm: f64,
    /// Corrective moves.
    pub iterations: usize,
}

/// Durable storage of a campaign's measurements.
pub trait Journal: Send + Sync {
    /// Everything recorded so far (for resume).
    fn recorded(&self) -> Result<Vec<Recorded>, String>;
    /// Make `m` durable; returns only once it is committed.
    fn record(&self, m: &Recorded) -> Result<(), String>;
    /// Note a skipped configuration (centring failed for a reason that is not a device fault).
    fn skipped(&self, index: usize, reason: &str) -> Result<(), String>;
}

/// Retry policy for device faults.
#[derive(Debug, Clone, PartialEq)]
pub struct Retry {
    /// Attempts per configuration before pausing.
    pub attempts: usize,
    /// First back-off delay, doubled after each failure.
    pub backoff: Duration,
}

impl Default for Retry {
    fn default() -> Self {
        Self {
            attempts: 3,
            backoff: Duration::from_millis(500),
        }
    }
}

/// How a campaign ended.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CampaignError {
    /// Device faults persisted: the campaign is paused at `index` and can be resumed.
    #[error("paused at configuration {index}: {reason}")]
    Paused {
        /// First configuration not measured.
        index: usize,
        /// The last fault.
        reason: String,
    },
    /// The journal could not store a measurement: nothing more may be measured.
    #[error("journal: {0}")]
    Journal(String),
    /// Cancelled by the operator.
    #[error("cancelled")]
    Cancelled,
}

/// Progress of a campaign, reported per configuration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CampaignSummary {
    /// Measurements recorded (including earlier runs).
    pub recorded: usize,
    /// Configurations skipped (ball lost, not converged).
    pub skipped: usize,
    /// Configurations in the plan.
    pub planned: usize,
}

fn is_device_fault(e: &CentringError) -> bool {
    matches!(
        e,
        CentringError::Device(
            DeviceError::Timeout { .. }
                | DeviceError::Disconnected { .. }
                | DeviceError::Protocol { .. }
                | DeviceError::Fault { .. }
        ) | CentringError::ReadingTimeout { .. }
    )
}

/// Measure every configuration of `plan` not yet in the journal.
pub async fn run(
    robot: &dyn Robot,
    indicators: &dyn Indicators,
    plan: &[Planned],
    journal: &dyn Journal,
    centring: &CentringOptions,
    retry: &Retry,
    monitor: &dyn Monitor,
) -> Result<CampaignSummary, CampaignError> {
    let done: std::collections::HashSet<usize> = journal
        .recorded()
        .map_err(CampaignError::Journal)?
        .into_iter()
        .map(|r| r.index)
        .collect();
    let mut skipped = 0;
    let mut recorded = done.len();
    for (index, p) in plan.iter().enumerate() {
        if done.contains(&index) {
            continue;
        }
        if monitor.is_cancelled() {
            return Err(CampaignError::Cancelled);
        }
        monitor.progress(index as f64 / plan.len() as f64, "centring");
        let mut delay = retry.backoff;
        let mut attempt = 0;
        loop {
            attempt += 1;
            match centre(robot, indicators, &p.q, centring, monitor).await {
                Ok(c) => {
                    let m = Recorded {
                        index,
                        ball: p.ball,
                        q: c.q,
                        residual_mm: c.residual_mm,
                        iterations: c.iterations,
                    };
                    journal.record(&m).map_err(CampaignError::Journal)?;
                    recorded += 1;
                    break;
                }
                Err(CentringError::Cancelled) => return Err(CampaignError::Cancelled),
                Err(e) if is_device_fault(&e) => {
                    if attempt >= retry.attempts {
                        return Err(CampaignError::Paused {
                            index,
                            reason: e.to_string(),
                        });
                    }
                    tracing::warn!(index, attempt, error = %e, "device fault, retrying");
                    tokio::time::sleep(delay).await;
                    delay *= 2;
                }
                Err(e) => {
                    journal
                        .skipped(index, &e.to_string())
                        .map_err(CampaignError::Journal)?;
                    skipped += 1;
                    break;
                }
            }
        }
    }
    monitor.progress(1.0, "centring");
    Ok(CampaignSummary {
        recorded,
        skipped,
        planned: plan.len(),
    })
}

#[cfg(test)]
#[path = "trical_tests.rs"]
mod tests;
