//! A lab from its description: for each cell the addresses of its devices and what the
//! campaigns need to know about it; [`Lab::connect`] starts one driver actor per device and
//! wraps it in its adapter. The simulated lab (`crate::sim`) produces the same description
//! with loopback addresses; a lab's configuration file will produce it for real devices.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use calibd_drivers::camera::{CameraConfig, CameraHandle, FolderCamera, FrameSource};
use calibd_drivers::can::{Cia402Config, Cia402Handle, SocketCanConnector, SocketcandConnector};
use calibd_drivers::joints::{JointsConfig, JointsHandle};
use calibd_drivers::microscope::{MicroscopeConfig, MicroscopeHandle};
use calibd_drivers::qtm::{QtmConfig, QtmHandle};
use calibd_drivers::rws::{RwsConfig, RwsHandle};
use calibd_drivers::smaract::{Mcs2Handle, McsHandle};
use calibd_drivers::uwave::{AxisMap, SerialConnector, UwaveConfig, UwaveHandle};
use calibd_drivers::{Backoff, Recorder, Stage, StageConfig, TcpConnector};

use super::adapters::{
    CameraMicroscope, JointInterface, Microscope, PerJoint, QtmStream, RwsModules, RwsRobot,
    SmaractStages, StageEnvelope, UwaveIndicators,
};
use super::devices::{DeviceLink, ProbeFuture};
use super::probes::{self, probe};
use super::{Cell, Lab, LabError, MocapCell, PcrCell, TricalCell};
use crate::model::dh::DhFile;
use crate::model::humanoid::MarkerDef;
use crate::model::pcr::PcrFile;
use crate::procedures::{Envelope, JointRobot, MotionLimiter, PoseSensor, Workspace};

/// An IRC5 controller reached over Robot Web Services.
#[derive(Debug, Clone)]
pub struct RwsLink {
    /// `host:port`.
    pub address: String,
    /// RWS user.
    pub user: String,
    /// RWS password (from a file or the environment; never logged).
    pub password: String,
    /// The RAPID module serving calibd's moves (`calib_q`, `calib_cmd`, ...).
    pub module: String,
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
    /// Data-request template (`{cc}` channel, `{gg}` group); empty waits for the
    /// indicators' own readings.
    pub request_template: String,
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
    /// Joint limits (deg) narrowing the model's, if configured.
    pub joint_limits_deg: Option<Vec<[f64; 2]>>,
    /// Box the TCP must stay in (mm, robot base frame: min, max), if configured.
    pub workspace_mm: Option<[[f64; 3]; 2]>,
    /// Joint speed of the controller's moves (deg/s), for a plan's estimated duration.
    pub joint_speed_deg_s: f64,
    /// Who resumes a campaign paused on a device fault.
    pub resume: super::resume::ResumePolicy,
    /// Folder this cell's device traffic is recorded to (lab file `record`), if any.
    pub record: Option<PathBuf>,
}

/// How the 3-PF cell's stage controller is reached.
#[derive(Debug, Clone, PartialEq)]
pub enum StageBackend {
    /// SmarAct MCS2 (SCPI over TCP, pm) at `host:port`.
    Mcs2(String),
    /// SmarAct MCS (ASCII, nm) at `host:port`.
    Mcs(String),
    /// CiA 402 drives through a socketcand server.
    Socketcand {
        /// `host:port` of socketcand.
        address: String,
        /// Bus name on the server.
        bus: String,
    },
    /// CiA 402 drives on a native SocketCAN interface (`can0`).
    SocketCan(String),
}

impl StageBackend {
    /// What the controller is, for operators.
    pub fn kind(&self) -> &'static str {
        match self {
            StageBackend::Mcs2(_) => "SmarAct MCS2",
            StageBackend::Mcs(_) => "SmarAct MCS",
            StageBackend::Socketcand { .. } => "CiA 402 drives (socketcand)",
            StageBackend::SocketCan(_) => "CiA 402 drives (SocketCAN)",
        }
    }

    /// The address shown to operators.
    pub fn address(&self) -> String {
        match self {
            StageBackend::Mcs2(a) | StageBackend::Mcs(a) => a.clone(),
            StageBackend::Socketcand { address, bus } => format!("{address} ({bus})"),
            StageBackend::SocketCan(iface) => iface.clone(),
        }
    }
}

