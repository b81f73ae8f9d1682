//! The campaign against the simulated cell: measure, identify, validate; resume after an
//! interruption; device faults retried, then paused.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::*;
use crate::design::balls::ball_pool;
use crate::procedures::fakes::{FakeIndicators, FakeRobot, SharedCell};
use crate::procedures::journal::{Journal, MemoryJournal};
use crate::procedures::{DeviceFuture, Robot};
use crate::twin::SerialTwin;
use crate::twin::cell::SimulatedCell;
use crate::util::NoMonitor;

fn setup(per_ball: usize) -> (SerialTwin, SharedCell, Vec<Planned>) {
    let twin = SerialTwin::irb120(1);
    let cell: SharedCell = Arc::new(Mutex::new(SimulatedCell::new(twin.clone(), 9)));
    let centres: Vec<_> = twin.plate.centres.iter().flatten().copied().collect();
    // The plan comes from the nominal model, as in the lab: a few mm off the real balls.
    let t2 = twin.clone();
    let pool = ball_pool(
        &twin.nominal,
        &centres,
        per_ball,
        5,
        move |r| t2.random_q(r),
        |q| q[4].abs() > 10f64.to_radians(),
    );
    let plan = pool
        .into_iter()
        .map(|(q, ball)| Planned { q, ball })
        .collect();
    (twin, cell, plan)
}

fn opts() -> CentringOptions {
    CentringOptions {
        settle: Duration::ZERO,
        ..Default::default()
    }
}

async fn campaign(
    robot: &dyn Robot,
    cell: &SharedCell,
    plan: &[Planned],
    journal: &dyn Journal,
) -> Result<Summary, CampaignError> {
    let retry = Retry {
        attempts: 3,
        backoff: Duration::from_millis(1),
    };
    run(
        robot,
        &FakeIndicators(cell.clone()),
        plan,
        0,
        journal,
        &opts(),
        &retry,
        &NoMonitor,
    )
    .await
}

#[tokio::test]
async fn campaign_then_identification_reaches_the_noise_level() {
    let (twin, cell, plan) = setup(20);
    assert_eq!(plan.len(), 60);
    let journal = MemoryJournal::default();
    let s = campaign(&FakeRobot(cell.clone()), &cell, &plan, &journal)
        .await
        .unwrap();
    assert_eq!(s.recorded + s.skipped, 60);
    assert!(s.recorded >= 57, "{s:?}");
    let rec: Vec<Recorded> = engine::recorded(&journal, 0, plan.len()).unwrap();
    // Every recorded configuration has the true TCP within epsilon (+ indicator noise) of its ball.
    for m in &rec {
        let e = (twin.true_tcp(&m.q) - twin.plate.centres[m.ball].unwrap()).norm();
        assert!(e < 0.012, "config {}: {e} mm", m.index);
    }
    // Identify from what was recorded, validate on the laser tracker.
    let meas: Vec<_> = rec
        .into_iter()
        .map(|m| crate::measure::PointMeasurement {
            q: m.q,
            target: crate::measure::Target::Ball(m.ball),
        })
        .collect();
    let ids: Vec<_> = twin
        .file
        .identify
        .iter()
        .map(|n| twin.nominal.param_by_name(n).unwrap())
        .collect();
    let p = crate::measure::PointProblem::new(twin.nominal.clone(), ids, twin.plate.clone(), meas)
        .unwrap();
    let sol = crate::identify::solve(
        &p,
        &p.unknowns(),
        &p.initial(),
        &Default::default(),
        &NoMonitor,
    )
    .unwrap();
    assert!(sol.stop.converged());
    let cal = p.model(&sol.x);
    let val = twin.tracker(100, 4);
    let err = |c: &crate::model::Chain| {
        crate::jobs::serial::identify::position_errors(c, &val)
            .iter()
            .sum::<f64>()
            / 100.0
    };
    let (before, after) = (err(&twin.nominal), err(&cal));
    assert!(before > 1.0 && after < 0.05, "{before} -> {after} mm");
}

#[tokio::test]
async fn an_interrupted_campaign_resumes_to_the_same_measurements() {
    let (_, cell, plan) = setup(4);
    let full = MemoryJournal::default();
    campaign(&FakeRobot(cell.clone()), &cell, &plan, &full)
        .await
        .unwrap();
    // A journal that dies after 5 entries (the "crash"), then a restart from what it holds,
    // with a fresh cell (the arm elsewhere).
    let broken = MemoryJournal::failing_after(5);
    let e = campaign(&FakeRobot(cell.clone()), &cell, &plan, &broken)
        .await
        .unwrap_err();
    assert!(matches!(e, CampaignError::Journal(_)));
    let resumed = MemoryJournal::with(broken.entries().unwrap());
    let (twin2, _, _) = setup(0);
    let cell2: SharedCell = Arc::new(Mutex::new(SimulatedCell::new(twin2, 9)));
    campaign(&FakeRobot(cell2.clone()), &cell2, &plan, &resumed)
        .await
        .unwrap();
    let (a, b) = (
        engine::recorded::<Recorded>(&full, 0, plan.len()).unwrap(),
        engine::recorded::<Recorded>(&resumed, 0, plan.len()).unwrap(),
    );
    assert_eq!(a.len(), b.len());
    assert_eq!(
        resumed.entries().unwrap().len(),
        full.entries().unwrap().len()
    );
    // Same configurations, each measured once, with identical joint values.
    for m in &a {
        let other: Vec<_> = b.iter().filter(|x| x.index == m.index).collect();
        assert_eq!(other.len(), 1);
        assert_eq!(m.q, other[0].q, "configuration {}", m.index);
    }
}

/// A robot whose joint moves fail `fails` times with a disconnection, then work.
struct Flaky {
    inner: FakeRobot,
    fails: AtomicUsize,
}

impl Robot for Flaky {
    fn joints(&self) -> DeviceFuture<'_, Vec<f64>> {
        self.inner.joints()
    }
    fn move_joints<'a>(&'a self, q: &'a [f64]) -> DeviceFuture<'a, ()> {
        if self.fails.load(Ordering::SeqCst) > 0 {
            self.fails.fetch_sub(1, Ordering::SeqCst);
            return Box::pin(async {
                Err(DeviceError::Disconnected {
                    device: "robot".into(),
                })
            });
        }
        self.inner.move_joints(q)
    }
    fn move_tool(&self, offset_mm: [f64; 3]) -> DeviceFuture<'_, ()> {
        self.inner.move_tool(offset_mm)
    }
}

#[tokio::test]
async fn device_faults_are_retried_then_pause_with_the_reason() {
    let (_, cell, plan) = setup(2);
    let flaky = Flaky {
        inner: FakeRobot(cell.clone()),
        fails: AtomicUsize::new(2),
    };
    let j = MemoryJournal::default();
    let s = campaign(&flaky, &cell, &plan, &j).await.unwrap();
    assert_eq!(s.recorded, plan.len());
    let dead = Flaky {
        inner: FakeRobot(cell.clone()),
        fails: AtomicUsize::new(usize::MAX / 2),
    };
    let j = MemoryJournal::default();
    let e = campaign(&dead, &cell, &plan, &j).await.unwrap_err();
    assert!(
        matches!(&e, CampaignError::Paused { index: 0, reason } if reason.contains("disconnected")),
        "{e}"
    );
    assert!(j.entries().unwrap().is_empty());
}
