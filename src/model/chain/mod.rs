//! Serial kinematic chain: MDH+beta joints (DH model files) or URDF joints with placement
//! errors, base and tool frames, static gravity torques and joint compliance, forward
//! kinematics and the analytic Jacobian of a point with respect to every parameter.
//!
//! Conventions are those of `../shared/spec/serial-robot.md` (MDH: `Rx(alpha) Dx(a) Ry(beta)
//! Rz(theta) Dz(d)`) and `../shared/spec/humanoid.md` (URDF: `origin * Dx Dy Dz Rx Ry Rz *
//! Rot(axis, theta)`), with `theta = q + offset + c * tau`. Internally angles are radians
//! and lengths are in the model's length unit (mm for DH files, m for URDF).
//!
//! Prismatic joints (see [`JointKind`]): MDH `Rz(theta_offset) Dz(d + q)`, URDF `origin *
//! errors * Dtrans(axis, q + offset)` with the offset a length. A mimic joint ([`Mimic`])
//! takes `multiplier * q[leader] + mimic offset` as its variable and has no column of its own.

use nalgebra::{Matrix3, Vector3};

use super::ModelError;
use super::joint::{JointKind, Mimic, Motion as JointMotion};
use super::params::{JointField, ParamId, Quantity, URDF_ERRORS, XYZABC};
use super::trig::{self, TrigMemo};
use crate::geometry::Frame;

pub use jacobian::JacobianScratch;

/// Geometry of one joint.
#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    /// Craig's modified DH with Hayati beta: `Rx(alpha) Dx(a) Ry(beta) Rz(theta) Dz(d)`.
    Mdh {
        /// alpha[i-1] (rad).
        alpha: f64,
        /// a[i-1] (length).
        a: f64,
        /// beta[i-1] (rad).
        beta: f64,
        /// d[i] (length).
        d: f64,
    },
    /// URDF joint: `origin * Dx Dy Dz Rx Ry Rz (errors) * Rot(axis, theta)`.
    Urdf {
        /// The nominal `<origin>` of the joint.
        origin: Frame,
        /// Placement errors dx, dy, dz (length), rx, ry, rz (rad).
        errors: [f64; 6],
        /// Unit rotation axis in the joint frame (ignored for fixed joints).
        axis: Vector3<f64>,
    },
}

/// One joint of the chain.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    /// Name (DH: `j1`..; URDF: the joint's name).
    pub name: String,
    /// Geometry.
    pub geometry: Geometry,
    /// Revolute, prismatic or fixed.
    pub kind: JointKind,
    /// For a mimic joint: how its variable follows another joint's (no table column).
    pub mimic: Option<Mimic>,
    /// Joint offset: theta_offset (rad) for MDH rows of any kind; for URDF the offset of the
    /// variable (rad for revolute, model length unit for prismatic joints).
    pub offset: f64,
    /// Compliance, rad/(N*m) (revolute joints with their own variable only).
    pub compliance: f64,
    /// Limits of the joint variable q (rad, or length for prismatic joints), if any.
    pub limits: Option<[f64; 2]>,
    /// Effort limit (N*m), if known (URDF).
    pub effort: Option<f64>,
}

/// A point mass moving with the frame after joint `body`.
#[derive(Debug, Clone, PartialEq)]
pub struct PointMass {
    /// Name (link name).
    pub name: String,
    /// Index of the joint whose output frame carries the mass.
    pub body: usize,
    /// Mass (kg).
    pub mass: f64,
    /// Centre of mass in that frame (model length unit).
    pub com: Vector3<f64>,
}

/// Unit system of a model's files and reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Units {
    /// True: lengths in millimetres; false: metres.
    pub mm: bool,
    /// True: angles in degrees in files; false: radians.
    pub deg: bool,
}

