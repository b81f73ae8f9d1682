//! The simulated TriCal cell: an IRB 120 twin ([`SimulatedCell`]) behind an RWS mock's arm
//! on a loopback port and a U-WAVE mock's indicators on a pseudo-terminal, described as a
//! [`BallCentringCell`] like a real cell.

use std::sync::{Arc, Mutex};

use calibd_drivers::mock::{self, Faults, MockArgs, MockDevice, RunningMock};
use calibd_drivers::rws::mock::ArmModel;
use calibd_drivers::uwave::AxisMap;
use calibd_drivers::uwave::mock::IndicatorModel;

use super::bench::{Bench, BenchHandle};
use super::with;
use crate::lab::{BallCentringCell, CellLink, LabError, RwsLink, UwaveLink};
use crate::twin::SerialTwin;
use crate::twin::cell::{INDICATOR_HALF_RANGE_MM, SimulatedCell};

/// Reading of an indicator at the tool-axis zero (mid-travel of the 12.7 mm ID-C112XB).
pub const INDICATOR_ZERO_MM: f64 = INDICATOR_HALF_RANGE_MM;

/// Settings of the simulated TriCal cell.
#[derive(Debug, Clone)]
pub struct SimTricalOptions {
    /// Joint speed of the simulated arm (deg/s).
    pub arm_speed_deg_s: f64,
    /// Indicator streaming rate (readings per second and channel).
    pub indicator_rate_hz: f64,
    /// Largest joint change of one move (deg), in the driver and the envelope.
    pub max_joint_step_deg: f64,
    /// Faults planned on the RWS mock's replies.
    pub rws_faults: Vec<calibd_drivers::mock::FaultSpec>,
    /// While set, the indicators stop sending (a stalled receiver).
    pub indicator_stall: Arc<std::sync::atomic::AtomicBool>,
    /// Data-request template the receiver answers (empty: readings only stream).
    pub uwave_request: String,
    /// Filled with the cell's twin when it starts: tests change the true robot through it
    /// (parameters drifting between nights).
    pub twin: TwinHandle,
    /// Filled with the centring device's bench (coupling, set buttons) when it starts.
    pub hands: HandsHandle,
}

/// Where the simulated TriCal cell's operator hands are published once started.
pub type HandsHandle = Arc<std::sync::OnceLock<Hands>>;

/// The operator's hands on a simulated TriCal cell's device: mate it on its coupling, take
/// it off, press the indicators' set buttons (see [`super::bench`]).
#[derive(Clone)]
pub struct Hands {
    cell: Shared,
    bench: BenchHandle,
    axes: [AxisMap; 3],
}

impl std::fmt::Debug for Hands {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Hands")
            .field("axes", &self.axes)
            .finish_non_exhaustive()
    }
}

impl Hands {
    /// Mate the device on its coupling platform.
    pub fn mate(&self) {
        lock(&self.bench).mate();
    }

    /// Put the device back on the robot's flange.
    pub fn unmate(&self) {
        lock(&self.bench).unmate();
    }

    /// Press every indicator's set button where the plungers stand now; what they show
    /// after (mm).
    pub fn set(&self) -> [f64; 3] {
        let p = plungers(&self.cell, &self.bench, &self.axes);
        let mut b = lock(&self.bench);
        b.set(p);
        std::array::from_fn(|k| b.display_mm(k, p[k], self.axes[k].zero_mm))
    }
}

fn lock(b: &BenchHandle) -> std::sync::MutexGuard<'_, Bench> {
    b.lock().unwrap_or_else(|p| p.into_inner())
}

/// Each indicator's plunger position from mid-travel (mm): on the coupling's master ball
/// when mated, else on the twin's nearest ball, saturated at the ends of travel; a free
/// plunger (no ball) is fully extended, at the bottom of its range whichever way the axis
/// is mapped.
fn plungers(cell: &Shared, bench: &BenchHandle, axes: &[AxisMap; 3]) -> [f64; 3] {
    let h = INDICATOR_HALF_RANGE_MM;
    let mated = lock(bench).mated();
    let v = match mated {
        Some(m) => Some(m),
        None => with(cell, |c| c.indicator_values()),
    };
    std::array::from_fn(|k| match v {
        Some(v) => (axes[k].sign * v[k]).clamp(-h, h),
        None => -h,
    })
}

