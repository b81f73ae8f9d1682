//! Compensation: the joints that put the TCP of a calibrated serial model (geometry, beta,
//! joint compliance under gravity) on a target pose. The closed form of the ideal arm
//! ([`Opw`]) gives the branches; the one nearest the reference joints is refined by
//! damped Newton steps on the full model, where the static torques are evaluated at the
//! joints themselves (`../shared/spec/serial-robot.md`).

use nalgebra::{Matrix6, Vector3, Vector6};

use super::chain::{Chain, joint_axis};
use super::opw::{NotOpw, Opw, nearest_turn};
use crate::geometry::Frame;

/// Outcome of one target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// The model reaches the target within the tolerances, inside the joint limits.
    Reached,
    /// The model reaches the target only with a joint beyond its limits.
    OutOfJointLimits,
    /// No joint values put the TCP on the target.
    OutOfReach,
    /// The answer is at (or the solver stalled near) a singular configuration.
    Singular,
}

impl Status {
    /// The numeric code of the main table's `status_code` column.
    pub fn code(self) -> f64 {
        match self {
            Status::Reached => 0.0,
            Status::OutOfJointLimits => 1.0,
            Status::OutOfReach => 2.0,
            Status::Singular => 3.0,
        }
    }

    /// The name used in results.
    pub fn name(self) -> &'static str {
        match self {
            Status::Reached => "reached",
            Status::OutOfJointLimits => "out_of_joint_limits",
            Status::OutOfReach => "out_of_reach",
            Status::Singular => "singular",
        }
    }
}

/// Tolerances and thresholds of the solver (internal units: model length unit, rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerances {
    /// A target is reached when the position residual is at most this.
    pub position: f64,
    /// ... and the orientation residual at most this (rad).
    pub angle: f64,
    /// Below this |sin| of the wrist or elbow angle the answer is singular.
    pub singular_sin: f64,
    /// Below this distance of the wrist centre from axis 1 the answer is singular.
    pub singular_shoulder: f64,
}

/// The answer for one target.
#[derive(Debug, Clone, PartialEq)]
pub struct Answer {
    /// Joint values (rad): the solution, or for an unreached target the closest approach.
    pub q: [f64; 6],
    /// Distance from the model's TCP at `q` to the target (model length unit).
    pub residual_position: f64,
    /// Angle between the model's TCP frame at `q` and the target (rad).
    pub residual_angle: f64,
    /// Outcome.
    pub status: Status,
    /// Why, for every status but `Reached` (empty then).
    pub reason: String,
}

/// The solver of one calibrated model.
#[derive(Debug, Clone)]
pub struct Compensator {
    chain: Chain,
    opw: Opw,
    tol: Tolerances,
    compliant: bool,
    limits: [Option<[f64; 2]>; 6],
}

/// Work buffers of one solve (reused across targets).
#[derive(Debug, Default)]
pub struct Scratch {
    frames: Vec<Frame>,
}

/// Newton iterations per branch.
const MAX_ITERATIONS: usize = 40;

impl Compensator {
    /// The solver of `chain` (a 6R MDH arm close to an OPW arm; wrist offsets up to
    /// `wrist_tol` are left to the Newton refinement).
    pub fn new(chain: Chain, tol: Tolerances, wrist_tol: f64) -> Result<Self, NotOpw> {
        let opw = Opw::of(&chain, wrist_tol)?;
        let compliant =
            chain.joints.iter().any(|j| j.compliance != 0.0) && !chain.masses.is_empty();
        let mut limits = [None; 6];
        for (l, j) in limits.iter_mut().zip(&chain.joints) {
            *l = j.limits;
        }
        Ok(Self {
            chain,
            opw,
            tol,
            compliant,
            limits,
        })
    }

    /// The model.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// The model's TCP at `q` with its static deflection (what `serial.fk` computes).
    pub fn tcp(&self, q: &[f64], s: &mut Scratch) -> Frame {
        self.frames(q, s);
        self.tcp_of(s)
    }

    /// Joint frames at `q` in {0} with the static torques at `q` (compliance off for the
    /// torques, as the model defines them), into `s.frames`.
    fn frames(&self, q: &[f64], s: &mut Scratch) {
        self.chain.joint_frames(q, None, &mut s.frames);
        if self.compliant {
            let tau = self.chain.torques_from_frames(&s.frames);
            self.chain.joint_frames(q, Some(&tau), &mut s.frames);
        }
    }

    fn tcp_of(&self, s: &Scratch) -> Frame {
        let last = s.frames.last().copied().unwrap_or_else(Frame::identity);
        self.chain
            .base_frame()
            .mul(&last)
            .mul(&self.chain.tool_frame())
    }

