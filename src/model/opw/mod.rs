//! Closed-form inverse kinematics of a 6R arm with an ortho-parallel base and a spherical
//! wrist (the OPW family of Brandstötter et al. 2014), written for the modified-DH rows of
//! a serial model file: the start point and the branch of [`super::compensate`].
//!
//! The structure is read from the model itself, rounded to the ideal arm: every alpha to
//! the nearest multiple of 90 deg, beta to 0, and the wrist offsets a4, a5, d5 to 0. A
//! calibrated model is a little off this ideal arm; its exact joints come from a Newton
//! iteration started here. The constant part of the first row (alpha0, a0, beta0) is folded
//! into the base, so joint 1 is a rotation about z of the base frame.

use std::f64::consts::{FRAC_PI_2, PI};

use nalgebra::Matrix3;

use super::chain::{Chain, Geometry};
use super::joint::JointKind;
use crate::geometry::Frame;

/// How far (rad) an alpha or beta may be from its ideal value for the closed form to apply.
const ANGLE_TOL: f64 = 2.0 * PI / 180.0;
/// Below this |sin| a wrist, elbow or shoulder configuration counts as singular in the
/// closed form (the joints it couples are then not separated).
const SIN_EPS: f64 = 1e-12;

/// Why a chain does not have the OPW structure.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("not a 6R arm with an ortho-parallel base and a spherical wrist: {0}")]
pub struct NotOpw(pub String);

/// The ideal arm of a model: the numbers the closed form needs (internal units).
#[derive(Debug, Clone, PartialEq)]
pub struct Opw {
    /// Robot frame {0} in {W}, times the constant part of row 1.
    base: Frame,
    /// TCP in the flange frame.
    tool: Frame,
    /// d1 (length).
    d1: f64,
    /// a1, offset of axis 2 from axis 1.
    a1: f64,
    /// sin(alpha1) (+1 or -1).
    s1: f64,
    /// d2 + d3: offset of the arm plane along axis 2.
    b: f64,
    /// a2: from axis 2 to axis 3.
    a2: f64,
    /// From axis 3 to the wrist centre, in the plane of the arm.
    l3: f64,
    /// Angle of that segment in frame 3 at theta3 = 0.
    psi3: f64,
    /// sin(alpha3), sin(alpha4), sin(alpha5) (+1 or -1 each).
    s3: f64,
    s4: f64,
    s5: f64,
    /// d6: wrist centre to flange along axis 6.
    d6: f64,
    /// theta_offset of each joint (theta = q + offset).
    offsets: [f64; 6],
}

/// Where a configuration stands relative to the three singularities of the ideal arm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Singularity {
    /// |sin(theta5)|: 0 when axes 4 and 6 are aligned (wrist singularity).
    pub wrist: f64,
    /// |sin| of the elbow angle: 0 when the arm is stretched or folded (elbow singularity).
    pub elbow: f64,
    /// Distance of the wrist centre from axis 1, beyond the offset b (shoulder singularity
    /// at 0), in the model's length unit.
    pub shoulder: f64,
}

/// The nearest multiple of 90 deg to `v` as (value, sin, cos), or `None` beyond the tolerance.
fn snap(v: f64) -> Option<(f64, f64, f64)> {
    let k = (v / FRAC_PI_2).round();
    ((v - k * FRAC_PI_2).abs() <= ANGLE_TOL).then(|| {
        let m = (k as i64).rem_euclid(4);
        let (s, c) = [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0)][m as usize];
        (k * FRAC_PI_2, s, c)
    })
}

