//! In-memory motion-capture devices: a point robot of two joints whose one marker is at
//! (q0, q1, 1) m, and a seeded noisy 100 Hz stream of it (tests of the mocap campaign).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::procedures::{DeviceError, DeviceFuture, JointRobot, MarkerFrames, MarkerStream};
use crate::util::Rng;

/// A point robot: one marker at (q0, q1, 1) m; moves fail while `failing` > 0.
#[derive(Debug)]
pub struct FakePointRobot {
    /// Joint values (rad).
    pub q: Mutex<Vec<f64>>,
    /// Moves still to fail.
    pub failing: AtomicUsize,
    /// Moves done.
    pub moves: AtomicUsize,
}

impl FakePointRobot {
    /// At the origin; the first `failing` moves fail.
    pub fn new(failing: usize) -> Arc<Self> {
        Arc::new(Self {
            q: Mutex::new(vec![0.0, 0.0]),
            failing: AtomicUsize::new(failing),
            moves: AtomicUsize::new(0),
        })
    }
}

impl JointRobot for FakePointRobot {
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
#[derive(Debug)]
pub struct FakeMarkers {
    robot: Arc<FakePointRobot>,
    rng: Mutex<Rng>,
}

impl FakeMarkers {
    /// The stream of `robot`'s marker, noise seeded with `seed`.
    pub fn new(robot: Arc<FakePointRobot>, seed: u64) -> Self {
        Self {
            robot,
            rng: Mutex::new(Rng::new(seed)),
        }
    }
}

impl MarkerStream for FakeMarkers {
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
