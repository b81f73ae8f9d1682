//! `serial.fk`: TCP poses (x, y, z, a, b, c in {W}) of a serial model over a joints table,
//! with the static deflection of the model's compliances.
//!
//! A joints table given as a CSV file is streamed: validated row by row when the job is
//! prepared (its hash kept, and its rows too while they are few, see [`KEPT_VALUES`]), then
//! read again row by row when it runs, so that `calibd run --out poses.csv` holds one row at
//! a time whatever the table's length ([`FkJob::write_csv`]). A file that changed between
//! the two readings fails the job (kept rows are checked by hashing the file again).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::joints::JointColumns;
use super::{ChainSpec, SerialModel, load_model};
use crate::model::Quantity;
use crate::run::Run;
use crate::run::rows::{CsvRows, CsvSink, HashingReader};
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::Monitor;

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::serial_model")]
    model: Value,
    #[serde(default)]
    chain: Option<ChainSpec>,
    #[schemars(schema_with = "crate::run::schema::table")]
    joints: Value,
    #[serde(default)]
    parameters: BTreeMap<String, f64>,
    #[serde(default)]
    #[allow(dead_code)]
    options: Option<serde_json::Map<String, Value>>,
}

/// Columns of the poses table.
const POSE_COLUMNS: [&str; 6] = ["x", "y", "z", "a", "b", "c"];

/// Where the joint rows come from.
#[derive(Debug)]
enum Joints {
    /// Parsed whole (inline rows, an uploaded dataset): internal units, limits checked.
    Rows(Vec<Vec<f64>>),
    /// A CSV file, already validated by one streamed reading.
    File {
        /// The file.
        path: PathBuf,
        /// Hex SHA-256 of its bytes at validation.
        sha256: String,
        /// The validated rows (internal units, one row after another), when they are at
        /// most [`KEPT_VALUES`] values: the run then hashes the file instead of parsing it
        /// again.
        kept: Option<Vec<f64>>,
    },
}

/// The most joint values a file's validation keeps for the run (8 MB): below it, a run
/// reads the file once to check its hash instead of parsing it a second time; above it,
/// memory stays flat in the number of rows.
const KEPT_VALUES: usize = 1 << 20;

/// A validated `serial.fk` job.
#[derive(Debug)]
pub struct FkJob {
    model: SerialModel,
    joints: Joints,
}

/// Validate a `serial.fk` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<FkJob, JobError> {
    prepare_keeping(doc, inputs, KEPT_VALUES)
}

/// Validate a `serial.fk` job, keeping a joints file's rows when they are at most
/// `kept_values` values.
fn prepare_keeping(
    doc: &Value,
    inputs: &Inputs<'_>,
    kept_values: usize,
) -> Result<FkJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let mut model = load_model(inputs, &spec.model, spec.chain.as_ref())?;
    let (joints, first) = match inputs.table_file(&spec.joints) {
        Some(path) => {
            let mut first = None;
            let mut kept = Some(Vec::new());
            let sha256 = each_file_row(&model, &path, None, &mut |_, q| {
                first.get_or_insert_with(|| q.to_vec());
                if let Some(v) = &mut kept {
                    if v.len() + q.len() > kept_values {
                        kept = None;
                    } else {
                        v.extend_from_slice(q);
                    }
                }
                Ok(())
            })?;
            inputs.record_sha256("joints", sha256.clone());
            (Joints::File { path, sha256, kept }, first)
        }
        None => {
            let table = inputs.table("joints", &spec.joints)?;
            let q = model.joints("joints", &table)?;
            let first = q.first().cloned();
            (Joints::Rows(q), first)
        }
    };
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
        if let Some(q0) = &first
            && !pose(&model.chain, q0).iter().all(|x| x.is_finite())
        {
            return Err(JobError::invalid(
                format!("parameters.{name}"),
                format!("{v}: the forward kinematics is not finite with this value"),
            ));
        }
    }
    Ok(FkJob { model, joints })
}

/// Read the joints CSV file `path` row by row, calling `f` with each row's number (from 1)
/// and joint values (internal units, limits checked); the file's hex SHA-256. With
/// `expected`, a file whose hash differs fails (it changed since it was validated).
fn each_file_row(
    model: &SerialModel,
    path: &Path,
    expected: Option<&str>,
    f: &mut dyn FnMut(usize, &[f64]) -> Result<(), JobError>,
) -> Result<String, JobError> {
    let file = File::open(path).map_err(|e| file_error(path, e))?;
    let mut rows = CsvRows::new("joints", HashingReader::new(file), &|_: &str| false)?;
    let cols = JointColumns::new(model, "joints", rows.columns())?;
    let (mut values, mut q) = (Vec::new(), Vec::new());
    while let Some(row) = rows.next_into(&mut values)? {
        cols.read(model, row, &values, &mut q)?;
        f(row, &q)?;
    }
    let sha256 = rows.into_inner().hex();
    if let Some(h) = expected {
        same_hash(path, &sha256, h)?;
    }
    Ok(sha256)
}