impl Units {
    /// Unit name of a quantity in files and reports.
    pub fn name(&self, q: Quantity) -> &'static str {
        match (q, self.mm, self.deg) {
            (Quantity::Length, true, _) => "mm",
            (Quantity::Length, false, _) => "m",
            (Quantity::Angle, _, true) => "deg",
            (Quantity::Angle, _, false) => "rad",
            (Quantity::Compliance, _, true) => "deg/(N*m)",
            (Quantity::Compliance, _, false) => "rad/(N*m)",
            (Quantity::Scalar, _, _) => "1",
        }
    }

    /// Factor from the internal value to the file value.
    pub fn to_file(&self, q: Quantity) -> f64 {
        match q {
            Quantity::Angle | Quantity::Compliance if self.deg => 180.0 / std::f64::consts::PI,
            _ => 1.0,
        }
    }

    /// Metres per model length unit.
    pub fn metre(&self) -> f64 {
        if self.mm { 1e-3 } else { 1.0 }
    }
}

/// A serial chain with base and tool frames and its masses.
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    /// Joints from the base outwards.
    pub joints: Vec<Joint>,
    /// Robot frame {0} in the world frame {W}: x, y, z (length), a, b, c (rad).
    pub base: [f64; 6],
    /// TCP frame in the last joint's frame: x, y, z, a, b, c.
    pub tool: [f64; 6],
    /// Gravity vector in frame {0} (m/s^2).
    pub gravity: Vector3<f64>,
    /// Masses carried by the chain (links and payload).
    pub masses: Vec<PointMass>,
    /// Units of files and reports.
    pub units: Units,
    /// Cached constant part of each joint (`pre` transform), refreshed on every change.
    pre: Vec<Frame>,
    /// Cached base and tool frames with the values they were built from.
    ends: [([f64; 6], Frame); 2],
    /// Cached rotation factors of the base and tool frames (see [`EndRotations`]).
    end_rots: [EndRotations; 2],
    /// Cached constant rotations of each MDH joint (`None` for URDF joints).
    mdh_rots: Vec<Option<MdhRotations>>,
    /// Index of the joint of each joint variable (moving joints that are not mimic joints).
    actuated: Vec<usize>,
    /// Joint variable of each joint, if it has its own.
    var_of: Vec<Option<usize>>,
    /// Index of the first parameter of each joint in the flat parameter list.
    param_start: Vec<usize>,
}

/// `Rx(alpha)` and `Ry(beta)` of an MDH joint with the values they were built from, so that
/// the point Jacobian takes no sine or cosine of a constant per configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
struct MdhRotations {
    alpha: f64,
    beta: f64,
    rx: Frame,
    ry: Frame,
}

/// `Rz(a)` and `Ry(b)` of a base or tool frame `x y z a b c` with the values they were built
/// from (the factors its generators are recorded with).
#[derive(Debug, Clone, Copy, PartialEq)]
struct EndRotations {
    values: [f64; 6],
    rz: Matrix3<f64>,
    ry: Matrix3<f64>,
}

impl EndRotations {
    fn of(v: &[f64; 6]) -> Self {
        Self {
            values: *v,
            rz: Frame::rot_z(v[3]).r,
            ry: Frame::rot_y(v[4]).r,
        }
    }
}

fn mdh_rotations(j: &Joint) -> Option<MdhRotations> {
    match j.geometry {
        Geometry::Mdh { alpha, beta, .. } => Some(MdhRotations {
            alpha,
            beta,
            rx: Frame::rot_x(alpha),
            ry: Frame::rot_y(beta),
        }),
        Geometry::Urdf { .. } => None,
    }
}

impl Chain {
    /// A chain from its parts; computes the caches.
    pub fn new(
        joints: Vec<Joint>,
        base: [f64; 6],
        tool: [f64; 6],
        gravity: Vector3<f64>,
        masses: Vec<PointMass>,
        units: Units,
    ) -> Self {
        let mut c = Self {
            joints,
            base,
            tool,
            gravity,
            masses,
            units,
            pre: Vec::new(),
            ends: [([f64::NAN; 6], Frame::identity()); 2],
            end_rots: [EndRotations::of(&[f64::NAN; 6]); 2],
            mdh_rots: Vec::new(),
            actuated: Vec::new(),
            var_of: Vec::new(),
            param_start: Vec::new(),
        };
        c.refresh();
        c
    }

    /// Recompute the caches; called after any geometric change.
    fn refresh(&mut self) {
        self.refresh_joints();
        self.refresh_ends();
        self.actuated = (0..self.joints.len())
            .filter(|&j| self.joints[j].has_variable())
            .collect();
        self.var_of = vec![None; self.joints.len()];
        for (k, &j) in self.actuated.iter().enumerate() {
            self.var_of[j] = Some(k);
        }
        let mut start = 0;
        self.param_start = self
            .joints
            .iter()
            .map(|j| {
                let s = start;
                start += joint_fields(j).len();
                s
            })
            .collect();
    }

