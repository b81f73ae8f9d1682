//! Piezo stages: the [`Stage`] trait with SmarAct MCS (ASCII, nm) and MCS2 (SCPI, pm)
//! backends over any byte stream, and their mocks. The CANopen CiA 402 backend is in
//! [`crate::can`].

pub mod identity;
pub mod line;
pub mod mcs;
pub mod mcs2;
pub mod mock;
pub mod stage;

pub use identity::{ChannelIdentity, StageIdentity};
pub use line::{LineCodec, LineState};
pub use mcs::McsHandle;
pub use mcs2::Mcs2Handle;
pub use stage::{Stage, StageConfig, StageStatus};
