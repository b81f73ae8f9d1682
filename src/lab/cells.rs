//! The three kinds of cell calibd drives, as campaigns see them: device handles behind the
//! procedure traits, the cell's current model (nominal until a calibration is accepted)
//! and what a campaign needs to plan (ball plate, envelope, joints, markers).

use std::sync::{Arc, Mutex};

use super::devices::DeviceLink;
use crate::model::dh::DhFile;
use crate::model::humanoid::MarkerDef;
use crate::model::pcr::PcrFile;
use crate::procedures::{
    Envelope, Indicators, JointRobot, LinearStages, MarkerStream, ModuleLoader, PoseSensor, Robot,
};

/// `Debug` (name and devices) and `current_model` of a cell type.
macro_rules! cell_common {
    ($cell:ident, $field:ident, $model:ty) => {
        impl std::fmt::Debug for $cell {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.debug_struct(stringify!($cell))
                    .field("name", &self.name)
                    .field("devices", &self.links)
                    .finish_non_exhaustive()
            }
        }

        impl $cell {
            /// The current model.
            pub fn current_model(&self) -> $model {
                current(&self.$field)
            }
        }
    };
}

cell_common!(TricalCell, model, DhFile);
cell_common!(PcrCell, model, PcrFile);
cell_common!(MocapCell, urdf, String);

fn current<T: Clone>(m: &Mutex<T>) -> T {
    m.lock().unwrap_or_else(|p| p.into_inner()).clone()
}

fn replace<T>(m: &Mutex<T>, v: T) {
    *m.lock().unwrap_or_else(|p| p.into_inner()) = v;
}

/// A ball-centring cell: a serial arm (RWS) with the three-indicator device (U-WAVE-R).
pub struct TricalCell {
    /// Cell name (jobs name it in `cell`).
    pub name: String,
    /// The arm, behind the cell's motion envelope.
    pub robot: Arc<dyn Robot>,
    /// The centring device.
    pub indicators: Arc<dyn Indicators>,
    /// The arm's controller as a store of program modules.
    pub modules: Arc<dyn ModuleLoader>,
    /// The cell's current model.
    pub model: Mutex<DhFile>,
    /// The lab file's model: the nominal kinematics the controller plans with.
    pub nominal: DhFile,
    /// Ballbar distances d12, d13, d23 of the plate (mm).
    pub ballbar: [f64; 3],
    /// The envelope the procedures enforce.
    pub envelope: Envelope,
    /// Joint speed of the controller's moves (deg/s), for a plan's estimated duration.
    pub joint_speed_deg_s: f64,
    /// Its devices: names (queue locks), addresses, probes.
    pub links: Vec<DeviceLink>,
}

/// A 3-PF cell: the continuum robot on three stages (MCS2) under a microscope.
pub struct PcrCell {
    /// Cell name.
    pub name: String,
    /// The three stages (joints q1..q3, m).
    pub stages: Arc<dyn LinearStages>,
    /// The microscope.
    pub microscope: Arc<dyn PoseSensor>,
    /// The cell's current model.
    pub model: Mutex<PcrFile>,
    /// Its devices: names (queue locks), addresses, probes.
    pub links: Vec<DeviceLink>,
}

/// A motion-capture cell: a humanoid's joint interface in a QTM room.
pub struct MocapCell {
    /// Cell name.
    pub name: String,
    /// The robot's joint interface.
    pub robot: Arc<dyn JointRobot>,
    /// The motion-capture stream.
    pub stream: Arc<dyn MarkerStream>,
    /// The current model: URDF text (nominal until a calibration is accepted).
    pub urdf: Mutex<String>,
    /// Root link of the measured chain (the waist).
    pub root_link: String,
    /// The measured joints, in the robot interface's order.
    pub joints: Vec<String>,
    /// Joint limits (rad), same order.
    pub limits: Vec<[f64; 2]>,
    /// Largest joint change of one posture move (rad): longer moves are split.
    pub max_step_rad: f64,
    /// Mean joint speed (rad/s) of the interface, for estimates.
    pub speed_rad_s: f64,
    /// The markers on the robot with their guessed positions.
    pub markers: Vec<MarkerDef>,
    /// Its devices: names (queue locks), addresses, probes.
    pub links: Vec<DeviceLink>,
}

