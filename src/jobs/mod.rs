//! Jobs: a JSON document with a `kind`, inputs and `options` (`../shared/spec/jobs.md`).
//! [`prepare`] validates a job completely (models loaded, tables parsed, units and limits
//! checked) before anything runs; [`Job::run`] executes it with a [`Monitor`] and wraps the
//! kind's fields in the result envelope. The same path serves `calibd run`, the daemon and
//! schedules.

pub mod envelope;
pub mod examples;
pub mod humanoid;
pub mod map_options;
pub mod offline;
pub mod pcr;
pub mod report_view;
pub mod schema;
pub mod serial;
pub mod tree;

use std::collections::BTreeMap;
use std::sync::Arc;

use serde_json::Value;

use crate::campaigns;
pub use crate::run::{
    Artefact, Cx, DirResolver, Inputs, JobError, Kind, NoReferences, Output, Produced, Resolver,
    RunFuture, Table, computed, parse_spec,
};
use crate::util::Monitor;

/// One entry of the kind registry: name, description and how to validate a document.
#[derive(Debug)]
pub struct KindInfo {
    /// The `kind` of job documents.
    pub name: &'static str,
    /// One line for `calibd kinds` and `GET /v1/kinds`.
    pub description: &'static str,
    /// JSON Schema of the kind's document (the spec its `prepare` parses), for
    /// `openapi.yaml` ([`schema::openapi_schemas`]).
    pub schema: fn(&mut schemars::SchemaGenerator) -> schemars::Schema,
    prepare: fn(&Value, &Inputs<'_>) -> Result<Arc<dyn Kind>, JobError>,
}

/// A registry entry: `kind!(name, description, prepare, Spec)` where `Spec` is the type
/// `prepare` gives [`parse_spec`]. A new kind derives `schemars::JsonSchema` on its spec
/// (and the option types in it; `serde_json::Value` inputs take a hand schema from
/// [`schema`], e.g. `#[schemars(schema_with = "crate::run::schema::table")]`), adds its
/// entry here, then runs `CALIBD_UPDATE_OPENAPI=1 cargo test --test it openapi_jobs::` to
/// write its schema into `openapi.yaml`. A spec without `JsonSchema` does not compile.
macro_rules! kind {
    ($name:literal, $desc:literal, $prepare:path, $spec:ty) => {
        KindInfo {
            name: $name,
            description: $desc,
            schema: <$spec as schemars::JsonSchema>::json_schema,
            prepare: |doc, inputs| Ok(Arc::new($prepare(doc, inputs)?) as Arc<dyn Kind>),
        }
    };
}

/// Every job kind calibd runs, with a one-line description.
pub const KINDS: &[KindInfo] = &[
    kind!(
        "serial.fk",
        "forward kinematics of a serial model over a joints table",
        serial::fk::prepare,
        serial::fk::Spec
    ),
    kind!(
        "serial.identify",
        "elasto-geometric identification of a serial arm from ball-centring or Cartesian measurements",
        serial::identify::prepare,
        serial::identify::Spec
    ),
    kind!(
        "serial.design",
        "DETMAX selection of n configurations from a pool, with observability indices",
        serial::design::prepare,
        serial::design::Spec
    ),
    kind!(
        "serial.dispersion",
        "dispersion of identification results over DETMAX-selected set sizes",
        serial::dispersion::prepare,
        serial::dispersion::Spec
    ),
    kind!(
        "serial.compensate",
        "joints that put the TCP of a calibrated serial model on target poses (closed form + Newton with compliance)",
        serial::compensate::prepare,
        serial::compensate::Spec
    ),
    kind!(
        "serial.compensate_program",
        "an ABB RAPID module's robtargets rewritten so the controller's nominal kinematics reach what the calibrated model predicts; optional upload over RWS",
        serial::compensate_program::prepare,
        serial::compensate_program::Spec
    ),
    kind!(
        "pcr.fk",
        "forward kinematics of a 3-PF continuum robot over a joints table",
        pcr::fk::prepare,
        pcr::fk::Spec
    ),
    kind!(
        "pcr.ik",
        "inverse kinematics of a 3-PF continuum robot over a poses table",
        pcr::ik::prepare,
        pcr::ik::Spec
    ),
    kind!(
        "pcr.sensitivity",
        "sensitivity of the 3-PF platform pose to each parameter type (Table 2)",
        pcr::sensitivity::prepare,
        pcr::sensitivity::Spec
    ),
    kind!(
        "pcr.identify",
        "three-step identification of a 3-PF robot and its microscope extrinsics (Table 3)",
        pcr::identify::prepare,
        pcr::identify::Spec
    ),
    kind!(
        "pcr.accuracy",
        "ISO 9283 pose accuracy of a 3-PF robot on a square, a circle or poses (Table 4)",
        pcr::accuracy::prepare,
        pcr::accuracy::Spec
    ),
    kind!(
        "pcr.pattern_pose",
        "platform pose (x, y, theta) from microscope images of a periodic or encoded pattern, by the phase method",
        pcr::pattern_pose::prepare,
        pcr::pattern_pose::Spec
    ),
    kind!(
        "pcr.mount_markers",
        "the six rod-mount markers in a wide-field image, written as the model's measured clamp positions",
        pcr::mount_markers::prepare,
        pcr::mount_markers::Spec
    ),
    kind!(
        "humanoid.identify",
        "whole-body elasto-geometric calibration of a humanoid from motion-capture markers",
        humanoid::identify::prepare,
        humanoid::identify::Spec
    ),
    kind!(
        "tree.identify",
        "elasto-geometric calibration of a modified-DH tree (torso + arms) from markers, lumped joint and lateral elasticity without torques",
        tree::prepare,
        tree::Spec
    ),
    kind!(
        "humanoid.validate",
        "marker RMSE of non-calibrated, geometric and full models on a validation session",
        humanoid::validate::prepare,
        humanoid::validate::Spec
    ),
    kind!(
        "cell.centre",
        "the centring loop on one ball of a ball-centring cell, from a joint configuration",
        campaigns::centre::prepare,
        campaigns::centre::Spec
    ),
    kind!(
        "cell.trical_campaign",
        "TriCal campaign on a cell: centre each (given or DETMAX) configuration, identify, validate",
        campaigns::trical::plan::prepare,
        campaigns::trical::plan::Spec
    ),
    kind!(
        "cell.verify",
        "ISO 9283 verification on a ball-centring cell: AP, RP, AD at ball centres through the nominal and the compensated model, read without centring",
        campaigns::verify::plan::prepare,
        campaigns::verify::plan::Spec
    ),
    kind!(
        "cell.zero_check",
        "commissioning: the three indicators read 0.000 mm on the mated coupling (operator prompt, journalled readings)",
        campaigns::commission::zero_plan::prepare_zero,
        campaigns::commission::zero_plan::ZeroSpec
    ),
    kind!(
        "cell.identify_tcp",
        "commissioning: the TCP from configurations jogged onto one ball and centred, proposed to the cell",
        campaigns::commission::plan::prepare_tcp,
        campaigns::commission::plan::TcpSpec
    ),
    kind!(
        "cell.locate_balls",
        "commissioning: each ball jogged onto and centred, its position in the robot frame and the base frame, proposed to the cell",
        campaigns::commission::plan::prepare_balls,
        campaigns::commission::plan::BallsSpec
    ),
    kind!(
        "cell.jog",
        "move a ball-centring cell's robot to given joints within its envelope (a teach-pendant jog)",
        campaigns::jog::prepare,
        campaigns::jog::Spec
    ),
    kind!(
        "cell.mocap_campaign",
        "motion-capture campaign: play NOCP (or given) postures, record and pre-process markers, identify",
        campaigns::mocap::plan::prepare,
        campaigns::mocap::plan::Spec
    ),
    kind!(
        "cell.pcr_campaign",
        "3-PF campaign: Poisson-disc joint sets on the stages, microscope poses, pcr.identify, optional pcr.accuracy",
        campaigns::pcr::plan::prepare,
        campaigns::pcr::plan::Spec
    ),
    kind!(
        "humanoid.design",
        "optimal calibration postures (NOCP / COCP) for a marker layout, with trajectory",
        humanoid::design::prepare,
        humanoid::design::Spec
    ),
];

/// A validated job.
#[derive(Debug)]
pub struct Job {
    /// The job kind.
    pub kind: String,
    /// SHA-256 of the job document and of each input, by field name.
    pub inputs_sha256: BTreeMap<String, String>,
    prepared: Arc<dyn Kind>,
}

/// A finished job: the result JSON (envelope + fields) and what else it produced.
#[derive(Debug, Clone)]
pub struct Completed {
    /// The result document.
    pub result: Value,
    /// The main table.
    pub main_table: Option<Table>,
    /// The main table as a CSV file, when it was streamed ([`Job::run_streamed_in`]).
    pub main_csv_file: Option<std::path::PathBuf>,
    /// Artefacts.
    pub artefacts: Vec<Artefact>,
    /// The model proposed for a cell, if any.
    pub candidate: Option<crate::lab::Candidate>,
}

/// Validate a job document; references (file names, dataset ids) go through `resolver`.
pub fn prepare(doc: &Value, resolver: &dyn Resolver) -> Result<Job, JobError> {
    let obj = doc
        .as_object()
        .ok_or_else(|| JobError::invalid("job", "must be a JSON object"))?;
    let kind = obj
        .get("kind")
        .and_then(Value::as_str)
        .ok_or_else(|| JobError::invalid("kind", "missing or not a string"))?
        .to_string();
    let inputs = Inputs::new(resolver);
    let info = KINDS
        .iter()
        .find(|k| k.name == kind)
        .ok_or_else(|| JobError::UnknownKind {
            kind: kind.clone(),
            known: KINDS.iter().map(|k| k.name).collect::<Vec<_>>().join(", "),
        })?;
    schema::check_document(&kind, doc)?;
    let prepared = (info.prepare)(doc, &inputs)?;
    let mut inputs_sha256 = inputs.into_hashes();
    inputs_sha256.insert(
        "job".into(),
        crate::run::input::sha256_hex(&serde_json::to_vec(doc).unwrap_or_default()),
    );
    Ok(Job {
        kind,
        inputs_sha256,
        prepared,
    })
}

impl Job {
    /// Devices the job drives (see [`Kind::devices`]).
    pub fn devices(&self) -> Vec<String> {
        self.prepared.devices()
    }

