//! `calibd mock <device>`: the registry of mock device servers, and the one place in the
//! crate that names every mock device. Each device's mock lives with its driver
//! (`<device>::mock`) and imports only the shared plumbing in [`crate::mock_kit`]; this file
//! imports those mocks, so there is no import circle. To add a device: a [`MockDevice`]
//! variant, its name, its arm in [`start`] (and an options conversion if it takes any).
//!
//! Each mock speaks the real protocol, in replay mode (serve a transcript) or simulate mode
//! (backed by a device model), with fault injection. [`MockArgs`] is the clap argument
//! struct the binary embeds; [`start`] binds and returns the address (tests), [`run`] also
//! prints the ready line and waits. The plumbing is re-exported here so that
//! `calibd_drivers::mock::{start_with, Faults, RunningMock, ...}` keep working.

use std::future::Future;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

pub use crate::mock_kit::{
    BoxIo, Conn, DELAY_FAULT, FaultKind, FaultSpec, Faults, Handler, MockError, MockTasks,
    RunningMock, fault, serve, start_pty_at, start_pty_with, start_with,
};

use crate::mock_kit::replay;
use crate::transcript::Transcript;
use crate::{can, joints, microscope, qtm, rws, smaract, uwave};

/// Which device to mock.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MockDevice {
    /// Qualisys QTM RT protocol 1.25 (little-endian port, base+1).
    Qtm,
    /// ABB IRC5 Robot Web Services 1.0 with Digest auth (an IRB 120).
    Abb,
    /// Mitutoyo U-WAVE-R receiver with three indicators (pty, or TCP like a terminal server).
    Uwave,
    /// SmarAct MCS (ASCII, nm).
    Mcs,
    /// SmarAct MCS2 (SCPI over TCP, pm).
    Mcs2,
    /// socketcand hub with one CiA 402 drive, node id 1.
    Can,
    /// Microscope pose server (`calibd-pose/1` over TCP): a pattern drifting slowly near the
    /// origin, with seeded image noise.
    Microscope,
    /// Joint interface (`calibd-joints/1` over TCP): a four-joint arm whose joints move
    /// linearly over each move's duration.
    Joints,
}

impl MockDevice {
    /// Lower-case name as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            MockDevice::Qtm => "qtm",
            MockDevice::Abb => "abb",
            MockDevice::Uwave => "uwave",
            MockDevice::Mcs => "mcs",
            MockDevice::Mcs2 => "mcs2",
            MockDevice::Can => "can",
            MockDevice::Microscope => "microscope",
            MockDevice::Joints => "joints",
        }
    }
}