/// A model of one cell kind.
#[derive(Debug, Clone, PartialEq)]
pub enum CellModel {
    /// DH model of a serial arm.
    Serial(DhFile),
    /// Model file of a 3-PF robot.
    Pcr(PcrFile),
    /// URDF text of a humanoid.
    Humanoid(String),
}

impl CellModel {
    /// The model as stored in the cell history (the model file's JSON; URDF as a string).
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            CellModel::Serial(f) => serde_json::to_value(f).unwrap_or_default(),
            CellModel::Pcr(f) => serde_json::to_value(f).unwrap_or_default(),
            CellModel::Humanoid(u) => serde_json::Value::String(u.clone()),
        }
    }
}

/// One cell of the lab.
pub enum Cell {
    /// Ball-centring calibration of a serial arm.
    BallCentring(TricalCell),
    /// Micrometre calibration of a 3-PF continuum robot.
    Pcr(PcrCell),
    /// Whole-body calibration of a humanoid from motion capture.
    Mocap(MocapCell),
}

impl std::fmt::Debug for Cell {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Cell")
            .field("name", &self.name())
            .field("kind", &self.kind())
            .field("devices", &self.devices())
            .finish()
    }
}

impl Cell {
    /// The cell's name.
    pub fn name(&self) -> &str {
        match self {
            Cell::BallCentring(c) => &c.name,
            Cell::Pcr(c) => &c.name,
            Cell::Mocap(c) => &c.name,
        }
    }

    /// The cell kind as the API names it.
    pub fn kind(&self) -> &'static str {
        match self {
            Cell::BallCentring(_) => "ball_centring",
            Cell::Pcr(_) => "pcr",
            Cell::Mocap(_) => "mocap",
        }
    }

    /// Device names (queue locks, device panel).
    pub fn devices(&self) -> Vec<String> {
        self.links().iter().map(|l| l.name.clone()).collect()
    }

    /// Its devices with their addresses and probes.
    pub fn links(&self) -> &[DeviceLink] {
        match self {
            Cell::BallCentring(c) => &c.links,
            Cell::Pcr(c) => &c.links,
            Cell::Mocap(c) => &c.links,
        }
    }

    /// The current model.
    pub fn current_model(&self) -> CellModel {
        match self {
            Cell::BallCentring(c) => CellModel::Serial(c.current_model()),
            Cell::Pcr(c) => CellModel::Pcr(c.current_model()),
            Cell::Mocap(c) => CellModel::Humanoid(c.current_model()),
        }
    }

    /// Read a stored model of this cell's kind back.
    pub fn parse_model(&self, v: &serde_json::Value) -> Result<CellModel, String> {
        match self {
            Cell::BallCentring(_) => serde_json::from_value(v.clone())
                .map(CellModel::Serial)
                .map_err(|e| e.to_string()),
            Cell::Pcr(_) => serde_json::from_value(v.clone())
                .map(CellModel::Pcr)
                .map_err(|e| e.to_string()),
            Cell::Mocap(_) => v
                .as_str()
                .map(|s| CellModel::Humanoid(s.to_string()))
                .ok_or_else(|| "a humanoid model is URDF text".to_string()),
        }
    }

    /// Make `m` the current model; refused if it is another kind's model.
    pub fn set_model(&self, m: CellModel) -> Result<(), String> {
        match (self, m) {
            (Cell::BallCentring(c), CellModel::Serial(f)) => replace(&c.model, f),
            (Cell::Pcr(c), CellModel::Pcr(f)) => replace(&c.model, f),
            (Cell::Mocap(c), CellModel::Humanoid(u)) => replace(&c.urdf, u),
            (c, _) => {
                return Err(format!(
                    "cell `{}` ({}) cannot take that kind of model",
                    c.name(),
                    c.kind()
                ));
            }
        }
        Ok(())
    }
}
