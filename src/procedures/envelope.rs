//! `MotionLimiter`: a decorator that enforces a cell's motion envelope (joint limits, the
//! largest joint step and tool move of one command, and a box the TCP must stay in) before
//! a command reaches the device, whatever the driver also checks.

use std::sync::Arc;

use nalgebra::Vector3;

use super::devices::{DeviceError, DeviceFuture, Robot};
use crate::model::Chain;

/// The envelope of a cell.
#[derive(Debug, Clone, PartialEq)]
pub struct Envelope {
    /// [lower, upper] of each joint (rad).
    pub limits: Vec<[f64; 2]>,
    /// Largest change of any joint in one joint move (rad).
    pub max_joint_step: f64,
    /// Largest tool-frame move (mm).
    pub max_tool_step_mm: f64,
    /// Box the TCP must stay in, if the cell has one.
    pub workspace_mm: Option<Workspace>,
}

/// A box the TCP must stay in (mm, the robot's base frame {0}: the controller's coordinates,
/// whatever world frame the model is calibrated in), with the model that places the TCP.
#[derive(Debug, Clone)]
pub struct Workspace {
    /// Lower corner (mm).
    pub min_mm: [f64; 3],
    /// Upper corner (mm).
    pub max_mm: [f64; 3],
    /// The cell's model (nominal: the envelope is a safety margin, not a measurement).
    pub chain: Arc<Chain>,
}

impl PartialEq for Workspace {
    fn eq(&self, o: &Self) -> bool {
        self.min_mm == o.min_mm && self.max_mm == o.max_mm
    }
}

impl Workspace {
    /// The TCP position (mm) and rotation in the robot's base frame at joints `q` (rad).
    fn tcp_mm(&self, q: &[f64]) -> (Vector3<f64>, nalgebra::Matrix3<f64>) {
        let f = self.chain.tcp_in_base(q, None);
        let scale = if self.chain.units.mm { 1.0 } else { 1000.0 };
        (f.p * scale, f.r)
    }

    /// Why `p` (mm) is outside the box, if it is.
    fn outside(&self, p: &Vector3<f64>) -> Option<String> {
        let axes = ["x", "y", "z"];
        (0..3).find_map(|k| {
            (!(p[k] >= self.min_mm[k] && p[k] <= self.max_mm[k])).then(|| {
                format!(
                    "TCP {} = {:.1} mm outside the workspace [{}, {}] mm",
                    axes[k], p[k], self.min_mm[k], self.max_mm[k]
                )
            })
        })
    }
}

impl Envelope {
    /// Why joints `q` (rad) are outside the envelope (count, joint limits, workspace box),
    /// if they are.
    pub fn outside(&self, q: &[f64]) -> Option<String> {
        if q.len() != self.limits.len() {
            return Some(format!(
                "{} joint values for {} joints",
                q.len(),
                self.limits.len()
            ));
        }
        for (k, (v, l)) in q.iter().zip(&self.limits).enumerate() {
            if !(v.is_finite() && *v >= l[0] && *v <= l[1]) {
                return Some(format!(
                    "joint {} target {:.3} deg outside [{:.3}, {:.3}] deg",
                    k + 1,
                    v.to_degrees(),
                    l[0].to_degrees(),
                    l[1].to_degrees()
                ));
            }
        }
        self.workspace_mm
            .as_ref()
            .and_then(|w| w.outside(&w.tcp_mm(q).0))
    }

    /// The joint moves of a move from `from` to `to` (rad) split as the approach splits it:
    /// straight in joint space, in steps of at most 0.99 `max_joint_step`, the last on `to`.
    pub fn steps(&self, from: &[f64], to: &[f64]) -> usize {
        let d = from
            .iter()
            .zip(to)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let step = 0.99 * self.max_joint_step;
        if !(step > 0.0) || d <= step {
            1
        } else {
            (d / step).ceil() as usize
        }
    }

