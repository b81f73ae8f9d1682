//! Feasibility of a posture: joint limits, static torque within the effort limit, a point
//! (end effector) inside a box of the root frame, and no contact between the spheres that
//! approximate the links. Generic: the caller supplies body frames and torques.

use nalgebra::Vector3;
use serde::Serialize;

use crate::geometry::Frame;

/// A sphere fixed on a body.
#[derive(Debug, Clone, PartialEq)]
pub struct Sphere {
    /// Body index (into the frames given to [`Constraints::check`]).
    pub body: usize,
    /// Centre in the body frame (m).
    pub centre: Vector3<f64>,
    /// Radius (m).
    pub radius: f64,
}

/// A point of a body that must stay inside an axis-aligned box of the root frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PointBox {
    /// Body index.
    pub body: usize,
    /// The point in the body frame (m).
    pub point: Vector3<f64>,
    /// Lower corner (m).
    pub min: Vector3<f64>,
    /// Upper corner (m).
    pub max: Vector3<f64>,
}

/// Why a posture is infeasible.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "constraint", rename_all = "snake_case")]
pub enum Violation {
    /// Joint `joint` at `value` outside its limits.
    JointLimit {
        /// Variable index.
        joint: usize,
        /// Value (rad).
        value: f64,
    },
    /// Static torque above the effort limit.
    Torque {
        /// Variable index.
        joint: usize,
        /// Torque (N*m).
        torque: f64,
        /// Effort limit (N*m).
        effort: f64,
    },
    /// The boxed point is outside its box.
    Box {
        /// The point in the root frame (m).
        point: [f64; 3],
    },
    /// Two bodies' spheres overlap.
    Collision {
        /// First body.
        body_a: usize,
        /// Second body.
        body_b: usize,
        /// Signed distance between the sphere surfaces (m, negative = overlap).
        distance: f64,
    },
}

/// The constraints of posture design.
#[derive(Debug, Clone, Default)]
pub struct Constraints {
    /// Joint limits (rad).
    pub limits: Vec<[f64; 2]>,
    /// Effort limits (N*m), `None` = unchecked.
    pub efforts: Vec<Option<f64>>,
    /// Optional end-effector box.
    pub ee_box: Option<PointBox>,
    /// Link spheres.
    pub spheres: Vec<Sphere>,
    /// Sphere index pairs to test.
    pub pairs: Vec<(usize, usize)>,
}

impl Constraints {
    /// Keep the sphere pairs whose bodies `allowed(a, b)` says may collide.
    pub fn set_pairs(&mut self, allowed: impl Fn(usize, usize) -> bool) {
        let s = &self.spheres;
        self.pairs = (0..s.len())
            .flat_map(|i| (i + 1..s.len()).map(move |j| (i, j)))
            .filter(|&(i, j)| s[i].body != s[j].body && allowed(s[i].body, s[j].body))
            .collect();
    }

    /// The first joint outside its limits, if any (checked first: cheapest).
    pub fn limit_violation(&self, q: &[f64]) -> Option<Violation> {
        self.limits
            .iter()
            .zip(q)
            .position(|(l, v)| !(*v >= l[0] - 1e-12 && *v <= l[1] + 1e-12))
            .map(|joint| Violation::JointLimit {
                joint,
                value: q[joint],
            })
    }

    /// The first violated constraint at a posture with body `frames` (root frame) and
    /// static `torques`, or `None` when feasible.
    pub fn check(&self, q: &[f64], frames: &[Frame], torques: &[f64]) -> Option<Violation> {
        if let Some(v) = self.limit_violation(q) {
            return Some(v);
        }
        for (joint, (t, e)) in torques.iter().zip(&self.efforts).enumerate() {
            if let Some(e) = e
                && t.abs() > *e
            {
                return Some(Violation::Torque {
                    joint,
                    torque: *t,
                    effort: *e,
                });
            }
        }
        if let Some(b) = &self.ee_box {
            let p = frames[b.body].apply(&b.point);
            if (0..3).any(|k| p[k] < b.min[k] || p[k] > b.max[k]) {
                return Some(Violation::Box {
                    point: [p.x, p.y, p.z],
                });
            }
        }
        let centres: Vec<Vector3<f64>> = self
            .spheres
            .iter()
            .map(|s| frames[s.body].apply(&s.centre))
            .collect();
        // The deepest overlap, if any.
        let mut worst: Option<(usize, usize, f64)> = None;
        for &(i, j) in &self.pairs {
            let d =
                (centres[i] - centres[j]).norm() - self.spheres[i].radius - self.spheres[j].radius;
            if d <= 0.0 && worst.is_none_or(|w| d < w.2) {
                worst = Some((i, j, d));
            }
        }
        worst.map(|(i, j, d)| Violation::Collision {
            body_a: self.spheres[i].body,
            body_b: self.spheres[j].body,
            distance: d,
        })
    }
}

/// Spheres of `radius` every `radius` along the segment from `a` to `b` (both ends included).
pub fn spheres_along(body: usize, a: Vector3<f64>, b: Vector3<f64>, radius: f64) -> Vec<Sphere> {
    let n = ((b - a).norm() / radius.max(1e-6)).ceil() as usize;
    (0..=n)
        .map(|k| Sphere {
            body,
            centre: a + (b - a) * (k as f64 / n.max(1) as f64),
            radius,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_constraint_is_reported() {
        let mut c = Constraints {
            limits: vec![[-1.0, 1.0]; 2],
            efforts: vec![Some(10.0), None],
            ee_box: Some(PointBox {
                body: 1,
                point: Vector3::zeros(),
                min: Vector3::new(-1.0, -1.0, -1.0),
                max: Vector3::new(1.0, 1.0, 1.0),
            }),
            spheres: [
                spheres_along(0, Vector3::zeros(), Vector3::x(), 0.1),
                spheres_along(1, Vector3::zeros(), Vector3::zeros(), 0.1),
            ]
            .concat(),
            pairs: vec![],
        };
        assert_eq!(c.spheres.len(), 12);
        c.set_pairs(|_, _| true);
        assert_eq!(c.pairs.len(), 11);
        let far = [Frame::identity(), Frame::trans(0.5, 0.5, 0.0)];
        assert_eq!(c.check(&[0.0, 0.0], &far, &[5.0, 100.0]), None);
        assert!(matches!(
            c.check(&[1.5, 0.0], &far, &[0.0, 0.0]),
            Some(Violation::JointLimit { joint: 0, .. })
        ));
        assert!(matches!(
            c.check(&[0.0, 0.0], &far, &[-11.0, 0.0]),
            Some(Violation::Torque { joint: 0, .. })
        ));
        let out = [Frame::identity(), Frame::trans(2.0, 0.0, 0.0)];
        assert!(matches!(
            c.check(&[0.0, 0.0], &out, &[0.0, 0.0]),
            Some(Violation::Box { .. })
        ));
        // A sphere of body 1 at (0.5, 0.15): 0.15 from the segment, radii sum 0.2: contact.
        let near = [Frame::identity(), Frame::trans(0.5, 0.15, 0.0)];
        match c.check(&[0.0, 0.0], &near, &[0.0, 0.0]) {
            Some(Violation::Collision { distance, .. }) => assert!((distance + 0.05).abs() < 1e-12),
            other => panic!("{other:?}"),
        }
        c.set_pairs(|_, _| false);
        assert_eq!(c.check(&[0.0, 0.0], &near, &[0.0, 0.0]), None);
    }
}
