//! `Frame`: a rigid transform (rotation matrix + translation) in 3-D, and the elementary
//! one-parameter motions (rotations and translations about the local axes) that model
//! parameters act through.

use nalgebra::{Matrix3, Vector3};

/// A rigid transform: maps a point `v` in the child frame to `r * v + p` in the parent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Rotation (orthonormal, det +1).
    pub r: Matrix3<f64>,
    /// Translation (origin of the child in the parent), in the model's length unit.
    pub p: Vector3<f64>,
}

/// A one-parameter elementary motion about or along a local axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Motion {
    /// Rotation about local x.
    Rx,
    /// Rotation about local y.
    Ry,
    /// Rotation about local z.
    Rz,
    /// Translation along local x.
    Dx,
    /// Translation along local y.
    Dy,
    /// Translation along local z.
    Dz,
}

impl Motion {
    /// The unit axis of the motion in the local frame.
    pub fn axis(self) -> Vector3<f64> {
        match self {
            Motion::Rx | Motion::Dx => Vector3::x(),
            Motion::Ry | Motion::Dy => Vector3::y(),
            Motion::Rz | Motion::Dz => Vector3::z(),
        }
    }

    /// Whether the motion is a rotation (else a translation).
    pub fn is_rotation(self) -> bool {
        matches!(self, Motion::Rx | Motion::Ry | Motion::Rz)
    }

    /// The transform of this motion by `v` (radians or length).
    pub fn frame(self, v: f64) -> Frame {
        match self {
            Motion::Rx => Frame::rot_x(v),
            Motion::Ry => Frame::rot_y(v),
            Motion::Rz => Frame::rot_z(v),
            Motion::Dx => Frame::trans(v, 0.0, 0.0),
            Motion::Dy => Frame::trans(0.0, v, 0.0),
            Motion::Dz => Frame::trans(0.0, 0.0, v),
        }
    }
}

impl Default for Frame {
    fn default() -> Self {
        Self::identity()
    }
}

impl Frame {
    /// The identity transform.
    pub fn identity() -> Self {
        Self {
            r: Matrix3::identity(),
            p: Vector3::zeros(),
        }
    }

    /// A pure translation.
    pub fn trans(x: f64, y: f64, z: f64) -> Self {
        Self {
            r: Matrix3::identity(),
            p: Vector3::new(x, y, z),
        }
    }

