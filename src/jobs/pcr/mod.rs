//! The 3-PF robot's job kinds (`pcr.fk`, `pcr.ik`, `pcr.sensitivity`, `pcr.identify`,
//! `pcr.accuracy`) and what they share: the model file, joint and pose tables in SI units
//! with limit checks, measurement tables, an optional external load.

pub mod accuracy;
pub mod fk;
pub mod identify;
pub mod ik;
pub mod sensitivity;

use serde::Deserialize;
use serde_json::Value;

use super::{Inputs, JobError, Table};
use crate::geometry::Pose2;
use crate::measure::pcr::PcrMeasurement;
use crate::model::pcr::{Load, Pcr, PcrFile};

/// A loaded 3-PF model: its file and the solvable robot.
#[derive(Debug, Clone)]
pub struct PcrModel {
    /// The model file.
    pub file: PcrFile,
    /// The robot (unloaded unless a load was applied).
    pub robot: Pcr,
}

/// `"load": {"force": [fx, fy], "moment": mz}` (N, N*m, components in {W}, applied at the
/// origin of {P}).
#[derive(Debug, Clone, Copy, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadSpec {
    /// Force (N).
    #[serde(default)]
    pub force: [f64; 2],
    /// Moment (N*m).
    #[serde(default)]
    pub moment: f64,
}

/// Load `model` (a 3-PF model file object or file name) and solve its home pose.
pub fn load_model(inputs: &Inputs<'_>, model: &Value) -> Result<PcrModel, JobError> {
    let file = PcrFile::from_value(inputs.json("model", model)?)?;
    let robot = file
        .robot()
        .map_err(|e| JobError::invalid("model", e.to_string()))?;
    Ok(PcrModel { file, robot })
}

impl PcrModel {
    /// The model under an external load (`field` names the option in errors).
    pub fn loaded(&self, field: &str, load: Option<&LoadSpec>) -> Result<Pcr, JobError> {
        match load {
            None => Ok(self.robot.clone()),
            Some(l) => {
                let load = Load {
                    force: l.force,
                    moment: l.moment,
                };
                self.robot
                    .with_load(load)
                    .map_err(|e| JobError::invalid(field, e.to_string()))
            }
        }
    }

    /// Joint values of every row of `t` (columns q1, q2, q3 in m), within the limits.
    pub fn joints(&self, field: &str, t: &Table) -> Result<Vec<[f64; 3]>, JobError> {
        let cols = t.cols(field, &["q1".into(), "q2".into(), "q3".into()])?;
        t.rows
            .iter()
            .enumerate()
            .map(|(i, row)| {
                let q = [row[cols[0]], row[cols[1]], row[cols[2]]];
                self.robot
                    .check_joints(&q)
                    .map_err(|e| JobError::row(field, i + 1, e.to_string()))?;
                Ok(q)
            })
            .collect()
    }

    /// Measurements from a table with q1, q2, q3 (m) and the readings x, y (m), theta (rad).
    pub fn measurements(&self, field: &str, t: &Table) -> Result<Vec<PcrMeasurement>, JobError> {
        let q = self.joints(field, t)?;
        let z = poses(field, t)?;
        Ok(q.into_iter()
            .zip(z)
            .map(|(q, z)| PcrMeasurement { q, z })
            .collect())
    }
}

/// Poses of every row of `t` (columns x, y in m, theta in rad).
pub fn poses(field: &str, t: &Table) -> Result<Vec<Pose2>, JobError> {
    let c = t.cols(field, &["x".into(), "y".into(), "theta".into()])?;
    Ok(t.rows
        .iter()
        .map(|r| Pose2::new(r[c[0]], r[c[1]], r[c[2]]))
        .collect())
}

/// A poses table (x, y, theta).
pub fn pose_table(poses: &[Pose2]) -> Table {
    let mut t = Table::new(&["x", "y", "theta"]);
    for p in poses {
        t.push(vec![p.x, p.y, p.theta]);
    }
    t
}

/// `{"length": "m", "angle": "rad"}`.
pub fn si_units() -> Value {
    serde_json::json!({"length": "m", "angle": "rad"})
}
