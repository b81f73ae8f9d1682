//! The lab: a map of named cells, each with its devices (driver actors behind the
//! procedure traits), its current model and its acceptance rule. A lab is built from a
//! description ([`connect`]); where the devices are — real instruments or the simulation's
//! mock servers on loopback (`crate::sim`) — is the description's business, not the lab's.

pub mod adapters;
pub mod cells;
pub mod config;
pub mod connect;
pub mod decision;
pub mod devices;
pub mod probes;
pub mod resume;
pub mod source;

use std::collections::BTreeMap;
use std::future::Future;
use std::pin::Pin;

pub use cells::{Cell, CellModel, MocapCell, PcrCell, TricalCell};
pub use connect::{
    BallCentringCell, CameraLink, CellLink, FrameSourceLink, JointsLink, MocapCellLink,
    PcrCellLink, PoseSourceLink, RwsLink, StageBackend, StagesLink, UwaveLink,
};
pub use decision::{Acceptance, Candidate, Decision, Evidence};
pub use devices::{DeviceLink, DeviceReport, DeviceStatus, Identity};
pub use source::ModelSource;

fn no_cell_message(name: &str, what: &str, have: &[String]) -> String {
    if have.is_empty() {
        format!("this daemon drives no lab: there is no {what} `{name}`")
    } else {
        format!(
            "no {what} `{name}` in this lab (it has: {})",
            have.join(", ")
        )
    }
}

/// Why a lab could not be built, or cannot give what a job asked for (converted to a job
/// error at the job boundary, [`crate::run::JobError`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LabError {
    /// No cell of that name and type.
    #[error("{}", no_cell_message(name, what, have))]
    NoCell {
        /// The cell the job named.
        name: String,
        /// The type of cell the job needs, e.g. "ball-centring cell".
        what: &'static str,
        /// The cells this lab has.
        have: Vec<String>,
    },
    /// A simulated device did not start.
    #[error("simulated {device}: {message}")]
    Mock {
        /// Which device.
        device: String,
        /// What went wrong.
        message: String,
    },
    /// Two cells share a name.
    #[error("two cells are named `{0}`")]
    DuplicateCell(String),
    /// A cell's description cannot be built into a cell.
    #[error("cell `{cell}`: {message}")]
    Cell {
        /// The cell.
        cell: String,
        /// What is wrong.
        message: String,
    },
    /// The lab file was refused.
    #[error("{0}")]
    Config(#[from] config::LabConfigError),
}

/// Something that must live as long as the lab and stop with it (the simulation's mock
/// servers).
pub trait Attached: Send + Sync {
    /// Addresses it serves on, for operators and tests.
    fn addresses(&self) -> Vec<String>;
    /// Stop it.
    fn stop(self: Box<Self>) -> Pin<Box<dyn Future<Output = ()> + Send>>;
}

/// The lab's cells by name.
#[derive(Default)]
pub struct Lab {
    cells: BTreeMap<String, Cell>,
    /// Each cell's resume setting (absent: the default).
    resume: BTreeMap<String, resume::ResumePolicy>,
    /// Where each cell's current model comes from (absent: nominal).
    sources: std::sync::Mutex<BTreeMap<String, ModelSource>>,
    attached: std::sync::Mutex<Vec<Box<dyn Attached>>>,
}

impl std::fmt::Debug for Lab {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Lab")
            .field("cells", &self.cells.values().collect::<Vec<_>>())
            .field("attached", &self.mock_addresses())
            .finish()
    }
}

/// The acceptance rule of each cell kind.
pub fn acceptance(cell: &Cell) -> Acceptance {
    match cell {
        // Below 2 um a difference is indistinguishable from the centring noise (10 um).
        Cell::BallCentring(_) => Acceptance {
            min_relative_gain: 0.1,
            min_gain: 0.002,
            unit: "mm",
        },
        // The microscope resolves about 0.1 um on the platform.
        Cell::Pcr(_) => Acceptance {
            min_relative_gain: 0.1,
            min_gain: 1e-7,
            unit: "m",
        },
        // A tenth of a millimetre of marker RMSE, the capture system's noise level.
        Cell::Mocap(_) => Acceptance {
            min_relative_gain: 0.1,
            min_gain: 0.1,
            unit: "mm",
        },
    }
}

