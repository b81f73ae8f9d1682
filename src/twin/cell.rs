//! A simulated ball-centring cell: an IRB 120 whose controller moves with the nominal
//! kinematics while the physical arm follows the true model, a plate of 12.7 mm balls, and
//! three dial indicators on the flange device. Pure state in memory, driven step by step by
//! the device mocks and fakes.

use nalgebra::Vector3;

use super::SerialTwin;
use crate::geometry::Frame;
use crate::util::Rng;

/// Why the simulated cell refused a command or a reading.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CellError {
    /// A joint target outside the limits.
    #[error("joint {joint} target {value_deg:.3} deg is outside the limits")]
    Limit {
        /// 1-based joint.
        joint: usize,
        /// Requested value.
        value_deg: f64,
    },
    /// The controller found no joint solution for a Cartesian move.
    #[error("no joint solution for the requested tool move")]
    Unreachable,
    /// An indicator is beyond its travel: no ball under the device.
    #[error("indicator {indicator} out of range ({value_mm:.3} mm): no ball under the device")]
    OutOfRange {
        /// 1-based indicator.
        indicator: usize,
        /// Reading.
        value_mm: f64,
    },
}

/// Range of each indicator around its zero (mm): half of the 12.7 mm travel.
pub const INDICATOR_HALF_RANGE_MM: f64 = 6.35;

/// The cell's state: the twin and the current joint values (rad).
#[derive(Debug, Clone)]
pub struct SimulatedCell {
    /// The twin (nominal and true models, plate).
    pub twin: SerialTwin,
    q: Vec<f64>,
    seed: u64,
    /// Standard deviation of the indicator noise (mm).
    pub indicator_noise_mm: f64,
}

impl SimulatedCell {
    /// A cell at rest at a comfortable home configuration.
    pub fn new(twin: SerialTwin, seed: u64) -> Self {
        let q = [0.0, 0.0, 0.0, 0.0, 30.0, 0.0]
            .iter()
            .map(|v: &f64| v.to_radians())
            .collect();
        Self {
            twin,
            q,
            seed,
            indicator_noise_mm: 0.0005,
        }
    }

    /// Current joint values (rad), as the encoders report them.
    pub fn joints(&self) -> Vec<f64> {
        self.q.clone()
    }

    /// Move to joint values (rad).
    pub fn move_joints(&mut self, q: &[f64]) -> Result<(), CellError> {
        if let Some((j, v, _)) = self.twin.nominal.limit_violation(q) {
            return Err(CellError::Limit {
                joint: j + 1,
                value_deg: v.to_degrees(),
            });
        }
        self.q = q.to_vec();
        Ok(())
    }

    /// Move the TCP by `offset_mm` along the tool axes, keeping the tool orientation, as the
    /// controller computes it: with the nominal model.
    pub fn move_tool(&mut self, offset_mm: [f64; 3]) -> Result<(), CellError> {
        let q = self.tool_move_target(&self.q, offset_mm)?;
        self.move_joints(&q)
    }

    /// The joint values (rad) a tool-frame move of `offset_mm` from `q` leads to, as the
    /// controller computes them with the nominal model.
    pub fn tool_move_target(&self, q: &[f64], offset_mm: [f64; 3]) -> Result<Vec<f64>, CellError> {
        let nominal = &self.twin.nominal;
        let now = nominal.tcp(q, None);
        let target = Frame {
            r: now.r,
            p: now.apply(&Vector3::from(offset_mm)),
        };
        pose_ik(nominal, q, &target).ok_or(CellError::Unreachable)
    }

    /// The three indicator readings (mm): the ball centre relative to the true TCP along the
    /// true tool axes, for the ball nearest the device, saturated at the end of travel. No
    /// ball within reach of the stems gives a [`CellError::OutOfRange`].
    pub fn read_indicators(&mut self) -> Result<[f64; 3], CellError> {
        let v = self.indicator_values().ok_or(CellError::OutOfRange {
            indicator: 1,
            value_mm: 3.0 * INDICATOR_HALF_RANGE_MM,
        })?;
        for (k, x) in v.iter().enumerate() {
            if x.abs() > INDICATOR_HALF_RANGE_MM {
                return Err(CellError::OutOfRange {
                    indicator: k + 1,
                    value_mm: *x,
                });
            }
        }
        Ok(v)
    }

    /// The indicator offsets (mm, 0.001 mm resolution) before saturation, with noise; `None`
    /// when no ball is within reach of the stems.
    pub fn indicator_values(&self) -> Option<[f64; 3]> {
        let tcp = {
            let tau = self.twin.truth.static_torques(&self.q);
            self.twin.truth.tcp(&self.q, Some(&tau))
        };
        let nearest = self
            .twin
            .plate
            .centres
            .iter()
            .flatten()
            .min_by(|a, b| (*a - tcp.p).norm().total_cmp(&(*b - tcp.p).norm()))
            .copied()?;
        let r = tcp.r.transpose() * (nearest - tcp.p);
        if r.norm() > 3.0 * INDICATOR_HALF_RANGE_MM {
            return None;
        }
        // Noise is a function of the arm's state, so the same pose always reads the same:
        // a resumed campaign measures exactly what an uninterrupted one would.
        let key = self.q.iter().fold(self.seed, |h, v| {
            (h ^ v.to_bits()).wrapping_mul(0x100_0000_01B3)
        });
        let mut rng = Rng::new(key);
        let mut out = [0.0; 3];
        for k in 0..3 {
            let v = r[k] + self.indicator_noise_mm * rng.normal();
            out[k] = (v * 1000.0).round() / 1000.0;
        }
        Some(out)
    }
}

pub use crate::model::ik::reach_pose as pose_ik;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_ik_reaches_a_pose_of_another_configuration() {
        let twin = SerialTwin::irb120(1);
        let q1 = [0.3, 0.2, -0.1, 0.5, 0.8, -0.4];
        let target = twin.nominal.tcp(&q1, None);
        let q0: Vec<f64> = q1.iter().map(|v| v + 0.05).collect();
        let q = pose_ik(&twin.nominal, &q0, &target).unwrap();
        let got = twin.nominal.tcp(&q, None);
        assert!((got.p - target.p).norm() < 1e-8 && got.angle_to(&target) < 1e-10);
    }

    #[test]
    fn tool_moves_use_the_nominal_model_so_the_true_tcp_moves_slightly_differently() {
        let twin = SerialTwin::irb120(1);
        let mut cell = SimulatedCell::new(twin.clone(), 1);
        cell.move_joints(&[0.3, 0.2, -0.1, 0.5, 0.8, -0.4]).unwrap();
        let before = twin.true_tcp(&cell.joints());
        cell.move_tool([1.0, 0.0, 0.0]).unwrap();
        let moved = (twin.true_tcp(&cell.joints()) - before).norm();
        // Commanded 1 mm; the true arm moves 1 mm to within the model error (1e-3 relative).
        assert!(
            (moved - 1.0).abs() < 5e-3 && (moved - 1.0).abs() > 0.0,
            "{moved}"
        );
    }
}
