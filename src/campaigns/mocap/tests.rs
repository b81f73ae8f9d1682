use std::sync::Arc;
use std::sync::atomic::Ordering;

use super::*;
use crate::procedures::MemoryJournal;
use crate::procedures::fakes::{FakeMarkers, FakePointRobot};
use crate::util::NoMonitor;

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

fn robot(failing: usize) -> Arc<FakePointRobot> {
    FakePointRobot::new(failing)
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
    let s = FakeMarkers::new(r.clone(), 1);
    let j = MemoryJournal::default();
    let sum = run(&*r, &s, &plan(), &j, &opts(), &quick(), &NoMonitor)
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
    let s = FakeMarkers::new(r.clone(), 2);
    let j = MemoryJournal::default();
    // Two faults < three attempts: recovered.
    let sum = run(&*r, &s, &plan()[..2], &j, &opts(), &quick(), &NoMonitor)
        .await
        .unwrap();
    assert_eq!(sum.recorded, 2);
    // Three faults on posture 2: paused there.
    r.failing.store(3, Ordering::SeqCst);
    let e = run(&*r, &s, &plan(), &j, &opts(), &quick(), &NoMonitor)
        .await
        .unwrap_err();
    assert!(matches!(e, CampaignError::Paused { index: 2, .. }), "{e:?}");
    let before = r.moves.load(Ordering::SeqCst);
    let sum = run(&*r, &s, &plan(), &j, &opts(), &quick(), &NoMonitor)
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
    let s = FakeMarkers::new(r.clone(), 3);
    let j = MemoryJournal::default();
    let mut p = plan();
    p[1] = vec![("c".to_string(), 0.0)];
    let sum = run(&*r, &s, &p, &j, &opts(), &quick(), &NoMonitor)
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
