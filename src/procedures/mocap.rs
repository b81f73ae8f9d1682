//! The motion-capture posture campaign: move the robot to each planned posture, wait, record
//! the marker stream for a window, pre-process it (zero-phase low-pass, stable samples:
//! [`crate::measure::mocap::preprocess`]) and journal the posture's averaged marker positions
//! before the next move. Resume skips journalled postures; device faults are retried with
//! doubling back-off, then the campaign pauses with the reason.

use std::collections::{BTreeMap, HashSet};
use std::time::{Duration, Instant};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::devices::{DeviceError, JointRobot, MarkerFrames, MarkerStream};
use super::journal::{EntryStatus, Journal, JournalEntry};
use super::trical::{CampaignError, CampaignSummary, Retry};
use crate::measure::mocap::{MocapOptions, preprocess};
use crate::util::Monitor;

/// How each posture is measured.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordOptions {
    /// Wait after the move before recording.
    pub settle: Duration,
    /// Length of the recording window.
    pub window: Duration,
    /// Pre-processing of the window (filter, stable samples).
    pub preprocess: MocapOptions,
}

/// One journalled posture: the joints read after the move and each marker's position
/// averaged over the window's stable samples.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PostureSample {
    /// Index in the plan.
    pub index: usize,
    /// Joint values read from the robot (rad), in the plan's joint order.
    pub q: Vec<f64>,
    /// Averaged position per marker label (m); `null` when it had no stable sample.
    pub markers: BTreeMap<String, Option<[f64; 3]>>,
    /// Frames recorded in the window.
    pub frames: usize,
    /// Stable samples averaged (per marker, at most).
    pub stable: usize,
}

/// Why a window gave no measurement.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PostureError {
    /// A device call failed.
    #[error(transparent)]
    Device(#[from] DeviceError),
    /// The window had no stable posture (the robot still moving, or too short a window).
    #[error("no stable samples in the recording window: {0}")]
    Unstable(String),
}

/// Average the stable samples of one recording window; the pre-processing is the one of
/// `humanoid.*` raw recordings.
pub fn reduce(
    rec: &MarkerFrames,
    opts: &MocapOptions,
) -> Result<(BTreeMap<String, Option<[f64; 3]>>, usize), PostureError> {
    let tracks: Vec<Vec<Option<Vector3<f64>>>> = (0..rec.labels.len())
        .map(|m| {
            rec.frames
                .iter()
                .map(|f| f.get(m).copied().flatten().map(Vector3::from))
                .collect()
        })
        .collect();
    let stable = preprocess(&rec.t_s, &tracks, None, opts)
        .map_err(|e| PostureError::Unstable(e.to_string()))?;
    let Some(kept) = stable.postures.iter().max_by_key(|p| p.len()) else {
        return Err(PostureError::Unstable(format!(
            "{} frames, none stable for {} samples",
            rec.t_s.len(),
            opts.min_stable
        )));
    };
    let mut out = BTreeMap::new();
    let mut most = 0;
    for (m, label) in rec.labels.iter().enumerate() {
        let pts: Vec<Vector3<f64>> = kept
            .iter()
            .filter(|&&s| stable.keep[m][s])
            .filter_map(|&s| stable.filtered[m][s])
            .collect();
        most = most.max(pts.len());
        let mean = (!pts.is_empty()).then(|| {
            let c = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
            [c.x, c.y, c.z]
        });
        out.insert(label.clone(), mean);
    }
    Ok((out, most))
}

async fn measure(
    robot: &dyn JointRobot,
    stream: &dyn MarkerStream,
    index: usize,
    posture: &[(String, f64)],
    opts: &RecordOptions,
) -> Result<PostureSample, PostureError> {
    robot.move_to(posture).await?;
    tokio::time::sleep(opts.settle).await;
    let names = robot.joint_names();
    let all = robot.joints().await?;
    let q = posture
        .iter()
        .map(|(n, _)| {
            names
                .iter()
                .position(|x| x == n)
                .and_then(|k| all.get(k).copied())
                .ok_or_else(|| {
                    PostureError::Device(DeviceError::Protocol {
                        device: "robot".into(),
                        message: format!("no reading of joint `{n}`"),
                    })
                })
        })
        .collect::<Result<Vec<f64>, _>>()?;
    let rec = stream.record(opts.window).await?;
    let (markers, stable) = reduce(&rec, &opts.preprocess)?;
    Ok(PostureSample {
        index,
        q,
        markers,
        frames: rec.t_s.len(),
        stable,
    })
}