impl Lab {
    /// A lab without cells (numerical jobs only).
    pub fn empty() -> Self {
        Self::default()
    }

    /// Add a cell.
    pub fn insert(&mut self, cell: Cell) -> Result<(), LabError> {
        let name = cell.name().to_string();
        if self.cells.contains_key(&name) {
            return Err(LabError::DuplicateCell(name));
        }
        self.cells.insert(name, cell);
        Ok(())
    }

    /// Set the resume setting of cell `name`.
    pub fn set_resume_policy(&mut self, name: &str, p: resume::ResumePolicy) {
        self.resume.insert(name.to_string(), p);
    }

    /// Keep `a` alive with the lab and stop it in [`Lab::stop`].
    pub fn attach(&mut self, a: Box<dyn Attached>) {
        self.attached
            .get_mut()
            .unwrap_or_else(|p| p.into_inner())
            .push(a);
    }

    /// The cells, by name.
    pub fn cells(&self) -> impl Iterator<Item = &Cell> {
        self.cells.values()
    }

    /// The cells' names, sorted.
    pub fn cell_names(&self) -> Vec<String> {
        self.cells.keys().cloned().collect()
    }

    /// Where cell `name`'s current model comes from (nominal until one is recorded).
    pub fn model_source(&self, name: &str) -> ModelSource {
        let s = self.sources.lock().unwrap_or_else(|p| p.into_inner());
        s.get(name).cloned().unwrap_or_default()
    }

    /// Record where cell `name`'s current model comes from (with [`Cell::set_model`]).
    pub fn set_model_source(&self, name: &str, source: ModelSource) {
        let mut s = self.sources.lock().unwrap_or_else(|p| p.into_inner());
        s.insert(name.to_string(), source);
    }

    /// The cell `name`.
    pub fn cell(&self, name: &str) -> Option<&Cell> {
        self.cells.get(name)
    }

    fn missing(&self, name: &str, what: &'static str) -> LabError {
        LabError::NoCell {
            name: name.into(),
            what,
            have: self.cells.keys().cloned().collect(),
        }
    }

    /// The ball-centring cell `name`.
    pub fn trical(&self, name: &str) -> Result<&TricalCell, LabError> {
        match self.cells.get(name) {
            Some(Cell::BallCentring(c)) => Ok(c),
            _ => Err(self.missing(name, "ball-centring cell")),
        }
    }

    /// The 3-PF cell `name`.
    pub fn pcr(&self, name: &str) -> Result<&PcrCell, LabError> {
        match self.cells.get(name) {
            Some(Cell::Pcr(c)) => Ok(c),
            _ => Err(self.missing(name, "3-PF cell")),
        }
    }

    /// The motion-capture cell `name`.
    pub fn mocap(&self, name: &str) -> Result<&MocapCell, LabError> {
        match self.cells.get(name) {
            Some(Cell::Mocap(c)) => Ok(c),
            _ => Err(self.missing(name, "motion-capture cell")),
        }
    }

    /// Decide on a candidate by its cell's acceptance rule (rejected if the cell is gone).
    pub fn decide(&self, c: &Candidate) -> Decision {
        match self.cells.get(&c.cell) {
            Some(cell) => acceptance(cell).decide(c),
            None => Decision {
                cell: c.cell.clone(),
                accepted: false,
                reason: format!("this lab has no cell `{}` any more", c.cell),
                validation: c.validation.clone(),
                model: c.model.to_json(),
            },
        }
    }

    /// Names of every device of every cell (device panel, queue locks).
    pub fn device_names(&self) -> Vec<String> {
        self.cells().flat_map(|c| c.devices()).collect()
    }

    /// Whether the lab is the simulated one (digital twins behind mock devices it started),
    /// not devices a lab file names: the page and `lab check` say so.
    pub fn is_simulated(&self) -> bool {
        !self.mock_addresses().is_empty()
    }

    /// Addresses of attached simulated devices.
    pub fn mock_addresses(&self) -> Vec<String> {
        self.attached
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .iter()
            .flat_map(|a| a.addresses())
            .collect()
    }

    /// Stop what is attached (the simulation's mock servers); the cells stay, their
    /// devices unreachable.
    pub async fn stop(&self) {
        let attached =
            std::mem::take(&mut *self.attached.lock().unwrap_or_else(|p| p.into_inner()));
        for a in attached {
            a.stop().await;
        }
    }
}
