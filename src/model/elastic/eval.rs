//! Forward kinematics of the elastic tree, the gravity directions in the joint frames, and
//! the exact derivatives of the marker positions with respect to every parameter.

use nalgebra::Vector3;

use super::bodies::Loads;
use super::gravity::{AXIS, COMPONENT, deflection};
use super::{Drive, ElasticTree, Lumping, RowKind, TParam};
use crate::geometry::{Frame, xyzabc_point_derivatives};

/// One sample: the measured joint values and the gravity direction in every joint frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeSample {
    /// Measured joint variables (rad).
    pub q: Vec<f64>,
    /// Unit gravity direction in each row's joint frame (zero for fixed rows), from the
    /// starting model with elasticity off; see [`ElasticTree::sample`].
    pub gravity: Vec<Vector3<f64>>,
    /// [`Lumping::Bodies`]: load factors of each elastic row (empty otherwise).
    pub loads: Vec<Loads>,
}

/// Frames of one row in the root frame.
#[derive(Debug, Clone, Copy)]
pub(super) struct RowFrames {
    /// The parent's output frame.
    pub(super) parent: Frame,
    /// Revolute: `parent Rx Dx Ry Rz(theta + q)` (before the deflection); fixed: `parent`.
    pub(super) joint: Frame,
    /// The row's output frame.
    pub(super) out: Frame,
    /// Deflection `[dz, dx, dy]`.
    pub(super) defl: [f64; 3],
}

impl ElasticTree {
    fn angle(&self, drive: &Drive, q: &[f64]) -> f64 {
        match drive {
            Drive::Variable(k) => q[*k],
            Drive::Coupled(c) => c.iter().map(|&(k, f)| f * q[k]).sum(),
        }
    }

    /// Frames of every row (root frame); deflections from the features of `s` when given.
    fn frames(&self, q: &[f64], s: Option<&TreeSample>) -> Vec<RowFrames> {
        let mut out: Vec<RowFrames> = Vec::with_capacity(self.rows.len());
        for (i, row) in self.rows.iter().enumerate() {
            let parent = row.parent.map_or_else(Frame::identity, |p| out[p].out);
            let f = match &row.kind {
                RowKind::Fixed { frame, errors } => {
                    let o = parent.mul(frame).mul(&Frame::from_xyzabc(errors));
                    RowFrames {
                        parent,
                        joint: parent,
                        out: o,
                        defl: [0.0; 3],
                    }
                }
                RowKind::Revolute { geometry: g, drive } => {
                    let joint = parent
                        .mul(&Frame::rot_x(g[0]))
                        .mul(&Frame::trans(g[1], 0.0, 0.0))
                        .mul(&Frame::rot_y(g[2]))
                        .mul(&Frame::rot_z(g[3] + self.angle(drive, q)));
                    let defl = match (s, self.lumping) {
                        (None, _) => [0.0; 3],
                        (Some(s), Lumping::Subtree) => deflection(&self.elastic[i], &s.gravity[i]),
                        (Some(s), Lumping::Bodies) => self.body_deflection(i, &s.loads[i]),
                    };
                    let o = joint
                        .mul(&Frame::rot_z(defl[0]))
                        .mul(&Frame::rot_x(defl[1]))
                        .mul(&Frame::rot_y(defl[2]))
                        .mul(&Frame::trans(0.0, 0.0, g[4]));
                    RowFrames {
                        parent,
                        joint,
                        out: o,
                        defl,
                    }
                }
            };
            out.push(f);
        }
        out
    }

    /// A sample with its gravity features from this model (elasticity off): the unit
    /// gravity direction in every row's joint frame (zero for fixed rows) and, for
    /// [`Lumping::Bodies`], the load factors. Computed once per sample from the starting model.
    pub fn sample(&self, q: Vec<f64>) -> TreeSample {
        let frames = self.frames(&q, None);
        let gravity = frames
            .iter()
            .zip(&self.rows)
            .map(|(f, r)| match r.kind {
                RowKind::Fixed { .. } => Vector3::zeros(),
                RowKind::Revolute { .. } => f.joint.r.transpose() * self.gravity_root,
            })
            .collect();
        let loads = self.loads(&frames);
        TreeSample { q, gravity, loads }
    }

    /// Output frame of every row in the root frame for a sample (elasticity on).
    pub fn row_frames(&self, s: &TreeSample) -> Vec<Frame> {
        self.frames(&s.q, Some(s)).iter().map(|f| f.out).collect()
    }

    /// Positions of every marker in the measurement frame.
    pub fn marker_positions(&self, s: &TreeSample) -> Vec<Vector3<f64>> {
        let frames = self.frames(&s.q, Some(s));
        let base = Frame::from_xyzabc(&self.base);
        self.markers
            .iter()
            .map(|m| base.apply(&frames[m.row].out.apply(&m.local)))
            .collect()
    }