    fn refresh_ends(&mut self) {
        self.end_rots = [EndRotations::of(&self.base), EndRotations::of(&self.tool)];
        // `Frame::from_xyzabc` with the rotation factors just computed (the same values).
        let frame = |v: &[f64; 6], e: &EndRotations| Frame {
            r: e.rz * e.ry * Frame::rot_x(v[5]).r,
            p: Vector3::new(v[0], v[1], v[2]),
        };
        self.ends = [
            (self.base, frame(&self.base, &self.end_rots[0])),
            (self.tool, frame(&self.tool, &self.end_rots[1])),
        ];
    }

    /// The constant parts of every joint (`pre` and the MDH rotations), each MDH `pre`
    /// from its cached rotations (the same values as [`pre_frame`]).
    /// (In place: a work chain refreshed at every evaluation allocates nothing.)
    fn refresh_joints(&mut self) {
        self.mdh_rots.clear();
        self.mdh_rots.extend(self.joints.iter().map(mdh_rotations));
        self.pre.clear();
        self.pre
            .extend(
                self.joints
                    .iter()
                    .zip(&self.mdh_rots)
                    .map(|(j, r)| match (&j.geometry, r) {
                        (Geometry::Mdh { a, .. }, Some(r)) => {
                            r.rx.mul(&Frame::trans(*a, 0.0, 0.0)).mul(&r.ry)
                        }
                        _ => pre_frame(j),
                    }),
            );
    }

    /// `Rz(a)` and `Ry(b)` of the base (`k = 0`) or tool (`k = 1`) values `v`, from the
    /// cache when they have not changed.
    fn end_rotations(&self, k: usize, v: &[f64; 6]) -> EndRotations {
        if self.end_rots[k].values == *v {
            self.end_rots[k]
        } else {
            EndRotations::of(v)
        }
    }

    /// `Rx(alpha)` and `Ry(beta)` of MDH joint `j`, from the cache when they have not changed.
    fn mdh_rotations(&self, j: usize, alpha: f64, beta: f64) -> (Frame, Frame) {
        match self.mdh_rots.get(j).copied().flatten() {
            Some(c) if c.alpha == alpha && c.beta == beta => (c.rx, c.ry),
            _ => (Frame::rot_x(alpha), Frame::rot_y(beta)),
        }
    }

    /// Base frame ({0} in {W}), from the cache when the values have not changed.
    pub fn base_frame(&self) -> Frame {
        if self.ends[0].0 == self.base {
            self.ends[0].1
        } else {
            Frame::from_xyzabc(&self.base)
        }
    }

    /// Tool frame (TCP in the last joint's frame), cached like the base.
    pub fn tool_frame(&self) -> Frame {
        if self.ends[1].0 == self.tool {
            self.ends[1].1
        } else {
            Frame::from_xyzabc(&self.tool)
        }
    }

    /// `t * pre_j * motion_j`: one joint of the forward pass.
    #[inline]
    fn advance(&self, t: &Frame, j: usize, m: JointMotion) -> Frame {
        self.advance_memo(t, j, m, None)
    }

    /// [`Chain::advance`] taking the joint angle's sine and cosine through `memo`.
    #[inline]
    fn advance_memo(
        &self,
        t: &Frame,
        j: usize,
        m: JointMotion,
        memo: Option<&mut TrigMemo>,
    ) -> Frame {
        let a = t.mul(&self.pre[j]);
        let theta = m.theta;
        match &self.joints[j].geometry {
            Geometry::Mdh { d, .. } => {
                let d = *d + m.shift;
                // a * Rz(theta) * Dz(d): rotate the first two columns, move along the third.
                let (s, c) = trig::sin_cos(theta, memo);
                let (c0, c1, c2) = (
                    a.r.column(0).into_owned(),
                    a.r.column(1).into_owned(),
                    a.r.column(2).into_owned(),
                );
                let mut r = a.r;
                r.set_column(0, &(c0 * c + c1 * s));
                r.set_column(1, &(c1 * c - c0 * s));
                Frame { r, p: a.p + c2 * d }
            }
            Geometry::Urdf { axis, .. } => match self.joints[j].kind {
                JointKind::Revolute => {
                    let (s, c) = trig::sin_cos(theta, memo);
                    a.mul(&Frame::rot_axis_sin_cos(axis, s, c))
                }
                JointKind::Prismatic => Frame {
                    r: a.r,
                    p: a.p + a.r * (axis * m.shift),
                },
                JointKind::Fixed => a,
            },
        }
    }