/// Fail unless the file at `path` still hashes to `expected` (hex SHA-256).
fn file_unchanged(path: &Path, expected: &str) -> Result<(), JobError> {
    let file = File::open(path).map_err(|e| file_error(path, e))?;
    let mut hashed = HashingReader::new(file);
    std::io::copy(&mut hashed, &mut std::io::sink()).map_err(|e| file_error(path, e))?;
    same_hash(path, &hashed.hex(), expected)
}

/// Fail when the joints file's hash `found` is not the `expected` one of its validation.
fn same_hash(path: &Path, found: &str, expected: &str) -> Result<(), JobError> {
    if found == expected {
        return Ok(());
    }
    Err(file_error(
        path,
        "the file changed after the job was validated",
    ))
}

/// An error reading the joints file at `path`.
fn file_error(path: &Path, message: impl ToString) -> JobError {
    JobError::Input {
        field: "joints".into(),
        reference: path.display().to_string(),
        message: message.to_string(),
    }
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
    /// Call `f` with each joints row's number (from 1) and pose (x, y, z in the model's
    /// length unit, a, b, c in its angle unit), in order; the number of rows.
    fn each_pose(
        &self,
        monitor: &dyn Monitor,
        f: &mut dyn FnMut(usize, [f64; 6]) -> Result<(), JobError>,
    ) -> Result<usize, JobError> {
        let c = &self.model.chain;
        let k = c.units.to_file(Quantity::Angle);
        let mut n = 0;
        let mut one = |row: usize, q: &[f64]| {
            if row.is_multiple_of(1024) && monitor.is_cancelled() {
                return Err(JobError::Cancelled);
            }
            let v = pose(c, q);
            n = row;
            f(row, [v[0], v[1], v[2], v[3] * k, v[4] * k, v[5] * k])
        };
        match &self.joints {
            Joints::Rows(q) => {
                for (i, q) in q.iter().enumerate() {
                    one(i + 1, q)?;
                }
            }
            Joints::File {
                path,
                sha256,
                kept: Some(values),
            } => {
                file_unchanged(path, sha256)?;
                let width = self.model.joint_columns().len().max(1);
                for (i, q) in values.chunks_exact(width).enumerate() {
                    one(i + 1, q)?;
                }
            }
            Joints::File {
                path,
                sha256,
                kept: None,
            } => {
                each_file_row(&self.model, path, Some(sha256), &mut one)?;
            }
        }
        Ok(n)
    }

    /// Compute the TCP poses: the typed result, the poses also as the main table.
    pub fn poses(&self, monitor: &dyn Monitor) -> Result<Run<SerialPoses>, JobError> {
        let mut poses = Table::new(&POSE_COLUMNS);
        self.each_pose(monitor, &mut |_, p| {
            poses.push(p.to_vec());
            Ok(())
        })?;
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

    /// Write the poses table as CSV to `out` row by row, each pose formatted as soon as it
    /// is computed (the same bytes as the main table's CSV); the number of rows. Memory is
    /// flat in the number of rows when the joints come from a file. A pose that is not
    /// finite fails, naming its row and column.
    pub fn write_csv(&self, out: &mut dyn Write, monitor: &dyn Monitor) -> Result<usize, JobError> {
        let io = |e: std::io::Error| JobError::io("writing the poses CSV", None, e);
        let mut sink = CsvSink::new(out, &POSE_COLUMNS).map_err(io)?;
        let n = self.each_pose(monitor, &mut |row, p| {
            if let Some(j) = p.iter().position(|v| !v.is_finite()) {
                return Err(JobError::NonFinite {
                    table: "main table".into(),
                    row,
                    column: POSE_COLUMNS[j].into(),
                    value: p[j],
                });
            }
            sink.row(&p).map_err(io)
        })?;
        sink.finish().map_err(io)?;
        Ok(n)
    }
}

impl Kind for FkJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::poses)
    }

    fn streams_main_csv(&self) -> bool {
        true
    }

    fn write_main_csv(
        &self,
        out: &mut dyn Write,
        monitor: &dyn Monitor,
    ) -> Result<usize, JobError> {
        self.write_csv(out, monitor)
    }

    fn large_main_table(&self) -> bool {
        matches!(self.joints, Joints::File { .. })
    }

    fn streamed_fields(&self, rows: usize) -> Result<serde_json::Map<String, Value>, JobError> {
        let units = PoseUnits {
            length: self.model.length_unit(),
            angle: self.model.angle_unit(),
        };
        let units = serde_json::to_value(units)
            .map_err(|e| JobError::internal("serialising the units", e))?;
        let mut m = serde_json::Map::new();
        m.insert("units".into(), units);
        // The poses are only in the main table (`GET /v1/jobs/{id}/table`): a table read
        // from a large file is never inlined in the JSON result.
        m.insert(
            "poses_in_main_table".into(),
            serde_json::json!({"rows": rows, "columns": POSE_COLUMNS}),
        );
        Ok(m)
    }
}

#[cfg(test)]
mod tests;
