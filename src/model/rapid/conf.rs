//! The ABB configuration data `cf1, cf4, cf6, cfx` of joint values, and the joints an IRC5
//! picks for a pose and its configuration (the controller's nominal inverse kinematics):
//! `cf1`, `cf4`, `cf6` are the quadrants (90 deg, `floor(q / 90)`) of axes 1, 4 and 6;
//! `cfx` = 4 (wrist centre behind axis 1) + 2 (wrist centre behind the lower arm) + 1
//! (axis 5 negative), "in front" meaning the side the wrist centre is on with every joint
//! at 0 (the three branches of the closed form, [`Opw`]).

use std::f64::consts::PI;

use crate::geometry::Frame;
use crate::model::Chain;
use crate::model::opw::{NotOpw, Opw};

/// The controller's kinematics: the nominal arm, flange in {0}.
#[derive(Debug, Clone)]
pub struct Controller {
    opw: Opw,
    /// Signs of the shoulder and elbow measures with every joint at 0.
    home: [f64; 2],
}

/// Quadrant of an angle (rad): `floor(deg / 90)`.
pub fn quadrant(q: f64) -> i64 {
    (q.to_degrees() / 90.0).floor() as i64
}

impl Controller {
    /// The controller of the nominal `chain` (its base and tool frames are ignored: poses
    /// are of the flange in the robot frame {0}).
    pub fn new(chain: &Chain) -> Result<Self, NotOpw> {
        let mut c = chain.clone();
        c.base = [0.0; 6];
        c.tool = [0.0; 6];
        let opw = Opw::of(&c, 1e-9)?;
        let s = opw.branch_signs(&[0.0; 6]);
        let sign = |v: f64| if v < 0.0 { -1.0 } else { 1.0 };
        Ok(Self {
            home: [sign(s[0]), sign(s[1])],
            opw,
        })
    }

    /// `cf1, cf4, cf6, cfx` of joint values `q` (rad).
    pub fn confdata(&self, q: &[f64; 6]) -> [i64; 4] {
        let s = self.opw.branch_signs(q);
        let behind_axis1 = s[0] * self.home[0] < 0.0;
        let behind_arm = s[1] * self.home[1] < 0.0;
        let negative5 = q[4] < 0.0;
        let cfx = 4 * i64::from(behind_axis1) + 2 * i64::from(behind_arm) + i64::from(negative5);
        [quadrant(q[0]), quadrant(q[3]), quadrant(q[5]), cfx]
    }

    /// The joints the controller moves to for the flange pose `flange` (in {0}) with
    /// configuration `cf`: the solution whose `cfx` matches, axes 1, 4, 6 turned into the
    /// quadrants given. `None` when no solution has that `cfx` or those quadrants.
    pub fn joints(&self, flange: &Frame, cf: [i64; 4]) -> Option<[f64; 6]> {
        self.candidates(flange, cf)
            .into_iter()
            .find(|(miss, _)| *miss == 0)
            .map(|(_, q)| q)
    }

    /// As [`Controller::joints`], but when no solution has the quadrants exactly, the one of
    /// the same `cfx` whose axes 1, 4, 6 lie fewest quadrants away (turned nearest to
    /// them); with the number of quadrants missed.
    pub fn nearest(&self, flange: &Frame, cf: [i64; 4]) -> Option<([f64; 6], i64)> {
        self.candidates(flange, cf)
            .into_iter()
            .min_by_key(|(miss, _)| *miss)
            .map(|(m, q)| (q, m))
    }

    fn candidates(&self, flange: &Frame, cf: [i64; 4]) -> Vec<(i64, [f64; 6])> {
        let mut out = Vec::new();
        for sol in self.opw.solve(flange, 0.0) {
            if self.confdata(&sol)[3] != cf[3] {
                continue;
            }
            let mut q = sol;
            let mut miss = 0;
            for (axis, c) in [(0, cf[0]), (3, cf[1]), (5, cf[2])] {
                // The turn of q nearest the middle of quadrant c.
                let mid = (c as f64 + 0.5) * PI / 2.0;
                let v = q[axis] + ((mid - q[axis]) / (2.0 * PI)).round() * 2.0 * PI;
                miss += (quadrant(v) - c).abs();
                q[axis] = v;
            }
            out.push((miss, q));
        }
        out
    }
}
