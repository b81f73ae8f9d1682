//! The 3-PF robot's job kinds (`pcr.fk`, `pcr.ik`, `pcr.sensitivity`, `pcr.identify`,
//! `pcr.accuracy`, `pcr.pattern_pose`, `pcr.mount_markers`) and what they share: the model file, joint and pose tables in SI units
//! with limit checks, measurement tables, an optional external load.

pub mod accuracy;
pub mod fk;
pub mod identify;
pub mod identify_options;
mod identify_report;
pub mod ik;
pub mod mount_markers;
pub mod pattern_pose;
pub mod sensitivity;
pub mod verdict;

use serde::Deserialize;
use serde_json::Value;

use crate::geometry::Pose2;
use crate::measure::pcr::PcrMeasurement;
use crate::model::pcr::{Load, Pcr, PcrFile};
use crate::run::{Inputs, JobError, Table};

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
#[derive(Debug, Clone, Copy, Default, Deserialize, schemars::JsonSchema)]
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

/// `units` of the 3-PF kinds' tables: SI (`{"length": "m", "angle": "rad"}`).
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct SiUnits {
    /// `m`.
    pub length: &'static str,
    /// `rad`.
    pub angle: &'static str,
}

/// The SI units.
pub const SI: SiUnits = SiUnits {
    length: "m",
    angle: "rad",
};

/// `{"length": "m", "angle": "rad"}`.
pub fn si_units() -> Value {
    serde_json::json!({"length": "m", "angle": "rad"})
}

/// A measurements table (q1, q2, q3, x, y, theta).
pub fn measurement_table(m: &[PcrMeasurement]) -> Table {
    let mut t = Table::new(&["q1", "q2", "q3", "x", "y", "theta"]);
    for r in m {
        t.push(vec![r.q[0], r.q[1], r.q[2], r.z.x, r.z.y, r.z.theta]);
    }
    t
}

/// The files of the 3-PF twin's data set (`calibd twin pcr`): the nominal model, the true
/// model (true robot parameters and extrinsics), 99 calibration and 56 validation
/// measurements at Poisson-disc joint sets, 20 joint sets and 16 poses for the FK and IK
/// examples. Deterministic in `seed`.
pub fn twin_files(seed: u64) -> Result<Vec<(String, String)>, JobError> {
    let twin = crate::twin::PcrTwin::nominal(seed).map_err(|e| JobError::Failed(e.to_string()))?;
    let lim = twin.file.limits();
    let (lo, hi) = (
        [lim[0][0], lim[1][0], lim[2][0]],
        [lim[0][1], lim[1][1], lim[2][1]],
    );
    let sample = |n: usize, s: u64| {
        crate::design::poisson_disc_n(lo, hi, n, s)
            .map(|(q, _)| q)
            .map_err(|e| JobError::Failed(e.to_string()))
    };
    let fail = |e: crate::model::pcr::PcrError| JobError::Failed(e.to_string());
    let cal = twin
        .measure(&sample(99, seed + 1)?, seed + 3)
        .map_err(fail)?;
    let val = twin
        .measure(&sample(56, seed + 2)?, seed + 4)
        .map_err(fail)?;
    let mut joints = Table::new(&["q1", "q2", "q3"]);
    for q in sample(20, seed + 5)? {
        joints.push(q.to_vec());
    }
    let square = crate::design::trajectory::square(&Pose2::default(), 0.002, 5);
    let json = |v: &PcrFile| {
        serde_json::to_string_pretty(v)
            .map_err(|e| JobError::internal("serialising a model file", e))
    };
    let truth = twin
        .file
        .with_values(&twin.true_params, &twin.true_extrinsics);
    Ok(vec![
        ("pcr3pf.json".into(), json(&twin.file)?),
        ("pcr3pf_true.json".into(), json(&truth)?),
        ("calibration.csv".into(), measurement_table(&cal).to_csv()),
        ("validation.csv".into(), measurement_table(&val).to_csv()),
        ("joints.csv".into(), joints.to_csv()),
        ("poses.csv".into(), pose_table(&square).to_csv()),
    ])
}
