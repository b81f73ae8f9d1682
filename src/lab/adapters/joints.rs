//! A humanoid's joint interface (`calibd-joints/1` driver) as a [`JointRobot`]: a posture
//! goes to the robot as moves within the cell's largest joint step (a longer one is split,
//! as the TriCal approach moves are), each timed by its largest joint change and the cell's
//! joint speed; the robot's refusals (unknown joint, out of limits, bad request) are
//! refusals, its other errors faults.

use std::collections::BTreeMap;
use std::time::Duration;

use calibd_drivers::DriverError;
use calibd_drivers::joints::{ErrorCode, JointsHandle};

use super::serial::device_error;
use crate::procedures::{DeviceError, DeviceFuture, JointRobot};

/// A robot reached over `calibd-joints/1`.
#[derive(Debug, Clone)]
pub struct JointInterface {
    handle: JointsHandle,
    name: String,
    joints: Vec<String>,
    speed_rad_s: f64,
    /// The cell's envelope: [lower, upper] (rad) of each of `joints`, largest step (rad).
    envelope: Option<(Vec<[f64; 2]>, f64)>,
}

impl JointInterface {
    /// Wrap a driver handle; `joints` are the joints this interface drives (in the order of
    /// [`JointRobot::joints`]), `speed_rad_s` the mean speed (rad/s) of the joint that moves
    /// most in a move, `name` the device name in errors.
    pub fn new(
        handle: JointsHandle,
        joints: Vec<String>,
        speed_rad_s: f64,
        name: impl Into<String>,
    ) -> Self {
        Self {
            handle,
            name: name.into(),
            joints,
            speed_rad_s,
            envelope: None,
        }
    }

    /// Refuse, before a byte leaves, a posture outside `limits` (rad, one pair per joint of
    /// the interface), and split a move of any joint by more than `max_step_rad` into steps.
    pub fn within(mut self, limits: Vec<[f64; 2]>, max_step_rad: f64) -> Self {
        self.envelope = Some((limits, max_step_rad));
        self
    }

    /// Why `target` leaves the envelope's joint limits, if it does.
    fn outside(&self, target: &BTreeMap<String, f64>) -> Option<String> {
        let (limits, _) = self.envelope.as_ref()?;
        target.iter().find_map(|(name, v)| {
            let k = self.joints.iter().position(|j| j == name);
            let [lo, hi] = k.and_then(|k| limits.get(k))?;
            (!(v >= lo && v <= hi))
                .then(|| format!("{name} = {v:.4} rad outside [{lo:.4}, {hi:.4}] rad"))
        })
    }

    /// The postures of the move from `now` to `target`: straight in joint space, in steps of
    /// at most 0.99 of the envelope's largest step (one step without an envelope).
    fn steps(
        &self,
        now: &BTreeMap<String, f64>,
        target: &BTreeMap<String, f64>,
    ) -> Vec<BTreeMap<String, f64>> {
        let travel = target
            .iter()
            .map(|(k, v)| now.get(k).map_or(0.0, |q| (v - q).abs()))
            .fold(0.0, f64::max);
        let step = self.envelope.as_ref().map_or(f64::INFINITY, |e| 0.99 * e.1);
        let n = if step > 0.0 && travel > step {
            (travel / step).ceil() as usize
        } else {
            1
        };
        (1..=n)
            .map(|i| {
                let s = i as f64 / n as f64;
                target
                    .iter()
                    .map(|(k, v)| {
                        let q = now.get(k).map_or(*v, |q| q + s * (v - q));
                        (k.clone(), if i == n { *v } else { q })
                    })
                    .collect()
            })
            .collect()
    }

    fn err(&self, e: DriverError) -> DeviceError {
        let refused = [
            ErrorCode::UnknownJoint,
            ErrorCode::OutOfLimits,
            ErrorCode::BadRequest,
        ]
        .map(|c| c.number());
        match e {
            DriverError::Device { code, message, .. } if refused.contains(&code) => {
                DeviceError::Refused {
                    device: self.name.clone(),
                    reason: message,
                }
            }
            e => device_error(&self.name, e),
        }
    }

    /// The move's duration: the largest joint change over the speed.
    fn duration(
        &self,
        now: &BTreeMap<String, f64>,
        target: &BTreeMap<String, f64>,
    ) -> Result<Duration, DeviceError> {
        let refuse = |reason: String| DeviceError::Refused {
            device: self.name.clone(),
            reason,
        };
        if !(self.speed_rad_s.is_finite() && self.speed_rad_s > 0.0) {
            return Err(refuse(format!(
                "joint speed {} rad/s is not a positive number",
                self.speed_rad_s
            )));
        }
        let travel = target
            .iter()
            .map(|(k, v)| now.get(k).map_or(0.0, |q| (v - q).abs()))
            .fold(0.0, f64::max);
        Duration::try_from_secs_f64(travel / self.speed_rad_s)
            .map_err(|_| refuse(format!("a move of {travel} rad has no finite duration")))
    }
}