impl Opw {
    /// The ideal arm of `chain`; an error says which row breaks the structure. Wrist
    /// offsets (a4, a5, d5) up to `wrist_tol` (length unit) are taken as zero.
    pub fn of(chain: &Chain, wrist_tol: f64) -> Result<Opw, NotOpw> {
        let n = chain.joints.len();
        if n != 6 || chain.dof() != 6 {
            return Err(NotOpw(format!(
                "{n} joints with {} variables (6 revolute joints needed)",
                chain.dof()
            )));
        }
        let mut alpha = [0.0; 6];
        let mut a = [0.0; 6];
        let mut d = [0.0; 6];
        let mut beta = [0.0; 6];
        let mut offsets = [0.0; 6];
        for (i, j) in chain.joints.iter().enumerate() {
            if j.kind != JointKind::Revolute || j.mimic.is_some() {
                return Err(NotOpw(format!("joint {} is not revolute", i + 1)));
            }
            let Geometry::Mdh {
                alpha: al,
                a: aa,
                beta: be,
                d: dd,
            } = j.geometry
            else {
                return Err(NotOpw(format!(
                    "joint {} is not a modified-DH row (URDF joint)",
                    i + 1
                )));
            };
            (alpha[i], a[i], beta[i], d[i]) = (al, aa, be, dd);
            offsets[i] = j.offset;
        }
        let sin_of = |i: usize, want: &[f64]| -> Result<f64, NotOpw> {
            match snap(alpha[i]) {
                Some((_, s, c)) if want.contains(&s) && (s != 0.0 || c == 1.0) => Ok(s),
                _ => Err(NotOpw(format!(
                    "alpha{i} = {:.3} deg (the structure needs {})",
                    alpha[i].to_degrees(),
                    if want.contains(&0.0) { "0" } else { "+-90 deg" }
                ))),
            }
        };
        let s1 = sin_of(1, &[1.0, -1.0])?;
        sin_of(2, &[0.0])?;
        let s3 = sin_of(3, &[1.0, -1.0])?;
        let s4 = sin_of(4, &[1.0, -1.0])?;
        let s5 = sin_of(5, &[1.0, -1.0])?;
        for (i, b) in beta.iter().enumerate().skip(1) {
            if b.abs() > ANGLE_TOL {
                return Err(NotOpw(format!(
                    "beta{i} = {:.3} deg is not near 0",
                    b.to_degrees()
                )));
            }
        }
        for (name, v) in [("a4", a[4]), ("a5", a[5]), ("d5", d[4])] {
            if v.abs() > wrist_tol {
                return Err(NotOpw(format!(
                    "{name} = {v}: the wrist is not spherical (offset above {wrist_tol})"
                )));
            }
        }
        // Row 1's constant part Rx(alpha0) Dx(a0) Ry(beta0) belongs to the base.
        let pre0 = Frame::rot_x(alpha[0])
            .mul(&Frame::trans(a[0], 0.0, 0.0))
            .mul(&Frame::rot_y(beta[0]));
        // Wrist centre in frame 3: Rx(alpha3) Dx(a3) Dz(d4) at theta4 = 0.
        let (wx, wy) = (a[3], -s3 * d[3]);
        Ok(Opw {
            base: chain.base_frame().mul(&pre0),
            tool: chain.tool_frame(),
            d1: d[0],
            a1: a[1],
            s1,
            b: -s1 * (d[1] + d[2]),
            a2: a[2],
            l3: wx.hypot(wy),
            psi3: wy.atan2(wx),
            s3,
            s4,
            s5,
            d6: d[5],
            offsets,
        })
    }

    /// Every solution (joint values q, rad, not wrapped) that puts the TCP at `target` (in
    /// {W}), up to eight; empty when the target is out of the ideal arm's reach. At a wrist
    /// singularity theta4 is `q4_hint` (converted to theta) and one wrist solution is given.
    pub fn solve(&self, target: &Frame, q4_hint: f64) -> Vec<[f64; 6]> {
        let f = self.base.inverse().mul(target).mul(&self.tool.inverse());
        let pc = f.p - f.r.column(2) * self.d6;
        let (px, py) = (pc.x, pc.y);
        let r2 = px * px + py * py - self.b * self.b;
        if r2 < 0.0 {
            return Vec::new();
        }
        let mut out = Vec::with_capacity(8);
        for xr in [r2.sqrt(), -r2.sqrt()] {
            let t1 = py.atan2(px) - self.b.atan2(xr);
            let u = xr - self.a1;
            let v = (pc.z - self.d1) * self.s1;
            let den = 2.0 * self.a2 * self.l3;
            let dd = (u * u + v * v - self.a2 * self.a2 - self.l3 * self.l3) / den;
            if !(dd.abs() <= 1.0) {
                continue;
            }
            for phi in [dd.acos(), -dd.acos()] {
                let t3 = phi - self.psi3;
                let t2 = v.atan2(u) - (self.l3 * phi.sin()).atan2(self.a2 + self.l3 * phi.cos());
                // Frame 3 rotation, then Rx(alpha3).
                let r03 = Frame::rot_z(t1).r
                    * rot_x_s(self.s1)
                    * Frame::rot_z(t2).r
                    * Frame::rot_z(t3).r
                    * rot_x_s(self.s3);
                let m = r03.transpose() * f.r;
                for t in self.wrist(&m, q4_hint + self.offsets[3]) {
                    let th = [t1, t2, t3, t[0], t[1], t[2]];
                    let mut q = [0.0; 6];
                    for k in 0..6 {
                        q[k] = wrap(th[k] - self.offsets[k]);
                    }
                    out.push(q);
                }
                if phi == 0.0 {
                    break;
                }
            }
            if xr == 0.0 {
                break;
            }
        }
        out
    }