    /// Position of every marker and its derivative with respect to every parameter
    /// (`f(marker, position, jacobian)`, one jacobian entry per [`ElasticTree::params`]).
    pub fn marker_jacobians(
        &self,
        s: &TreeSample,
        mut f: impl FnMut(usize, &Vector3<f64>, &[Vector3<f64>]),
    ) {
        let frames = self.frames(&s.q, Some(s));
        let base = Frame::from_xyzabc(&self.base);
        let mut jac = vec![Vector3::zeros(); self.params.len()];
        // Where each row's parameters start in `params` (they are contiguous per row).
        let mut first = vec![usize::MAX; self.rows.len()];
        for (g, p) in self.params.iter().enumerate().rev() {
            match p {
                TParam::Geometry(i, _) | TParam::Placement(i, _) | TParam::Elastic(i, _) => {
                    first[*i] = g;
                }
                _ => {}
            }
        }
        let mut wfirst = vec![usize::MAX; self.rows.len()];
        for (g, p) in self.params.iter().enumerate().rev() {
            if let TParam::Weight(i, _) = p {
                wfirst[*i] = g;
            }
        }
        let base_first = self
            .params
            .iter()
            .position(|p| *p == TParam::Base(0))
            .unwrap_or(0);
        for (m, marker) in self.markers.iter().enumerate() {
            jac.fill(Vector3::zeros());
            let p = frames[marker.row].out.apply(&marker.local);
            let rot = |axis: Vector3<f64>, o: Vector3<f64>| axis.cross(&(p - o));
            for &i in &self.paths[m] {
                let fr = &frames[i];
                let mut g = first[i];
                match &self.rows[i].kind {
                    RowKind::Fixed { frame, errors } => {
                        let pre = fr.parent.mul(frame);
                        let local = fr.out.inverse().apply(&p);
                        let d = xyzabc_point_derivatives(errors, &local);
                        for dk in d {
                            jac[g] = pre.r * dk;
                            g += 1;
                        }
                    }
                    RowKind::Revolute { geometry: geo, .. } => {
                        let (pr, pp) = (fr.parent.r, fr.parent.p);
                        let ex = pr * Vector3::x();
                        let after_x = fr.parent.mul(&Frame::rot_x(geo[0]));
                        let o_b = pp + ex * geo[1];
                        let ey = after_x.r * Vector3::y();
                        let (rj, oj) = (fr.joint.r, fr.joint.p);
                        let rz = rj * Frame::rot_z(fr.defl[0]).r;
                        let rzx = rz * Frame::rot_x(fr.defl[1]).r;
                        let axes = [rj * Vector3::z(), rz * Vector3::x(), rzx * Vector3::y()];
                        jac[g] = rot(ex, pp);
                        jac[g + 1] = ex;
                        jac[g + 2] = rot(ey, o_b);
                        jac[g + 3] = rot(axes[0], oj);
                        jac[g + 4] = fr.out.r * Vector3::z();
                        g += 5;
                        let d_axis = axes.map(|a| rot(a, oj));
                        let (je, le) = (self.joint_elastic[i], self.lateral_elastic[i]);
                        if self.lumping == Lumping::Subtree {
                            let u = &s.gravity[i];
                            let coeffs = (0..2).filter(|_| je).chain((2..6).filter(|_| le));
                            for c in coeffs {
                                jac[g] = d_axis[AXIS[c]] * u[COMPONENT[c]];
                                g += 1;
                            }
                            continue;
                        }
                        let t = self.torques(&s.loads[i]);
                        for a in (0..1).filter(|_| je).chain((1..3).filter(|_| le)) {
                            jac[g] = d_axis[a] * t[a];
                            g += 1;
                        }
                        let c = self.compliance[i];
                        for (b, f) in &s.loads[i] {
                            let w0 = wfirst[*b];
                            if w0 == usize::MAX {
                                continue;
                            }
                            for ((da, ca), fa) in d_axis.iter().zip(c).zip(f) {
                                for (jk, fk) in jac[w0..w0 + 4].iter_mut().zip(fa) {
                                    *jk += da * (ca * fk);
                                }
                            }
                        }
                    }
                }
            }
            for v in jac.iter_mut().take(base_first) {
                *v = base.r * *v;
            }
            let d = xyzabc_point_derivatives(&self.base, &p);
            jac[base_first..base_first + 6].copy_from_slice(&d);
            let rw = base.r * frames[marker.row].out.r;
            let mfirst = base_first + 6 + 3 * m;
            for a in 0..3 {
                jac[mfirst + a] = rw.column(a).into_owned();
            }
            f(m, &base.apply(&p), &jac);
        }
    }
}
