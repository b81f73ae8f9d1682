//! `Pose2`: a planar rigid transform (x, y, theta), used by the planar continuum robot and its
//! microscope.

use nalgebra::Vector2;

/// Planar pose of a child frame in a parent frame: translation (x, y) and angle theta (rad).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose2 {
    /// x of the child origin in the parent.
    pub x: f64,
    /// y of the child origin in the parent.
    pub y: f64,
    /// Angle of the child x axis in the parent (radians).
    pub theta: f64,
}

impl Pose2 {
    /// A pose from its three coordinates.
    pub fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    /// Composition `self * o` (o expressed in self's child frame).
    pub fn compose(&self, o: &Pose2) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2 {
            x: self.x + c * o.x - s * o.y,
            y: self.y + s * o.x + c * o.y,
            theta: self.theta + o.theta,
        }
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2 {
            x: -(c * self.x + s * self.y),
            y: s * self.x - c * self.y,
            theta: -self.theta,
        }
    }

    /// Maps a point of the child frame into the parent frame.
    pub fn apply(&self, v: &Vector2<f64>) -> Vector2<f64> {
        let (s, c) = self.theta.sin_cos();
        Vector2::new(self.x + c * v.x - s * v.y, self.y + s * v.x + c * v.y)
    }
}

/// Wraps an angle into (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let mut w = a % t;
    if w <= -std::f64::consts::PI {
        w += t;
    } else if w > std::f64::consts::PI {
        w -= t;
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compose_with_inverse_is_identity() {
        let p = Pose2::new(0.3, -0.1, 0.7);
        let id = p.compose(&p.inverse());
        assert!(id.x.abs() < 1e-15 && id.y.abs() < 1e-15 && id.theta.abs() < 1e-15);
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
    }
}
