//! `pcr.fk`: platform poses (x, y, theta in {W}, SI) of the 3-PF model over a joints table,
//! solved row after row with warm starts (continuation from home when a warm start fails).

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{LoadSpec, PcrModel, SI, SiUnits, load_model, pose_table};
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
    joints: Value,
    #[serde(default)]
    options: FkOptions,
}

#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
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

/// Unit of the limb wrenches.
#[derive(Debug, Clone, Serialize)]
pub struct WrenchUnit {
    /// `N`.
    pub force: &'static str,
    /// `N*m`.
    pub moment: &'static str,
}

/// One limb's proximal wrench.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Wrench {
    /// Force x (N).
    pub nx: f64,
    /// Force y (N).
    pub ny: f64,
    /// Moment (N*m).
    pub m: f64,
}

/// `wrenches` of `pcr.fk`: per joints row, the three limbs' wrenches.
#[derive(Debug, Clone, Serialize)]
pub struct Wrenches {
    /// Units.
    pub unit: WrenchUnit,
    /// Per row, per limb.
    pub rows: Vec<Vec<Wrench>>,
}

/// The result of `pcr.fk`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct PcrPoses {
    /// SI units.
    pub units: SiUnits,
    /// x, y, theta per joints row (also the main table).
    #[serde(serialize_with = "crate::report::json_rows")]
    pub poses: Table,
    /// Limb wrenches, when asked.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wrenches: Option<Wrenches>,
}

impl FkJob {
    /// Solve the forward kinematics: the typed result, the poses also as the main table.
    pub fn poses(&self, monitor: &dyn Monitor) -> Result<Run<PcrPoses>, JobError> {
        let sols = solve_rows(&self.robot, &self.q, "joints", monitor)?;
        let poses: Vec<_> = sols.iter().map(|e| e.pose).collect();
        let table = pose_table(&poses);
        let wrenches = self.wrenches.then(|| Wrenches {
            unit: WrenchUnit {
                force: "N",
                moment: "N*m",
            },
            rows: sols
                .iter()
                .map(|e| {
                    e.wrenches
                        .iter()
                        .map(|w| Wrench {
                            nx: w[0],
                            ny: w[1],
                            m: w[2],
                        })
                        .collect()
                })
                .collect(),
        });
        Ok(Run {
            result: PcrPoses {
                units: SI,
                poses: table.clone(),
                wrenches,
            },
            main_table: Some(table),
            artefacts: vec![],
        })
    }
}

impl Kind for FkJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::poses)
    }
}