    /// Number of joint variables (moving joints that are not mimic joints).
    pub fn dof(&self) -> usize {
        self.actuated.len()
    }

    /// Indices of the joints with their own variable, in joint-variable order.
    pub fn actuated(&self) -> &[usize] {
        &self.actuated
    }

    /// Every parameter of the model, in a fixed order: joints, then base, then tool.
    pub fn param_ids(&self) -> Vec<ParamId> {
        let mut ids: Vec<ParamId> = Vec::new();
        for (j, joint) in self.joints.iter().enumerate() {
            ids.extend(joint_fields(joint).iter().map(|f| ParamId::Joint(j, *f)));
        }
        ids.extend((0..6).map(ParamId::Base));
        ids.extend((0..6).map(ParamId::Tool));
        ids
    }

    /// Position of `id` in [`Chain::param_ids`].
    pub fn param_index(&self, id: ParamId) -> Option<usize> {
        let nj = self.param_start.last().map_or(0, |s| {
            s + joint_fields(&self.joints[self.joints.len() - 1]).len()
        });
        match id {
            ParamId::Joint(j, f) => {
                let fields = joint_fields(self.joints.get(j)?);
                fields
                    .iter()
                    .position(|x| *x == f)
                    .map(|k| self.param_start[j] + k)
            }
            ParamId::Base(k) => Some(nj + k as usize),
            ParamId::Tool(k) => Some(nj + 6 + k as usize),
        }
    }

    /// The public name of a parameter.
    pub fn param_name(&self, id: ParamId) -> String {
        match id {
            ParamId::Base(k) => format!("base.{}", XYZABC[k as usize]),
            ParamId::Tool(k) => format!("tool.{}", XYZABC[k as usize]),
            ParamId::Joint(j, f) => match (&self.joints[j].geometry, f) {
                (Geometry::Mdh { .. }, JointField::Alpha) => format!("alpha{j}"),
                (Geometry::Mdh { .. }, JointField::A) => format!("a{j}"),
                (Geometry::Mdh { .. }, JointField::Beta) => format!("beta{j}"),
                (Geometry::Mdh { .. }, JointField::D) => format!("d{}", j + 1),
                (Geometry::Mdh { .. }, JointField::Offset) => format!("theta_offset{}", j + 1),
                (Geometry::Mdh { .. }, JointField::Compliance) => format!("c{}", j + 1),
                (Geometry::Mdh { .. }, JointField::Multiplier) => format!("multiplier{}", j + 1),
                (_, JointField::Err(k)) => {
                    format!("{}.{}", self.joints[j].name, URDF_ERRORS[k as usize])
                }
                (_, JointField::Offset | JointField::LinearOffset) => {
                    format!("{}.offset", self.joints[j].name)
                }
                (_, JointField::Multiplier) => format!("{}.multiplier", self.joints[j].name),
                (_, JointField::Compliance) => format!("{}.c", self.joints[j].name),
                (_, other) => format!("{}.{other:?}", self.joints[j].name),
            },
        }
    }

    /// The parameter with a public name.
    pub fn param_by_name(&self, name: &str) -> Result<ParamId, ModelError> {
        self.param_ids()
            .into_iter()
            .find(|id| self.param_name(*id) == name)
            .ok_or_else(|| ModelError::UnknownParameter(name.to_string()))
    }

