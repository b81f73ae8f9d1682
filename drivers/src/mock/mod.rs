//! `calibd mock <device>`: mock device servers that speak the real protocols, in replay
//! mode (serve a transcript) or simulate mode (backed by a device model), with fault
//! injection. [`MockArgs`] is the clap argument struct the binary embeds; [`start`] binds
//! and returns the address (tests), [`run`] also prints the ready line and waits.

pub mod fault;
pub(crate) mod replay;
pub mod serve;

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;

use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

pub use fault::{FaultKind, FaultSpec, Faults};
pub use serve::{BoxIo, Conn, Handler};

use crate::transcript::{Transcript, TranscriptError};

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
    /// Inject a fault: KIND@N with KIND drop|stall|garbage|truncate|device-error|delay and N the
    /// reply number (1-based) it replaces. Repeatable.
    #[arg(long = "fault")]
    pub faults: Vec<FaultSpec>,
    /// Streaming rate of simulated data (QTM frames, U-WAVE readings), per second.
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
}

impl MockArgs {
    /// Defaults for `device` (simulate, loopback port 0, no faults).
    pub fn new(device: MockDevice) -> Self {
        MockArgs {
            device,
            listen: "127.0.0.1:0".into(),
            pty: false,
            replay: None,
            faults: Vec::new(),
            rate_hz: 100.0,
            user: "Default User".into(),
            password: "robotics".into(),
            uwave_request: String::new(),
        }
    }
}

/// Error starting a mock.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MockError {
    /// The listen address could not be bound.
    #[error("calibd-drivers: mock: cannot listen on {addr}: {source}")]
    Bind {
        /// Address asked for.
        addr: String,
        /// Bind error.
        #[source]
        source: std::io::Error,
    },
    /// The pseudo-terminal could not be created or linked.
    #[error("calibd-drivers: mock: pty: {0}")]
    Pty(String),
    /// The replay transcript is unreadable.
    #[error("calibd-drivers: mock: {0}")]
    Transcript(#[from] TranscriptError),
    /// The options do not fit the device.
    #[error("calibd-drivers: mock: {0}")]
    Usage(String),
}

/// A started mock.
#[derive(Debug)]
pub struct RunningMock {
    /// Where clients connect: `ip:port`, or a pty path for `uwave --pty`.
    pub addr: String,
    token: CancellationToken,
    tracker: TaskTracker,
}

impl RunningMock {
    /// Stops accepting, closes every connection and waits for the tasks.
    pub async fn stop(self) {
        self.token.cancel();
        self.tracker.close();
        self.tracker.wait().await;
    }
}

/// Binds and starts the mock; returns once it accepts connections.
pub async fn start(args: MockArgs) -> Result<RunningMock, MockError> {
    let faults = Faults::new(args.faults.clone());
    let token = CancellationToken::new();
    let tracker = TaskTracker::new();
    let handler: Handler = match &args.replay {
        Some(path) => {
            let t = Arc::new(Transcript::load(path)?);
            Arc::new(move |io, conn: Conn| {
                let t = t.clone();
                Box::pin(async move { replay::replay(io, &t, conn.token).await })
            })
        }
        None => match args.device {
            MockDevice::Uwave => crate::uwave::mock::handler(&args, faults),
            MockDevice::Qtm => crate::qtm::mock::handler(&args, faults),
            MockDevice::Abb => crate::rws::mock::handler(&args, faults),
            MockDevice::Mcs => crate::smaract::mock::mcs_handler(&args, faults),
            MockDevice::Mcs2 => crate::smaract::mock::mcs2_handler(&args, faults),
            MockDevice::Can => crate::can::mock::handler(&args, faults, &tracker, &token),
        },
    };
    let is_path = args.listen.contains('/');
    if args.device == MockDevice::Uwave && (args.pty || is_path) {
        let link = is_path.then(|| PathBuf::from(&args.listen));
        let addr = crate::uwave::mock::serve_pty(handler, link, &tracker, &token)?;
        return Ok(RunningMock {
            addr,
            token,
            tracker,
        });
    }
    if args.pty {
        return Err(MockError::Usage("--pty is only for the uwave mock".into()));
    }
    let listener = TcpListener::bind(&args.listen)
        .await
        .map_err(|source| MockError::Bind {
            addr: args.listen.clone(),
            source,
        })?;
    let addr = listener
        .local_addr()
        .map_err(|source| MockError::Bind {
            addr: args.listen.clone(),
            source,
        })?
        .to_string();
    tracker.spawn(serve::serve_tcp(listener, token.clone(), handler));
    Ok(RunningMock {
        addr,
        token,
        tracker,
    })
}

/// Starts a TCP mock around any handler (e.g. one built with a digital-twin model through
/// `qtm::mock::handler_with`, `rws::mock::handler_with`, ...).
pub async fn start_with(listen: &str, handler: Handler) -> Result<RunningMock, MockError> {
    let token = CancellationToken::new();
    let tracker = TaskTracker::new();
    let bind = |source| MockError::Bind {
        addr: listen.to_string(),
        source,
    };
    let listener = TcpListener::bind(listen).await.map_err(bind)?;
    let addr = listener.local_addr().map_err(bind)?.to_string();
    tracker.spawn(serve::serve_tcp(listener, token.clone(), handler));
    Ok(RunningMock {
        addr,
        token,
        tracker,
    })
}

/// Starts a serial mock on a new pseudo-terminal around any handler (e.g. the U-WAVE
/// receiver of a digital-twin fixture through `uwave::mock::handler_with`); `addr` of the
/// result is the pty path clients open.
pub fn start_pty_with(handler: Handler) -> Result<RunningMock, MockError> {
    let token = CancellationToken::new();
    let tracker = TaskTracker::new();
    let addr = crate::uwave::mock::serve_pty(handler, None, &tracker, &token)?;
    Ok(RunningMock {
        addr,
        token,
        tracker,
    })
}

/// Runs a mock until `shutdown` resolves; prints `mock <device> ready on <addr>` on stdout
/// once it accepts connections.
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