    /// Why the straight joint-space path from `from` to `to` (rad) leaves the envelope, if
    /// it does: the joint box is convex, so its ends decide; the TCP box is checked at
    /// points at most 1 deg of the largest joint change apart.
    pub fn path_outside(&self, from: &[f64], to: &[f64]) -> Option<String> {
        if let Some(why) = self.outside(from).or_else(|| self.outside(to)) {
            return Some(why);
        }
        let w = self.workspace_mm.as_ref()?;
        let d = from
            .iter()
            .zip(to)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let n = (d / 1f64.to_radians()).ceil().max(1.0) as usize;
        (1..n).find_map(|i| {
            let s = i as f64 / n as f64;
            let q: Vec<f64> = from.iter().zip(to).map(|(a, b)| a + s * (b - a)).collect();
            w.outside(&w.tcp_mm(&q).0)
        })
    }
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
            if let Some(why) = env.outside(q) {
                return Err(Self::refuse(why));
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
            if let Some(w) = &self.envelope.workspace_mm {
                let q = self.inner.joints().await?;
                let (p, r) = w.tcp_mm(&q);
                let to = p + r * Vector3::from(offset_mm);
                if let Some(why) = w.outside(&to) {
                    return Err(Self::refuse(why));
                }
            }
            self.inner.move_tool(offset_mm).await
        })
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use super::*;
    use crate::procedures::fakes::FakeRobot;
    use crate::twin::SerialTwin;
    use crate::twin::cell::SimulatedCell;

    fn block_on<F: std::future::Future>(f: F) -> F::Output {
        tokio::runtime::Builder::new_current_thread()
            .build()
            .expect("runtime")
            .block_on(f)
    }

    /// The twin's arm behind an envelope whose workspace is a box around the TCP at `q0`.
    fn limited(half_mm: f64) -> (MotionLimiter<FakeRobot>, FakeRobot, Vec<f64>, Arc<Chain>) {
        let twin = SerialTwin::irb120(7);
        let chain = Arc::new(twin.nominal.clone());
        let cell = Arc::new(Mutex::new(SimulatedCell::new(twin, 1)));
        let robot = FakeRobot(cell);
        let q0 = vec![0.1, 0.3, 0.2, 0.0, 0.8, 0.0];
        block_on(robot.move_joints(&q0)).expect("start pose");
        let p = chain.tcp_in_base(&q0, None).p * if chain.units.mm { 1.0 } else { 1000.0 };
        let envelope = Envelope {
            limits: vec![[-3.0, 3.0]; 6],
            max_joint_step: 0.5,
            max_tool_step_mm: 5.0,
            workspace_mm: Some(Workspace {
                min_mm: [p.x - half_mm, p.y - half_mm, p.z - half_mm],
                max_mm: [p.x + half_mm, p.y + half_mm, p.z + half_mm],
                chain: chain.clone(),
            }),
        };
        (
            MotionLimiter::new(robot.clone(), envelope),
            robot,
            q0,
            chain,
        )
    }

    #[test]
    fn a_move_that_takes_the_tcp_out_of_the_workspace_is_refused_before_it_is_sent() {
        let (lim, robot, q0, chain) = limited(10.0);
        // 0.1 rad of joint 1 swings the TCP by tens of millimetres: outside the 10 mm box.
        let mut q = q0.clone();
        q[0] += 0.1;
        let moved = (chain.tcp(&q, None).p - chain.tcp(&q0, None).p).norm();
        assert!(moved > 20.0, "{moved}");
        let e = block_on(lim.move_joints(&q)).unwrap_err().to_string();
        assert!(e.contains("outside the workspace"), "{e}");
        assert_eq!(
            block_on(robot.joints()).expect("joints"),
            q0,
            "nothing moved"
        );
        // A small move inside the box goes through.
        let mut q = q0.clone();
        q[5] += 0.05;
        block_on(lim.move_joints(&q)).expect("inside the box");
        assert_eq!(block_on(robot.joints()).expect("joints"), q);
        // A 4 mm tool step from the box's centre stays inside a 10 mm box; a second box of
        // 3 mm refuses it.
        block_on(lim.move_tool([0.0, 0.0, 4.0])).expect("inside");
        let (lim, robot, q0, _) = limited(3.0);
        let e = block_on(lim.move_tool([0.0, 0.0, 4.0]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("outside the workspace"), "{e}");
        assert_eq!(block_on(robot.joints()).expect("joints"), q0);
    }
}
