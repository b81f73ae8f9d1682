//! The TriCal measurement campaign: centre the device on a ball in each planned
//! configuration and record the joints, each measurement made durable through a
//! [`Journal`] before the next move; resume skips what is already recorded; device faults
//! are retried with back-off and then pause the campaign with the reason.

use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::centring::{CentringError, CentringOptions, centre};
use super::devices::{DeviceError, Indicators, Robot};
use super::journal::{EntryStatus, Journal, JournalEntry};
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

/// The recorded measurements of a journal (entries at `offset..offset + len`).
pub fn recorded(journal: &dyn Journal, offset: usize, len: usize) -> Result<Vec<Recorded>, String> {
    Ok(journal
        .entries()?
        .into_iter()
        .filter(|e| {
            e.status == EntryStatus::Measured && e.index >= offset && e.index < offset + len
        })
        .filter_map(|e| serde_json::from_value::<Recorded>(e.data).ok())
        .collect())
}

/// Measure every configuration of `plan` not yet in the journal; plan entry `k` is journal
/// index `offset + k` (a campaign's phases use disjoint ranges).
#[allow(clippy::too_many_arguments)]
pub async fn run(
    robot: &dyn Robot,
    indicators: &dyn Indicators,
    plan: &[Planned],
    offset: usize,
    journal: &dyn Journal,
    centring: &CentringOptions,
    retry: &Retry,
    monitor: &dyn Monitor,
) -> Result<CampaignSummary, CampaignError> {
    let entries = journal.entries().map_err(CampaignError::Journal)?;
    let done: std::collections::HashSet<usize> = entries.iter().map(|e| e.index).collect();
    let mut recorded = entries
        .iter()
        .filter(|e| {
            e.status == EntryStatus::Measured && e.index >= offset && e.index < offset + plan.len()
        })
        .count();
    let mut skipped = entries
        .iter()
        .filter(|e| {
            e.status == EntryStatus::Skipped && e.index >= offset && e.index < offset + plan.len()
        })
        .count();
    let t0 = std::time::Instant::now();
    let mut this_run = 0usize;
    let todo = plan.len() - recorded - skipped;
    for (k, p) in plan.iter().enumerate() {
        let index = offset + k;
        if done.contains(&index) {
            continue;
        }
        if monitor.is_cancelled() {
            return Err(CampaignError::Cancelled);
        }
        let eta = if this_run > 0 {
            let per = t0.elapsed().as_secs_f64() / this_run as f64;
            format!("{:.0} s", per * (todo - this_run) as f64)
        } else {
            "unknown".into()
        };
        monitor.report(
            k as f64 / plan.len() as f64,
            "centring",
            &format!(
                "configuration {}/{} (ball {}): {recorded} recorded, {skipped} skipped, ETA {eta}",
                k + 1,
                plan.len(),
                p.ball + 1
            ),
        );
        this_run += 1;
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
                    let data = serde_json::to_value(&m)
                        .map_err(|e| CampaignError::Journal(e.to_string()))?;
                    journal
                        .append(&JournalEntry {
                            index,
                            status: EntryStatus::Measured,
                            data,
                        })
                        .map_err(CampaignError::Journal)?;
                    recorded += 1;
                    tracing::info!(
                        index,
                        ball = p.ball + 1,
                        moves = m.iterations,
                        residual_mm = m.residual_mm,
                        "centred"
                    );
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
                    let data = serde_json::json!({"reason": e.to_string()});
                    journal
                        .append(&JournalEntry {
                            index,
                            status: EntryStatus::Skipped,
                            data,
                        })
                        .map_err(CampaignError::Journal)?;
                    tracing::warn!(index, reason = %e, "configuration skipped");
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
