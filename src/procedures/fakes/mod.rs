//! In-memory devices, one for every device trait: a robot and indicators sharing one
//! [`SimulatedCell`] (here), stages and a microscope ([`stages`]), a joint robot and a
//! marker stream ([`mocap`]).

pub mod mocap;
pub mod stages;

pub use mocap::{FakeMarkers, FakePointRobot};
pub use stages::{FakeScope, FakeStages};

use std::sync::{Arc, Mutex};

use super::devices::{DeviceError, DeviceFuture, Indicators, Robot};
use crate::twin::cell::{CellError, SimulatedCell};

/// A shared simulated cell.
pub type SharedCell = Arc<Mutex<SimulatedCell>>;

fn fault(device: &str, e: CellError) -> DeviceError {
    match e {
        CellError::Limit { .. } | CellError::Unreachable => DeviceError::Refused {
            device: device.into(),
            reason: e.to_string(),
        },
        _ => DeviceError::Fault {
            device: device.into(),
            message: e.to_string(),
        },
    }
}

fn lock<'a>(
    cell: &'a SharedCell,
    device: &str,
) -> Result<std::sync::MutexGuard<'a, SimulatedCell>, DeviceError> {
    cell.lock().map_err(|_| DeviceError::Fault {
        device: device.into(),
        message: "simulation state poisoned".into(),
    })
}

/// The simulated arm.
#[derive(Debug, Clone)]
pub struct FakeRobot(pub SharedCell);

/// The simulated indicators.
#[derive(Debug, Clone)]
pub struct FakeIndicators(pub SharedCell);

impl Robot for FakeRobot {
    fn joints(&self) -> DeviceFuture<'_, Vec<f64>> {
        Box::pin(async move { Ok(lock(&self.0, "robot")?.joints()) })
    }
    fn move_joints<'a>(&'a self, q: &'a [f64]) -> DeviceFuture<'a, ()> {
        Box::pin(async move {
            lock(&self.0, "robot")?
                .move_joints(q)
                .map_err(|e| fault("robot", e))
        })
    }
    fn move_tool(&self, offset_mm: [f64; 3]) -> DeviceFuture<'_, ()> {
        Box::pin(async move {
            lock(&self.0, "robot")?
                .move_tool(offset_mm)
                .map_err(|e| fault("robot", e))
        })
    }
}

impl Indicators for FakeIndicators {
    fn read(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async move {
            lock(&self.0, "indicators")?
                .read_indicators()
                .map_err(|e| fault("indicators", e))
        })
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::procedures::{CentringError, CentringOptions, centre};
    use crate::twin::SerialTwin;
    use crate::util::{NoMonitor, Rng};

    fn opts() -> CentringOptions {
        CentringOptions {
            settle: Duration::ZERO,
            ..Default::default()
        }
    }

    /// From a start a few millimetres off (a nominal-model guess), the loop brings the true
    /// TCP within epsilon of the ball in a few moves.
    #[tokio::test]
    async fn centres_the_true_tcp_on_the_ball() {
        let twin = SerialTwin::irb120(1);
        let cell: SharedCell = Arc::new(Mutex::new(SimulatedCell::new(twin.clone(), 4)));
        let (robot, ind) = (FakeRobot(cell.clone()), FakeIndicators(cell.clone()));
        let mut rng = Rng::new(3);
        let mut done = 0;
        while done < 6 {
            let ball = done % 3;
            let centre_w = twin.plate.centres[ball].unwrap();
            let Some(q_true) = twin.reach(&twin.random_q(&mut rng), &centre_w) else {
                continue;
            };
            // Start 0.2 deg off on every joint.
            let q_d: Vec<f64> = q_true
                .iter()
                .map(|v| v + 0.2f64.to_radians() * rng.range(-1.0, 1.0))
                .collect();
            let c = centre(&robot, &ind, &q_d, &opts(), &NoMonitor)
                .await
                .unwrap();
            let err = (twin.true_tcp(&c.q) - centre_w).norm();
            assert!(
                err < 0.010 + 0.002,
                "ball {}: {err} mm after {} moves",
                ball + 1,
                c.iterations
            );
            assert!(
                c.iterations >= 1 && c.iterations <= 6,
                "{} moves",
                c.iterations
            );
            done += 1;
        }
    }

