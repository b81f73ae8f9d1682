use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use super::*;
use crate::procedures::{DeviceFuture, MemoryJournal};
use crate::util::{NoMonitor, Rng};

/// A point robot: one marker at (q0, q1, 1) m; moves fail while `failing` > 0.
struct FakeRobot {
    q: Mutex<Vec<f64>>,
    failing: AtomicUsize,
    moves: AtomicUsize,
}

impl JointRobot for FakeRobot {
    fn joint_names(&self) -> Vec<String> {
        vec!["a".into(), "b".into()]
    }
    fn joints(&self) -> DeviceFuture<'_, Vec<f64>> {
        Box::pin(async move { Ok(self.q.lock().map(|q| q.clone()).unwrap_or_default()) })
    }
    fn move_to<'a>(&'a self, posture: &'a [(String, f64)]) -> DeviceFuture<'a, ()> {
        Box::pin(async move {
            if self
                .failing
                .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1))
                .is_ok()
            {
                return Err(DeviceError::Disconnected {
                    device: "fake".into(),
                });
            }
            self.moves.fetch_add(1, Ordering::SeqCst);
            let mut q = self.q.lock().map_err(|_| DeviceError::Disconnected {
                device: "fake".into(),
            })?;
            for (n, v) in posture {
                match n.as_str() {
                    "a" => q[0] = *v,
                    "b" => q[1] = *v,
                    _ => {
                        return Err(DeviceError::Refused {
                            device: "fake".into(),
                            reason: format!("no joint {n}"),
                        });
                    }
                }
            }
            Ok(())
        })
    }
}

/// 100 Hz frames of the robot's marker with 0.3 mm noise (seeded).
struct FakeStream<'r> {
    robot: &'r FakeRobot,
    rng: Mutex<Rng>,
}

impl MarkerStream for FakeStream<'_> {
    fn record(&self, d: Duration) -> DeviceFuture<'_, MarkerFrames> {
        Box::pin(async move {
            let q = self.robot.q.lock().map(|q| q.clone()).unwrap_or_default();
            let mut rng = self
                .rng
                .lock()
                .map_err(|_| DeviceError::Disconnected { device: "s".into() })?;
            let n = (d.as_secs_f64() * 100.0) as usize;
            Ok(MarkerFrames {
                labels: vec!["m".into()],
                t_s: (0..n).map(|i| i as f64 / 100.0).collect(),
                frames: (0..n)
                    .map(|_| {
                        vec![Some([
                            q[0] + 3e-4 * rng.normal(),
                            q[1] + 3e-4 * rng.normal(),
                            1.0 + 3e-4 * rng.normal(),
                        ])]
                    })
                    .collect(),
            })
        })
    }
}

fn opts() -> RecordOptions {
    RecordOptions {
        settle: Duration::ZERO,
        window: Duration::from_secs(1),
        preprocess: MocapOptions::default(),
    }
}

fn plan() -> Vec<Vec<(String, f64)>> {
    (0..5)
        .map(|k| {
            vec![
                ("a".to_string(), 0.1 * k as f64),
                ("b".to_string(), -0.2 * k as f64),
            ]
        })
        .collect()
}

fn robot(failing: usize) -> FakeRobot {
    FakeRobot {
        q: Mutex::new(vec![0.0, 0.0]),
        failing: AtomicUsize::new(failing),
        moves: AtomicUsize::new(0),
    }
}

fn quick() -> Retry {
    Retry {
        attempts: 3,
        backoff: Duration::from_millis(1),
    }
}

#[tokio::test]
async fn averages_stable_samples_to_well_below_the_frame_noise() {
    let r = robot(0);
    let s = FakeStream {
        robot: &r,
        rng: Mutex::new(Rng::new(1)),
    };
    let j = MemoryJournal::default();
    let sum = run(&r, &s, &plan(), &j, &opts(), &quick(), &NoMonitor)
        .await
        .unwrap();
    assert_eq!((sum.recorded, sum.skipped, sum.planned), (5, 0, 5));
    let rec: Vec<PostureSample> = engine::recorded(&j, 0, 5).unwrap();
    for (k, p) in rec.iter().enumerate() {
        let m = p.markers["m"].unwrap();
        // 0.3 mm frame noise; 10 kept samples of a 5 Hz low-pass at 100 Hz: the mean is within
        // 0.3 mm (1 sigma of a single frame, a loose bound: the mean is far better).
        assert!((m[0] - 0.1 * k as f64).abs() < 3e-4, "{m:?}");
        assert!((m[1] + 0.2 * k as f64).abs() < 3e-4, "{m:?}");
        assert_eq!(p.q, vec![0.1 * k as f64, -0.2 * k as f64]);
        assert_eq!(p.stable, 10);
        assert_eq!(p.frames, 100);
    }
}

#[tokio::test]
async fn retries_then_pauses_and_resumes_without_measuring_twice() {
    let r = robot(2);
    let s = FakeStream {
        robot: &r,
        rng: Mutex::new(Rng::new(2)),
    };
    let j = MemoryJournal::default();
    // Two faults < three attempts: recovered.
    let sum = run(&r, &s, &plan()[..2], &j, &opts(), &quick(), &NoMonitor)
        .await
        .unwrap();
    assert_eq!(sum.recorded, 2);
    // Three faults on posture 2: paused there.
    r.failing.store(3, Ordering::SeqCst);
    let e = run(&r, &s, &plan(), &j, &opts(), &quick(), &NoMonitor)
        .await
        .unwrap_err();
    assert!(matches!(e, CampaignError::Paused { index: 2, .. }), "{e:?}");
    let before = r.moves.load(Ordering::SeqCst);
    let sum = run(&r, &s, &plan(), &j, &opts(), &quick(), &NoMonitor)
        .await
        .unwrap();
    assert_eq!(sum.recorded, 5);
    // Only postures 2, 3, 4 moved again.
    assert_eq!(r.moves.load(Ordering::SeqCst) - before, 3);
    let idx: Vec<usize> = j.entries().unwrap().iter().map(|e| e.index).collect();
    assert_eq!(idx, vec![0, 1, 2, 3, 4]);
}

#[tokio::test]
async fn refused_posture_is_skipped() {
    let r = robot(0);
    let s = FakeStream {
        robot: &r,
        rng: Mutex::new(Rng::new(3)),
    };
    let j = MemoryJournal::default();
    let mut p = plan();
    p[1] = vec![("c".to_string(), 0.0)];
    let sum = run(&r, &s, &p, &j, &opts(), &quick(), &NoMonitor)
        .await
        .unwrap();
    assert_eq!((sum.recorded, sum.skipped), (4, 1));
}

#[test]
fn still_moving_window_is_unstable() {
    let rec = MarkerFrames {
        labels: vec!["m".into()],
        t_s: (0..100).map(|i| i as f64 / 100.0).collect(),
        frames: (0..100)
            .map(|i| vec![Some([0.5 * i as f64 / 100.0, 0.0, 1.0])])
            .collect(),
    };
    assert!(matches!(
        reduce(&rec, &MocapOptions::default()),
        Err(PostureError::Unstable(_))
    ));
}
