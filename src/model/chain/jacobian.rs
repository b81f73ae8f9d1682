//! The analytic Jacobian of a point on a [`Chain`] with respect to every parameter: the
//! generators of each joint and of the base and tool frames are recorded on the way out,
//! then each column is the generator's velocity at the point.

use nalgebra::Vector3;

use super::{Chain, EndRotations, Geometry, joint_fields};
use crate::geometry::{Frame, Motion};
use crate::model::joint::JointKind;
use crate::model::params::{JointField, ParamId};
use crate::model::trig::{self, TrigMemo};

/// Reusable work space of [`Chain::body_point_jacobian_with`]: the generators recorded on
/// the way out (no allocation per configuration once it has grown).
#[derive(Default)]
pub struct JacobianScratch {
    recs: Vec<(usize, Gen, f64)>,
    /// The base frame's generators (the same for every configuration) with the base
    /// values and first column they were recorded for.
    base: Option<([u64; 6], usize, Vec<(usize, Gen, f64)>)>,
    /// Parameter columns to compute (all when empty); the others are left zero.
    wanted: Vec<bool>,
}

impl JacobianScratch {
    /// Compute only the parameter columns `k` with `wanted[k]` (all when `wanted` is
    /// empty); the others are left zero. The columns computed are the same either way.
    pub fn set_wanted(&mut self, wanted: Vec<bool>) {
        self.wanted = wanted;
    }
}

impl std::fmt::Debug for JacobianScratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JacobianScratch")
            .field("capacity", &self.recs.capacity())
            .finish()
    }
}

/// Where a joint's generator acts, recorded during the forward pass for the Jacobian.
#[derive(Clone, Copy)]
enum Gen {
    Rot {
        axis: Vector3<f64>,
        origin: Vector3<f64>,
    },
    Trans {
        dir: Vector3<f64>,
    },
}

impl Chain {
    /// Position in {W} of a point fixed at `local` in the TCP frame, and its derivative with
    /// respect to every parameter (columns in [`Chain::param_ids`] order, written to `jac`,
    /// which must hold that many entries).
    pub fn point_jacobian(
        &self,
        q: &[f64],
        tau: Option<&[f64]>,
        local: &Vector3<f64>,
        jac: &mut [Vector3<f64>],
    ) -> Vector3<f64> {
        self.body_point_jacobian(q, tau, self.joints.len(), local, jac)
    }

    /// As [`Chain::point_jacobian`] for a point on the output frame of joint `body`
    /// (`body == joints.len()` means the TCP frame, after the tool).
    pub fn body_point_jacobian(
        &self,
        q: &[f64],
        tau: Option<&[f64]>,
        body: usize,
        local: &Vector3<f64>,
        jac: &mut [Vector3<f64>],
    ) -> Vector3<f64> {
        self.body_point_jacobian_with(q, tau, body, local, jac, &mut JacobianScratch::default())
    }

    /// [`Chain::point_jacobian`] with a reusable work space (for many configurations).
    pub fn point_jacobian_with(
        &self,
        q: &[f64],
        tau: Option<&[f64]>,
        local: &Vector3<f64>,
        jac: &mut [Vector3<f64>],
        scratch: &mut JacobianScratch,
    ) -> Vector3<f64> {
        self.body_point_jacobian_with(q, tau, self.joints.len(), local, jac, scratch)
    }

    /// [`Chain::body_point_jacobian`] with a reusable work space. The constant rotations of
    /// the MDH joints and of the base and tool frames come from the chain's caches (the
    /// same values, computed once per parameter change rather than once per configuration).
    pub fn body_point_jacobian_with(
        &self,
        q: &[f64],
        tau: Option<&[f64]>,
        body: usize,
        local: &Vector3<f64>,
        jac: &mut [Vector3<f64>],
        scratch: &mut JacobianScratch,
    ) -> Vector3<f64> {
        self.body_point_jacobian_memo(q, tau, body, local, jac, scratch, None)
    }