/// Where the simulated TriCal cell's twin is published once started.
pub type TwinHandle = Arc<std::sync::OnceLock<Arc<Mutex<SimulatedCell>>>>;

impl Default for SimTricalOptions {
    fn default() -> Self {
        Self {
            arm_speed_deg_s: 720.0,
            indicator_rate_hz: 200.0,
            max_joint_step_deg: 30.0,
            rws_faults: Vec::new(),
            indicator_stall: Arc::default(),
            uwave_request: String::new(),
            twin: TwinHandle::default(),
            hands: HandsHandle::default(),
        }
    }
}

type Shared = super::Shared<SimulatedCell>;

fn rad(q_deg: &[f64; 6]) -> Vec<f64> {
    q_deg.iter().map(|v| v.to_radians()).collect()
}

/// The twin's arm behind the RWS mock: the controller plans with the nominal model, the
/// physical arm (what the indicators see) follows the controller's joints.
struct TwinArm {
    cell: Shared,
    speed_deg_s: f64,
}

impl ArmModel for TwinArm {
    fn home_deg(&self) -> [f64; 6] {
        let q = with(&self.cell, |c| c.joints());
        std::array::from_fn(|i| q.get(i).map_or(0.0, |v| v.to_degrees()))
    }
    fn tool_pose(&self, q_deg: &[f64; 6]) -> ([f64; 3], [f64; 4]) {
        let f = with(&self.cell, |c| c.twin.nominal.tcp(&rad(q_deg), None));
        let q = nalgebra::UnitQuaternion::from_matrix(&f.r);
        ([f.p.x, f.p.y, f.p.z], [q.w, q.i, q.j, q.k])
    }
    fn rel_tool(&self, q_deg: &[f64; 6], dp_mm: [f64; 3]) -> Option<[f64; 6]> {
        let q = with(&self.cell, |c| c.tool_move_target(&rad(q_deg), dp_mm)).ok()?;
        Some(std::array::from_fn(|i| q[i].to_degrees()))
    }
    fn speed_deg_s(&self) -> f64 {
        self.speed_deg_s
    }
    fn moved(&mut self, q_deg: &[f64; 6]) {
        // The controller already refused targets outside its limits.
        let _ = with(&self.cell, |c| c.move_joints(&rad(q_deg)));
    }
}

/// The twin's indicators behind the U-WAVE mock: plungers at mid-travel when the TCP is on
/// the ball centre, saturated at the ends of travel, fully extended with no ball; on the
/// coupling when mated; each display relative to its last set (see [`super::bench`]).
struct TwinIndicators {
    cell: Shared,
    bench: BenchHandle,
    stall: Arc<std::sync::atomic::AtomicBool>,
    /// Tool axis k is read on `axes[k].channel` as `zero_mm + sign * error` (the inverse of
    /// the lab file's `axis_mm = sign * (reading_mm - zero_mm)`).
    axes: [AxisMap; 3],
}

impl IndicatorModel for TwinIndicators {
    fn channels(&self) -> Vec<u8> {
        self.axes.iter().map(|a| a.channel).collect()
    }
    fn read_mm(&mut self, channel: u8, _t_s: f64) -> Option<f64> {
        if self.stall.load(std::sync::atomic::Ordering::SeqCst) {
            return None;
        }
        let k = self.axes.iter().position(|a| a.channel == channel)?;
        let p = plungers(&self.cell, &self.bench, &self.axes)[k];
        Some(lock(&self.bench).display_mm(k, p, self.axes[k].zero_mm))
    }
}

fn mock_err(device: &str, e: impl std::fmt::Display) -> LabError {
    LabError::Mock {
        device: device.into(),
        message: e.to_string(),
    }
}

/// Start the simulated TriCal cell: the twin (true parameters from `seed`), an RWS mock on
/// a loopback port and a U-WAVE mock on a pseudo-terminal; returns the cell's description.
pub(super) async fn start(
    seed: u64,
    o: &SimTricalOptions,
) -> Result<(CellLink, Vec<RunningMock>), LabError> {
    let rws_args = MockArgs::new(MockDevice::Abb);
    let at = Served {
        rws: "127.0.0.1:0".into(),
        uwave: None,
        user: rws_args.user,
        password: rws_args.password,
    };
    let (link, mocks) = start_at(seed, o, &at).await?;
    Ok((CellLink::BallCentring(link), mocks))
}

