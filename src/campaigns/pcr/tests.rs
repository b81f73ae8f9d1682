use super::*;
use crate::campaigns::engine::{CampaignError, Summary};
use crate::procedures::Journal;
use crate::procedures::{EntryStatus, MemoryJournal};
use crate::util::NoMonitor;

use crate::procedures::fakes::{FakeScope, FakeStages};

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
    let st = FakeStages::new(2);
    let j = MemoryJournal::default();
    // Two timeouts, three attempts: the first joint set is measured on the third.
    let s = run(
        &*st,
        &FakeScope(st.clone()),
        &plan,
        10,
        &j,
        &opts(3),
        &NoMonitor,
    )
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
    run(
        &*st,
        &FakeScope(st.clone()),
        &plan,
        10,
        &j,
        &opts(3),
        &NoMonitor,
    )
    .await
    .expect("resume");
    assert_eq!(st.moves.lock().expect("lock").len(), 2);
    // Persistent faults pause at the first unmeasured index.
    *st.faults.lock().expect("lock") = 5;
    let j2 = MemoryJournal::default();
    let e = run(
        &*st,
        &FakeScope(st.clone()),
        &plan,
        0,
        &j2,
        &opts(2),
        &NoMonitor,
    )
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