    /// Current value of a parameter (internal units).
    pub fn param(&self, id: ParamId) -> f64 {
        match id {
            ParamId::Base(k) => self.base[k as usize],
            ParamId::Tool(k) => self.tool[k as usize],
            ParamId::Joint(j, f) => {
                let joint = &self.joints[j];
                match (&joint.geometry, f) {
                    (_, JointField::Offset | JointField::LinearOffset) => joint.offset,
                    (_, JointField::Compliance) => joint.compliance,
                    (_, JointField::Multiplier) => {
                        joint.mimic.as_ref().map_or(f64::NAN, |m| m.multiplier)
                    }
                    (Geometry::Mdh { alpha, .. }, JointField::Alpha) => *alpha,
                    (Geometry::Mdh { a, .. }, JointField::A) => *a,
                    (Geometry::Mdh { beta, .. }, JointField::Beta) => *beta,
                    (Geometry::Mdh { d, .. }, JointField::D) => *d,
                    (Geometry::Urdf { errors, .. }, JointField::Err(k)) => errors[k as usize],
                    _ => f64::NAN,
                }
            }
        }
    }

    /// Set one parameter (internal units).
    pub fn set_param(&mut self, id: ParamId, v: f64) {
        self.set_param_raw(id, v);
        match id {
            ParamId::Joint(j, _) => {
                self.pre[j] = pre_frame(&self.joints[j]);
                self.mdh_rots[j] = mdh_rotations(&self.joints[j]);
            }
            _ => self.refresh_ends(),
        }
    }

    /// Set many parameters at once (internal units), refreshing caches once.
    pub fn set_params(&mut self, ids: &[ParamId], values: &[f64]) {
        for (id, v) in ids.iter().zip(values) {
            self.set_param_raw(*id, *v);
        }
        self.refresh_joints();
        self.refresh_ends();
    }

    fn set_param_raw(&mut self, id: ParamId, v: f64) {
        match id {
            ParamId::Base(k) => self.base[k as usize] = v,
            ParamId::Tool(k) => self.tool[k as usize] = v,
            ParamId::Joint(j, f) => {
                let joint = &mut self.joints[j];
                match (&mut joint.geometry, f) {
                    (_, JointField::Offset | JointField::LinearOffset) => joint.offset = v,
                    (_, JointField::Compliance) => joint.compliance = v,
                    (_, JointField::Multiplier) => {
                        if let Some(m) = joint.mimic.as_mut() {
                            m.multiplier = v;
                        }
                    }
                    (Geometry::Mdh { alpha, .. }, JointField::Alpha) => *alpha = v,
                    (Geometry::Mdh { a, .. }, JointField::A) => *a = v,
                    (Geometry::Mdh { beta, .. }, JointField::Beta) => *beta = v,
                    (Geometry::Mdh { d, .. }, JointField::D) => *d = v,
                    (Geometry::Urdf { errors, .. }, JointField::Err(k)) => errors[k as usize] = v,
                    _ => {}
                }
            }
        }
    }

    /// Value of joint `j`'s variable: its own `q[k]`, a mimic joint's `multiplier *
    /// q[leader] + offset`, 0 for a fixed joint.
    fn value(&self, j: usize, q: &[f64]) -> f64 {
        match (&self.joints[j].mimic, self.var_of[j]) {
            (Some(m), _) => m.multiplier * q[m.leader] + m.offset,
            (None, Some(k)) => q[k],
            (None, None) => 0.0,
        }
    }

    /// Static torque of joint `j` (0 for a joint without its own variable).
    fn tau_of(&self, j: usize, tau: Option<&[f64]>) -> f64 {
        match (self.var_of[j], tau) {
            (Some(k), Some(t)) => t[k],
            _ => 0.0,
        }
    }

    /// Rotation and translation of joint `j` at `q`: revolute `theta = value + offset + c *
    /// tau`; prismatic URDF `shift = value + offset`; MDH rows keep `theta = offset` when
    /// they do not rotate and add the value of a prismatic row to `d`.
    fn motion(&self, j: usize, q: &[f64], tau: Option<&[f64]>) -> JointMotion {
        let joint = &self.joints[j];
        let v = self.value(j, q);
        let mdh = matches!(joint.geometry, Geometry::Mdh { .. });
        match joint.kind {
            JointKind::Revolute => JointMotion {
                theta: v + joint.offset + joint.compliance * self.tau_of(j, tau),
                shift: 0.0,
            },
            JointKind::Prismatic if mdh => JointMotion {
                theta: joint.offset,
                shift: v,
            },
            JointKind::Prismatic => JointMotion {
                theta: 0.0,
                shift: v + joint.offset,
            },
            JointKind::Fixed => JointMotion {
                theta: if mdh { joint.offset } else { 0.0 },
                shift: 0.0,
            },
        }
    }