    /// The plan checked against its cell's envelope, for kinds that move (see
    /// [`Kind::preflight`]).
    pub fn preflight(
        &self,
        lab: &crate::lab::Lab,
        monitor: &dyn Monitor,
    ) -> Option<Result<crate::run::Preflight, JobError>> {
        self.prepared.preflight(lab, monitor)
    }

    /// Whether an interrupted or paused run can continue from its journal.
    pub fn resumable(&self) -> bool {
        self.prepared.resumable()
    }

    /// Whether the job can write its main table as CSV row by row
    /// ([`crate::jobs::offline::write_main_csv`]), without building the table or the result.
    pub fn streams_main_csv(&self) -> bool {
        self.prepared.streams_main_csv()
    }

    /// Write the main table as CSV to `out` row by row (see [`Kind::write_main_csv`]); the
    /// number of rows.
    pub fn write_main_csv(
        &self,
        out: &mut dyn std::io::Write,
        monitor: &dyn Monitor,
    ) -> Result<usize, JobError> {
        self.prepared.write_main_csv(out, monitor)
    }

    /// Run the job in `cx` and wrap its output in the result envelope.
    pub async fn run_in(&self, cx: Cx) -> Result<Completed, JobError> {
        let started = chrono::Utc::now();
        let Produced {
            output: out,
            candidate,
        } = self.prepared.clone().run(cx).await?;
        if let Some((row, column, value)) =
            out.main_table.as_ref().and_then(Table::first_non_finite)
        {
            return Err(JobError::NonFinite {
                table: "main table".into(),
                row,
                column: column.into(),
                value,
            });
        }
        let mut out = out;
        withhold_rejected(&mut out);
        let finished = chrono::Utc::now();
        let result = envelope::wrap(
            &self.kind,
            started,
            finished,
            &self.inputs_sha256,
            out.fields,
        );
        Ok(Completed {
            result,
            main_table: out.main_table,
            main_csv_file: None,
            artefacts: out.artefacts,
            candidate,
        })
    }