    /// Rotation about x by `a` radians.
    pub fn rot_x(a: f64) -> Self {
        let (s, c) = a.sin_cos();
        Self {
            r: Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c),
            p: Vector3::zeros(),
        }
    }

    /// Rotation about y by `a` radians.
    pub fn rot_y(a: f64) -> Self {
        let (s, c) = a.sin_cos();
        Self {
            r: Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c),
            p: Vector3::zeros(),
        }
    }

    /// Rotation about z by `a` radians.
    pub fn rot_z(a: f64) -> Self {
        let (s, c) = a.sin_cos();
        Self::rot_z_sin_cos(s, c)
    }

    /// [`Frame::rot_z`] of the angle whose sine and cosine are `s` and `c`.
    #[inline]
    pub fn rot_z_sin_cos(s: f64, c: f64) -> Self {
        Self {
            r: Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
            p: Vector3::zeros(),
        }
    }

    /// Rotation by `a` radians about the unit axis `u` (Rodrigues).
    pub fn rot_axis(u: &Vector3<f64>, a: f64) -> Self {
        let (s, c) = a.sin_cos();
        Self::rot_axis_sin_cos(u, s, c)
    }

    /// [`Frame::rot_axis`] of the angle whose sine and cosine are `s` and `c`.
    #[inline]
    pub fn rot_axis_sin_cos(u: &Vector3<f64>, s: f64, c: f64) -> Self {
        let k = u.cross_matrix();
        Self {
            r: Matrix3::identity() + k * s + k * k * (1.0 - c),
            p: Vector3::zeros(),
        }
    }

    /// `Dx(x) Dy(y) Dz(z) Rz(a) Ry(b) Rx(c)`: the base/tool convention of the serial
    /// model, and also URDF's `xyz` + `rpy` (roll = c, pitch = b, yaw = a). Angles in radians.
    pub fn from_xyzabc(v: &[f64; 6]) -> Self {
        let r = Frame::rot_z(v[3]).r * Frame::rot_y(v[4]).r * Frame::rot_x(v[5]).r;
        Self {
            r,
            p: Vector3::new(v[0], v[1], v[2]),
        }
    }

    /// Inverse of [`Frame::from_xyzabc`]: ZYX Euler angles (b in [-pi/2, pi/2]).
    pub fn to_xyzabc(&self) -> [f64; 6] {
        let r = &self.r;
        let b = (-r[(2, 0)]).clamp(-1.0, 1.0).asin();
        let (a, c) = if r[(2, 0)].abs() < 1.0 - 1e-12 {
            (r[(1, 0)].atan2(r[(0, 0)]), r[(2, 1)].atan2(r[(2, 2)]))
        } else {
            // Gimbal lock: only a - c (or a + c) is defined; put it all in a.
            ((-r[(0, 1)]).atan2(r[(1, 1)]), 0.0)
        };
        [self.p.x, self.p.y, self.p.z, a, b, c]
    }

    /// Composition `self * other`.
    #[inline]
    pub fn mul(&self, o: &Frame) -> Frame {
        Frame {
            r: self.r * o.r,
            p: self.r * o.p + self.p,
        }
    }

    /// `self * Frame::rot_x(a)` given `m = Frame::rot_x(a).r`, without the products with
    /// its zeros and ones: the same values (those products are exact and add nothing; only
    /// the sign of a zero result can differ).
    #[inline]
    pub fn then_rot_x(&self, m: &Matrix3<f64>) -> Frame {
        let (c0, c1, c2) = (self.r.column(0), self.r.column(1), self.r.column(2));
        Frame {
            r: Matrix3::from_columns(&[
                c0.into_owned(),
                c1 * m[(1, 1)] + c2 * m[(2, 1)],
                c1 * m[(1, 2)] + c2 * m[(2, 2)],
            ]),
            p: self.p,
        }
    }

    /// `self * Frame::rot_y(b)` given `m = Frame::rot_y(b).r`, as [`Frame::then_rot_x`].
    #[inline]
    pub fn then_rot_y(&self, m: &Matrix3<f64>) -> Frame {
        let (c0, c1, c2) = (self.r.column(0), self.r.column(1), self.r.column(2));
        Frame {
            r: Matrix3::from_columns(&[
                c0 * m[(0, 0)] + c2 * m[(2, 0)],
                c1.into_owned(),
                c0 * m[(0, 2)] + c2 * m[(2, 2)],
            ]),
            p: self.p,
        }
    }

    /// `self * Frame::rot_z_sin_cos(s, c)`, as [`Frame::then_rot_x`].
    #[inline]
    pub fn then_rot_z_sin_cos(&self, s: f64, c: f64) -> Frame {
        let (c0, c1, c2) = (self.r.column(0), self.r.column(1), self.r.column(2));
        Frame {
            r: Matrix3::from_columns(&[c0 * c + c1 * s, c0 * (-s) + c1 * c, c2.into_owned()]),
            p: self.p,
        }
    }

    /// `self * Frame::trans(x, 0, 0)`, as [`Frame::then_rot_x`].
    #[inline]
    pub fn then_dx(&self, x: f64) -> Frame {
        Frame {
            r: self.r,
            p: self.r.column(0) * x + self.p,
        }
    }

    /// `self * Frame::trans(0, 0, z)`, as [`Frame::then_rot_x`].
    #[inline]
    pub fn then_dz(&self, z: f64) -> Frame {
        Frame {
            r: self.r,
            p: self.r.column(2) * z + self.p,
        }
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Frame {
        let rt = self.r.transpose();
        Frame {
            r: rt,
            p: -(rt * self.p),
        }
    }

    /// Maps a point of the child frame into the parent frame.
    #[inline]
    pub fn apply(&self, v: &Vector3<f64>) -> Vector3<f64> {
        self.r * v + self.p
    }

    /// Angle of the relative rotation between two frames (radians).
    pub fn angle_to(&self, o: &Frame) -> f64 {
        let rel = self.r.transpose() * o.r;
        ((rel.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos()
    }
}

impl std::ops::Mul for Frame {
    type Output = Frame;
    fn mul(self, o: Frame) -> Frame {
        Frame::mul(&self, &o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xyzabc_round_trip_and_inverse() {
        let v = [1.0, -2.0, 3.0, 0.3, -0.4, 1.2];
        let f = Frame::from_xyzabc(&v);
        let back = f.to_xyzabc();
        for k in 0..6 {
            assert!(
                (back[k] - v[k]).abs() < 1e-12,
                "{k}: {} vs {}",
                back[k],
                v[k]
            );
        }
        let id = f * f.inverse();
        assert!((id.r - Matrix3::identity()).norm() < 1e-14);
        assert!(id.p.norm() < 1e-14);
    }

    /// The structured products equal the general ones bit for bit (no zero results here).
    #[test]
    fn structured_products_equal_the_general_ones() {
        let f = Frame::from_xyzabc(&[1.0, -2.0, 3.0, 0.3, -0.4, 1.2]);
        let bits =
            |g: &Frame| -> Vec<u64> { g.r.iter().chain(g.p.iter()).map(|v| v.to_bits()).collect() };
        let (a, b, t) = (0.37_f64, -1.1_f64, 2.9_f64);
        let (s, c) = t.sin_cos();
        assert_eq!(
            bits(&f.then_rot_x(&Frame::rot_x(a).r)),
            bits(&f.mul(&Frame::rot_x(a)))
        );
        assert_eq!(
            bits(&f.then_rot_y(&Frame::rot_y(b).r)),
            bits(&f.mul(&Frame::rot_y(b)))
        );
        assert_eq!(
            bits(&f.then_rot_z_sin_cos(s, c)),
            bits(&f.mul(&Frame::rot_z(t)))
        );
        assert_eq!(
            bits(&f.then_dx(0.25)),
            bits(&f.mul(&Frame::trans(0.25, 0.0, 0.0)))
        );
        assert_eq!(
            bits(&f.then_dz(-7.5)),
            bits(&f.mul(&Frame::trans(0.0, 0.0, -7.5)))
        );
    }

    #[test]
    fn rodrigues_matches_elementary_rotations() {
        for (u, f) in [
            (Vector3::x(), Frame::rot_x(0.7)),
            (Vector3::y(), Frame::rot_y(0.7)),
            (Vector3::z(), Frame::rot_z(0.7)),
        ] {
            assert!((Frame::rot_axis(&u, 0.7).r - f.r).norm() < 1e-15);
        }
        // A rotation about z by 90 degrees maps x to y.
        let y = Frame::rot_z(std::f64::consts::FRAC_PI_2).apply(&Vector3::x());
        assert!((y - Vector3::y()).norm() < 1e-15);
    }
}