    #[tokio::test]
    async fn a_lost_ball_and_a_tiny_budget_abort_with_reasons() {
        let twin = SerialTwin::irb120(1);
        let cell: SharedCell = Arc::new(Mutex::new(SimulatedCell::new(twin.clone(), 4)));
        let (robot, ind) = (FakeRobot(cell.clone()), FakeIndicators(cell.clone()));
        let mut rng = Rng::new(8);
        let q_true = loop {
            if let Some(q) = twin.reach(&twin.random_q(&mut rng), &twin.plate.centres[0].unwrap()) {
                break q;
            }
        };
        // 1 deg off: several millimetres, above a 1 mm step limit.
        let q_d: Vec<f64> = q_true
            .iter()
            .enumerate()
            .map(|(k, v)| if k == 1 { v + 0.5f64.to_radians() } else { *v })
            .collect();
        let tight = CentringOptions {
            max_step_mm: 1.0,
            ..opts()
        };
        let e = centre(&robot, &ind, &q_d, &tight, &NoMonitor)
            .await
            .unwrap_err();
        assert!(matches!(e, CentringError::BallLost { .. }), "{e}");
        let budget = CentringOptions {
            max_iterations: 0,
            ..opts()
        };
        let e = centre(&robot, &ind, &q_d, &budget, &NoMonitor)
            .await
            .unwrap_err();
        assert!(
            matches!(e, CentringError::NotConverged { iterations: 0, .. }),
            "{e}"
        );
        // Far away from every ball: the indicators are out of range, a device fault.
        let e = centre(
            &robot,
            &ind,
            &[0.0, 0.0, 0.0, 0.0, 0.5, 0.0],
            &opts(),
            &NoMonitor,
        )
        .await
        .unwrap_err();
        assert!(
            matches!(e, CentringError::Device(DeviceError::Fault { .. })),
            "{e}"
        );
    }

    /// Indicators whose every reading is the one before it (one line always queued on the
    /// link): the first reading after a move is from before the move.
    struct Lagging {
        inner: FakeIndicators,
        queued: Mutex<Option<[f64; 3]>>,
    }

    impl Indicators for Lagging {
        fn read(&self) -> DeviceFuture<'_, [f64; 3]> {
            Box::pin(async move {
                let now = self.inner.read().await?;
                let mut q = self.queued.lock().map_err(|_| DeviceError::Fault {
                    device: "indicators".into(),
                    message: "poisoned".into(),
                })?;
                Ok(q.replace(now).unwrap_or(now))
            })
        }
    }

    /// A reading produced before the last move is never acted on: with a stale line
    /// before every fresh one, the loop makes the same moves to the same pose as with
    /// prompt indicators.
    #[tokio::test]
    async fn a_reading_from_before_the_move_is_not_acted_on() {
        let twin = SerialTwin::irb120(1);
        let mut rng = Rng::new(3);
        let centre_w = twin.plate.centres[0].unwrap();
        let q_true = loop {
            if let Some(q) = twin.reach(&twin.random_q(&mut rng), &centre_w) {
                break q;
            }
        };
        let q_d: Vec<f64> = q_true.iter().map(|v| v + 0.2f64.to_radians()).collect();
        let run = |lag: bool| {
            let cell: SharedCell = Arc::new(Mutex::new(SimulatedCell::new(twin.clone(), 4)));
            let q_d = q_d.clone();
            async move {
                let robot = FakeRobot(cell.clone());
                let prompt = FakeIndicators(cell);
                if lag {
                    let ind = Lagging {
                        inner: prompt,
                        queued: Mutex::new(None),
                    };
                    centre(&robot, &ind, &q_d, &opts(), &NoMonitor).await
                } else {
                    centre(&robot, &prompt, &q_d, &opts(), &NoMonitor).await
                }
            }
        };
        let a = run(false).await.unwrap();
        let b = run(true).await.unwrap();
        assert!(a.iterations >= 2, "{} moves", a.iterations);
        assert_eq!(a.iterations, b.iterations);
        assert_eq!(a.q, b.q);
        assert!((twin.true_tcp(&b.q) - centre_w).norm() < 0.012);
        // Readings that never agree (the arm keeps moving) stop the loop with a reason.
        let cell: SharedCell = Arc::new(Mutex::new(SimulatedCell::new(twin.clone(), 4)));
        struct Drifting(Mutex<f64>);
        impl Indicators for Drifting {
            fn read(&self) -> DeviceFuture<'_, [f64; 3]> {
                Box::pin(async move {
                    let mut v = self.0.lock().map_err(|_| DeviceError::Fault {
                        device: "indicators".into(),
                        message: "poisoned".into(),
                    })?;
                    *v += 0.005;
                    Ok([*v, 0.0, 0.0])
                })
            }
        }
        let e = centre(
            &FakeRobot(cell),
            &Drifting(Mutex::new(0.0)),
            &q_d,
            &opts(),
            &NoMonitor,
        )
        .await
        .unwrap_err();
        assert!(
            matches!(e, CentringError::NotSettled { readings: 8, .. }),
            "{e}"
        );
    }
}
