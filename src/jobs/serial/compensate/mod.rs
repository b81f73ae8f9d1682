//! `serial.compensate`: the joints that put the TCP of a calibrated serial model on target
//! poses (x, y, z, a, b, c of {T} in {W}, the convention `serial.fk` writes), one row per
//! target, each with its residual and a status; an unreachable row never fails the others.
//! The maths is [`crate::model::compensate`]; this module reads the job and writes tables.

use std::fmt::Write as _;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{ChainSpec, ModelInput, SerialModel, load_model, named_urdf, read_model};
use crate::geometry::Frame;
use crate::model::compensate::{Compensator, Scratch, Status, Tolerances};
use crate::model::dh::Payload;
use crate::model::{PointMass, Quantity};
use crate::run::Run;
use crate::run::{Artefact, Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::Monitor;

/// A `serial.compensate` job document.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    /// A DH model or DH tree (with `chain.name`), or a `serial.identify` result whose
    /// `calibrated_model` is used.
    #[schemars(schema_with = "crate::run::schema::serial_model")]
    model: Value,
    #[serde(default)]
    chain: Option<ChainSpec>,
    /// Target poses `x, y, z, a, b, c` of {T} in {W} (as `serial.fk` writes them), with
    /// optional reference joints `q1..q6`.
    #[schemars(schema_with = "crate::run::schema::table")]
    targets: Value,
    /// Replaces the model's payload (changes the static deflection).
    #[serde(default)]
    payload: Option<Payload>,
    #[serde(default)]
    options: Options,
}

/// `options` of a `serial.compensate` job.
#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct Options {
    /// Reference joints (model angle unit) for rows without their own.
    #[serde(default)]
    reference: Option<Vec<f64>>,
    /// Largest position residual of a reached target (mm).
    #[serde(default)]
    tolerance_mm: Option<f64>,
    /// Largest orientation residual of a reached target (deg).
    #[serde(default)]
    tolerance_deg: Option<f64>,
}

/// Default position tolerance of a reached target: 0.1 um.
const TOLERANCE_MM: f64 = 1e-4;
/// Default orientation tolerance: 1e-5 deg (0.17 urad).
const TOLERANCE_DEG: f64 = 1e-5;
/// |sin| of the wrist or elbow angle below which an answer is singular (0.057 deg).
const SINGULAR_SIN: f64 = 1e-3;
/// Distance (mm) of the wrist centre from axis 1 below which an answer is singular.
const SINGULAR_SHOULDER_MM: f64 = 1.0;
/// Wrist offsets (a4, a5, d5, mm) a calibrated model may have and still start from the
/// spherical-wrist closed form.
const WRIST_OFFSET_MM: f64 = 5.0;

/// Pose columns of the targets table, as `serial.fk` writes them.
const POSE_COLUMNS: [&str; 6] = ["x", "y", "z", "a", "b", "c"];

/// A validated `serial.compensate` job.
#[derive(Debug)]
pub struct CompensateJob {
    model: SerialModel,
    solver: Compensator,
    /// Target frames in {W} with each row's reference joints (rad).
    targets: Vec<(Frame, [f64; 6])>,
}

/// Validate a `serial.compensate` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<CompensateJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let mut model = resolve_model(inputs, &spec.model, spec.chain.as_ref())?;
    if let Some(p) = &spec.payload {
        set_payload(&mut model, p)?;
    }
    let mm = 1e-3 / model.chain.units.metre();
    let positive = |field: &str, v: Option<f64>, default: f64| match v {
        None => Ok(default),
        Some(v) if v.is_finite() && v > 0.0 => Ok(v),
        Some(v) => Err(JobError::invalid(
            field,
            format!("{v} is not a positive number"),
        )),
    };
    let tol = Tolerances {
        position: positive(
            "options.tolerance_mm",
            spec.options.tolerance_mm,
            TOLERANCE_MM,
        )? * mm,
        angle: positive(
            "options.tolerance_deg",
            spec.options.tolerance_deg,
            TOLERANCE_DEG,
        )?
        .to_radians(),
        singular_sin: SINGULAR_SIN,
        singular_shoulder: SINGULAR_SHOULDER_MM * mm,
    };
    let solver = Compensator::new(model.chain.clone(), tol, WRIST_OFFSET_MM * mm)
        .map_err(|e| JobError::invalid("model", e.to_string()))?;
    let to_rad = 1.0 / model.chain.units.to_file(Quantity::Angle);
    let reference = match &spec.options.reference {
        None => [0.0; 6],
        Some(r) => joints6("options.reference", r, to_rad)?,
    };
    let table = inputs.table("targets", &spec.targets)?;
    let targets = read_targets(&model, &table, reference, to_rad)?;
    Ok(CompensateJob {
        model,
        solver,
        targets,
    })
}

