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
            (
                EntryStatus::Skipped,
                serde_json::json!({ "reason": reason }),
            )
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedures::MemoryJournal;
    use crate::util::NoMonitor;
    use std::sync::Mutex;

    /// Stages that settle 1 nm past the target; the first `faults` moves time out.
    struct FakeStages {
        faults: Mutex<usize>,
        moves: Mutex<Vec<[f64; 3]>>,
    }
    impl LinearStages for FakeStages {
        fn move_to<'a>(&'a self, q: &'a [f64; 3]) -> DeviceFuture<'a, [f64; 3]> {
            Box::pin(async move {
                let mut f = self.faults.lock().expect("lock");
                if *f > 0 {
                    *f -= 1;
                    return Err(DeviceError::Timeout {
                        device: "stages".into(),
                        timeout_ms: 1,
                    });
                }
                self.moves.lock().expect("lock").push(*q);
                Ok(q.map(|v| v + 1e-9))
            })
        }
        fn positions(&self) -> DeviceFuture<'_, [f64; 3]> {
            Box::pin(async { Ok([0.0; 3]) })
        }
    }
    /// A microscope that sees the last joint set scaled (a known linear map).
    struct FakeScope<'a>(&'a FakeStages);
    impl PoseSensor for FakeScope<'_> {
        fn read_pose(&self) -> DeviceFuture<'_, [f64; 3]> {
            Box::pin(async move {
                let q = self
                    .0
                    .moves
                    .lock()
                    .expect("lock")
                    .last()
                    .copied()
                    .unwrap_or_default();
                Ok([2.0 * q[0], 3.0 * q[1], q[2]])
            })
        }
    }
    use super::super::devices::DeviceFuture;

    fn opts(attempts: usize) -> PcrOptions {
        PcrOptions {
            limits: [[-1e-3, 1e-3]; 3],
            settle: Duration::ZERO,
            retry: Retry {
                attempts,
                backoff: Duration::from_millis(1),
            },
        }
    }

    #[tokio::test]
    async fn faults_are_retried_then_pause_and_the_envelope_skips() {
        let plan = [[1e-4, 2e-4, 3e-4], [5e-3, 0.0, 0.0], [-1e-4, 0.0, 1e-4]];
        let st = FakeStages {
            faults: Mutex::new(2),
            moves: Mutex::default(),
        };
        let j = MemoryJournal::default();
        // Two timeouts, three attempts: the first joint set is measured on the third.
        let s = run(&st, &FakeScope(&st), &plan, 10, &j, &opts(3), &NoMonitor)
            .await
            .expect("campaign");
        assert_eq!((s.recorded, s.skipped, s.planned), (2, 1, 3));
        let rec = recorded(&j, 10, 3).expect("journal");
        assert_eq!(rec[0].index, 10);
        assert_eq!(rec[0].q, [1e-4 + 1e-9, 2e-4 + 1e-9, 3e-4 + 1e-9]);
        assert_eq!(rec[0].z, [2.0 * 1e-4, 3.0 * 2e-4, 3e-4]);
        let e = j.entries().expect("entries");
        assert_eq!(e[1].status, EntryStatus::Skipped);
        assert!(e[1].data["reason"].as_str().unwrap_or("").contains("q1"));
        // The out-of-envelope joint set never reached the stages.
        assert_eq!(st.moves.lock().expect("lock").len(), 2);
        // Resume: nothing left, nothing measured again.
        run(&st, &FakeScope(&st), &plan, 10, &j, &opts(3), &NoMonitor)
            .await
            .expect("resume");
        assert_eq!(st.moves.lock().expect("lock").len(), 2);
        // Persistent faults pause at the first unmeasured index.
        *st.faults.lock().expect("lock") = 5;
        let j2 = MemoryJournal::default();
        let e = run(&st, &FakeScope(&st), &plan, 0, &j2, &opts(2), &NoMonitor)
            .await
            .expect_err("paused");
        assert!(matches!(e, CampaignError::Paused { index: 0, .. }), "{e}");
        assert!(j2.entries().expect("entries").is_empty());
    }
}
