//! [`Lumping::Bodies`]: the gravity torque about each axis of an elastic joint as a sum over
//! the links it carries, `sum_b F_b(q) . h_b`, with `h_b = (w c_b, w)` a link's unknown
//! weight moment (N*m, its frame) and weight (N) and `F_b` the factors the kinematics give
//! (computed once per sample from the starting model, as the gravity directions are):
//! `F_b = (R_b^T (u x a), (o_b - o_j) . (u x a))` for the unit gravity direction `u`, the
//! joint axis `a` (z, x or y of the joint frame) through `o_j`, and the link frame `(R_b, o_b)`.
//! The deflection about the axis is its compliance times that torque.

use nalgebra::Vector3;

use super::eval::RowFrames;
use super::{ElasticTree, Lumping};

/// Load factors of one elastic row: for each revolute row `b` it carries, the four factors of
/// `h_b` in the torque about the joint's z, x and y axes.
pub type Loads = Vec<(usize, [[f64; 4]; 3])>;

impl ElasticTree {
    /// Load factors of every row from rigid frames (empty for rows without elasticity).
    pub(super) fn loads(&self, frames: &[RowFrames]) -> Vec<Loads> {
        (0..self.rows.len())
            .map(|j| {
                let elastic = self.has_joint_elasticity(j) || self.has_lateral_elasticity(j);
                if self.lumping != Lumping::Bodies || !elastic {
                    return Vec::new();
                }
                let jf = &frames[j].joint;
                let axes = [
                    jf.r * Vector3::z(),
                    jf.r * Vector3::x(),
                    jf.r * Vector3::y(),
                ];
                let ga = axes.map(|a| self.gravity_root.cross(&a));
                self.subtree[j]
                    .iter()
                    .map(|&b| {
                        let fb = &frames[b].out;
                        let lever = fb.p - jf.p;
                        let f = ga.map(|v| {
                            let r = fb.r.transpose() * v;
                            [r.x, r.y, r.z, lever.dot(&v)]
                        });
                        (b, f)
                    })
                    .collect()
            })
            .collect()
    }

    /// Gravity torques (N*m) about z, x, y of a joint with load factors `loads`.
    pub(super) fn torques(&self, loads: &Loads) -> [f64; 3] {
        let mut t = [0.0; 3];
        for (b, f) in loads {
            let h = &self.weights[*b];
            for (ta, fa) in t.iter_mut().zip(f) {
                *ta += fa.iter().zip(h).map(|(x, y)| x * y).sum::<f64>();
            }
        }
        t
    }

    /// Deflection `[dz, dx, dy]` (rad) of row `j`.
    pub(super) fn body_deflection(&self, j: usize, loads: &Loads) -> [f64; 3] {
        let t = self.torques(loads);
        let c = &self.compliance[j];
        [c[0] * t[0], c[1] * t[1], c[2] * t[2]]
    }
}
