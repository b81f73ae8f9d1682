//! A lab from its description: for each cell the addresses of its devices and what the
//! campaigns need to know about it; [`Lab::connect`] starts one driver actor per device and
//! wraps it in its adapter. The simulated lab (`crate::sim`) produces the same description
//! with loopback addresses; a lab's configuration file will produce it for real devices.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use calibd_drivers::joints::{JointsConfig, JointsHandle};
use calibd_drivers::microscope::{MicroscopeConfig, MicroscopeHandle};
use calibd_drivers::qtm::{QtmConfig, QtmHandle};
use calibd_drivers::rws::{RwsConfig, RwsHandle};
use calibd_drivers::smaract::Mcs2Handle;
use calibd_drivers::uwave::{AxisMap, SerialConnector, UwaveConfig, UwaveHandle};
use calibd_drivers::{Backoff, StageConfig, TcpConnector};

use super::adapters::{
    JointInterface, Microscope, QtmStream, RwsRobot, SmaractStages, UwaveIndicators,
};
use super::{Cell, Lab, MocapCell, PcrCell, TricalCell};
use crate::model::dh::DhFile;
use crate::model::humanoid::MarkerDef;
use crate::model::pcr::PcrFile;
use crate::procedures::{Envelope, MotionLimiter};

/// An IRC5 controller reached over Robot Web Services.
#[derive(Debug, Clone)]
pub struct RwsLink {
    /// `host:port`.
    pub address: String,
    /// RWS user.
    pub user: String,
    /// RWS password (from a file or the environment; never logged).
    pub password: String,
}

/// A U-WAVE-R receiver on a serial port.
#[derive(Debug, Clone)]
pub struct UwaveLink {
    /// Serial device path.
    pub path: String,
    /// Baud rate.
    pub baud: u32,
    /// Channel, sign and zero reading (mm) of each tool axis.
    pub axes: [AxisMap; 3],
}

/// A ball-centring cell.
#[derive(Debug, Clone)]
pub struct BallCentringCell {
    /// Cell name.
    pub name: String,
    /// The arm's controller.
    pub rws: RwsLink,
    /// The indicators' receiver.
    pub uwave: UwaveLink,
    /// Ballbar distances d12, d13, d23 (mm).
    pub ballbar: [f64; 3],
    /// Nominal model (the current one until a calibration is accepted).
    pub model: DhFile,
    /// Largest joint change of one move (deg).
    pub max_joint_step_deg: f64,
    /// Largest tool move of the centring loop (mm).
    pub max_tool_step_mm: f64,
}

/// A 3-PF cell.
#[derive(Debug, Clone)]
pub struct PcrCellLink {
    /// Cell name.
    pub name: String,
    /// MCS2 controller `host:port`.
    pub mcs2: String,
    /// MCS2 channels of the joints q1, q2, q3.
    pub channels: [u8; 3],
    /// Microscope pose server `host:port`.
    pub microscope: String,
    /// Nominal model.
    pub model: PcrFile,
}

/// A motion-capture cell.
#[derive(Debug, Clone)]
pub struct MocapCellLink {
    /// Cell name.
    pub name: String,
    /// The robot's joint interface (`calibd-joints/1`) `host:port`.
    pub joints: String,
    /// Mean speed (rad/s) of the joint that moves most in a move: a move's duration is its
    /// largest joint change over this speed.
    pub joints_speed_rad_s: f64,
    /// QTM RT server `host:port`.
    pub qtm: String,
    /// Nominal URDF text.
    pub urdf: String,
    /// Root link of the measured chain.
    pub root_link: String,
    /// Measured joints, in the interface's order.
    pub joint_names: Vec<String>,
    /// Joint limits (rad).
    pub limits: Vec<[f64; 2]>,
    /// Markers with their guessed positions.
    pub markers: Vec<MarkerDef>,
}

/// One cell's description.
#[derive(Debug, Clone)]
pub enum CellLink {
    /// Ball-centring cell.
    BallCentring(BallCentringCell),
    /// 3-PF cell.
    Pcr(PcrCellLink),
    /// Motion-capture cell.
    Mocap(MocapCellLink),
}

fn backoff() -> Backoff {
    Backoff {
        initial: Duration::from_millis(50),
        max: Duration::from_millis(500),
        ..Backoff::default()
    }
}

