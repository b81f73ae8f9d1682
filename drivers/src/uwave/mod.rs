//! Mitutoyo U-WAVE-R receiver (serial, 57600 8N1, CR lines): codec, driver and mock.

pub mod codec;
pub mod driver;
pub mod mock;

pub use codec::{ReceiverInfo, Unit, UwaveCodec, UwaveLine, parse_line};
pub use driver::{
    AxisMap, ChannelReading, Reading, SerialConnector, Transmitter, UwaveConfig, UwaveHandle,
    UwaveIdentity, UwaveState,
};
