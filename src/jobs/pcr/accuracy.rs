//! `pcr.accuracy`: ISO 9283 pose accuracy of a (calibrated) 3-PF model used for control:
//! inverse kinematics gives the joints of each commanded pose of a trajectory (a square, a
//! circle or a poses table), the robot reaches each pose `repetitions` times, the microscope
//! readings (converted to {W} with the model's extrinsics) give AP_P, AP_theta and RP per
//! pose and their max, mean and min (the paper's Table 4). The reached poses come from a
//! measurements table, or from a digital twin of the robot for simulation.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::{PcrModel, load_model, poses};
use crate::design::trajectory::{circle, square};
use crate::geometry::Pose2;
use crate::measure::pcr::accuracy::{AccuracySummary, PoseAccuracy, pose_accuracy, summarise};
use crate::measure::pcr::{PcrMeasurement, measured_pose};
use crate::model::pcr::PcrFile;
use crate::run::Run;
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::twin::PcrTwin;
use crate::util::{Monitor, Rng};

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::json_file")]
    model: Value,
    #[schemars(schema_with = "trajectory_schema")]
    trajectory: Value,
    #[serde(default = "default_repetitions")]
    #[schemars(range(min = 1))]
    repetitions: usize,
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::table_opt")]
    reached: Option<Value>,
    #[serde(default)]
    twin: Option<TwinSpec>,
    /// A second model (e.g. the nominal one) commanding the same trajectory on the twin,
    /// reported beside `model`'s accuracy.
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::json_file_opt")]
    compare_with: Option<Value>,
    #[serde(default)]
    #[allow(dead_code)]
    options: Option<Map<String, Value>>,
}

fn default_repetitions() -> usize {
    30
}

/// `{"square": side}` or `{"circle": diameter}` (m), with the number of poses and centre.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(extend("oneOf" = [{"required": ["square"]}, {"required": ["circle"]}]))]
struct TrajectorySpec {
    #[serde(default)]
    square: Option<f64>,
    #[serde(default)]
    circle: Option<f64>,
    /// Square: poses per side including both corners (default 5: 16 poses).
    #[serde(default)]
    points_per_side: Option<usize>,
    /// Circle: number of poses (default 16).
    #[serde(default)]
    points: Option<usize>,
    /// Centre (x, y) in {W} (m), default the origin.
    #[serde(default)]
    centre: Option<[f64; 2]>,
    /// Platform angle of every pose (rad), default 0.
    #[serde(default)]
    theta: Option<f64>,
}

/// A digital twin as the source of reached poses: the true robot is the nominal `model`
/// perturbed by its uncertainties with `seed`; the microscope adds its repeatability noise.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct TwinSpec {
    #[schemars(schema_with = "crate::run::schema::json_file")]
    model: Value,
    seed: u64,
    #[serde(default)]
    noise_seed: Option<u64>,
}

#[derive(Debug)]
enum Source {
    Reached(Vec<PcrMeasurement>),
    Twin(Box<PcrTwin>, u64),
}

/// A validated `pcr.accuracy` job.
#[derive(Debug)]
pub struct AccuracyJob {
    model: PcrModel,
    name: String,
    commanded: Vec<Pose2>,
    repetitions: usize,
    source: Source,
    /// A second model commanding the same trajectory (twin only).
    compare_with: Option<PcrModel>,
}

/// Schema of a `trajectory` field: `{square | circle, ...}` or a poses table.
pub(crate) fn trajectory_schema(g: &mut schemars::SchemaGenerator) -> schemars::Schema {
    schemars::json_schema!({"anyOf": [
        g.subschema_for::<TrajectorySpec>(),
        crate::run::schema::table(g),
    ]})
}