/// The stages of a 3-PF cell.
#[derive(Debug, Clone, PartialEq)]
pub struct StagesLink {
    /// The controller.
    pub backend: StageBackend,
    /// Channels (MCS) or CANopen node ids (CiA 402) of the joints q1, q2, q3.
    pub channels: [u8; 3],
    /// Picometres per position count (CiA 402 drives).
    pub pm_per_count: i64,
}

/// Where a camera's frames come from.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameSourceLink {
    /// A `calibd-frames/1` server at `host:port` (a camera bridge, or the mock camera).
    Network(String),
    /// Numbered image files written into a folder.
    Folder(PathBuf),
}

impl FrameSourceLink {
    /// The address shown to operators.
    pub fn address(&self) -> String {
        match self {
            FrameSourceLink::Network(a) => a.clone(),
            FrameSourceLink::Folder(p) => p.display().to_string(),
        }
    }
}

/// A microscope camera whose frames calibd measures (`[cell.camera]`).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraLink {
    /// Where the frames come from.
    pub source: FrameSourceLink,
    /// Exposure time (us).
    pub exposure_us: f64,
    /// Frame rate (Hz).
    pub frame_rate_hz: f64,
    /// The pattern and the pixel size.
    pub pattern: crate::measure::pattern::PatternSetup,
}

/// How a 3-PF cell reads its platform's pose.
#[derive(Debug, Clone, PartialEq)]
pub enum PoseSourceLink {
    /// A `calibd-pose/1` server at `host:port` (a vision PC computing the pose).
    Server(String),
    /// A camera: calibd computes the pose from its frames.
    Camera(CameraLink),
}

impl PoseSourceLink {
    /// The address shown to operators.
    pub fn address(&self) -> String {
        match self {
            PoseSourceLink::Server(a) => a.clone(),
            PoseSourceLink::Camera(c) => c.source.address(),
        }
    }
}

/// A 3-PF cell.
#[derive(Debug, Clone)]
pub struct PcrCellLink {
    /// Cell name.
    pub name: String,
    /// The stages.
    pub stages: StagesLink,
    /// The microscope: a pose server or a camera.
    pub microscope: PoseSourceLink,
    /// Largest stage move of one command (m).
    pub max_stage_step_m: f64,
    /// Nominal model (its joint box is the stages' envelope).
    pub model: PcrFile,
    /// Who resumes a campaign paused on a device fault.
    pub resume: super::resume::ResumePolicy,
    /// Folder this cell's device traffic is recorded to (lab file `record`), if any.
    pub record: Option<PathBuf>,
}

/// A humanoid's joint interface (`calibd-joints/1` over TCP).
#[derive(Debug, Clone, PartialEq)]
pub struct JointsLink {
    /// `host:port` of the interface (the robot's bridge).
    pub address: String,
    /// Joint speed the move durations are planned with (rad/s).
    pub speed_rad_s: f64,
    /// Largest change of any joint in one move (rad).
    pub max_step_rad: f64,
}

