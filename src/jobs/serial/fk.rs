//! `serial.fk`: TCP poses (x, y, z, a, b, c in {W}) of a serial model over a joints table,
//! with the static deflection of the model's compliances.

use std::sync::Arc;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{ChainSpec, SerialModel, load_model};
use crate::jobs::{Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::model::Quantity;
use crate::report::Run;
use crate::util::Monitor;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    model: Value,
    #[serde(default)]
    chain: Option<ChainSpec>,
    joints: Value,
    #[serde(default)]
    parameters: BTreeMap<String, f64>,
    #[serde(default)]
    #[allow(dead_code)]
    options: Option<serde_json::Map<String, Value>>,
}

/// A validated `serial.fk` job.
#[derive(Debug)]
pub struct FkJob {
    model: SerialModel,
    q: Vec<Vec<f64>>,
}

/// Validate a `serial.fk` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<FkJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let mut model = load_model(inputs, &spec.model, spec.chain.as_ref())?;
    let table = inputs.table("joints", &spec.joints)?;
    let q = model.joints("joints", &table)?;
    for (name, v) in &spec.parameters {
        let id = model.chain.param_by_name(name).map_err(|_| {
            JobError::invalid(format!("parameters.{name}"), "unknown parameter name")
        })?;
        if !v.is_finite() {
            return Err(JobError::invalid(
                format!("parameters.{name}"),
                format!("{v} is not finite"),
            ));
        }
        let to_file = model.chain.units.to_file(id.quantity());
        model.chain.set_param(id, v / to_file);
        // A value far outside the model's range overflows the kinematics: name it here
        // rather than compute a table of NaN.
        if let Some(q0) = q.first()
            && !pose(&model.chain, q0).iter().all(|x| x.is_finite())
        {
            return Err(JobError::invalid(
                format!("parameters.{name}"),
                format!("{v}: the forward kinematics is not finite with this value"),
            ));
        }
    }
    Ok(FkJob { model, q })
}

/// The elasto-geometric TCP pose (x, y, z, a, b, c in the chain's internal units).
fn pose(c: &crate::model::Chain, q: &[f64]) -> [f64; 6] {
    let tau = c.static_torques(q);
    c.tcp(q, Some(&tau)).to_xyzabc()
}

/// Length and angle units of a pose table.
#[derive(Debug, Clone, Serialize)]
pub struct PoseUnits {
    /// Model length unit.
    pub length: &'static str,
    /// Model angle unit.
    pub angle: &'static str,
}

/// The result of `serial.fk`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct SerialPoses {
    /// Units of the poses.
    pub units: PoseUnits,
    /// x, y, z, a, b, c per joints row (also the main table).
    #[serde(serialize_with = "crate::report::json_rows")]
    pub poses: Table,
}

impl FkJob {
    /// Compute the TCP poses: the typed result, the poses also as the main table.
    pub fn poses(&self, monitor: &dyn Monitor) -> Result<Run<SerialPoses>, JobError> {
        let c = &self.model.chain;
        let k = c.units.to_file(Quantity::Angle);
        let mut poses = Table::new(&["x", "y", "z", "a", "b", "c"]);
        for (i, q) in self.q.iter().enumerate() {
            if i % 1024 == 0 && monitor.is_cancelled() {
                return Err(JobError::Cancelled);
            }
            let v = pose(c, q);
            poses.push(vec![v[0], v[1], v[2], v[3] * k, v[4] * k, v[5] * k]);
        }
        Ok(Run {
            result: SerialPoses {
                units: PoseUnits {
                    length: self.model.length_unit(),
                    angle: self.model.angle_unit(),
                },
                poses: poses.clone(),
            },
            main_table: Some(poses),
            artefacts: vec![],
        })
    }
}

impl Kind for FkJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::poses)
    }
}