    /// The joints that put the TCP on `target` (in {W}), nearest `reference` (rad).
    pub fn solve(&self, target: &Frame, reference: &[f64; 6], s: &mut Scratch) -> Answer {
        let mut seeds = self.opw.solve(target, reference[3]);
        for q in seeds.iter_mut() {
            for k in 0..6 {
                q[k] = nearest_turn(q[k], reference[k], self.limits[k]);
            }
        }
        let dist = |q: &[f64; 6]| -> f64 {
            q.iter()
                .zip(reference)
                .map(|(a, b)| (a - b) * (a - b))
                .sum()
        };
        // Seeds inside the limits first, each group nearest the reference first.
        seeds.sort_by(|a, b| {
            let (ia, ib) = (self.inside(a), self.inside(b));
            ib.cmp(&ia).then(dist(a).total_cmp(&dist(b)))
        });
        let mut first_converged: Option<Answer> = None;
        for seed in &seeds {
            let a = self.refine(target, *seed, s);
            if a.status == Status::Reached || a.status == Status::Singular {
                // Near a singularity the ideal arm's branch can lie far from the model's
                // (the Newton moved a joint a long way): the Newton from the reference may
                // then find a solution nearer to it.
                let moved = a.q.iter().zip(seed).any(|(x, y)| (x - y).abs() > 0.05);
                if moved {
                    let b = self.refine(target, *reference, s);
                    let ok = b.status == Status::Reached || b.status == Status::Singular;
                    if ok && dist(&b.q) < dist(&a.q) {
                        return b;
                    }
                }
                return a;
            }
            if a.status == Status::OutOfJointLimits && first_converged.is_none() {
                first_converged = Some(a);
            }
        }
        if let Some(a) = first_converged {
            return a;
        }
        // No branch of the ideal arm, or none converged: the closest approach from the
        // reference (a calibrated arm may reach a little beyond the ideal one).
        let mut a = self.refine(target, *reference, s);
        if a.status == Status::OutOfReach && seeds.is_empty() {
            a.reason = format!(
                "out of reach: the closest pose the model reaches is {:.6} mm and {:.6} deg away",
                a.residual_position / self.mm(),
                a.residual_angle.to_degrees()
            );
        }
        a
    }

    /// Model length units per millimetre.
    fn mm(&self) -> f64 {
        1e-3 / self.chain.units.metre()
    }

    fn inside(&self, q: &[f64; 6]) -> bool {
        self.chain.limit_violation(q).is_none()
    }

