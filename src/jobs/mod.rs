//! Jobs: a JSON document with a `kind`, inputs and `options` (`../shared/spec/jobs.md`).
//! [`prepare`] validates a job completely (models loaded, tables parsed, units and limits
//! checked) before anything runs; [`Job::run`] executes it with a [`Monitor`] and wraps the
//! kind's fields in the result envelope. The same path serves `calibd run`, the daemon and
//! schedules.

pub mod cell;
pub mod envelope;
pub mod error;
pub mod examples;
pub mod humanoid;
pub mod input;
pub mod pcr;
pub mod serial;
pub mod table;

use std::collections::BTreeMap;

use serde_json::{Map, Value};

pub use error::JobError;
pub use input::{DirResolver, Inputs, NoReferences, Resolver};
pub use table::Table;

use crate::util::Monitor;

/// Every job kind calibd runs offline, with a one-line description.
pub const KINDS: &[(&str, &str)] = &[
    (
        "serial.fk",
        "forward kinematics of a serial model over a joints table",
    ),
    (
        "serial.identify",
        "elasto-geometric identification of a serial arm from ball-centring or Cartesian measurements",
    ),
    (
        "serial.design",
        "DETMAX selection of n configurations from a pool, with observability indices",
    ),
    (
        "serial.dispersion",
        "dispersion of identification results over DETMAX-selected set sizes",
    ),
    (
        "pcr.fk",
        "forward kinematics of a 3-PF continuum robot over a joints table",
    ),
    (
        "pcr.ik",
        "inverse kinematics of a 3-PF continuum robot over a poses table",
    ),
    (
        "pcr.sensitivity",
        "sensitivity of the 3-PF platform pose to each parameter type (Table 2)",
    ),
    (
        "pcr.identify",
        "three-step identification of a 3-PF robot and its microscope extrinsics (Table 3)",
    ),
    (
        "pcr.accuracy",
        "ISO 9283 pose accuracy of a 3-PF robot on a square, a circle or poses (Table 4)",
    ),
    (
        "humanoid.identify",
        "whole-body elasto-geometric calibration of a humanoid from motion-capture markers",
    ),
    (
        "humanoid.validate",
        "marker RMSE of non-calibrated, geometric and full models on a validation session",
    ),
    (
        "cell.centre",
        "the centring loop on one ball of a ball-centring cell, from a joint configuration",
    ),
    (
        "cell.trical_campaign",
        "TriCal campaign on a cell: centre each (given or DETMAX) configuration, identify, validate",
    ),
    (
        "cell.mocap_campaign",
        "motion-capture campaign: play NOCP (or given) postures, record and pre-process markers, identify",
    ),
    (
        "cell.pcr_campaign",
        "3-PF campaign: Poisson-disc joint sets on the stages, microscope poses, pcr.identify, optional pcr.accuracy",
    ),
    (
        "humanoid.design",
        "optimal calibration postures (NOCP / COCP) for a marker layout, with trajectory",
    ),
];

/// A file produced by a job besides its result JSON.
#[derive(Debug, Clone, PartialEq)]
pub struct Artefact {
    /// File name, e.g. `calibrated_model.json`.
    pub name: String,
    /// Media type, e.g. `application/json`, `text/csv`, `image/svg+xml`.
    pub media_type: String,
    /// Content.
    pub content: Vec<u8>,
}

/// What a kind returns: its result fields, its main table and artefacts.
#[derive(Debug, Clone, Default)]
pub struct Output {
    /// Kind-specific result fields (merged into the envelope).
    pub fields: Map<String, Value>,
    /// The table `calibd run --out FILE.csv` writes.
    pub main_table: Option<Table>,
    /// Extra files (CSV tables, calibrated models, plots).
    pub artefacts: Vec<Artefact>,
}

/// What a job may use besides its inputs: the lab's devices, its own measurement journal
/// (durable in the daemon, in memory offline) and the runtime the device drivers run on.
/// Numerical kinds need none of it.
#[derive(Clone, Copy, Default)]
pub struct RunContext<'a> {
    /// Devices, by cell.
    pub lab: Option<&'a crate::lab::Lab>,
    /// The job's measurement journal.
    pub journal: Option<&'a dyn crate::procedures::Journal>,
    /// The async runtime of the drivers (the job itself runs on a blocking thread).
    pub runtime: Option<&'a tokio::runtime::Handle>,
}

impl std::fmt::Debug for RunContext<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunContext")
            .field("lab", &self.lab.is_some())
            .field("journal", &self.journal.is_some())
            .field("runtime", &self.runtime.is_some())
            .finish()
    }
}

/// A validated job of one kind, ready to execute.
pub trait Prepared: Send + Sync + std::fmt::Debug {
    /// Execute it; long loops poll `monitor` for cancellation.
    fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError>;

    /// Execute it with devices and a journal; the default ignores them.
    fn execute_in(&self, ctx: &RunContext<'_>, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let _ = ctx;
        self.execute(monitor)
    }