/// The journalled posture samples of `0..len`.
pub fn recorded(journal: &dyn Journal, len: usize) -> Result<Vec<PostureSample>, String> {
    Ok(journal
        .entries()?
        .into_iter()
        .filter(|e| e.status == EntryStatus::Measured && e.index < len)
        .filter_map(|e| serde_json::from_value::<PostureSample>(e.data).ok())
        .collect())
}

fn append(
    journal: &dyn Journal,
    index: usize,
    status: EntryStatus,
    data: serde_json::Value,
) -> Result<(), CampaignError> {
    journal
        .append(&JournalEntry {
            index,
            status,
            data,
        })
        .map_err(CampaignError::Journal)
}

/// Measure every posture of `plan` (named joint values, rad) not yet in the journal.
/// Refused postures (outside the robot's limits) are journalled as skipped.
pub async fn run(
    robot: &dyn JointRobot,
    stream: &dyn MarkerStream,
    plan: &[Vec<(String, f64)>],
    journal: &dyn Journal,
    opts: &RecordOptions,
    retry: &Retry,
    monitor: &dyn Monitor,
) -> Result<CampaignSummary, CampaignError> {
    let entries = journal.entries().map_err(CampaignError::Journal)?;
    let done: HashSet<usize> = entries.iter().map(|e| e.index).collect();
    let count = |s: EntryStatus| {
        entries
            .iter()
            .filter(|e| e.status == s && e.index < plan.len())
            .count()
    };
    let (mut recorded, mut skipped) = (count(EntryStatus::Measured), count(EntryStatus::Skipped));
    let todo = plan.len() - recorded - skipped;
    let t0 = Instant::now();
    let mut this_run = 0usize;
    for (index, posture) in plan.iter().enumerate() {
        if done.contains(&index) {
            continue;
        }
        if monitor.is_cancelled() {
            return Err(CampaignError::Cancelled);
        }
        let eta = match this_run {
            0 => "unknown".to_string(),
            n => format!(
                "{:.0} s",
                t0.elapsed().as_secs_f64() / n as f64 * (todo - n) as f64
            ),
        };
        monitor.report(
            index as f64 / plan.len() as f64,
            "postures",
            &format!(
                "posture {}/{}: {recorded} recorded, {skipped} skipped, ETA {eta}",
                index + 1,
                plan.len()
            ),
        );
        this_run += 1;
        let mut delay = retry.backoff;
        let mut attempt = 0;
        loop {
            attempt += 1;
            match measure(robot, stream, index, posture, opts).await {
                Ok(s) => {
                    let data = serde_json::to_value(&s)
                        .map_err(|e| CampaignError::Journal(e.to_string()))?;
                    append(journal, index, EntryStatus::Measured, data)?;
                    recorded += 1;
                    tracing::info!(
                        index,
                        frames = s.frames,
                        stable = s.stable,
                        "posture recorded"
                    );
                    break;
                }
                Err(PostureError::Device(DeviceError::Refused { reason, .. })) => {
                    append(
                        journal,
                        index,
                        EntryStatus::Skipped,
                        serde_json::json!({"reason": reason}),
                    )?;
                    tracing::warn!(index, %reason, "posture skipped");
                    skipped += 1;
                    break;
                }
                Err(e) => {
                    if attempt >= retry.attempts {
                        return Err(CampaignError::Paused {
                            index,
                            reason: e.to_string(),
                        });
                    }
                    tracing::warn!(index, attempt, error = %e, "posture failed, retrying");
                    tokio::time::sleep(delay).await;
                    delay *= 2;
                }
            }
        }
    }
    monitor.progress(1.0, "postures");
    Ok(CampaignSummary {
        recorded,
        skipped,
        planned: plan.len(),
    })
}

#[cfg(test)]
#[path = "mocap_tests.rs"]
mod tests;