    /// Damped Newton from `q` on the full model; the answer classified.
    pub fn refine(&self, target: &Frame, mut q: [f64; 6], s: &mut Scratch) -> Answer {
        let (mut e, mut tcp) = self.error(target, &q, s);
        let mut cost = weighted(&e, self.weight());
        let mut lambda = 1e-12;
        for _ in 0..MAX_ITERATIONS {
            let (p, w) = (e.fixed_rows::<3>(0).norm(), e.fixed_rows::<3>(3).norm());
            if p <= self.tol.position * 1e-3 && w <= self.tol.angle * 1e-3 {
                break;
            }
            let j = self.jacobian(&tcp, s);
            let wt = self.weight();
            let mut jw = j;
            for r in 3..6 {
                jw.row_mut(r).scale_mut(wt);
            }
            let mut ew = e;
            ew.fixed_rows_mut::<3>(3).scale_mut(wt);
            let jtj = jw.transpose() * jw;
            let g = jw.transpose() * ew;
            let mut improved = false;
            for _ in 0..12 {
                let a = jtj + Matrix6::identity() * (lambda * (1.0 + jtj.diagonal().max()));
                let Some(dq) = a.cholesky().map(|c| c.solve(&g)) else {
                    lambda *= 10.0;
                    continue;
                };
                let scale = (0.5 / dq.amax()).min(1.0);
                let mut qn = q;
                for k in 0..6 {
                    qn[k] += dq[k] * scale;
                }
                let (en, tn) = self.error(target, &qn, s);
                let cn = weighted(&en, wt);
                if cn < cost {
                    (q, e, tcp, cost) = (qn, en, tn, cn);
                    lambda = (lambda * 0.1).max(1e-15);
                    improved = true;
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        self.classify(target, q, &tcp)
    }

    /// Weight of an angle (rad) against a length in the least squares: 100 mm per rad in the
    /// model's length unit, so that a closest approach balances position and orientation.
    fn weight(&self) -> f64 {
        100.0 * self.mm()
    }

    /// Pose error (target minus model: position, then rotation vector in {W}) and the TCP.
    fn error(&self, target: &Frame, q: &[f64; 6], s: &mut Scratch) -> (Vector6<f64>, Frame) {
        let f = self.tcp(q, s);
        let dp = target.p - f.p;
        let w = rotation_vector(&(target.r * f.r.transpose()));
        (Vector6::new(dp.x, dp.y, dp.z, w.x, w.y, w.z), f)
    }

    /// Geometric Jacobian of the TCP in {W} from the frames in `s` (torques held: their
    /// change with q moves the TCP by compliance times a torque change, a second-order term
    /// that only slows the convergence down to linear with a tiny ratio).
    fn jacobian(&self, tcp: &Frame, s: &Scratch) -> Matrix6<f64> {
        let base = self.chain.base_frame();
        let mut j = Matrix6::zeros();
        for (k, &ji) in self.chain.actuated().iter().enumerate() {
            let f = base.mul(&s.frames[ji]);
            let z = f.r * joint_axis(&self.chain.joints[ji]);
            let v = z.cross(&(tcp.p - f.p));
            j.fixed_view_mut::<3, 1>(0, k).copy_from(&v);
            j.fixed_view_mut::<3, 1>(3, k).copy_from(&z);
        }
        j
    }

    /// The answer at `q`, where the model's TCP is `f`: residuals, limits, singularity.
    fn classify(&self, target: &Frame, q: [f64; 6], f: &Frame) -> Answer {
        let residual_position = (f.p - target.p).norm();
        // Not `Frame::angle_to`: its acos has a floor of ~1e-8 rad.
        let residual_angle = rotation_vector(&(target.r * f.r.transpose())).norm();
        let mut a = Answer {
            q,
            residual_position,
            residual_angle,
            status: Status::Reached,
            reason: String::new(),
        };
        let sing = self.opw.singularity(&q);
        let singular = sing.wrist < self.tol.singular_sin
            || sing.elbow < self.tol.singular_sin
            || sing.shoulder < self.tol.singular_shoulder;
        let what = if sing.wrist < self.tol.singular_sin {
            "wrist singularity (axes 4 and 6 aligned): joints 4 and 6 are not determined separately"
        } else if sing.elbow < self.tol.singular_sin {
            "elbow singularity (arm stretched or folded)"
        } else {
            "shoulder singularity (wrist centre on axis 1): joint 1 is not determined"
        };
        if residual_position > self.tol.position || residual_angle > self.tol.angle {
            if singular {
                a.status = Status::Singular;
                a.reason = format!(
                    "the solver stalled at a {what}; residual {:.6} mm, {:.6} deg",
                    residual_position / self.mm(),
                    residual_angle.to_degrees()
                );
            } else {
                a.status = Status::OutOfReach;
                a.reason = format!(
                    "out of reach: the closest pose the model reaches is {:.6} mm and {:.6} deg away",
                    residual_position / self.mm(),
                    residual_angle.to_degrees()
                );
            }
            return a;
        }
        if let Some((k, v, l)) = self.chain.limit_violation(&q) {
            a.status = Status::OutOfJointLimits;
            let to = self.chain.units.to_file(super::Quantity::Angle);
            a.reason = format!(
                "q{} = {:.4} is outside its limits [{}, {}] on every branch that reaches the target",
                k + 1,
                v * to,
                l[0] * to,
                l[1] * to
            );
            return a;
        }
        if singular {
            a.status = Status::Singular;
            a.reason = format!("reached at a {what}");
        }
        a
    }
}

/// Sum of squares with the rotation rows weighted by `w`.
fn weighted(e: &Vector6<f64>, w: f64) -> f64 {
    e.fixed_rows::<3>(0).norm_squared() + e.fixed_rows::<3>(3).norm_squared() * w * w
}

/// The rotation vector (axis times angle, rad) of a rotation matrix.
pub fn rotation_vector(r: &nalgebra::Matrix3<f64>) -> Vector3<f64> {
    let v = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    ) * 0.5;
    let s = v.norm();
    let c = ((r.trace() - 1.0) * 0.5).clamp(-1.0, 1.0);
    let angle = s.atan2(c);
    if s < 1e-12 {
        if c > 0.0 {
            return v;
        }
        // Half a turn: the axis from the symmetric part.
        let b = (r + nalgebra::Matrix3::identity()) * 0.5;
        let k = (0..3)
            .max_by(|&i, &j| b[(i, i)].total_cmp(&b[(j, j)]))
            .unwrap_or(0);
        let axis = b.column(k) / b[(k, k)].max(1e-300).sqrt();
        return axis * std::f64::consts::PI;
    }
    v * (angle / s)
}

#[cfg(test)]
mod tests;