    /// Whether an interrupted or paused run can continue from its journal (campaigns).
    fn resumable(&self) -> bool {
        false
    }

    /// Names of the devices the job drives while it runs (none for numerical kinds). The
    /// daemon's queue never runs two jobs that share a device, and only operators may
    /// submit a job that drives one.
    fn devices(&self) -> Vec<String> {
        Vec::new()
    }
}

/// A validated job.
#[derive(Debug)]
pub struct Job {
    /// The job kind.
    pub kind: String,
    /// SHA-256 of the job document and of each input, by field name.
    pub inputs_sha256: BTreeMap<String, String>,
    prepared: Box<dyn Prepared>,
}

/// A finished job: the result JSON (envelope + fields) and what else it produced.
#[derive(Debug, Clone)]
pub struct Completed {
    /// The result document.
    pub result: Value,
    /// The main table.
    pub main_table: Option<Table>,
    /// Artefacts.
    pub artefacts: Vec<Artefact>,
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
    let prepared: Box<dyn Prepared> = match kind.as_str() {
        "serial.fk" => Box::new(serial::fk::prepare(doc, &inputs)?),
        "serial.identify" => Box::new(serial::identify::prepare(doc, &inputs)?),
        "serial.design" => Box::new(serial::design::prepare(doc, &inputs)?),
        "serial.dispersion" => Box::new(serial::dispersion::prepare(doc, &inputs)?),
        "pcr.fk" => Box::new(pcr::fk::prepare(doc, &inputs)?),
        "pcr.ik" => Box::new(pcr::ik::prepare(doc, &inputs)?),
        "pcr.sensitivity" => Box::new(pcr::sensitivity::prepare(doc, &inputs)?),
        "pcr.identify" => Box::new(pcr::identify::prepare(doc, &inputs)?),
        "pcr.accuracy" => Box::new(pcr::accuracy::prepare(doc, &inputs)?),
        "humanoid.identify" => Box::new(humanoid::identify::prepare(doc, &inputs)?),
        "humanoid.validate" => Box::new(humanoid::validate::prepare(doc, &inputs)?),
        "humanoid.design" => Box::new(humanoid::design::prepare(doc, &inputs)?),
        "cell.centre" => Box::new(cell::centre::prepare(doc)?),
        "cell.trical_campaign" => Box::new(cell::trical::prepare(doc, &inputs)?),
        "cell.mocap_campaign" => Box::new(cell::mocap::prepare(doc, &inputs)?),
        "cell.pcr_campaign" => Box::new(cell::pcr::prepare(doc, &inputs)?),
        other => return Err(JobError::UnknownKind(other.to_string())),
    };
    let mut inputs_sha256 = inputs.into_hashes();
    inputs_sha256.insert(
        "job".into(),
        input::sha256_hex(&serde_json::to_vec(doc).unwrap_or_default()),
    );
    Ok(Job {
        kind,
        inputs_sha256,
        prepared,
    })
}

impl Job {
    /// Devices the job drives (see [`Prepared::devices`]).
    pub fn devices(&self) -> Vec<String> {
        self.prepared.devices()
    }

    /// Whether an interrupted or paused run can continue from its journal.
    pub fn resumable(&self) -> bool {
        self.prepared.resumable()
    }

    /// Run the job and wrap its output in the result envelope.
    pub fn run(&self, monitor: &dyn Monitor) -> Result<Completed, JobError> {
        self.run_in(&RunContext::default(), monitor)
    }

    /// Run the job with devices and a journal.
    pub fn run_in(
        &self,
        ctx: &RunContext<'_>,
        monitor: &dyn Monitor,
    ) -> Result<Completed, JobError> {
        let started = chrono::Utc::now();
        let out = self.prepared.execute_in(ctx, monitor)?;
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
            artefacts: out.artefacts,
        })
    }
}

/// Deserialize a job document into a kind's typed spec, naming the offending field.
pub fn parse_spec<T: serde::de::DeserializeOwned>(doc: &Value) -> Result<T, JobError> {
    serde_path_to_error::deserialize(doc).map_err(|e| {
        let path = e.path().to_string();
        JobError::invalid(
            if path == "." { "job".to_string() } else { path },
            e.into_inner().to_string(),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::monitor::NoMonitor;

    /// A kind whose computation overflows on its second row.
    #[derive(Debug)]
    struct Overflowing;

    impl Prepared for Overflowing {
        fn execute(&self, _: &dyn Monitor) -> Result<Output, JobError> {
            let mut t = Table::new(&["x", "y"]);
            t.push(vec![1.0, 2.0]);
            t.push(vec![1e308 * 10.0, f64::NAN]);
            Ok(Output {
                main_table: Some(t),
                ..Default::default()
            })
        }
    }

    #[test]
    fn a_result_that_is_not_finite_fails_the_job_naming_row_and_column() {
        let job = Job {
            kind: "test.overflow".into(),
            inputs_sha256: BTreeMap::new(),
            prepared: Box::new(Overflowing),
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
