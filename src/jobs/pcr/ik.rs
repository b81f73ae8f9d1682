//! `pcr.ik`: joint values (q1, q2, q3 in m) that bring the platform of the 3-PF model to
//! each pose of a table, solved row after row with warm starts.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{LoadSpec, PcrModel, SI, SiUnits, load_model, poses};
use crate::geometry::Pose2;
use crate::model::pcr::{Equilibrium, Pcr};
use crate::run::Run;
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::Monitor;

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::json_file")]
    model: Value,
    #[schemars(schema_with = "crate::run::schema::table")]
    poses: Value,
    #[serde(default)]
    options: IkOptions,
}

#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct IkOptions {
    /// External load on the platform.
    #[serde(default)]
    load: Option<LoadSpec>,
}

/// A validated `pcr.ik` job.
#[derive(Debug)]
pub struct IkJob {
    robot: Pcr,
    poses: Vec<Pose2>,
}

/// Validate a `pcr.ik` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<IkJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let model: PcrModel = load_model(inputs, &spec.model)?;
    let table = inputs.table("poses", &spec.poses)?;
    let poses = poses("poses", &table)?;
    let robot = model.loaded("options.load", spec.options.load.as_ref())?;
    Ok(IkJob { robot, poses })
}

/// Inverse kinematics of every pose, warm-started along the list; `field` names the table
/// in errors.
pub fn solve_rows(
    robot: &Pcr,
    poses: &[Pose2],
    field: &str,
    monitor: &dyn Monitor,
) -> Result<Vec<Equilibrium>, JobError> {
    let mut out: Vec<Equilibrium> = Vec::with_capacity(poses.len());
    for (i, p) in poses.iter().enumerate() {
        if i % 64 == 0 {
            if monitor.is_cancelled() {
                return Err(JobError::Cancelled);
            }
            monitor.progress(i as f64 / poses.len().max(1) as f64, "inverse kinematics");
        }
        let eq = match out.last() {
            Some(prev) => robot.ik_from(prev, p).or_else(|_| robot.ik(p)),
            None => robot.ik(p),
        }
        .map_err(|e| JobError::row(field, i + 1, e.to_string()))?;
        out.push(eq);
    }
    Ok(out)
}

/// A joints table (q1, q2, q3).
pub fn joint_table(sols: &[Equilibrium]) -> Table {
    let mut t = Table::new(&["q1", "q2", "q3"]);
    for e in sols {
        t.push(e.q.to_vec());
    }
    t
}

/// The result of `pcr.ik`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct PcrJoints {
    /// SI units.
    pub units: SiUnits,
    /// Joints per pose (also the main table).
    #[serde(serialize_with = "crate::report::json_rows")]
    pub joints: Table,
}

impl IkJob {
    /// Solve the inverse kinematics: the typed result, the joints also as the main table.
    pub fn joints(&self, monitor: &dyn Monitor) -> Result<Run<PcrJoints>, JobError> {
        let sols = solve_rows(&self.robot, &self.poses, "poses", monitor)?;
        let table = joint_table(&sols);
        Ok(Run {
            result: PcrJoints {
                units: SI,
                joints: table.clone(),
            },
            main_table: Some(table),
            artefacts: vec![],
        })
    }
}

impl Kind for IkJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::joints)
    }
}