impl JointRobot for JointInterface {
    fn joint_names(&self) -> Vec<String> {
        self.joints.clone()
    }

    fn joints(&self) -> DeviceFuture<'_, Vec<f64>> {
        Box::pin(async move {
            let r = self.handle.read().await.map_err(|e| self.err(e))?;
            self.joints
                .iter()
                .map(|n| {
                    r.positions_rad
                        .get(n)
                        .copied()
                        .ok_or_else(|| DeviceError::Protocol {
                            device: self.name.clone(),
                            message: format!("the robot reports no position of {n}"),
                        })
                })
                .collect()
        })
    }

    fn move_to<'a>(&'a self, posture: &'a [(String, f64)]) -> DeviceFuture<'a, ()> {
        Box::pin(async move {
            let target: BTreeMap<String, f64> = posture.iter().cloned().collect();
            if let Some(reason) = self.outside(&target) {
                return Err(DeviceError::Refused {
                    device: self.name.clone(),
                    reason,
                });
            }
            let mut now = self
                .handle
                .read()
                .await
                .map_err(|e| self.err(e))?
                .positions_rad;
            for step in self.steps(&now, &target) {
                let duration = self.duration(&now, &step)?;
                tracing::debug!(
                    device = %self.name,
                    joints = step.len(),
                    duration_s = duration.as_secs_f64(),
                    "move"
                );
                self.handle
                    .move_to(step.clone(), duration)
                    .await
                    .map_err(|e| self.err(e))?;
                now.extend(step);
            }
            Ok(())
        })
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use calibd_drivers::TcpConnector;
    use calibd_drivers::joints::JointsConfig;
    use calibd_drivers::joints::mock::{JointModel, Linear, handler_with};
    use calibd_drivers::mock::{Faults, start_with};

    use super::*;

    #[tokio::test]
    async fn postures_move_at_the_speed_and_refusals_are_refusals() {
        let model: Arc<Mutex<dyn JointModel>> = Arc::new(Mutex::new(Linear::demo()));
        let m = start_with("127.0.0.1:0", handler_with(model, Faults::default()))
            .await
            .expect("mock");
        let h = JointsHandle::connect(TcpConnector::new(m.addr.clone()), JointsConfig::default());
        let names = vec!["joint_3".to_string(), "joint_1".to_string()];
        let r = JointInterface::new(h, names.clone(), 5.0, "arm.joints");
        assert_eq!(r.joint_names(), names);
        let t0 = std::time::Instant::now();
        // joint_3 travels 1 rad at 5 rad/s: 0.2 s.
        r.move_to(&[("joint_3".into(), 1.0), ("joint_1".into(), -0.5)])
            .await
            .expect("move");
        let took = t0.elapsed().as_secs_f64();
        assert!((0.2..1.0).contains(&took), "{took} s");
        assert_eq!(r.joints().await.expect("joints"), vec![1.0, -0.5]);
        let e = r
            .move_to(&[("joint_2".into(), 9.0)])
            .await
            .expect_err("out of limits");
        assert!(
            matches!(&e, DeviceError::Refused { device, reason } if device == "arm.joints" && reason.contains("out_of_limits")),
            "{e}"
        );
        let e = r
            .move_to(&[("knee".into(), 0.0)])
            .await
            .expect_err("unknown joint");
        assert!(matches!(e, DeviceError::Refused { .. }), "{e}");
        // The cell's envelope refuses before the robot is asked: nothing moves.
        let fenced = JointInterface::new(r.handle.clone(), names.clone(), 5.0, "arm.joints")
            .within(vec![[-0.5, 0.9], [-1.0, 1.0]], 0.3);
        let e = fenced
            .move_to(&[("joint_3".into(), 0.95)])
            .await
            .expect_err("outside the cell's limits");
        assert!(e.to_string().contains("outside [-0.5000, 0.9000]"), "{e}");
        assert_eq!(r.joints().await.expect("joints"), vec![1.0, -0.5]);
        // A 0.5 rad move of joint_1 within a 0.3 rad step: two moves of 0.25 rad, each at
        // 5 rad/s (0.05 s), ending on the target.
        let planned = fenced.steps(
            &BTreeMap::from([("joint_3".to_string(), 0.4), ("joint_1".to_string(), -0.5)]),
            &BTreeMap::from([("joint_1".to_string(), 0.0)]),
        );
        assert_eq!(planned.len(), 2);
        assert!((planned[0]["joint_1"] + 0.25).abs() < 1e-12, "{planned:?}");
        fenced
            .move_to(&[("joint_3".into(), 0.4), ("joint_1".into(), 0.0)])
            .await
            .expect("a split move");
        assert_eq!(r.joints().await.expect("joints"), vec![0.4, 0.0]);
        let bad = JointInterface::new(r.handle.clone(), names, 0.0, "arm.joints");
        let e = bad
            .move_to(&[("joint_1".into(), 0.0)])
            .await
            .expect_err("no speed");
        assert!(matches!(e, DeviceError::Refused { .. }), "{e}");
        m.stop().await;
    }
}
