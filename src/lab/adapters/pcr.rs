//! The 3-PF cell's driver actors behind the procedure traits: SmarAct stages (any
//! [`Stage`] backend, positions in pm) as [`LinearStages`] in metres, the microscope's
//! `calibd-pose/1` driver as a [`PoseSensor`].

use std::sync::Arc;

use calibd_drivers::link::BoxFuture;
use calibd_drivers::microscope::MicroscopeHandle;
use calibd_drivers::{DriverError, Stage, StageStatus};

use super::serial::device_error;
use crate::procedures::{DeviceError, DeviceFuture, LinearStages, PoseSensor};

/// Picometres per metre.
const PM_PER_M: f64 = 1e12;

/// Three channels of one stage controller as the robot's joints q1..q3.
pub struct SmaractStages {
    stage: Arc<dyn Stage>,
    channels: [u8; 3],
    name: String,
    envelope: Option<StageEnvelope>,
}

/// Where the stages may go: each joint's travel (m) and the largest move of one command
/// (m); a target outside is refused before a byte leaves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageEnvelope {
    /// [lower, upper] of q1..q3 (m).
    pub limits_m: [[f64; 2]; 3],
    /// Largest change of any joint in one move (m).
    pub max_step_m: f64,
}

/// Three single-channel controllers (CiA 402 drives, one per node) as one controller whose
/// channel k is drive k's channel 0.
pub struct PerJoint(pub [Arc<dyn Stage>; 3]);

impl std::fmt::Debug for PerJoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PerJoint").finish_non_exhaustive()
    }
}

impl PerJoint {
    fn drive(&self, ch: u8) -> Result<&Arc<dyn Stage>, DriverError> {
        self.0
            .get(usize::from(ch))
            .ok_or_else(|| DriverError::InvalidRequest {
                device: "can",
                detail: format!("joint {ch} of 3"),
            })
    }
}

impl Stage for PerJoint {
    fn move_absolute(&self, ch: u8, pos_pm: i64) -> BoxFuture<'_, Result<i64, DriverError>> {
        Box::pin(async move { self.drive(ch)?.move_absolute(0, pos_pm).await })
    }
    fn position(&self, ch: u8) -> BoxFuture<'_, Result<i64, DriverError>> {
        Box::pin(async move { self.drive(ch)?.position(0).await })
    }
    fn status(&self, ch: u8) -> BoxFuture<'_, Result<StageStatus, DriverError>> {
        Box::pin(async move { self.drive(ch)?.status(0).await })
    }
    fn reference(&self, ch: u8) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(async move { self.drive(ch)?.reference(0).await })
    }
}

impl std::fmt::Debug for SmaractStages {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SmaractStages")
            .field("name", &self.name)
            .field("channels", &self.channels)
            .finish()
    }
}

impl SmaractStages {
    /// Joint k is channel `channels[k]` of `stage`; `name` is the device name in errors.
    pub fn new(stage: Arc<dyn Stage>, channels: [u8; 3], name: impl Into<String>) -> Self {
        Self {
            stage,
            channels,
            name: name.into(),
            envelope: None,
        }
    }

    /// Refuse moves outside `envelope`.
    pub fn within(mut self, envelope: StageEnvelope) -> Self {
        self.envelope = Some(envelope);
        self
    }

    /// Why a move from `now` to `q` (m) leaves the envelope, if it does.
    fn refused(&self, now: &[f64; 3], q: &[f64; 3]) -> Option<String> {
        let e = self.envelope.as_ref()?;
        (0..3).find_map(|k| {
            let [lo, hi] = e.limits_m[k];
            if !(q[k] >= lo && q[k] <= hi) {
                Some(format!(
                    "q{} = {} m outside the travel [{lo}, {hi}] m",
                    k + 1,
                    q[k]
                ))
            } else if (q[k] - now[k]).abs() > e.max_step_m {
                Some(format!(
                    "q{} moves {} m, above the {} m step limit",
                    k + 1,
                    (q[k] - now[k]).abs(),
                    e.max_step_m
                ))
            } else {
                None
            }
        })
    }
}

fn to_pm(device: &str, q: f64) -> Result<i64, DeviceError> {
    let v = q * PM_PER_M;
    if !(v.is_finite() && v.abs() < 9e18) {
        return Err(DeviceError::Refused {
            device: device.into(),
            reason: format!("position {q} m is not a finite stage position"),
        });
    }
    Ok(v.round() as i64)
}