/// Parse a `trajectory` field (a square, a circle or a poses table): its name and the
/// commanded poses; campaigns validate their trajectory with it before calling
/// [`AccuracyJob::reached`].
pub fn trajectory(inputs: &Inputs<'_>, v: &Value) -> Result<(String, Vec<Pose2>), JobError> {
    let field = "trajectory";
    if !v.is_object() {
        let t = inputs.table(field, v)?;
        return Ok(("poses".into(), poses(field, &t)?));
    }
    let s: TrajectorySpec =
        crate::run::parse_spec(v).map_err(|e| JobError::invalid(field, e.to_string()))?;
    let c = s.centre.unwrap_or([0.0, 0.0]);
    let centre = Pose2::new(c[0], c[1], s.theta.unwrap_or(0.0));
    if ![centre.x, centre.y, centre.theta]
        .iter()
        .all(|v| v.is_finite())
    {
        return Err(JobError::invalid(field, "centre and theta must be finite"));
    }
    let size_ok = |v: f64| v.is_finite() && v > 0.0;
    match (s.square, s.circle) {
        (Some(side), None) if size_ok(side) => {
            let n = s.points_per_side.unwrap_or(5);
            if n < 2 {
                return Err(JobError::invalid(
                    "trajectory.points_per_side",
                    "must be at least 2",
                ));
            }
            Ok((format!("square {side} m"), square(&centre, side, n)))
        }
        (None, Some(d)) if size_ok(d) => {
            let n = s.points.unwrap_or(16);
            if n < 1 {
                return Err(JobError::invalid("trajectory.points", "must be at least 1"));
            }
            Ok((format!("circle {d} m"), circle(&centre, d, n)))
        }
        (Some(v), None) | (None, Some(v)) => Err(JobError::invalid(
            field,
            format!("size {v} must be a positive number of metres"),
        )),
        _ => Err(JobError::invalid(
            field,
            "give exactly one of {\"square\": side} or {\"circle\": diameter} (m), or a poses table",
        )),
    }
}

/// Validate a `pcr.accuracy` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<AccuracyJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let model = load_model(inputs, &spec.model)?;
    let (name, commanded) = trajectory(inputs, &spec.trajectory)?;
    if commanded.is_empty() {
        return Err(JobError::invalid("trajectory", "has no pose"));
    }
    if spec.repetitions == 0 {
        return Err(JobError::invalid("repetitions", "must be at least 1"));
    }
    let compare_with = match &spec.compare_with {
        Some(v) if spec.twin.is_some() => Some(load_model(inputs, v).map_err(|e| match e {
            JobError::Invalid { field, message } if field == "model" => JobError::Invalid {
                field: "compare_with".into(),
                message,
            },
            e => e,
        })?),
        Some(_) => {
            return Err(JobError::invalid(
                "compare_with",
                "needs a `twin`: a reached table holds the poses of one model's joints only",
            ));
        }
        None => None,
    };
    let source = match (spec.reached, spec.twin) {
        (Some(r), None) => {
            let t = inputs.table("reached", &r)?;
            let m = model.measurements("reached", &t)?;
            return AccuracyJob::reached(model, name, commanded, spec.repetitions, m);
        }
        (None, Some(tw)) => {
            let file = PcrFile::from_value(inputs.json("twin.model", &tw.model)?)?;
            let twin = PcrTwin::new(&file, tw.seed)
                .map_err(|e| JobError::invalid("twin.model", e.to_string()))?;
            Source::Twin(Box::new(twin), tw.noise_seed.unwrap_or(tw.seed ^ 0xACC))
        }
        _ => {
            return Err(JobError::invalid(
                "reached",
                "give the reached poses as a `reached` measurements table (q1, q2, q3, x, y, theta; repetitions rows per pose, in order) or a `twin` {model, seed} to simulate them",
            ));
        }
    };
    Ok(AccuracyJob {
        model,
        name,
        commanded,
        repetitions: spec.repetitions,
        source,
        compare_with,
    })
}

/// `trajectory` of a `pcr.accuracy` result.
#[derive(Debug, Clone, Serialize)]
pub struct TrajectoryInfo {
    /// `square 0.002 m`, `circle ...` or `poses`.
    pub name: String,
    /// Commanded poses.
    pub poses: usize,
    /// Repetitions per pose.
    pub repetitions: usize,
}

/// Units of the `per_pose` columns.
#[derive(Debug, Clone, Serialize)]
pub struct AccuracyUnits {
    /// m.
    pub x: &'static str,
    /// m.
    pub y: &'static str,
    /// rad.
    pub theta: &'static str,
    /// m.
    pub q: &'static str,
    /// m.
    pub ap_p: &'static str,
    /// rad.
    pub ap_theta: &'static str,
    /// m.
    pub rp: &'static str,
}

