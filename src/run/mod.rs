//! The job core, below every kind: the [`Kind`] trait each job kind implements, the
//! context a running job gets ([`Cx`]), what it returns ([`Output`], [`Produced`],
//! [`Run`]), its error ([`JobError`]), tables and input references. It imports only the
//! layers below (maths, procedures, lab), never a kind, a campaign or the registry.

pub mod context;
pub mod error;
pub mod input;
pub mod preflight;
pub mod rows;
pub mod schema;
pub mod table;

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;

use serde::Serialize;
use serde_json::{Map, Value};

pub use context::Cx;
pub use error::JobError;
pub use input::{DirResolver, Inputs, NoReferences, Resolver};
pub use preflight::Preflight;
pub use table::Table;

use crate::util::Monitor;

/// The calibd version written into every result and calibrated model.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// A file produced by a job besides its result JSON (also what the store keeps and serves).
#[derive(Debug, Clone, PartialEq)]
pub struct Artefact {
    /// File name, e.g. `calibrated_model.json`.
    pub name: String,
    /// Media type, e.g. `application/json`, `text/csv`, `image/svg+xml`.
    pub media_type: String,
    /// Content.
    pub content: Vec<u8>,
}

impl Artefact {
    /// A table as a CSV artefact.
    pub fn csv(name: &str, t: &Table) -> Self {
        Self {
            name: name.into(),
            media_type: "text/csv".into(),
            content: t.to_csv().into_bytes(),
        }
    }
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

/// What a run produced: the kind's output and, for a campaign, the model it proposes for
/// its cell (the service decides on it in the same transaction that stores the result).
#[derive(Debug, Clone)]
pub struct Produced {
    /// The output.
    pub output: Output,
    /// The proposed model.
    pub candidate: Option<crate::lab::Candidate>,
}

impl From<Output> for Produced {
    fn from(output: Output) -> Self {
        Self {
            output,
            candidate: None,
        }
    }
}

impl Output {
    /// An output whose result fields are `result` serialised (a kind's typed result).
    pub fn typed<T: serde::Serialize>(result: &T) -> Result<Self, JobError> {
        match serde_json::to_value(result) {
            Ok(Value::Object(fields)) => Ok(Self {
                fields,
                ..Default::default()
            }),
            Ok(other) => Err(JobError::internal(
                "serialising a result",
                format!("it serialised to {other} instead of an object"),
            )),
            Err(e) => Err(JobError::internal("serialising a result", e)),
        }
    }
}

/// The future a kind's run returns.
pub type RunFuture = Pin<Box<dyn Future<Output = Result<Produced, JobError>> + Send>>;

/// A validated job of one kind, ready to run: every kind, numerical or device-driven,
/// implements this one trait. Numerical work goes to the blocking pool through
/// [`Cx::compute`]; campaigns are async and await their devices.
pub trait Kind: Send + Sync + std::fmt::Debug + 'static {
    /// Names of the devices the job drives while it runs (none for numerical kinds). The
    /// daemon's queue never runs two jobs that share a device, and only operators may
    /// submit a job that drives one.
    fn devices(&self) -> Vec<String> {
        Vec::new()
    }

    /// Whether an interrupted or paused run can continue from its journal (campaigns).
    fn resumable(&self) -> bool {
        false
    }

    /// Run the job in `cx`.
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture;

    /// The plan the job would execute on its cell in `lab`, checked against the cell's
    /// envelope, without moving anything (dry runs, submission); `None` for kinds without one.
    fn preflight(
        &self,
        _lab: &crate::lab::Lab,
        _monitor: &dyn Monitor,
    ) -> Option<Result<Preflight, JobError>> {
        None
    }

    /// Whether [`Kind::write_main_csv`] can write the main table without running the job
    /// through [`Kind::run`] (no result JSON, no table held in memory).
    fn streams_main_csv(&self) -> bool {
        false
    }

    /// Write the main table as CSV to `out` row by row, the same bytes as the main table of
    /// a run; the number of rows. Only kinds whose [`Kind::streams_main_csv`] is true.
    fn write_main_csv(
        &self,
        _out: &mut dyn std::io::Write,
        _monitor: &dyn Monitor,
    ) -> Result<usize, JobError> {
        Err(JobError::internal(
            "streaming the main table",
            "this kind does not stream its main table",
        ))
    }

    /// Whether the daemon should stream this job's main table to a file instead of running
    /// it through [`Kind::run`]: its input is a large file read row by row, so the table
    /// would not fit in memory or in a JSON result. Only kinds that stream their table.
    fn large_main_table(&self) -> bool {
        false
    }

    /// The result fields of a streamed run that wrote `rows` rows: everything but the rows,
    /// which are only in the main table.
    fn streamed_fields(&self, _rows: usize) -> Result<Map<String, Value>, JobError> {
        Err(JobError::internal(
            "streaming the main table",
            "this kind does not stream its main table",
        ))
    }
}

/// Run a numerical kind: `f` on the blocking pool with the context's monitor; its typed
/// result becomes the job's output.
pub fn computed<K: Kind, T: serde::Serialize + Send + 'static>(
    kind: Arc<K>,
    cx: Cx,
    f: fn(&K, &dyn Monitor) -> Result<Run<T>, JobError>,
) -> RunFuture {
    Box::pin(async move {
        let run = cx.compute(move |m| f(&kind, m)).await?;
        run.into_output().map(Produced::from)
    })
}

/// A kind's typed result with its main table and artefacts (plots included): what the
/// campaigns and the service read instead of the JSON fields.
#[derive(Debug, Clone)]
pub struct Run<T> {
    /// The typed result; its serialisation is the job's result fields.
    pub result: T,
    /// The table `calibd run --out FILE.csv` writes.
    pub main_table: Option<Table>,
    /// Artefacts (files, CSV tables, SVG plots).
    pub artefacts: Vec<Artefact>,
}

impl<T: Serialize> Run<T> {
    /// The job output: the result serialised as the fields map, the table and artefacts.
    pub fn into_output(self) -> Result<Output, JobError> {
        let fields = match serde_json::to_value(&self.result)
            .map_err(|e| JobError::internal("serialising the result", e))?
        {
            Value::Object(m) => m,
            other => {
                return Err(JobError::internal(
                    "serialising the result",
                    format!("it serialised to {other}, not an object"),
                ));
            }
        };
        Ok(Output {
            fields,
            main_table: self.main_table,
            artefacts: self.artefacts,
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
