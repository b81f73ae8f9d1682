//! The nuisance-only fit of a [`PointProblem`] in its cheap form: with every chain
//! parameter held, each measurement's flange frame is fixed, so the fit of the base and
//! tool frames and the unknown ball centres needs two frame products per measurement per
//! evaluation instead of the chain's forward kinematics (and its analytic Jacobian). The
//! residuals are those of the full problem bit for bit (the same `base * flange * tool`
//! products); the Jacobian is the same to rounding.

use nalgebra::{DMatrix, Vector3};

use super::{PointProblem, Target};
use crate::geometry::Frame;
use crate::identify::{IdentifyError, Problem};
use crate::model::ParamId;

/// What a free unknown of the fit is.
#[derive(Debug, Clone, Copy)]
enum Role {
    /// Base frame component 0..6 (x, y, z, a, b, c).
    Base(usize),
    /// Tool frame component 0..6.
    Tool(usize),
    /// Coordinate `axis` of the centre of ball `ball`.
    Centre { ball: usize, axis: usize },
}

/// [`PointProblem`] with only frame and ball-centre unknowns free, the others held.
pub(super) struct FramesFit<'a> {
    inner: &'a PointProblem,
    x0: Vec<f64>,
    free: Vec<usize>,
    roles: Vec<Role>,
    /// Flange frame of every measurement with the held chain parameters and its torques.
    flanges: Vec<Frame>,
}

impl<'a> FramesFit<'a> {
    /// The fit of the unknowns `free` with the others held at `x0`; `None` when a chain
    /// parameter other than the base and tool frames is among them.
    pub(super) fn new(inner: &'a PointProblem, x0: &[f64], free: &[usize]) -> Option<Self> {
        let nid = inner.ids.len();
        let roles = free
            .iter()
            .map(|&k| match inner.ids.get(k) {
                Some(ParamId::Base(c)) => Some(Role::Base(*c as usize)),
                Some(ParamId::Tool(c)) => Some(Role::Tool(*c as usize)),
                Some(ParamId::Joint(..)) => None,
                None => inner
                    .free_balls
                    .get((k - nid) / 3)
                    .map(|&ball| Role::Centre {
                        ball,
                        axis: (k - nid) % 3,
                    }),
            })
            .collect::<Option<Vec<Role>>>()?;
        let chain = inner.model(x0);
        let flanges = inner
            .meas
            .iter()
            .zip(&inner.tau)
            .map(|(m, t)| chain.flange(&m.q, Some(t)))
            .collect();
        Some(Self {
            inner,
            x0: x0.to_vec(),
            free: free.to_vec(),
            roles,
            flanges,
        })
    }

    /// The full unknowns, the base and tool values and frames, and the ball centres at the
    /// free unknowns `xs`.
    fn state(&self, xs: &[f64]) -> State {
        let mut x = self.x0.clone();
        for (&k, v) in self.free.iter().zip(xs) {
            x[k] = *v;
        }
        let (mut base, mut tool) = (self.inner.chain.base, self.inner.chain.tool);
        for (id, v) in self.inner.ids.iter().zip(&x) {
            match id {
                ParamId::Base(c) => base[*c as usize] = *v,
                ParamId::Tool(c) => tool[*c as usize] = *v,
                ParamId::Joint(..) => {}
            }
        }
        State {
            centres: self.inner.centres(&x),
            base_frame: Frame::from_xyzabc(&base),
            tool_frame: Frame::from_xyzabc(&tool),
            base,
            tool,
        }
    }
}

struct State {
    centres: Vec<Vector3<f64>>,
    base: [f64; 6],
    tool: [f64; 6],
    base_frame: Frame,
    tool_frame: Frame,
}

/// Generators of `frame * Dx Dy Dz Rz(a) Ry(b) Rx(c)` for the values `v` at the point `p`:
/// the derivative of `p` with respect to each of the six values.
fn xyzabc_columns(frame: &Frame, v: &[f64; 6], p: &Vector3<f64>) -> [Vector3<f64>; 6] {
    let r = frame.r;
    let o = frame.apply(&Vector3::new(v[0], v[1], v[2]));
    let rz = r * Frame::rot_z(v[3]).r;
    let ry = rz * Frame::rot_y(v[4]).r;
    let arm = p - o;
    [
        r.column(0).into(),
        r.column(1).into(),
        r.column(2).into(),
        r.column(2).cross(&arm),
        rz.column(1).cross(&arm),
        ry.column(0).cross(&arm),
    ]
}

impl Problem for FramesFit<'_> {
    fn residual_count(&self) -> usize {
        self.inner.residual_count()
    }

    fn unknown_count(&self) -> usize {
        self.free.len()
    }

    fn residuals(&self, xs: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        let s = self.state(xs);
        for (i, (m, f)) in self.inner.meas.iter().zip(&self.flanges).enumerate() {
            let target = match m.target {
                Target::Ball(k) => s.centres[k],
                Target::Point(p) => p,
            };
            let e = s.base_frame.mul(f).mul(&s.tool_frame).p - target;
            r[3 * i..3 * i + 3].copy_from_slice(e.as_slice());
        }
        self.inner.distance_rows(&s.centres, r);
        Ok(())
    }

    fn jacobian(&self, xs: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        let s = self.state(xs);
        j.as_mut_slice().fill(0.0);
        let wants = |base: bool| {
            self.roles.iter().any(|r| match r {
                Role::Base(_) => base,
                Role::Tool(_) => !base,
                Role::Centre { .. } => false,
            })
        };
        let (need_base, need_tool) = (wants(true), wants(false));
        for (i, (m, f)) in self.inner.meas.iter().zip(&self.flanges).enumerate() {
            let bf = s.base_frame.mul(f);
            let p = bf.mul(&s.tool_frame).p;
            let zero = [Vector3::zeros(); 6];
            let bc = if need_base {
                xyzabc_columns(&Frame::identity(), &s.base, &p)
            } else {
                zero
            };
            let tc = if need_tool {
                xyzabc_columns(&bf, &s.tool, &p)
            } else {
                zero
            };
            for (c, role) in self.roles.iter().enumerate() {
                match *role {
                    Role::Base(k) => j.view_mut((3 * i, c), (3, 1)).copy_from(&bc[k]),
                    Role::Tool(k) => j.view_mut((3 * i, c), (3, 1)).copy_from(&tc[k]),
                    Role::Centre { ball, axis } => {
                        if m.target == Target::Ball(ball) {
                            j[(3 * i + axis, c)] = -1.0;
                        }
                    }
                }
            }
        }
        let base = 3 * self.inner.meas.len();
        for (k, &(bi, bj, _)) in self.inner.plate.distances.iter().enumerate() {
            let diff = s.centres[bi] - s.centres[bj];
            let u = diff / diff.norm().max(f64::MIN_POSITIVE);
            for (c, role) in self.roles.iter().enumerate() {
                if let Role::Centre { ball, axis } = *role {
                    let sign = if ball == bi {
                        1.0
                    } else if ball == bj {
                        -1.0
                    } else {
                        continue;
                    };
                    j[(base + k, c)] = self.inner.distance_weight * sign * u[axis];
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