/// A motion-capture cell.
#[derive(Debug, Clone)]
pub struct MocapCellLink {
    /// Cell name.
    pub name: String,
    /// The robot's joint interface.
    pub joints: JointsLink,
    /// QTM RT server `host:port`.
    pub qtm: String,
    /// QTM label -> model marker name (labels not listed keep their name).
    pub labels: std::collections::BTreeMap<String, String>,
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
    /// Who resumes a campaign paused on a device fault.
    pub resume: super::resume::ResumePolicy,
    /// Folder this cell's device traffic is recorded to (lab file `record`), if any.
    pub record: Option<PathBuf>,
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

impl CellLink {
    /// The cell's recording folder (lab file `record`), to read or move into a session.
    pub fn record_mut(&mut self) -> &mut Option<PathBuf> {
        match self {
            CellLink::BallCentring(d) => &mut d.record,
            CellLink::Pcr(d) => &mut d.record,
            CellLink::Mocap(d) => &mut d.record,
        }
    }
}

fn backoff() -> Backoff {
    Backoff {
        initial: Duration::from_millis(50),
        max: Duration::from_millis(500),
        ..Backoff::default()
    }
}

fn ball_centring(d: BallCentringCell, rec: &Rec) -> Result<TricalCell, LabError> {
    let chain = d.model.to_chain().map_err(|e| LabError::Cell {
        cell: d.name.clone(),
        message: format!("model: {e}"),
    })?;
    let mut limits = chain.variable_limits();
    if let Some(l) = &d.joint_limits_deg {
        // The configured envelope narrows the model's limits, never widens them.
        for (m, c) in limits.iter_mut().zip(l) {
            *m = [m[0].max(c[0].to_radians()), m[1].min(c[1].to_radians())];
        }
    }
    let mut rws_limits = RwsConfig::default().limits_deg;
    if limits.len() != rws_limits.len() {
        return Err(LabError::Cell {
            cell: d.name,
            message: format!(
                "the model has {} joints; an IRC5 arm over RWS has 6",
                limits.len()
            ),
        });
    }
    for (r, l) in rws_limits.iter_mut().zip(&limits) {
        *r = (l[0].to_degrees(), l[1].to_degrees());
    }
    let rws = RwsHandle::connect(
        rec.tcp(&d.rws.address, &d.name, "abb")?,
        RwsConfig {
            host: d.rws.address.clone(),
            user: d.rws.user.clone(),
            password: d.rws.password.clone(),
            timeout: Duration::from_secs(2),
            move_timeout: Duration::from_secs(20),
            poll: Duration::from_millis(5),
            limits_deg: rws_limits,
            max_joint_step_deg: d.max_joint_step_deg,
            max_tool_step_mm: d.max_tool_step_mm,
            backoff: backoff(),
        },
    );
    let uwave = UwaveHandle::connect(
        SerialConnector {
            path: d.uwave.path.clone(),
            baud: d.uwave.baud,
            recorder: rec.recorder(&d.name, "uwave")?,
        },
        UwaveConfig {
            timeout: Duration::from_millis(500),
            axes: d.uwave.axes,
            request_template: d.uwave.request_template.clone(),
            backoff: backoff(),
            ..UwaveConfig::default()
        },
    );
    let envelope = Envelope {
        limits,
        max_joint_step: d.max_joint_step_deg.to_radians(),
        max_tool_step_mm: d.max_tool_step_mm,
        workspace_mm: d.workspace_mm.map(|b| Workspace {
            min_mm: b[0],
            max_mm: b[1],
            chain: Arc::new(chain),
        }),
    };
    let (rws_name, uwave_name) = (format!("{}.rws", d.name), format!("{}.uwave", d.name));
    // Errors name the device and where it is reached.
    let (rws_at, uwave_at) = (
        format!("{rws_name} at {}", d.rws.address),
        format!("{uwave_name} at {}", d.uwave.path),
    );
    let module = d.rws.module.clone();
    let channels = d.uwave.axes.map(|a| a.channel);
    let links = vec![
        DeviceLink::new(
            rws_name,
            "ABB IRC5 (RWS 1.0)",
            d.rws.address,
            probe(rws.clone(), move |h| probes::rws(h, module.clone())),
        ),
        absent_port(DeviceLink::new(
            uwave_name,
            "Mitutoyo U-WAVE-R",
            d.uwave.path,
            probe(uwave.clone(), move |h| probes::uwave(h, channels)),
        )),
    ];
    Ok(TricalCell {
        modules: Arc::new(RwsModules::new(rws.clone(), rws_at.clone())),
        robot: Arc::new(MotionLimiter::new(
            RwsRobot::new(rws, rws_at),
            envelope.clone(),
        )),
        indicators: Arc::new(UwaveIndicators::new(uwave, uwave_at)),
        nominal: d.model.clone(),
        model: Mutex::new(d.model),
        ballbar: d.ballbar,
        joint_speed_deg_s: d.joint_speed_deg_s,
        envelope,
        links,
        name: d.name,
    })
}

/// A serial device whose port does not exist is failed from the start (an unplugged
/// receiver): its cell is unavailable until a probe finds it, the other cells serve.
fn absent_port(link: DeviceLink) -> DeviceLink {
    if Path::new(&link.address).exists() {
        link
    } else {
        let error = format!("serial port {}: no such file or directory", link.address);
        link.failed_from_start(error)
    }
}

/// Where the lab's traffic is recorded, if anywhere.
struct Rec(Option<PathBuf>);

impl Rec {
    /// A recorder for `cell`'s `device`, if recording.
    fn recorder(&self, cell: &str, device: &str) -> Result<Option<Recorder>, LabError> {
        let Some(dir) = &self.0 else {
            return Ok(None);
        };
        let path = dir.join(format!("{cell}.{device}.jsonl"));
        std::fs::create_dir_all(dir).map_err(|e| LabError::Cell {
            cell: cell.into(),
            message: format!("recording: cannot create the folder {}: {e}", dir.display()),
        })?;
        Recorder::create(
            &path,
            device,
            &format!("cell {cell}, recorded by calibd's lab"),
        )
        .map(Some)
        .map_err(|e| LabError::Cell {
            cell: cell.into(),
            message: format!("recording to {}: {e}", path.display()),
        })
    }

