//! The correction of one robtarget: the joints the *calibrated* model needs to put the TCP
//! on the target (on the branch the controller uses for it today), then the target the
//! controller's *nominal* kinematics reach with those joints: t' = nominal FK(calibrated
//! IK(t)), with the configuration data of those joints.

use super::conf::Controller;
use crate::geometry::Frame;
use crate::model::Chain;
use crate::model::compensate::{Compensator, Scratch, Status, Tolerances, rotation_vector};
use crate::model::opw::NotOpw;

/// The two models: the calibrated one solved for the flange, the controller's nominal one.
#[derive(Debug)]
pub struct Filter {
    /// Calibrated model, flange pose in the program's world frame.
    pub calibrated: Compensator,
    /// Nominal model (rigid), flange in {0}.
    pub nominal: Chain,
    /// The controller's kinematics.
    pub controller: Controller,
    /// The program's world frame in the nominal {0} (identity: the robot frame).
    pub world_in_base: Frame,
}

/// Why a target was not corrected.
#[derive(Debug, Clone, PartialEq)]
pub enum Failure {
    /// The controller's nominal kinematics have no solution with the target's `cfx` (the
    /// program fails on the controller as it is).
    Configuration(String),
    /// The calibrated model does not reach it.
    Solver(Status, String),
}

/// A corrected target.
#[derive(Debug, Clone, PartialEq)]
pub struct Corrected {
    /// The joints (rad) on the real robot, per the calibrated model.
    pub q: [f64; 6],
    /// The new target pose (TCP in the work object).
    pub target: Frame,
    /// Its configuration data.
    pub conf: [i64; 4],
    /// Quadrants the original `cf1, cf4, cf6` missed on the nominal controller (0: the
    /// target's configuration was reachable exactly).
    pub quadrants_missed: i64,
}

impl Filter {
    /// The filter of a calibrated and a nominal model (6R, near the OPW structure; wrist
    /// offsets of the calibrated one up to `wrist_tol`). `world`: the program's world
    /// frame is each model's {W} (their `base` frames used), else the robot frame {0}.
    pub fn new(
        calibrated: &Chain,
        nominal: &Chain,
        world: bool,
        tol: Tolerances,
        wrist_tol: f64,
    ) -> Result<Self, NotOpw> {
        let mut cal = calibrated.clone();
        cal.tool = [0.0; 6];
        if !world {
            cal.base = [0.0; 6];
        }
        let world_in_base = if world {
            nominal.base_frame().inverse()
        } else {
            Frame::identity()
        };
        Ok(Self {
            calibrated: Compensator::new(cal, tol, wrist_tol)?,
            nominal: nominal.clone(),
            controller: Controller::new(nominal)?,
            world_in_base,
        })
    }

    /// Correct target `t` (TCP in the work object) with configuration `cf`, for the tool
    /// frame `tool` (TCP in the flange) and the work object `wobj` (in the world).
    pub fn correct(
        &self,
        t: &Frame,
        cf: [i64; 4],
        tool: &Frame,
        wobj: &Frame,
        s: &mut Scratch,
    ) -> Result<Corrected, Failure> {
        let flange = wobj.mul(t).mul(&tool.inverse());
        let in_base = self.world_in_base.mul(&flange);
        let Some((reference, missed)) = self.controller.nearest(&in_base, cf) else {
            return Err(Failure::Configuration(format!(
                "no solution of the nominal kinematics has cfx = {} for this pose (out of \
                 reach, or the configuration is wrong)",
                cf[3]
            )));
        };
        // Newton from the controller's joints: the same branch, turns and quadrants.
        let a = self.calibrated.refine(&flange, reference, s);
        let reached = a.status == Status::Reached
            || (a.status == Status::Singular && a.reason.starts_with("reached"));
        if !reached {
            return Err(Failure::Solver(a.status, a.reason));
        }
        let nominal = self.nominal.flange(&a.q, None);
        let target = wobj
            .inverse()
            .mul(&self.world_in_base.inverse())
            .mul(&nominal)
            .mul(tool);
        Ok(Corrected {
            q: a.q,
            target,
            conf: self.controller.confdata(&a.q),
            quadrants_missed: missed,
        })
    }
}

/// Position change (model length unit) and rotation angle (rad) from `a` to `b`.
pub fn difference(a: &Frame, b: &Frame) -> (f64, f64) {
    (
        (b.p - a.p).norm(),
        rotation_vector(&(a.r.transpose() * b.r)).norm(),
    )
}
