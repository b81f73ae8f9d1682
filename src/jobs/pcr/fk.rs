//! `pcr.fk`: platform poses (x, y, theta in {W}, SI) of the 3-PF model over a joints table,
//! solved row after row with warm starts (continuation from home when a warm start fails).

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::{LoadSpec, PcrModel, load_model, pose_table, si_units};
use crate::jobs::{Cx, Inputs, JobError, Kind, Output, RunFuture, computed, parse_spec};
use crate::model::pcr::{Equilibrium, Pcr};
use crate::util::Monitor;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    model: Value,
    joints: Value,
    #[serde(default)]
    options: FkOptions,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FkOptions {
    /// External load on the platform.
    #[serde(default)]
    load: Option<LoadSpec>,
    /// Also report the proximal wrenches of every rod.
    #[serde(default)]
    wrenches: bool,
}

/// A validated `pcr.fk` job.
#[derive(Debug)]
pub struct FkJob {
    robot: Pcr,
    q: Vec<[f64; 3]>,
    wrenches: bool,
}

/// Validate a `pcr.fk` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<FkJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let model: PcrModel = load_model(inputs, &spec.model)?;
    let table = inputs.table("joints", &spec.joints)?;
    let q = model.joints("joints", &table)?;
    let robot = model.loaded("options.load", spec.options.load.as_ref())?;
    Ok(FkJob {
        robot,
        q,
        wrenches: spec.options.wrenches,
    })
}

/// Forward kinematics of every row, warm-started along the list.
pub fn solve_rows(
    robot: &Pcr,
    q: &[[f64; 3]],
    field: &str,
    monitor: &dyn Monitor,
) -> Result<Vec<Equilibrium>, JobError> {
    let mut out: Vec<Equilibrium> = Vec::with_capacity(q.len());
    for (i, qi) in q.iter().enumerate() {
        if i % 64 == 0 {
            if monitor.is_cancelled() {
                return Err(JobError::Cancelled);
            }
            monitor.progress(i as f64 / q.len().max(1) as f64, "forward kinematics");
        }
        let eq = match out.last() {
            Some(prev) => robot.fk_from(prev, qi).or_else(|_| robot.fk(qi)),
            None => robot.fk(qi),
        }
        .map_err(|e| JobError::row(field, i + 1, e.to_string()))?;
        out.push(eq);
    }
    Ok(out)
}

impl Kind for FkJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::execute)
    }
}

impl FkJob {
    /// Compute the job's output (on the blocking pool, see [`Kind::run`]).
    pub fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let sols = solve_rows(&self.robot, &self.q, "joints", monitor)?;
        let poses: Vec<_> = sols.iter().map(|e| e.pose).collect();
        let table = pose_table(&poses);
        let mut fields = Map::new();
        fields.insert("units".into(), si_units());
        fields.insert("poses".into(), table.to_json_rows());
        if self.wrenches {
            let w: Vec<Value> = sols
                .iter()
                .map(|e| {
                    json!(
                        e.wrenches
                            .iter()
                            .map(|w| json!({"nx": w[0], "ny": w[1], "m": w[2]}))
                            .collect::<Vec<_>>()
                    )
                })
                .collect();
            fields.insert(
                "wrenches".into(),
                json!({"unit": {"force": "N", "moment": "N*m"}, "rows": w}),
            );
        }
        Ok(Output {
            fields,
            main_table: Some(table),
            artefacts: vec![],
        })
    }
}
