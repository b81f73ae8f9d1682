//! Qualisys QTM RT protocol 1.25 (TCP 22223, little endian): packets, codec, 3D
//! parameters XML, driver and mock.

pub mod codec;
pub mod driver;
pub mod identity;
pub mod mock;
pub mod packet;
pub mod params;
pub mod state;

pub use codec::QtmCodec;
pub use driver::{QtmConfig, QtmHandle, QtmState, StreamTransport};
pub use identity::QtmIdentity;
pub use packet::{Component, DataFrame, Packet};
pub use params::{Settings3d, SettingsGeneral};
