//! Marker positions of the humanoid model in the measurement frame and their exact
//! derivatives with respect to every model parameter.
//!
//! A marker on body `b` of chain `c` is at `T_root * FK_c(q, tau)[b] * local`, with
//! `T_root = C * B * E` (cluster mode; `C` = identity in identify mode) or `F * G^-1 * E`
//! (support-foot mode, `G` = root-to-foot kinematics), and `E` the base deflection
//! `from_urdf_errors(c_w ⊙ w)`, `w = (J^T)^-1 tau_support` the wrench the support leg carries
//! at the root origin in root axes.

use nalgebra::Vector3;

use super::{BaseMode, Humanoid, TreeChain};
use crate::geometry::{Frame, urdf_errors_point_derivatives, xyzabc_point_derivatives};

/// The robot state of one sample.
#[derive(Debug, Clone, PartialEq)]
pub struct State {
    /// Measured joint values (rad), in [`Humanoid::variables`] order.
    pub q: Vec<f64>,
    /// Measured joint torques (N*m), same order (zeros when not measured).
    pub tau: Vec<f64>,
    /// Pose of the root cluster in the measurement frame (cluster mode).
    pub cluster: Option<Frame>,
    /// Wrench carried by the support leg at the root (force N, moment N*m, root axes),
    /// computed once from the starting model by [`Humanoid::fill_wrench`] (as static
    /// torques are for serial arms), so that it is data during the fit.
    pub wrench: [f64; 6],
}

impl State {
    /// A state with joint values only.
    pub fn from_q(q: Vec<f64>) -> Self {
        let n = q.len();
        Self {
            q,
            tau: vec![0.0; n],
            cluster: None,
            wrench: [0.0; 6],
        }
    }
}

/// Per-sample quantities shared by every marker of the sample.
struct Root {
    /// `T_root` without E: `C * B` or `F * G^-1`.
    pre: Frame,
    /// Base deflection transform and its six numbers.
    e: [f64; 6],
    ef: Frame,
    /// Wrench at the root (6).
    w: [f64; 6],
    /// Support chain flange G (support mode).
    g: Option<Frame>,
}

impl TreeChain {
    fn q(&self, s: &State) -> Vec<f64> {
        self.vars.iter().map(|&v| s.q[v]).collect()
    }
    fn tau(&self, s: &State) -> Vec<f64> {
        self.vars.iter().map(|&v| s.tau[v]).collect()
    }
}

impl Humanoid {
    /// The wrench `w = (J^T)^+ tau` carried by the support leg, at the root origin in root
    /// axes (force, moment), or zeros without a support leg.
    pub fn support_wrench(&self, s: &State) -> [f64; 6] {
        self.support_wrench_conditioned(s).0
    }

    /// [`Humanoid::support_wrench`] and the condition number of the support leg's Jacobian
    /// (columns in m/rad and 1): near a singular leg (a straight knee) the torques do not
    /// determine the wrench, and samples there should not carry base elasticity.
    pub fn support_wrench_conditioned(&self, s: &State) -> ([f64; 6], f64) {
        let Some(tc) = &self.support else {
            return ([0.0; 6], 1.0);
        };
        let (q, tau) = (tc.q(s), tc.tau(s));
        let mut frames = Vec::new();
        tc.chain.joint_frames(&q, Some(&tau), &mut frames);
        let n = tc.chain.dof();
        let mut jt = nalgebra::DMatrix::zeros(n, 6);
        for (k, &j) in tc.chain.actuated().iter().enumerate() {
            let f = &frames[j];
            let a = f.r * crate::model::chain::joint_axis(&tc.chain.joints[j]);
            let v = f.p.cross(&a);
            for r in 0..3 {
                jt[(k, r)] = v[r];
                jt[(k, 3 + r)] = a[r];
            }
        }
        let t = nalgebra::DVector::from_vec(tau);
        let svd = jt.svd(true, true);
        let smax = svd.singular_values.max();
        let smin = svd.singular_values.min();
        let cond = if smin > 0.0 {
            smax / smin
        } else {
            f64::INFINITY
        };
        let w = match svd.solve(&t, 1e-9 * smax.max(f64::MIN_POSITIVE)) {
            Ok(w) if w.len() == 6 => [w[0], w[1], w[2], w[3], w[4], w[5]],
            _ => [0.0; 6],
        };
        (w, cond)
    }

    /// Set `s.wrench` from this model's support leg (zeros without base elasticity) and
    /// return the condition number of the support leg's Jacobian (1 without).
    pub fn fill_wrench(&self, s: &mut State) -> f64 {
        let (w, cond) = if self.base_elastic {
            self.support_wrench_conditioned(s)
        } else {
            ([0.0; 6], 1.0)
        };
        s.wrench = w;
        cond
    }

    fn root(&self, s: &State) -> Root {
        let b = Frame::from_xyzabc(&self.base);
        let (pre, g) = match &self.base_mode {
            BaseMode::Identify => (b, None),
            BaseMode::Cluster => (s.cluster.unwrap_or_else(Frame::identity).mul(&b), None),
            BaseMode::SupportFoot { .. } => {
                let g = self.support.as_ref().map_or_else(Frame::identity, |tc| {
                    tc.chain.flange(&tc.q(s), Some(&tc.tau(s)))
                });
                (b.mul(&g.inverse()), Some(g))
            }
        };
        let w = if self.base_elastic {
            s.wrench
        } else {
            [0.0; 6]
        };
        let e: [f64; 6] = std::array::from_fn(|k| self.base_compliance[k] * w[k]);
        Root {
            pre,
            e,
            ef: Frame::from_urdf_errors(&e),
            w,
            g,
        }
    }