    /// Whether the daemon streams this job's main table ([`Kind::large_main_table`]).
    pub fn large_main_table(&self) -> bool {
        self.prepared.streams_main_csv() && self.prepared.large_main_table()
    }

    /// Run the job in `cx` writing its main table row by row to the CSV file `csv` (on the
    /// blocking pool) instead of holding it: the result carries every field but the rows.
    pub async fn run_streamed_in(
        &self,
        cx: Cx,
        csv: std::path::PathBuf,
    ) -> Result<Completed, JobError> {
        let started = chrono::Utc::now();
        let kind = self.prepared.clone();
        let path = csv.clone();
        let rows = cx
            .compute(move |m| {
                let io = |e: std::io::Error| JobError::io("writing the main table", Some(&path), e);
                let file = std::fs::File::create(&path).map_err(io)?;
                let mut out = std::io::BufWriter::with_capacity(1 << 16, file);
                let n = kind.write_main_csv(&mut out, m)?;
                out.into_inner().map_err(|e| io(e.into_error()))?;
                Ok(n)
            })
            .await;
        let rows = match rows {
            Ok(n) => n,
            Err(e) => {
                let _ = std::fs::remove_file(&csv);
                return Err(e);
            }
        };
        let fields = self.prepared.streamed_fields(rows)?;
        let result = envelope::wrap(
            &self.kind,
            started,
            chrono::Utc::now(),
            &self.inputs_sha256,
            fields,
        );
        Ok(Completed {
            result,
            main_table: None,
            main_csv_file: Some(csv),
            artefacts: Vec::new(),
            candidate: None,
        })
    }
}

/// A rejected identification (result field `verdict` = `rejected`) makes no calibrated
/// model: its `calibrated_*` artefacts and result fields are renamed `rejected_*`
/// (`rejected_model.json`), kept for inspection but never taken for a calibration.
pub fn withhold_rejected(out: &mut Output) {
    if out.fields.get("verdict").and_then(Value::as_str) != Some("rejected") {
        return;
    }
    let renamed = |name: &str| {
        name.strip_prefix("calibrated_")
            .map(|r| format!("rejected_{r}"))
    };
    for a in &mut out.artefacts {
        if let Some(n) = renamed(&a.name) {
            a.name = n;
        }
    }
    let keys: Vec<String> = out
        .fields
        .keys()
        .filter(|k| renamed(k).is_some())
        .cloned()
        .collect();
    for k in keys {
        if let (Some(v), Some(n)) = (out.fields.remove(&k), renamed(&k)) {
            out.fields.insert(n, v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::monitor::NoMonitor;

    /// A kind whose computation overflows on its second row.
    #[derive(Debug)]
    struct Overflowing;

    impl Overflowing {
        fn table(&self, _: &dyn Monitor) -> Result<crate::run::Run<BTreeMap<(), ()>>, JobError> {
            let mut t = Table::new(&["x", "y"]);
            t.push(vec![1.0, 2.0]);
            t.push(vec![1e308 * 10.0, f64::NAN]);
            Ok(crate::run::Run {
                result: BTreeMap::new(),
                main_table: Some(t),
                artefacts: Vec::new(),
            })
        }
    }

    impl Kind for Overflowing {
        fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
            computed(self, cx, Self::table)
        }
    }

    #[test]
    fn an_unknown_kind_lists_the_kinds() {
        let e = prepare(&serde_json::json!({"kind": "serial.fkk"}), &NoReferences)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`serial.fkk`"), "{e}");
        for k in KINDS {
            assert!(e.contains(k.name), "{} missing from: {e}", k.name);
        }
    }

    #[test]
    fn a_result_that_is_not_finite_fails_the_job_naming_row_and_column() {
        let job = Job {
            kind: "test.overflow".into(),
            inputs_sha256: BTreeMap::new(),
            prepared: Arc::new(Overflowing),
        };
        let e = job.run(&NoMonitor).unwrap_err();
        assert!(matches!(e, JobError::NonFinite { row: 2, .. }), "{e:?}");
        let m = e.to_string();
        assert!(
            m.contains("row 2") && m.contains("`x`") && m.contains("inf"),
            "{m}"
        );
        assert!(
            !e.is_invalid_input(),
            "the inputs parsed; the computation failed"
        );
    }
}