    /// Physical quantity of joint variable `k` (angle or length), for table units.
    pub fn variable_quantity(&self, k: usize) -> Quantity {
        match self.joints[self.actuated[k]].kind {
            JointKind::Prismatic => Quantity::Length,
            _ => Quantity::Angle,
        }
    }

    /// Output frame of every joint in frame {0}, for joint variables `q` (rad) and optional
    /// static torques `tau` (N*m, compliance off when `None`).
    pub fn joint_frames(&self, q: &[f64], tau: Option<&[f64]>, out: &mut Vec<Frame>) {
        out.clear();
        let mut t = Frame::identity();
        for j in 0..self.joints.len() {
            t = self.advance(&t, j, self.motion(j, q, tau));
            out.push(t);
        }
    }

    /// Flange frame (output of the last joint) in {0}.
    pub fn flange(&self, q: &[f64], tau: Option<&[f64]>) -> Frame {
        let mut t = Frame::identity();
        for j in 0..self.joints.len() {
            t = self.advance(&t, j, self.motion(j, q, tau));
        }
        t
    }

    /// TCP frame in the robot frame {0} (the controller's base coordinates): chain * tool.
    pub fn tcp_in_base(&self, q: &[f64], tau: Option<&[f64]>) -> Frame {
        self.flange(q, tau).mul(&self.tool_frame())
    }

    /// TCP frame in the world frame {W}: base * chain * tool.
    pub fn tcp(&self, q: &[f64], tau: Option<&[f64]>) -> Frame {
        self.base_frame()
            .mul(&self.flange(q, tau))
            .mul(&self.tool_frame())
    }

    /// [`Chain::tcp`] with the joint sines and cosines of this configuration through `memo`
    /// (one per joint): the same frame bit for bit.
    pub fn tcp_memo(&self, q: &[f64], tau: Option<&[f64]>, memo: &mut [TrigMemo]) -> Frame {
        let mut t = Frame::identity();
        for j in 0..self.joints.len() {
            t = self.advance_memo(&t, j, self.motion(j, q, tau), memo.get_mut(j));
        }
        self.base_frame().mul(&t).mul(&self.tool_frame())
    }

    /// Static motor torques (N*m; N for prismatic joints) of the joint variables that hold
    /// the chain against gravity at `q` (zero velocity and acceleration), compliance off. A
    /// mimic joint's load reaches its leader's variable times the multiplier (virtual work).
    pub fn static_torques(&self, q: &[f64]) -> Vec<f64> {
        let mut frames = Vec::with_capacity(self.joints.len());
        self.joint_frames(q, None, &mut frames);
        self.torques_from_frames(&frames)
    }

    /// Static torques from precomputed joint frames (see [`Chain::joint_frames`]): one
    /// backward pass accumulating the mass and first moment carried by each joint.
    pub fn torques_from_frames(&self, frames: &[Frame]) -> Vec<f64> {
        let metre = self.units.metre();
        let mut tau = vec![0.0; self.dof()];
        let (mut mass, mut moment) = (0.0, Vector3::zeros());
        for j in (0..self.joints.len()).rev() {
            let f = &frames[j];
            for pm in self.masses.iter().filter(|pm| pm.body == j) {
                mass += pm.mass;
                moment += f.apply(&pm.com) * pm.mass;
            }
            let joint = &self.joints[j];
            // The joint axis passes through the output frame's origin (the motion rotates
            // about its own axis); its direction is the motion axis in that frame.
            let axis = f.r * joint_axis(joint);
            let load = match joint.kind {
                JointKind::Revolute => {
                    let arm = (moment - f.p * mass) * metre;
                    axis.dot(&arm.cross(&(-self.gravity)))
                }
                JointKind::Prismatic => mass * axis.dot(&(-self.gravity)),
                JointKind::Fixed => continue,
            };
            match (&joint.mimic, self.var_of[j]) {
                (Some(m), _) => tau[m.leader] += m.multiplier * load,
                (None, Some(k)) => tau[k] += load,
                (None, None) => {}
            }
        }
        tau
    }