fn ball_centring(d: BallCentringCell) -> TricalCell {
    let chain_limits = d.model.to_chain().map(|c| {
        c.actuated()
            .iter()
            .map(|&j| {
                c.joints[j]
                    .limits
                    .unwrap_or([-std::f64::consts::PI, std::f64::consts::PI])
            })
            .collect::<Vec<_>>()
    });
    let rws = RwsHandle::connect(
        TcpConnector::new(d.rws.address.clone()),
        RwsConfig {
            host: d.rws.address.clone(),
            user: d.rws.user.clone(),
            password: d.rws.password.clone(),
            timeout: Duration::from_secs(2),
            move_timeout: Duration::from_secs(20),
            poll: Duration::from_millis(5),
            max_joint_step_deg: d.max_joint_step_deg,
            backoff: backoff(),
            ..RwsConfig::default()
        },
    );
    let uwave = UwaveHandle::connect(
        SerialConnector {
            path: d.uwave.path.clone(),
            baud: d.uwave.baud,
            recorder: None,
        },
        UwaveConfig {
            timeout: Duration::from_millis(500),
            axes: d.uwave.axes,
            backoff: backoff(),
            ..UwaveConfig::default()
        },
    );
    let envelope = Envelope {
        limits: chain_limits.unwrap_or_default(),
        max_joint_step: d.max_joint_step_deg.to_radians(),
        max_tool_step_mm: d.max_tool_step_mm,
    };
    let (rws_name, uwave_name) = (format!("{}.rws", d.name), format!("{}.uwave", d.name));
    TricalCell {
        robot: Arc::new(MotionLimiter::new(
            RwsRobot::new(rws, rws_name.clone()),
            envelope.clone(),
        )),
        indicators: Arc::new(UwaveIndicators::new(uwave, uwave_name.clone())),
        model: Mutex::new(d.model),
        ballbar: d.ballbar,
        envelope,
        devices: vec![rws_name, uwave_name],
        name: d.name,
    }
}

fn pcr(d: PcrCellLink) -> PcrCell {
    let mcs2 = Mcs2Handle::connect(
        TcpConnector::new(d.mcs2.clone()),
        StageConfig {
            timeout: Duration::from_secs(1),
            move_timeout: Duration::from_secs(10),
            poll: Duration::from_millis(2),
            backoff: backoff(),
        },
    );
    let scope = MicroscopeHandle::connect(
        TcpConnector::new(d.microscope.clone()),
        MicroscopeConfig {
            timeout: Duration::from_secs(1),
            backoff: backoff(),
        },
    );
    let (st, mi) = (format!("{}.mcs2", d.name), format!("{}.microscope", d.name));
    PcrCell {
        stages: Arc::new(SmaractStages::new(Arc::new(mcs2), d.channels, st.clone())),
        microscope: Arc::new(Microscope::new(scope, mi.clone())),
        model: Mutex::new(d.model),
        devices: vec![st, mi],
        name: d.name,
    }
}

fn mocap(d: MocapCellLink) -> MocapCell {
    let qtm = QtmHandle::connect(
        TcpConnector::new(d.qtm.clone()),
        QtmConfig {
            timeout: Duration::from_secs(2),
            backoff: backoff(),
            ..QtmConfig::default()
        },
    );
    let joints = JointsHandle::connect(
        TcpConnector::new(d.joints.clone()),
        JointsConfig {
            timeout: Duration::from_secs(2),
            backoff: backoff(),
            ..JointsConfig::default()
        },
    );
    let (j, q) = (format!("{}.joints", d.name), format!("{}.qtm", d.name));
    MocapCell {
        robot: Arc::new(JointInterface::new(
            joints,
            d.joint_names.clone(),
            d.joints_speed_rad_s,
            j.clone(),
        )),
        stream: Arc::new(QtmStream::new(qtm, q.clone())),
        urdf: Mutex::new(d.urdf),
        root_link: d.root_link,
        joints: d.joint_names,
        limits: d.limits,
        markers: d.markers,
        devices: vec![j, q],
        name: d.name,
    }
}

impl Lab {
    /// Connect to every device of `cells` (driver actors on the current tokio runtime;
    /// they connect and reconnect in the background, so an absent device is reported by
    /// the first request, never here).
    pub fn connect(cells: Vec<CellLink>) -> Result<Lab, super::LabError> {
        let mut lab = Lab::empty();
        for c in cells {
            let cell = match c {
                CellLink::BallCentring(d) => Cell::BallCentring(ball_centring(d)),
                CellLink::Pcr(d) => Cell::Pcr(pcr(d)),
                CellLink::Mocap(d) => Cell::Mocap(mocap(d)),
            };
            lab.insert(cell)?;
        }
        Ok(lab)
    }
}