/// Where the simulated TriCal cell's devices are served.
#[derive(Debug, Clone)]
pub struct Served {
    /// RWS listen address (`127.0.0.1:0` picks a port).
    pub rws: String,
    /// A path to link to the U-WAVE receiver's pseudo-terminal (`None`: the pty's own).
    pub uwave: Option<std::path::PathBuf>,
    /// RWS user the controller accepts.
    pub user: String,
    /// RWS password the controller accepts.
    pub password: String,
}

/// The IRB 120 twin's cell (nominal model and ballbar) for `seed`, as the simulated lab
/// (`lab = "sim"`) serves it.
pub fn twin_cell(seed: u64) -> (crate::model::dh::DhFile, [f64; 3]) {
    let twin = SerialTwin::irb120(seed);
    (twin.file, twin.ballbar)
}

/// Start the simulated TriCal cell's devices at `at`.
pub async fn start_at(
    seed: u64,
    o: &SimTricalOptions,
    at: &Served,
) -> Result<(BallCentringCell, Vec<RunningMock>), LabError> {
    let axis = |c| AxisMap {
        channel: c,
        sign: 1.0,
        zero_mm: INDICATOR_ZERO_MM,
    };
    start_twin_at(
        SerialTwin::irb120(seed),
        seed,
        o,
        at,
        [axis(0), axis(1), axis(2)],
    )
    .await
}

/// Start the devices of a TriCal cell around `twin` at `at`; the indicators report the
/// twin's tool-axis errors through `axes` (channel, sign and zero as a lab file maps them).
pub async fn start_twin_at(
    twin: SerialTwin,
    seed: u64,
    o: &SimTricalOptions,
    at: &Served,
    axes: [AxisMap; 3],
) -> Result<(BallCentringCell, Vec<RunningMock>), LabError> {
    let file = twin.file.clone();
    let ballbar = twin.ballbar;
    let cell: Shared = Arc::new(Mutex::new(SimulatedCell::new(twin, seed ^ 0x5eed)));
    // A second start with the same options keeps the first twin published.
    let _ = o.twin.set(cell.clone());
    let mut rws_args = MockArgs::new(MockDevice::Abb);
    rws_args.user = at.user.clone();
    rws_args.password = at.password.clone();
    let arm = TwinArm {
        cell: cell.clone(),
        speed_deg_s: o.arm_speed_deg_s,
    };
    let rws_mock = mock::start_with(
        &at.rws,
        calibd_drivers::rws::mock::handler_with(
            Box::new(arm),
            &rws_args,
            Faults::new(o.rws_faults.clone()),
        ),
    )
    .await
    .map_err(|e| mock_err("rws", e))?;
    let mut uw_args = MockArgs::new(MockDevice::Uwave);
    uw_args.rate_hz = o.indicator_rate_hz;
    uw_args.uwave_request = o.uwave_request.clone();
    let bench: BenchHandle = Arc::new(Mutex::new(Bench::new(seed)));
    let _ = o.hands.set(Hands {
        cell: cell.clone(),
        bench: bench.clone(),
        axes: axes.clone(),
    });
    let ind: Arc<Mutex<dyn IndicatorModel>> = Arc::new(Mutex::new(TwinIndicators {
        cell,
        bench,
        stall: o.indicator_stall.clone(),
        axes: axes.clone(),
    }));
    let uw_mock = mock::start_pty_at(
        calibd_drivers::uwave::mock::handler_with(ind, &uw_args, Faults::default()),
        at.uwave.clone(),
    )
    .map_err(|e| mock_err("uwave", e))?;
    let link = BallCentringCell {
        resume: Default::default(),
        record: None,
        name: "irb120".into(),
        rws: RwsLink {
            address: rws_mock.addr.clone(),
            user: rws_args.user.clone(),
            password: rws_args.password.clone(),
            module: "CalibServer".into(),
        },
        uwave: UwaveLink {
            path: uw_mock.addr.clone(),
            baud: 57_600,
            axes,
            request_template: o.uwave_request.clone(),
        },
        ballbar,
        model: file,
        max_joint_step_deg: o.max_joint_step_deg,
        max_tool_step_mm: 6.5,
        joint_limits_deg: None,
        workspace_mm: None,
        joint_speed_deg_s: o.arm_speed_deg_s,
    };
    Ok((link, vec![rws_mock, uw_mock]))
}