impl CompensateJob {
    /// The job for `targets` (frames in {W}, reference joints in rad) on `model` with the
    /// default tolerances: the typed entry point for campaigns.
    pub fn for_targets(
        model: SerialModel,
        targets: Vec<(Frame, [f64; 6])>,
    ) -> Result<CompensateJob, JobError> {
        let mm = 1e-3 / model.chain.units.metre();
        let tol = Tolerances {
            position: TOLERANCE_MM * mm,
            angle: TOLERANCE_DEG.to_radians(),
            singular_sin: SINGULAR_SIN,
            singular_shoulder: SINGULAR_SHOULDER_MM * mm,
        };
        let solver = Compensator::new(model.chain.clone(), tol, WRIST_OFFSET_MM * mm)
            .map_err(|e| JobError::invalid("model", e.to_string()))?;
        Ok(CompensateJob {
            model,
            solver,
            targets,
        })
    }
}

/// The model: a model file as `serial.fk` takes it, or a `serial.identify` result (inline
/// or a file) whose `calibrated_model` is used.
pub(crate) fn resolve_model(
    inputs: &Inputs<'_>,
    model: &Value,
    chain: Option<&ChainSpec>,
) -> Result<SerialModel, JobError> {
    let doc = match model {
        Value::Object(_) => Some(model.clone()),
        Value::String(_) if !named_urdf(model) => match read_model(inputs, model)? {
            ModelInput::Json(d) => Some(d),
            // URDF (also an uploaded dataset, known by its text): read as such below.
            ModelInput::Urdf(_) => None,
        },
        _ => None,
    };
    match doc.as_ref().and_then(|d| d.get("calibrated_model")) {
        Some(inner) => load_model(inputs, inner, chain),
        None => load_model(inputs, model, chain),
    }
}

/// Replace the model's payload (the point mass named `payload` on the last body).
pub(crate) fn set_payload(model: &mut SerialModel, p: &Payload) -> Result<(), JobError> {
    if !(p.mass >= 0.0 && p.mass.is_finite()) || p.com_in_flange.iter().any(|v| !v.is_finite()) {
        return Err(JobError::invalid(
            "payload",
            "mass must be a finite number >= 0 and com_in_flange finite",
        ));
    }
    let chain = &mut model.chain;
    let last = chain.joints.len().saturating_sub(1);
    chain
        .masses
        .retain(|m| !(m.name == "payload" && m.body == last));
    chain.masses.push(PointMass {
        name: "payload".into(),
        body: last,
        mass: p.mass,
        com: p.com_in_flange.into(),
    });
    Ok(())
}

/// Six joint values in the model's angle unit, to radians.
fn joints6(field: &str, v: &[f64], to_rad: f64) -> Result<[f64; 6], JobError> {
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        return Err(JobError::invalid(
            field,
            format!("needs 6 finite joint values, got {v:?}"),
        ));
    }
    let mut q = [0.0; 6];
    for k in 0..6 {
        q[k] = v[k] * to_rad;
    }
    Ok(q)
}

/// The target frames and reference joints of every row of the targets table.
fn read_targets(
    model: &SerialModel,
    t: &Table,
    reference: [f64; 6],
    to_rad: f64,
) -> Result<Vec<(Frame, [f64; 6])>, JobError> {
    let cols: Vec<String> = POSE_COLUMNS.iter().map(|c| c.to_string()).collect();
    let pose = t.cols("targets", &cols)?;
    let qcols = model.joint_columns();
    let present: Vec<&String> = qcols.iter().filter(|c| t.has(c)).collect();
    let qidx = match present.len() {
        0 => None,
        n if n == qcols.len() => Some(t.cols("targets", &qcols)?),
        _ => {
            return Err(JobError::invalid(
                "targets",
                format!(
                    "reference joints need every column {qcols:?}, the table has only {present:?}"
                ),
            ));
        }
    };
    Ok(t.rows
        .iter()
        .map(|row| {
            let v = |k: usize| row[pose[k]];
            let f = Frame::from_xyzabc(&[
                v(0),
                v(1),
                v(2),
                v(3) * to_rad,
                v(4) * to_rad,
                v(5) * to_rad,
            ]);
            let mut r = reference;
            if let Some(ix) = &qidx {
                for k in 0..6 {
                    r[k] = row[ix[k]] * to_rad;
                }
            }
            (f, r)
        })
        .collect())
}

