//! `MotionLimiter`: a decorator that enforces a cell's motion envelope (joint limits and the
//! largest joint step of one move) in the procedure, whatever the driver also checks.

use super::devices::{DeviceError, DeviceFuture, Robot};

/// The envelope of a cell.
#[derive(Debug, Clone, PartialEq)]
pub struct Envelope {
    /// [lower, upper] of each joint (rad).
    pub limits: Vec<[f64; 2]>,
    /// Largest change of any joint in one joint move (rad).
    pub max_joint_step: f64,
    /// Largest tool-frame move (mm).
    pub max_tool_step_mm: f64,
}

/// A robot whose moves are checked against an envelope before they are sent.
#[derive(Debug, Clone)]
pub struct MotionLimiter<R> {
    inner: R,
    envelope: Envelope,
}

impl<R: Robot> MotionLimiter<R> {
    /// Wrap `inner`.
    pub fn new(inner: R, envelope: Envelope) -> Self {
        Self { inner, envelope }
    }

    fn refuse(reason: String) -> DeviceError {
        DeviceError::Refused {
            device: "envelope".into(),
            reason,
        }
    }
}

impl<R: Robot> Robot for MotionLimiter<R> {
    fn joints(&self) -> DeviceFuture<'_, Vec<f64>> {
        self.inner.joints()
    }

    fn move_joints<'a>(&'a self, q: &'a [f64]) -> DeviceFuture<'a, ()> {
        Box::pin(async move {
            let env = &self.envelope;
            if q.len() != env.limits.len() {
                return Err(Self::refuse(format!(
                    "{} joint values for {} joints",
                    q.len(),
                    env.limits.len()
                )));
            }
            for (k, (v, l)) in q.iter().zip(&env.limits).enumerate() {
                if !(v.is_finite() && *v >= l[0] && *v <= l[1]) {
                    return Err(Self::refuse(format!(
                        "joint {} target {:.3} deg outside [{:.3}, {:.3}] deg",
                        k + 1,
                        v.to_degrees(),
                        l[0].to_degrees(),
                        l[1].to_degrees()
                    )));
                }
            }
            let now = self.inner.joints().await?;
            let step = now
                .iter()
                .zip(q)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            if step > env.max_joint_step {
                return Err(Self::refuse(format!(
                    "joint step {:.3} deg above the {:.3} deg limit",
                    step.to_degrees(),
                    env.max_joint_step.to_degrees()
                )));
            }
            self.inner.move_joints(q).await
        })
    }

    fn move_tool(&self, offset_mm: [f64; 3]) -> DeviceFuture<'_, ()> {
        Box::pin(async move {
            let n = offset_mm.iter().map(|v| v * v).sum::<f64>().sqrt();
            if !(n.is_finite() && n <= self.envelope.max_tool_step_mm) {
                return Err(Self::refuse(format!(
                    "tool move {n:.3} mm above the {} mm limit",
                    self.envelope.max_tool_step_mm
                )));
            }
            self.inner.move_tool(offset_mm).await
        })
    }
}
