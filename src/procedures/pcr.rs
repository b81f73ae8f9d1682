//! The 3-PF measurement campaign: drive the three stages to each planned joint set, wait
//! for them to settle, read the microscope, and append the measurement to the [`Journal`]
//! before the next move. Resume skips what the journal holds; device faults are retried
//! with doubling back-off and then pause the campaign (same policy and errors as
//! [`super::trical`]).

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::devices::{DeviceError, LinearStages, PoseSensor};
use super::journal::{EntryStatus, Journal, JournalEntry};
use super::trical::{CampaignError, CampaignSummary, Retry};
use crate::util::Monitor;

/// One recorded measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PcrRecorded {
    /// Index in the journal.
    pub index: usize,
    /// Commanded joints (m).
    pub q_cmd: [f64; 3],
    /// Joints the stages settled at (m): what the identification uses.
    pub q: [f64; 3],
    /// Microscope reading x (m), y (m), theta (rad).
    pub z: [f64; 3],
}

/// How the campaign moves and waits.
#[derive(Debug, Clone, PartialEq)]
pub struct PcrOptions {
    /// Joint limits the plan must respect (m): the cell's motion envelope.
    pub limits: [[f64; 2]; 3],
    /// Wait after the stages report settled, before the image (vibrations die out).
    pub settle: Duration,
    /// Device-fault retries.
    pub retry: Retry,
}

fn is_device_fault(e: &DeviceError) -> bool {
    !matches!(e, DeviceError::Refused { .. })
}

/// The recorded measurements of a journal (entries at `offset..offset + len`).
pub fn recorded(
    journal: &dyn Journal,
    offset: usize,
    len: usize,
) -> Result<Vec<PcrRecorded>, String> {
    Ok(journal
        .entries()?
        .into_iter()
        .filter(|e| {
            e.status == EntryStatus::Measured && e.index >= offset && e.index < offset + len
        })
        .filter_map(|e| serde_json::from_value::<PcrRecorded>(e.data).ok())
        .collect())
}

async fn measure_one(
    stages: &dyn LinearStages,
    scope: &dyn PoseSensor,
    q: &[f64; 3],
    settle: Duration,
) -> Result<([f64; 3], [f64; 3]), DeviceError> {
    let at = stages.move_to(q).await?;
    if !settle.is_zero() {
        tokio::time::sleep(settle).await;
    }
    let z = scope.read_pose().await?;
    Ok((at, z))
}

/// Measure every joint set of `plan` not yet in the journal; plan entry `k` is journal
/// index `offset + k`. A joint set outside `opts.limits` is journalled as skipped, never
/// sent to the stages.
pub async fn run(
    stages: &dyn LinearStages,
    scope: &dyn PoseSensor,
    plan: &[[f64; 3]],
    offset: usize,
    journal: &dyn Journal,
    opts: &PcrOptions,
    monitor: &dyn Monitor,
) -> Result<CampaignSummary, CampaignError> {
    let entries = journal.entries().map_err(CampaignError::Journal)?;
    let mine = |s: EntryStatus| {
        entries
            .iter()
            .filter(|e| e.status == s && e.index >= offset && e.index < offset + plan.len())
            .count()
    };
    let (mut recorded, mut skipped) = (mine(EntryStatus::Measured), mine(EntryStatus::Skipped));
    let done: std::collections::HashSet<usize> = entries.iter().map(|e| e.index).collect();
    let todo = plan.len() - recorded - skipped;
    let t0 = Instant::now();
    let mut this_run = 0usize;
    for (k, q) in plan.iter().enumerate() {
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
            "measuring",
            &format!(
                "joint set {}/{}: {recorded} recorded, {skipped} skipped, ETA {eta}",
                k + 1,
                plan.len()
            ),
        );
        this_run += 1;
        let (status, data) = if let Some(j) =
            (0..3).find(|&j| !(q[j] >= opts.limits[j][0] && q[j] <= opts.limits[j][1]))
        {
            let reason = format!(
                "q{} = {} m is outside the envelope [{}, {}] m",
                j + 1,
                q[j],
                opts.limits[j][0],
                opts.limits[j][1]
            );
            (EntryStatus::Skipped, serde_json::json!({ "reason": reason }))
        } else {
            let (at, z) = with_retry(stages, scope, q, opts, index).await?;
            let m = PcrRecorded {
                index,
                q_cmd: *q,
                q: at,
                z,
            };
            let v = serde_json::to_value(&m).map_err(|e| CampaignError::Journal(e.to_string()))?;
            (EntryStatus::Measured, v)
        };
        journal
            .append(&JournalEntry {
                index,
                status,
                data,
            })
            .map_err(CampaignError::Journal)?;
        match status {
            EntryStatus::Measured => recorded += 1,
            EntryStatus::Skipped => skipped += 1,
        }
    }
    monitor.progress(1.0, "measuring");
    Ok(CampaignSummary {
        recorded,
        skipped,
        planned: plan.len(),
    })
}

/// One joint set, retried on device faults with doubling back-off, then paused.
async fn with_retry(
    stages: &dyn LinearStages,
    scope: &dyn PoseSensor,
    q: &[f64; 3],
    opts: &PcrOptions,
    index: usize,
) -> Result<([f64; 3], [f64; 3]), CampaignError> {
    let mut delay = opts.retry.backoff;
    let mut attempt = 0;
    loop {
        attempt += 1;
        match measure_one(stages, scope, q, opts.settle).await {
            Ok(r) => return Ok(r),
            Err(e) if is_device_fault(&e) && attempt < opts.retry.attempts => {
                tracing::warn!(index, attempt, error = %e, "device fault, retrying");
                tokio::time::sleep(delay).await;
                delay *= 2;
            }
            Err(e) => {
                return Err(CampaignError::Paused {
                    index,
                    reason: e.to_string(),
                });
            }
        }
    }
}