/// Status of one row in the result.
#[derive(Debug, Clone, Serialize)]
pub struct RowStatus {
    /// Row of the targets table (from 1).
    pub row: usize,
    /// `reached`, `out_of_joint_limits`, `out_of_reach` or `singular`.
    pub status: Status,
    /// Why (absent when reached).
    #[serde(skip_serializing_if = "String::is_empty")]
    pub reason: String,
}

/// Counts per status and the largest residual of the reached rows.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Summary {
    /// Rows in the targets table.
    pub targets: usize,
    /// Rows reached.
    pub reached: usize,
    /// Rows reachable only beyond a joint limit.
    pub out_of_joint_limits: usize,
    /// Rows out of reach.
    pub out_of_reach: usize,
    /// Rows at a singularity.
    pub singular: usize,
    /// Largest position residual of a reached row (mm).
    pub max_residual_mm: f64,
    /// Largest orientation residual of a reached row (deg).
    pub max_residual_deg: f64,
}

/// Units of the result's tables.
#[derive(Debug, Clone, Serialize)]
pub struct Units {
    /// Unit of the joint columns (the model's angle unit).
    pub joints: &'static str,
}

/// The result of `serial.compensate`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct Compensation {
    /// Units.
    pub units: Units,
    /// Counts per status.
    pub summary: Summary,
    /// Status and reason of every row.
    pub rows: Vec<RowStatus>,
    /// q1..qN, residual_mm, residual_deg, status_code per target (also the main table).
    #[serde(serialize_with = "crate::report::json_rows")]
    pub joints: Table,
}

impl CompensateJob {
    /// Solve every target: the typed result, the joints as the main table and a CSV
    /// artefact with the status names and reasons.
    pub fn compensate(&self, monitor: &dyn Monitor) -> Result<Run<Compensation>, JobError> {
        let to_file = self.model.chain.units.to_file(Quantity::Angle);
        let mm = 1e-3 / self.model.chain.units.metre();
        let mut columns = self.model.joint_columns();
        columns.extend(["residual_mm", "residual_deg", "status_code"].map(String::from));
        let mut table = Table {
            columns: columns.clone(),
            rows: Vec::with_capacity(self.targets.len()),
        };
        let mut csv = columns[..columns.len() - 1].join(",") + ",status,reason\n";
        let mut rows = Vec::with_capacity(self.targets.len());
        let mut summary = Summary {
            targets: self.targets.len(),
            ..Default::default()
        };
        let mut scratch = Scratch::default();
        for (i, (target, reference)) in self.targets.iter().enumerate() {
            if i % 1024 == 0 {
                if monitor.is_cancelled() {
                    return Err(JobError::Cancelled);
                }
                monitor.progress(i as f64 / self.targets.len().max(1) as f64, "compensation");
            }
            let a = self.solver.solve(target, reference, &mut scratch);
            let (res_mm, res_deg) = (a.residual_position / mm, a.residual_angle.to_degrees());
            let mut row: Vec<f64> = a.q.iter().map(|v| v * to_file).collect();
            row.extend([res_mm, res_deg, a.status.code()]);
            for v in &row[..row.len() - 1] {
                let _ = write!(csv, "{v},");
            }
            let _ = writeln!(csv, "{},{}", a.status.name(), quote(&a.reason));
            table.push(row);
            match a.status {
                Status::Reached => {
                    summary.reached += 1;
                    summary.max_residual_mm = summary.max_residual_mm.max(res_mm);
                    summary.max_residual_deg = summary.max_residual_deg.max(res_deg);
                }
                Status::OutOfJointLimits => summary.out_of_joint_limits += 1,
                Status::OutOfReach => summary.out_of_reach += 1,
                Status::Singular => summary.singular += 1,
            }
            rows.push(RowStatus {
                row: i + 1,
                status: a.status,
                reason: a.reason,
            });
        }
        let artefacts = vec![Artefact {
            name: "compensated_joints.csv".into(),
            media_type: "text/csv".into(),
            content: csv.into_bytes(),
        }];
        Ok(Run {
            result: Compensation {
                units: Units {
                    joints: self.model.angle_unit(),
                },
                summary,
                rows,
                joints: table.clone(),
            },
            main_table: Some(table),
            artefacts,
        })
    }
}

/// A CSV field: quoted, inner quotes doubled.
fn quote(s: &str) -> String {
    format!("\"{}\"", s.replace('"', "\"\""))
}

impl Kind for CompensateJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::compensate)
    }
}

#[cfg(test)]
mod tests;