/// One commanded pose: its joints by inverse kinematics and its accuracy.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct PoseRow {
    /// Commanded x (m).
    pub x: f64,
    /// Commanded y (m).
    pub y: f64,
    /// Commanded theta (rad).
    pub theta: f64,
    /// Joint 1 (m).
    pub q1: f64,
    /// Joint 2 (m).
    pub q2: f64,
    /// Joint 3 (m).
    pub q3: f64,
    /// AP_P (m).
    pub ap_p: f64,
    /// AP_theta (rad).
    pub ap_theta: f64,
    /// RP (m).
    pub rp: f64,
}

/// The result of `pcr.accuracy` (the paper's Table 4): serialises to the job's fields.
#[derive(Debug, Clone, Serialize)]
pub struct PcrAccuracy {
    /// The trajectory.
    pub trajectory: TrajectoryInfo,
    /// `reached table` or `digital twin`.
    pub source: &'static str,
    /// Units of `per_pose`.
    pub units: AccuracyUnits,
    /// Per commanded pose (also the main table).
    pub per_pose: Vec<PoseRow>,
    /// Max, mean, min over the poses.
    pub summary: AccuracySummary,
    /// The same trajectory commanded through `compare_with` (e.g. the nominal model), on
    /// the same twin and measured the same way, when the job names one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub compared: Option<ComparedAccuracy>,
}

/// The accuracy of the trajectory commanded through a second model, side by side.
#[derive(Debug, Clone, Serialize)]
pub struct ComparedAccuracy {
    /// The model file's `name`.
    pub model: String,
    /// AP_P of each commanded pose (m), in the order of `per_pose`.
    pub ap_p_m: Vec<f64>,
    /// Max, mean, min over the poses.
    pub summary: AccuracySummary,
    /// Mean AP_P through `compare_with` over mean AP_P through `model`: how many times
    /// more accurate the job's model commands the trajectory.
    pub mean_ap_p_ratio: f64,
}

impl AccuracyJob {
    /// A `pcr.accuracy` job on measured poses (the campaign's entry point; the JSON path
    /// calls it too): the model used for control, the trajectory (name, commanded poses),
    /// repetitions and the reached measurements grouped by pose.
    pub fn reached(
        model: PcrModel,
        name: String,
        commanded: Vec<Pose2>,
        repetitions: usize,
        reached: Vec<PcrMeasurement>,
    ) -> Result<AccuracyJob, JobError> {
        if commanded.is_empty() {
            return Err(JobError::invalid("trajectory", "has no pose"));
        }
        if repetitions == 0 {
            return Err(JobError::invalid("repetitions", "must be at least 1"));
        }
        for (i, m) in reached.iter().enumerate() {
            model
                .robot
                .check_joints(&m.q)
                .map_err(|e| JobError::row("reached", i + 1, e.to_string()))?;
        }
        let want = commanded.len() * repetitions;
        if reached.len() != want {
            return Err(JobError::invalid(
                "reached",
                format!(
                    "has {} rows; {} poses x {} repetitions need {want}, grouped by pose",
                    reached.len(),
                    commanded.len(),
                    repetitions
                ),
            ));
        }
        Ok(AccuracyJob {
            model,
            name,
            commanded,
            repetitions,
            source: Source::Reached(reached),
            compare_with: None,
        })
    }

    /// The poses attained at the joints `q` of each commanded pose, `repetitions` readings
    /// each, in {W} through this job's model's extrinsics (the measuring side is the same
    /// whichever model commands).
    fn attained(&self, q: &[[f64; 3]]) -> Result<Vec<Vec<Pose2>>, JobError> {
        let ext = self.model.file.extrinsics;
        let r = self.repetitions;
        Ok(match &self.source {
            Source::Reached(m) => m
                .chunks(r)
                .map(|c| c.iter().map(|m| measured_pose(&ext, &m.z)).collect())
                .collect(),
            Source::Twin(twin, seed) => {
                let truth = twin
                    .true_poses(q)
                    .map_err(|e| JobError::Failed(format!("twin: {e}")))?;
                let mut rng = Rng::new(*seed);
                truth
                    .iter()
                    .map(|eq| {
                        (0..r)
                            .map(|_| measured_pose(&ext, &twin.read(&eq.pose, &mut rng)))
                            .collect()
                    })
                    .collect()
            }
        })
    }