    /// Limits of the joint variables (rad or length), in variable order; a joint without
    /// limits turns a full turn, [-pi, pi].
    pub fn variable_limits(&self) -> Vec<[f64; 2]> {
        self.actuated()
            .iter()
            .map(|&j| {
                self.joints[j]
                    .limits
                    .unwrap_or([-std::f64::consts::PI, std::f64::consts::PI])
            })
            .collect()
    }

    /// Check a joint vector against the limits; returns the first violation
    /// (variable index, value, limits) if any.
    pub fn limit_violation(&self, q: &[f64]) -> Option<(usize, f64, [f64; 2])> {
        for (k, &j) in self.actuated.iter().enumerate() {
            if let Some(l) = self.joints[j].limits {
                let v = q[k];
                let tol = 1e-9;
                if !(v >= l[0] - tol && v <= l[1] + tol) {
                    return Some((k, v, l));
                }
            }
        }
        None
    }
}

/// The parameter fields a joint has, in flat-list order: compliance only for a revolute
/// joint with its own variable, the multiplier only for a mimic joint.
fn joint_fields(j: &Joint) -> &'static [JointField] {
    use JointField::*;
    let mimic = j.mimic.is_some();
    match (&j.geometry, j.kind, mimic) {
        (Geometry::Mdh { .. }, JointKind::Revolute, false) => {
            &[Alpha, A, Beta, D, Offset, Compliance]
        }
        (Geometry::Mdh { .. }, JointKind::Fixed, _) => &[Alpha, A, Beta, D, Offset],
        (Geometry::Mdh { .. }, _, true) => &[Alpha, A, Beta, D, Offset, Multiplier],
        (Geometry::Mdh { .. }, JointKind::Prismatic, false) => &[Alpha, A, Beta, D, Offset],
        (Geometry::Urdf { .. }, JointKind::Revolute, false) => &[
            Err(0),
            Err(1),
            Err(2),
            Err(3),
            Err(4),
            Err(5),
            Offset,
            Compliance,
        ],
        (Geometry::Urdf { .. }, JointKind::Revolute, true) => &[
            Err(0),
            Err(1),
            Err(2),
            Err(3),
            Err(4),
            Err(5),
            Offset,
            Multiplier,
        ],
        (Geometry::Urdf { .. }, JointKind::Prismatic, false) => {
            &[Err(0), Err(1), Err(2), Err(3), Err(4), Err(5), LinearOffset]
        }
        (Geometry::Urdf { .. }, JointKind::Prismatic, true) => &[
            Err(0),
            Err(1),
            Err(2),
            Err(3),
            Err(4),
            Err(5),
            LinearOffset,
            Multiplier,
        ],
        (Geometry::Urdf { .. }, JointKind::Fixed, _) => {
            &[Err(0), Err(1), Err(2), Err(3), Err(4), Err(5)]
        }
    }
}

/// The constant transform before the joint motion.
fn pre_frame(j: &Joint) -> Frame {
    match &j.geometry {
        Geometry::Mdh { alpha, a, beta, .. } => Frame::rot_x(*alpha)
            .mul(&Frame::trans(*a, 0.0, 0.0))
            .mul(&Frame::rot_y(*beta)),
        Geometry::Urdf { origin, errors, .. } => origin.mul(&Frame::from_urdf_errors(errors)),
    }
}

/// Rotation axis of a joint in its output frame.
pub(crate) fn joint_axis(j: &Joint) -> Vector3<f64> {
    match &j.geometry {
        Geometry::Mdh { .. } => Vector3::z(),
        Geometry::Urdf { axis, .. } => *axis,
    }
}

impl Frame {
    /// `Dx(dx) Dy(dy) Dz(dz) Rx(rx) Ry(ry) Rz(rz)`: URDF placement errors.
    pub fn from_urdf_errors(e: &[f64; 6]) -> Frame {
        let r = Frame::rot_x(e[3]).r * Frame::rot_y(e[4]).r * Frame::rot_z(e[5]).r;
        Frame {
            r,
            p: Vector3::new(e[0], e[1], e[2]),
        }
    }
}

mod jacobian;
#[cfg(test)]
mod tests;