    /// [`Chain::point_jacobian_with`] with the joint sines and cosines of this configuration
    /// through `memo` (one per joint) when there is one: the same values bit for bit.
    pub fn point_jacobian_memo(
        &self,
        q: &[f64],
        tau: Option<&[f64]>,
        local: &Vector3<f64>,
        jac: &mut [Vector3<f64>],
        scratch: &mut JacobianScratch,
        memo: Option<&mut [TrigMemo]>,
    ) -> Vector3<f64> {
        let body = self.joints.len();
        self.body_point_jacobian_memo(q, tau, body, local, jac, scratch, memo)
    }

    #[allow(clippy::too_many_arguments)]
    fn body_point_jacobian_memo(
        &self,
        q: &[f64],
        tau: Option<&[f64]>,
        body: usize,
        local: &Vector3<f64>,
        jac: &mut [Vector3<f64>],
        scratch: &mut JacobianScratch,
        mut memo: Option<&mut [TrigMemo]>,
    ) -> Vector3<f64> {
        for v in jac.iter_mut() {
            *v = Vector3::zeros();
        }
        // Records (parameter column, generator, coefficient) gathered on the way out.
        let nb = self.param_index(ParamId::Base(0)).unwrap_or(0);
        let key = self.base.map(f64::to_bits);
        let base = match scratch.base.take() {
            // Compared element by element (an array compare calls memcmp).
            Some(b) if b.0.iter().zip(&key).all(|(a, k)| a == k) && b.1 == nb => b,
            _ => {
                let mut gens = Vec::with_capacity(6);
                let base_rots = self.end_rotations(0, &self.base);
                push_xyzabc_gens(&Frame::identity(), &self.base, &base_rots, nb, &mut gens);
                (key, nb, gens)
            }
        };
        let recs = &mut scratch.recs;
        recs.clear();
        recs.extend_from_slice(&base.2);
        scratch.base = Some(base);
        let wanted = &scratch.wanted;
        let mut t = self.base_frame();
        let last = if body >= self.joints.len() {
            self.joints.len()
        } else {
            body + 1
        };
        for j in 0..last {
            let joint = &self.joints[j];
            let ps = self.param_start[j];
            let m = self.motion(j, q, tau);
            let tau_k = self.tau_of(j, tau);
            let fields = joint_fields(joint);
            // The field's column: at its usual place in `fields` (`hint`), else searched.
            let col = |f: JointField, hint: usize| {
                if fields.get(hint) == Some(&f) {
                    Some(ps + hint)
                } else {
                    fields.iter().position(|x| *x == f).map(|c| ps + c)
                }
            };
            // A mimic joint's multiplier moves it by the leader's variable per unit.
            let q_lead = joint.mimic.as_ref().map_or(0.0, |mm| q[mm.leader]);
            let mj = memo.as_deref_mut().and_then(|m| m.get_mut(j));
            let mut push = |f: JointField, hint: usize, g: Gen, coef: f64| {
                if let Some(c) = col(f, hint) {
                    if wanted.get(c) != Some(&false) {
                        recs.push((c, g, coef));
                    }
                }
            };
            match &joint.geometry {
                Geometry::Mdh { alpha, a, beta, d } => {
                    let (rx, ry) = self.mdh_rotations(j, *alpha, *beta);
                    let f0 = t;
                    let x0 = Gen::Rot {
                        axis: f0.r.column(0).into(),
                        origin: f0.p,
                    };
                    push(JointField::Alpha, 0, x0, 1.0);
                    // The elementary factors without their products with zeros and ones
                    // (the same values, see `Frame::then_rot_x`).
                    let f1 = f0.then_rot_x(&rx.r);
                    let dx = Gen::Trans {
                        dir: f1.r.column(0).into(),
                    };
                    push(JointField::A, 1, dx, 1.0);
                    let f1 = f1.then_dx(*a);
                    let y1 = Gen::Rot {
                        axis: f1.r.column(1).into(),
                        origin: f1.p,
                    };
                    push(JointField::Beta, 2, y1, 1.0);
                    let f2 = f1.then_rot_y(&ry.r);
                    let zg = Gen::Rot {
                        axis: f2.r.column(2).into(),
                        origin: f2.p,
                    };
                    let zt = Gen::Trans {
                        dir: f2.r.column(2).into(),
                    };
                    push(JointField::Offset, 4, zg, 1.0);
                    push(JointField::Compliance, 5, zg, tau_k);
                    push(JointField::D, 3, zt, 1.0);
                    let mg = if joint.kind == JointKind::Prismatic {
                        zt
                    } else {
                        zg
                    };
                    push(JointField::Multiplier, 5, mg, q_lead);
                    let (sin, cos) = trig::sin_cos(m.theta, mj);
                    t = f2.then_rot_z_sin_cos(sin, cos).then_dz(*d + m.shift);
                }
                Geometry::Urdf {
                    origin,
                    errors,
                    axis,
                } => {
                    let mut f = t.mul(origin);
                    let motions = [
                        Motion::Dx,
                        Motion::Dy,
                        Motion::Dz,
                        Motion::Rx,
                        Motion::Ry,
                        Motion::Rz,
                    ];
                    for (e, mo) in motions.iter().enumerate() {
                        let dir: Vector3<f64> = f.r * mo.axis();
                        let g = if mo.is_rotation() {
                            Gen::Rot {
                                axis: dir,
                                origin: f.p,
                            }
                        } else {
                            Gen::Trans { dir }
                        };
                        push(JointField::Err(e as u8), e, g, 1.0);
                        f = f.mul(&mo.frame(errors[e]));
                    }
                    let dir = f.r * axis;
                    match joint.kind {
                        JointKind::Revolute => {
                            let g = Gen::Rot {
                                axis: dir,
                                origin: f.p,
                            };
                            push(JointField::Offset, 6, g, 1.0);
                            push(JointField::Compliance, 7, g, tau_k);
                            push(JointField::Multiplier, 7, g, q_lead);
                        }
                        JointKind::Prismatic => {
                            let g = Gen::Trans { dir };
                            push(JointField::LinearOffset, 6, g, 1.0);
                            push(JointField::Multiplier, 7, g, q_lead);
                        }
                        JointKind::Fixed => {}
                    }
                    t = self.advance_memo(&t, j, m, mj);
                }
            }
        }
        if body >= self.joints.len() {
            // The tool's columns follow the base's six (as `param_index` places them).
            let nt = nb + 6;
            let tool_rots = self.end_rotations(1, &self.tool);
            push_xyzabc_gens(&t, &self.tool, &tool_rots, nt, recs);
            t = t.mul(&self.tool_frame());
        }
        let p = t.apply(local);
        for &(col, g, coef) in recs.iter() {
            if wanted.get(col) == Some(&false) {
                continue;
            }
            let v = match g {
                Gen::Rot { axis, origin } => axis.cross(&(p - origin)),
                Gen::Trans { dir } => dir,
            };
            jac[col] += v * coef;
        }
        p
    }
}

/// Records the generators of `frame * Dx Dy Dz Rz(a) Ry(b) Rx(c)` starting at column `col0`.
fn push_xyzabc_gens(
    frame: &Frame,
    v: &[f64; 6],
    rots: &EndRotations,
    col0: usize,
    recs: &mut Vec<(usize, Gen, f64)>,
) {
    for k in 0..3 {
        recs.push((
            col0 + k,
            Gen::Trans {
                dir: frame.r.column(k).into(),
            },
            1.0,
        ));
    }
    let o = frame.apply(&Vector3::new(v[0], v[1], v[2]));
    let r = frame.r;
    recs.push((
        col0 + 3,
        Gen::Rot {
            axis: r.column(2).into(),
            origin: o,
        },
        1.0,
    ));
    let rz = r * rots.rz;
    recs.push((
        col0 + 4,
        Gen::Rot {
            axis: rz.column(1).into(),
            origin: o,
        },
        1.0,
    ));
    let ry = rz * rots.ry;
    recs.push((
        col0 + 5,
        Gen::Rot {
            axis: ry.column(0).into(),
            origin: o,
        },
        1.0,
    ));
}