    /// theta4, theta5, theta6 with `Rz(t4) Rx(alpha4) Rz(t5) Rx(alpha5) Rz(t6) = m`: two
    /// solutions, or one (theta4 = `t4_hint`) at the wrist singularity.
    fn wrist(&self, m: &Matrix3<f64>, t4_hint: f64) -> Vec<[f64; 3]> {
        let z = m.column(2);
        let c5 = (-z.z * self.s4 * self.s5).clamp(-1.0, 1.0);
        let s5abs = (1.0 - c5 * c5).max(0.0).sqrt();
        let mut out = Vec::with_capacity(2);
        let signs: &[f64] = if s5abs < SIN_EPS {
            &[0.0]
        } else {
            &[1.0, -1.0]
        };
        for &sg in signs {
            let s5 = sg * s5abs;
            let t5 = s5.atan2(c5);
            let t4 = if sg == 0.0 {
                t4_hint
            } else {
                (self.s5 * z.y / s5).atan2(self.s5 * z.x / s5)
            };
            let r = Frame::rot_z(t4).r * rot_x_s(self.s4) * Frame::rot_z(t5).r * rot_x_s(self.s5);
            let n = r.transpose() * m;
            out.push([t4, t5, n[(1, 0)].atan2(n[(0, 0)])]);
        }
        out
    }

    /// Signed branch measures at `q` (rad): the wrist centre's x in frame 1 (its sign tells
    /// in front of or behind axis 1), the sine of the elbow angle and the sine of theta5.
    pub fn branch_signs(&self, q: &[f64]) -> [f64; 3] {
        let th = |k: usize| q[k] + self.offsets[k];
        let phi = th(2) + self.psi3;
        let (x, y) = (self.a2 + self.l3 * phi.cos(), self.l3 * phi.sin());
        let x1 = self.a1 + th(1).cos() * x - th(1).sin() * y;
        [x1, phi.sin(), th(4).sin()]
    }

    /// The singularity measures of the ideal arm at joint values `q` (rad).
    pub fn singularity(&self, q: &[f64]) -> Singularity {
        let th = |k: usize| q[k] + self.offsets[k];
        let phi = th(2) + self.psi3;
        // Wrist centre in frame 1 (x1, along axis 2 is b): x1 = a1 + (Rz(t2) (X, Y))_x.
        let (x, y) = (self.a2 + self.l3 * phi.cos(), self.l3 * phi.sin());
        let x1 = self.a1 + th(1).cos() * x - th(1).sin() * y;
        Singularity {
            wrist: th(4).sin().abs(),
            elbow: phi.sin().abs(),
            shoulder: x1.abs(),
        }
    }
}

/// `Rx(alpha)` for alpha = +-90 deg given by its sine.
fn rot_x_s(s: f64) -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -s, 0.0, s, 0.0)
}

/// An angle in (-pi, pi].
pub fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

/// The value `q + 2 pi k` nearest `reference`, preferring one within `limits` (rad) when
/// any is; `q` itself when no limit and no reference move it.
pub fn nearest_turn(q: f64, reference: f64, limits: Option<[f64; 2]>) -> f64 {
    let tau = 2.0 * PI;
    let base = q + ((reference - q) / tau).round() * tau;
    let Some([lo, hi]) = limits else {
        return base;
    };
    let inside = |v: f64| v >= lo - 1e-9 && v <= hi + 1e-9;
    if inside(base) {
        return base;
    }
    // The nearest turn inside the limits, if the range holds one.
    let mut best: Option<f64> = None;
    let k0 = ((lo - q) / tau).ceil() as i64;
    let k1 = ((hi - q) / tau).floor() as i64;
    for k in k0..=k1.min(k0 + 8) {
        let v = q + k as f64 * tau;
        if inside(v) && best.is_none_or(|b| (v - reference).abs() < (b - reference).abs()) {
            best = Some(v);
        }
    }
    best.unwrap_or(base)
}

#[cfg(test)]
mod tests;