    /// A TCP connector to `addr`, recording if asked.
    fn tcp(&self, addr: &str, cell: &str, device: &str) -> Result<TcpConnector, LabError> {
        Ok(TcpConnector {
            addr: addr.to_string(),
            recorder: self.recorder(cell, device)?,
        })
    }
}

/// A probe as the lab keeps it.
type Probe = Box<dyn Fn() -> ProbeFuture + Send + Sync>;

/// The stage controller of a 3-PF cell, the channels of q1..q3 on it, and its probe.
fn stages(
    s: &StagesLink,
    cell: &str,
    rec: &Rec,
) -> Result<(Arc<dyn Stage>, [u8; 3], Probe), LabError> {
    let cfg = StageConfig {
        timeout: Duration::from_secs(1),
        move_timeout: Duration::from_secs(10),
        poll: Duration::from_millis(2),
        backoff: backoff(),
    };
    let drive = |node: u8| Cia402Config {
        node,
        pm_per_count: s.pm_per_count,
        backoff: backoff(),
        ..Cia402Config::default()
    };
    let ch = s.channels;
    let drives = |one: &dyn Fn(u8) -> Cia402Handle| -> (Arc<dyn Stage>, [u8; 3], Probe) {
        let d = Arc::new(ch.map(one));
        let per: [Arc<dyn Stage>; 3] = [
            Arc::new(d[0].clone()),
            Arc::new(d[1].clone()),
            Arc::new(d[2].clone()),
        ];
        (
            Arc::new(PerJoint(per)),
            [0, 1, 2],
            Box::new(probe(d, probes::cia402)),
        )
    };
    match &s.backend {
        StageBackend::Mcs2(a) => {
            let h = Arc::new(Mcs2Handle::connect(rec.tcp(a, cell, "mcs2")?, cfg));
            let p = probe(h.clone(), move |h| probes::mcs2(h, ch));
            Ok((h, ch, Box::new(p)))
        }
        StageBackend::Mcs(a) => {
            let h = Arc::new(McsHandle::connect(rec.tcp(a, cell, "mcs")?, cfg));
            let p = probe(h.clone(), move |h| probes::mcs(h, ch));
            Ok((h, ch, Box::new(p)))
        }
        StageBackend::Socketcand { address, bus } => Ok(drives(&|node| {
            Cia402Handle::connect(
                SocketcandConnector {
                    addr: address.clone(),
                    bus: bus.clone(),
                    recorder: None,
                },
                drive(node),
            )
        })),
        StageBackend::SocketCan(iface) => Ok(drives(&|node| {
            Cia402Handle::connect(
                SocketCanConnector {
                    iface: iface.clone(),
                },
                drive(node),
            )
        })),
    }
}

fn pcr(d: PcrCellLink, rec: &Rec) -> Result<PcrCell, LabError> {
    let (stage, channels, stage_probe) = stages(&d.stages, &d.name, rec)?;
    let (st, mi) = (
        format!("{}.stages", d.name),
        format!("{}.microscope", d.name),
    );
    let st_at = format!("{st} at {}", d.stages.backend.address());
    let mi_at = format!("{mi} at {}", d.microscope.address());
    let (microscope, mi_link) = pose_source(&d, &mi, mi_at, rec)?;
    let envelope = StageEnvelope {
        limits_m: d.model.limits(),
        max_step_m: d.max_stage_step_m,
    };
    let links = vec![
        DeviceLink::new(
            st,
            d.stages.backend.kind(),
            d.stages.backend.address(),
            stage_probe,
        ),
        mi_link,
    ];
    Ok(PcrCell {
        stages: Arc::new(SmaractStages::new(stage, channels, st_at).within(envelope)),
        microscope,
        model: Mutex::new(d.model),
        links,
        name: d.name,
    })
}

/// The microscope of a 3-PF cell as a pose sensor, and its device link named `mi`.
fn pose_source(
    d: &PcrCellLink,
    mi: &str,
    mi_at: String,
    rec: &Rec,
) -> Result<(Arc<dyn PoseSensor>, DeviceLink), LabError> {
    let cam = match &d.microscope {
        PoseSourceLink::Server(addr) => {
            let scope = MicroscopeHandle::connect(
                rec.tcp(addr, &d.name, "microscope")?,
                MicroscopeConfig {
                    timeout: Duration::from_secs(1),
                    backoff: backoff(),
                },
            );
            let link = DeviceLink::new(
                mi,
                "microscope (calibd-pose/1)",
                addr.clone(),
                probe(scope.clone(), probes::microscope),
            );
            return Ok((Arc::new(Microscope::new(scope, mi_at)), link));
        }
        PoseSourceLink::Camera(c) => c,
    };
    // A frame's transfer, a slow bridge and the slowest frame period all fit in it.
    let timeout = Duration::from_secs(10) + Duration::from_secs_f64(2.0 / cam.frame_rate_hz);
    let (source, link): (Arc<dyn FrameSource>, DeviceLink) = match &cam.source {
        FrameSourceLink::Network(addr) => {
            let h = CameraHandle::connect(
                rec.tcp(addr, &d.name, "camera")?,
                CameraConfig {
                    timeout,
                    backoff: backoff(),
                    exposure_us: cam.exposure_us,
                    frame_rate_hz: cam.frame_rate_hz,
                },
            );
            let link = DeviceLink::new(
                mi,
                "microscope camera (calibd-frames/1)",
                addr.clone(),
                probe(h.clone(), probes::camera),
            );
            (Arc::new(h), link)
        }
        FrameSourceLink::Folder(dir) => {
            let f = Arc::new(FolderCamera::new(dir.clone(), cam.frame_rate_hz, timeout));
            let link = DeviceLink::new(
                mi,
                "microscope camera (frame folder)",
                dir.display().to_string(),
                probe(f.clone(), probes::camera_folder),
            );
            (f, link)
        }
    };
    let sensor = CameraMicroscope::new(source, cam.pattern, mi_at).map_err(|e| LabError::Cell {
        cell: d.name.clone(),
        message: format!("camera: {e}"),
    })?;
    Ok((Arc::new(sensor), link))
}

fn mocap(d: MocapCellLink, rec: &Rec) -> Result<MocapCell, LabError> {
    let qtm = QtmHandle::connect(
        rec.tcp(&d.qtm, &d.name, "qtm")?,
        QtmConfig {
            timeout: Duration::from_secs(2),
            backoff: backoff(),
            ..QtmConfig::default()
        },
    );
    let joints = JointsHandle::connect(
        rec.tcp(&d.joints.address, &d.name, "joints")?,
        JointsConfig {
            timeout: Duration::from_secs(2),
            backoff: backoff(),
            ..JointsConfig::default()
        },
    );
    let (j, q) = (format!("{}.joints", d.name), format!("{}.qtm", d.name));
    let (j_at, q_at) = (
        format!("{j} at {}", d.joints.address),
        format!("{q} at {}", d.qtm),
    );
    let (joints_probe, names) = (
        joints.clone(),
        Arc::new((d.joint_names.clone(), d.limits.clone())),
    );
    let cell_markers = Arc::new(probes::CellMarkers {
        labels: d.labels.clone(),
        markers: d.markers.iter().map(|m| m.name.clone()).collect(),
    });
    let robot: Arc<dyn JointRobot> = Arc::new(
        JointInterface::new(joints, d.joint_names.clone(), d.joints.speed_rad_s, j_at)
            .within(d.limits.clone(), d.joints.max_step_rad),
    );
    let links = vec![
        DeviceLink::new(
            j,
            "joint interface (calibd-joints/1)",
            d.joints.address,
            probe(joints_probe, move |h| probes::joints(h, names.clone())),
        ),
        DeviceLink::new(
            q,
            "Qualisys QTM (RT 1.25)",
            d.qtm,
            probe(qtm.clone(), move |h| probes::qtm(h, cell_markers.clone())),
        ),
    ];
    Ok(MocapCell {
        robot,
        stream: Arc::new(QtmStream::new(qtm, q_at).with_labels(d.labels)),
        urdf: Mutex::new(d.urdf),
        root_link: d.root_link,
        joints: d.joint_names,
        limits: d.limits,
        max_step_rad: d.joints.max_step_rad,
        speed_rad_s: d.joints.speed_rad_s,
        markers: d.markers,
        links,
        name: d.name,
    })
}

impl Lab {
    /// Connect to every device of `cells` (driver actors on the current tokio runtime;
    /// they connect and reconnect in the background, so an absent device is reported by
    /// the first request or probe, never here; a serial port that does not exist fails its
    /// device from the start).
    pub fn connect(cells: Vec<CellLink>) -> Result<Lab, super::LabError> {
        Lab::connect_recording(cells, None)
    }

