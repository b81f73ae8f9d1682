use super::*;
use crate::campaigns::engine::{CampaignError, Summary};
use crate::procedures::Journal;
use crate::procedures::{EntryStatus, MemoryJournal};
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
use crate::procedures::DeviceFuture;

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
    let rec: Vec<PcrRecorded> = engine::recorded(&j, 10, 3).expect("journal");
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

/// Measure every joint set of `plan` not yet in the journal; plan entry `k` is journal
/// index `offset + k`.
async fn run(
    stages: &dyn LinearStages,
    scope: &dyn PoseSensor,
    plan: &[[f64; 3]],
    offset: usize,
    journal: &dyn Journal,
    opts: &PcrOptions,
    monitor: &dyn Monitor,
) -> Result<Summary, CampaignError> {
    let step = StagesAndScope {
        stages,
        scope,
        options: opts,
    };
    engine::run(&step, plan, offset, journal, &opts.retry, monitor).await
}