impl LinearStages for SmaractStages {
    fn move_to<'a>(&'a self, q: &'a [f64; 3]) -> DeviceFuture<'a, [f64; 3]> {
        Box::pin(async move {
            if self.envelope.is_some() {
                let now = self.positions().await?;
                if let Some(reason) = self.refused(&now, q) {
                    return Err(DeviceError::Refused {
                        device: self.name.clone(),
                        reason,
                    });
                }
            }
            let t: [i64; 3] = [
                to_pm(&self.name, q[0])?,
                to_pm(&self.name, q[1])?,
                to_pm(&self.name, q[2])?,
            ];
            let c = self.channels;
            // The three moves run together; each returns once its channel stopped.
            let (a, b, d) = tokio::join!(
                self.stage.move_absolute(c[0], t[0]),
                self.stage.move_absolute(c[1], t[1]),
                self.stage.move_absolute(c[2], t[2]),
            );
            let err = |e| device_error(&self.name, e);
            Ok([
                a.map_err(err)? as f64 / PM_PER_M,
                b.map_err(err)? as f64 / PM_PER_M,
                d.map_err(err)? as f64 / PM_PER_M,
            ])
        })
    }

    fn positions(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async move {
            let mut out = [0.0; 3];
            for (o, &c) in out.iter_mut().zip(&self.channels) {
                let p = self
                    .stage
                    .position(c)
                    .await
                    .map_err(|e| device_error(&self.name, e))?;
                *o = p as f64 / PM_PER_M;
            }
            Ok(out)
        })
    }
}

named_adapter!(
    /// The microscope over `calibd-pose/1`.
    Microscope,
    MicroscopeHandle
);

impl PoseSensor for Microscope {
    fn read_pose(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async move {
            let p = self
                .handle
                .pose()
                .await
                .map_err(|e| device_error(&self.name, e))?;
            Ok([p.x_m, p.y_m, p.theta_rad])
        })
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use super::*;

    /// A stage controller that records the moves it receives.
    #[derive(Default)]
    struct Recording {
        at_pm: Mutex<[i64; 3]>,
        moves: Mutex<Vec<(u8, i64)>>,
    }

    impl Stage for Recording {
        fn move_absolute(&self, ch: u8, pos_pm: i64) -> BoxFuture<'_, Result<i64, DriverError>> {
            Box::pin(async move {
                self.moves.lock().expect("lock").push((ch, pos_pm));
                self.at_pm.lock().expect("lock")[usize::from(ch)] = pos_pm;
                Ok(pos_pm)
            })
        }
        fn position(&self, ch: u8) -> BoxFuture<'_, Result<i64, DriverError>> {
            Box::pin(async move { Ok(self.at_pm.lock().expect("lock")[usize::from(ch)]) })
        }
        fn status(&self, _: u8) -> BoxFuture<'_, Result<StageStatus, DriverError>> {
            Box::pin(async move { Ok(StageStatus::default()) })
        }
        fn reference(&self, _: u8) -> BoxFuture<'_, Result<(), DriverError>> {
            Box::pin(async move { Ok(()) })
        }
    }

    #[test]
    fn a_target_outside_the_travel_or_too_far_is_refused_before_a_command_leaves() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .expect("runtime");
        let rec = Arc::new(Recording::default());
        let stages =
            SmaractStages::new(rec.clone(), [0, 1, 2], "cell.stages at x").within(StageEnvelope {
                limits_m: [[-0.01, 0.01]; 3],
                max_step_m: 0.002,
            });
        let e = rt
            .block_on(stages.move_to(&[0.0, 0.011, 0.0]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("q2") && e.contains("outside the travel"), "{e}");
        let e = rt
            .block_on(stages.move_to(&[0.003, 0.0, 0.0]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("q1") && e.contains("step limit"), "{e}");
        assert!(
            rec.moves.lock().expect("lock").is_empty(),
            "nothing was sent"
        );
        let at = rt
            .block_on(stages.move_to(&[0.001, -0.002, 0.0]))
            .expect("inside");
        assert_eq!(at, [0.001, -0.002, 0.0]);
        assert_eq!(rec.moves.lock().expect("lock").len(), 3);
    }
}