    /// Pose of the root link in the measurement frame for a sample.
    pub fn root_pose(&self, s: &State) -> Frame {
        let r = self.root(s);
        r.pre.mul(&r.ef)
    }

    /// Pose in the root frame of the link carrying marker `m`.
    fn marker_body(&self, m: usize, s: &State, frames: &mut Vec<Frame>) -> Frame {
        match self.marker_at[m] {
            None => Frame::identity(),
            Some((c, body)) => {
                let tc = &self.chains[c];
                tc.chain.joint_frames(&tc.q(s), Some(&tc.tau(s)), frames);
                frames[body]
            }
        }
    }

    /// Positions of every marker in the measurement frame for a sample.
    pub fn marker_positions(&self, s: &State) -> Vec<Vector3<f64>> {
        let t = self.root_pose(s);
        let mut frames = Vec::new();
        (0..self.markers.len())
            .map(|m| {
                t.apply(
                    &self
                        .marker_body(m, s, &mut frames)
                        .apply(&self.marker_pos[m]),
                )
            })
            .collect()
    }

    /// Position of marker `m` in the measurement frame and its derivative with respect to
    /// every parameter (written to `jac`, one entry per [`Humanoid::params`]).
    pub fn marker_jacobian(&self, m: usize, s: &State, jac: &mut [Vector3<f64>]) -> Vector3<f64> {
        let mut out = Vector3::zeros();
        self.marker_jacobians(s, &[m], |_, p, j| {
            out = *p;
            jac.copy_from_slice(j);
        });
        out
    }

    /// [`Humanoid::marker_jacobian`] for several markers of one sample, sharing the root
    /// pose and chain kinematics: `f(marker, position, jacobian over every parameter)`.
    pub fn marker_jacobians(
        &self,
        s: &State,
        markers: &[usize],
        mut f: impl FnMut(usize, &Vector3<f64>, &[Vector3<f64>]),
    ) {
        let root = self.root(s);
        let t = root.pre.mul(&root.ef);
        let chain_state: Vec<(Vec<f64>, Vec<f64>, Vec<Frame>)> = self
            .chains
            .iter()
            .map(|tc| {
                let (q, tau) = (tc.q(s), tc.tau(s));
                let mut frames = Vec::new();
                tc.chain.joint_frames(&q, Some(&tau), &mut frames);
                (q, tau, frames)
            })
            .collect();
        let support_state = self.support.as_ref().map(|tc| (tc.q(s), tc.tau(s)));
        let (base_first, comp_first) = (self.layout.base, self.layout.compliance);
        let mut jac = vec![Vector3::zeros(); self.params.len()];
        let mut buf = Vec::new();
        for &m in markers {
            jac.fill(Vector3::zeros());
            let local = self.marker_pos[m];
            // Point in the root frame, its chain derivatives and the body rotation.
            let (p_r, r_body) = match self.marker_at[m] {
                None => (local, nalgebra::Matrix3::identity()),
                Some((c, body)) => {
                    let tc = &self.chains[c];
                    let (q, tau, frames) = &chain_state[c];
                    buf.resize(tc.params, Vector3::zeros());
                    let p = tc
                        .chain
                        .body_point_jacobian(q, Some(tau), body, &local, &mut buf);
                    for &(g, col) in &tc.cols {
                        jac[g] += t.r * buf[col];
                    }
                    (p, frames[body].r)
                }
            };
            let u = root.ef.apply(&p_r);
            let p = root.pre.apply(&u);
            for a in 0..3 {
                jac[self.layout.markers[m] + a] = t.r * r_body.column(a);
            }
            // Base (or foot) pose.
            let (outer, inner) = match (&self.base_mode, root.g) {
                (BaseMode::SupportFoot { .. }, Some(g)) => {
                    (Frame::identity(), g.inverse().apply(&u))
                }
                (BaseMode::Cluster, _) => (s.cluster.unwrap_or_else(Frame::identity), u),
                _ => (Frame::identity(), u),
            };
            let d = xyzabc_point_derivatives(&self.base, &inner);
            for k in 0..6 {
                jac[base_first + k] = outer.r * d[k];
            }
            if let Some(c0) = comp_first {
                let d = urdf_errors_point_derivatives(&root.e, &p_r);
                for k in 0..6 {
                    jac[c0 + k] = root.pre.r * d[k] * root.w[k];
                }
            }
            // Support leg: p = F * G^-1 * u, dp = -F.R G.R^T dG(G^-1 u).
            if let (Some(tc), Some(g), Some((q, tau))) = (&self.support, root.g, &support_state) {
                let p_foot = g.inverse().apply(&u);
                buf.resize(tc.params, Vector3::zeros());
                tc.chain.body_point_jacobian(
                    q,
                    Some(tau),
                    tc.chain.joints.len() - 1,
                    &p_foot,
                    &mut buf,
                );
                let fr = Frame::from_xyzabc(&self.base);
                let rot = -(fr.r * g.r.transpose());
                for &(gi, col) in &tc.cols {
                    jac[gi] += rot * buf[col];
                }
            }
            f(m, &p, &jac);
        }
    }
}
