//! Device drivers for calibd: one async actor per device, generic over its transport, plus
//! mock servers that speak the same protocols (replay and simulate modes, fault injection).
//!
//! Modules: [`camera`] (`calibd-frames/1` and folder frame sources), [`uwave`] (Mitutoyo U-WAVE-R), [`rws`] (ABB IRC5 Robot Web Services 1.0),
//! [`smaract`] (MCS / MCS2 / CiA 402 piezo stages), [`can`] (socketcand, SocketCAN, CANopen),
//! [`qtm`] (Qualisys RT), [`microscope`] (`calibd-pose/1`), [`joints`] (`calibd-joints/1`, a
//! humanoid's joint interface), [`mock`] (`calibd mock`: the
//! one registry of mock devices), [`mock_kit`] (what every mock shares), [`transcript`]
//! (recording format), [`link`] (connectors and back-off), [`error`], [`identity`] (what
//! each driver reports about the device it talks to, for `calibd lab check`).
#![warn(missing_docs)]

pub mod actor;
pub mod bench;
pub mod camera;
pub mod can;
pub mod error;
pub mod identity;
pub mod joints;
pub mod link;
pub mod microscope;
pub mod mock;
pub mod mock_kit;
pub mod qtm;
pub mod rws;
pub mod smaract;
pub mod tee;
pub mod transcript;
pub mod uwave;

pub use error::{CodecError, DriverError};
pub use identity::{DeviceIdentity, Identity};
pub use link::{Backoff, Connect, Once, TcpConnector};
pub use smaract::{Stage, StageConfig, StageStatus};
pub use tee::{Side, Tee};
pub use transcript::{Recorder, Transcript};