    /// ISO 9283 accuracy of each commanded pose from its attained poses.
    fn accuracies(&self, reached: &[Vec<Pose2>]) -> Vec<PoseAccuracy> {
        self.commanded
            .iter()
            .zip(reached)
            .map(|(c, p)| pose_accuracy(c, p))
            .collect()
    }

    /// The trajectory commanded through `compare_with`, side by side with `model`'s.
    fn compared(
        &self,
        own: &AccuracySummary,
        monitor: &dyn Monitor,
    ) -> Result<Option<ComparedAccuracy>, JobError> {
        let Some(other) = &self.compare_with else {
            return Ok(None);
        };
        let control =
            super::ik::solve_rows(&other.robot, &self.commanded, "compare_with", monitor)?;
        let q: Vec<[f64; 3]> = control.iter().map(|e| e.q).collect();
        let acc = self.accuracies(&self.attained(&q)?);
        let summary = summarise(&acc);
        Ok(Some(ComparedAccuracy {
            model: other.file.name.clone(),
            ap_p_m: acc.iter().map(|a| a.ap_p).collect(),
            mean_ap_p_ratio: summary.ap_p_um.mean / own.ap_p_um.mean,
            summary,
        }))
    }

    /// Run it: the typed result, with the per-pose table as the main table.
    pub fn evaluate(&self, monitor: &dyn Monitor) -> Result<Run<PcrAccuracy>, JobError> {
        let robot = &self.model.robot;
        let control = super::ik::solve_rows(robot, &self.commanded, "trajectory", monitor)?;
        let r = self.repetitions;
        let q: Vec<[f64; 3]> = control.iter().map(|e| e.q).collect();
        let reached = self.attained(&q)?;
        if monitor.is_cancelled() {
            return Err(JobError::Cancelled);
        }
        let acc = self.accuracies(&reached);
        let mut t = Table::new(&[
            "x", "y", "theta", "q1", "q2", "q3", "ap_p", "ap_theta", "rp",
        ]);
        let mut per_pose = Vec::with_capacity(acc.len());
        for ((c, e), a) in self.commanded.iter().zip(&control).zip(&acc) {
            let row = PoseRow {
                x: c.x,
                y: c.y,
                theta: c.theta,
                q1: e.q[0],
                q2: e.q[1],
                q3: e.q[2],
                ap_p: a.ap_p,
                ap_theta: a.ap_theta,
                rp: a.rp,
            };
            t.push(vec![
                row.x,
                row.y,
                row.theta,
                row.q1,
                row.q2,
                row.q3,
                row.ap_p,
                row.ap_theta,
                row.rp,
            ]);
            per_pose.push(row);
        }
        let result = PcrAccuracy {
            trajectory: TrajectoryInfo {
                name: self.name.clone(),
                poses: self.commanded.len(),
                repetitions: r,
            },
            source: match self.source {
                Source::Reached(_) => "reached table",
                Source::Twin(..) => "digital twin",
            },
            units: AccuracyUnits {
                x: "m",
                y: "m",
                theta: "rad",
                q: "m",
                ap_p: "m",
                ap_theta: "rad",
                rp: "m",
            },
            per_pose,
            summary: summarise(&acc),
            compared: None,
        };
        let result = PcrAccuracy {
            compared: self.compared(&result.summary, monitor)?,
            ..result
        };
        // The plot: commanded against the mean attained position (mm).
        let mm = |x: f64| x * 1e3;
        let commanded: Vec<(f64, f64)> =
            self.commanded.iter().map(|c| (mm(c.x), mm(c.y))).collect();
        let attained: Vec<(f64, f64)> = reached
            .iter()
            .map(|p| {
                let n = p.len().max(1) as f64;
                let (sx, sy) = p.iter().fold((0.0, 0.0), |(a, b), q| (a + q.x, b + q.y));
                (mm(sx / n), mm(sy / n))
            })
            .collect();
        let dataset = format!(
            "trajectory {}: {} poses x {} repetitions ({})",
            self.name,
            self.commanded.len(),
            r,
            result.source
        );
        let artefacts = vec![crate::report::svg_artefact(
            "trajectory.svg",
            crate::report::plots::trajectory(&commanded, &attained, "mm", &dataset),
        )];
        Ok(Run {
            result,
            main_table: Some(t),
            artefacts,
        })
    }
}

impl Kind for AccuracyJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::evaluate)
    }
}