/// Arguments of `calibd mock`.
#[derive(Debug, Clone, clap::Args)]
pub struct MockArgs {
    /// Device to mock.
    #[arg(value_enum)]
    pub device: MockDevice,
    /// Address to listen on (`127.0.0.1:0` picks a free port); for `uwave` a path names a
    /// symlink to create for the pty slave.
    #[arg(long, default_value = "127.0.0.1:0")]
    pub listen: String,
    /// `uwave` only: serve on a fresh pseudo-terminal and print its path.
    #[arg(long)]
    pub pty: bool,
    /// Replay this transcript to every client instead of simulating.
    #[arg(long)]
    pub replay: Option<PathBuf>,
    /// With `--replay`: a client that sends other bytes than recorded ends the replay with
    /// an error naming the line and both versions (default: logged as a warning).
    #[arg(long, requires = "replay")]
    pub strict: bool,
    /// Inject a fault: KIND@N with KIND drop|stall|garbage|truncate|device-error|delay and N the
    /// reply number (1-based) it replaces. Repeatable.
    #[arg(long = "fault")]
    pub faults: Vec<FaultSpec>,
    /// Streaming rate of simulated data (QTM frames, U-WAVE readings), per second; for
    /// `uwave` 0 streams none (readings on request only).
    #[arg(long, default_value_t = 100.0)]
    pub rate_hz: f64,
    /// RWS user name accepted by the `abb` mock.
    #[arg(long, default_value = "Default User")]
    pub user: String,
    /// RWS password accepted by the `abb` mock.
    #[arg(long, default_value = "robotics")]
    pub password: String,
    /// `uwave` only: data-request template the mock answers with a reading (`{cc}`, `{gg}`
    /// placeholders). The real request is unverified; empty = readings only stream.
    #[arg(long, default_value = "")]
    pub uwave_request: String,
    /// `abb` only: RAPID program module listed as loaded in T_ROB1 (the calibd module;
    /// empty = none, to rehearse a controller where it is missing).
    #[arg(long, default_value = "CalibServer")]
    pub rapid_module: String,
    /// `microscope` only: seed of the simulated image noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

impl MockArgs {
    /// Defaults for `device` (simulate, loopback port 0, no faults).
    pub fn new(device: MockDevice) -> Self {
        MockArgs {
            device,
            listen: "127.0.0.1:0".into(),
            pty: false,
            replay: None,
            strict: false,
            faults: Vec::new(),
            rate_hz: 100.0,
            user: "Default User".into(),
            password: "robotics".into(),
            uwave_request: String::new(),
            rapid_module: "CalibServer".into(),
            seed: 1,
        }
    }
}

impl From<&MockArgs> for qtm::mock::QtmOptions {
    fn from(a: &MockArgs) -> Self {
        qtm::mock::QtmOptions { rate_hz: a.rate_hz }
    }
}

impl From<&MockArgs> for uwave::mock::UwaveOptions {
    fn from(a: &MockArgs) -> Self {
        uwave::mock::UwaveOptions {
            rate_hz: a.rate_hz,
            request: a.uwave_request.clone(),
        }
    }
}

impl From<&MockArgs> for rws::mock::Credentials {
    fn from(a: &MockArgs) -> Self {
        rws::mock::Credentials {
            user: a.user.clone(),
            password: a.password.clone(),
        }
    }
}

impl From<&MockArgs> for rws::mock::RwsMockOptions {
    fn from(a: &MockArgs) -> Self {
        rws::mock::RwsMockOptions {
            credentials: a.into(),
            controller: rws::mock::ControllerInfo {
                program_modules: (!a.rapid_module.is_empty())
                    .then(|| a.rapid_module.clone())
                    .into_iter()
                    .collect(),
                ..rws::mock::ControllerInfo::default()
            },
        }
    }
}

/// Binds and starts the mock; returns once it accepts connections.
pub async fn start(args: MockArgs) -> Result<RunningMock, MockError> {
    let faults = Faults::new(args.faults.clone());
    let tasks = MockTasks::new();
    let handler: Handler = match &args.replay {
        Some(path) => replay::handler(
            Transcript::load(path)?,
            replay::ReplayOptions {
                label: path.display().to_string(),
                strict: args.strict,
            },
        ),
        None => match args.device {
            MockDevice::Uwave => uwave::mock::handler(&args, faults),
            MockDevice::Qtm => qtm::mock::handler(&args, faults),
            MockDevice::Abb => rws::mock::handler(&args, faults),
            MockDevice::Mcs => smaract::mock::mcs_handler(faults),
            MockDevice::Mcs2 => smaract::mock::mcs2_handler(faults),
            MockDevice::Can => can::mock::handler(faults, &tasks.tracker, &tasks.token),
            MockDevice::Microscope => microscope::mock::handler_with(
                Arc::new(Mutex::new(microscope::mock::Drifting::new(args.seed))),
                faults,
            ),
            MockDevice::Joints => joints::mock::handler_with(
                Arc::new(Mutex::new(joints::mock::Linear::demo())),
                faults,
            ),
        },
    };
    let is_path = args.listen.contains('/');
    if args.device == MockDevice::Uwave && (args.pty || is_path) {
        let link = is_path.then(|| PathBuf::from(&args.listen));
        return tasks.serve_pty(handler, link);
    }
    if args.pty {
        return Err(MockError::Usage("--pty is only for the uwave mock".into()));
    }
    tasks.serve_tcp(&args.listen, handler).await
}

/// Runs a mock until `shutdown` resolves; prints `mock <device> ready (<mode>) on <addr>` on
/// stdout once it accepts connections.
pub async fn run(
    args: MockArgs,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), MockError> {
    let device = args.device.name();
    let mode = if args.replay.is_some() {
        "replay"
    } else {
        "simulate"
    };
    let m = start(args).await?;
    println!("mock {device} ready ({mode}) on {}", m.addr);
    tracing::info!(device, addr = %m.addr, mode, "mock ready");
    shutdown.await;
    m.stop().await;
    Ok(())
}