    /// [`Lab::connect`], teeing every device's traffic to `<dir>/<cell>.<device>.jsonl`
    /// (`calibd-transcript/1`; a cell's own `record` folder before `dir`): a session becomes
    /// replayable fixtures.
    pub fn connect_recording(
        cells: Vec<CellLink>,
        dir: Option<&Path>,
    ) -> Result<Lab, super::LabError> {
        let mut lab = Lab::empty();
        for c in cells {
            let (name, policy, record) = match &c {
                CellLink::BallCentring(d) => (d.name.clone(), d.resume, d.record.clone()),
                CellLink::Pcr(d) => (d.name.clone(), d.resume, d.record.clone()),
                CellLink::Mocap(d) => (d.name.clone(), d.resume, d.record.clone()),
            };
            lab.set_resume_policy(&name, policy);
            // The cell's own folder (lab file `record`) before the lab-wide one.
            let rec = &Rec(record.or_else(|| dir.map(Path::to_path_buf)));
            let cell = match c {
                CellLink::BallCentring(d) => Cell::BallCentring(ball_centring(d, rec)?),
                CellLink::Pcr(d) => Cell::Pcr(pcr(d, rec)?),
                CellLink::Mocap(d) => Cell::Mocap(mocap(d, rec)?),
            };
            lab.insert(cell)?;
        }
        Ok(lab)
    }
}
