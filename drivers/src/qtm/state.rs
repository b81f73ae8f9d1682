//! Configuration and published state of the QTM driver.

use std::time::Duration;

use crate::link::Backoff;
use crate::transcript::Recorder;

/// Driver configuration.
#[derive(Debug, Clone)]
pub struct QtmConfig {
    /// Protocol version to ask for first (1.25 is what calibd speaks).
    pub version: (u32, u32),
    /// Oldest version accepted while negotiating down (same major; the 3D layout used here
    /// needs at least 1.8).
    pub min_version: (u32, u32),
    /// Reply timeout for commands and the handshake.
    pub timeout: Duration,
    /// Reconnection back-off.
    pub backoff: Backoff,
    /// Local address for the UDP data socket (port 0 = any free port).
    pub udp_bind: String,
    /// Frames buffered per subscriber before a slow subscriber starts losing them.
    pub frame_buffer: usize,
    /// Records UDP datagrams (`"udp":true` chunks); TCP traffic is recorded by the connector.
    pub udp_recorder: Option<Recorder>,
}

impl Default for QtmConfig {
    fn default() -> Self {
        QtmConfig {
            version: (1, 25),
            min_version: (1, 22),
            timeout: Duration::from_secs(5),
            backoff: Backoff::default(),
            udp_bind: "0.0.0.0:0".into(),
            frame_buffer: 4096,
            udp_recorder: None,
        }
    }
}

/// How frames travel while streaming.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StreamTransport {
    /// On the command connection.
    Tcp,
    /// As UDP datagrams to a local socket the driver binds.
    Udp,
}

/// Link and stream state published on the watch channel.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct QtmState {
    /// True while the TCP connection is open and negotiated.
    pub connected: bool,
    /// Successful (re)connections.
    pub connects: u64,
    /// Negotiated protocol version.
    pub version: Option<(u32, u32)>,
    /// Last event id received (unsolicited or from GetState).
    pub last_event: Option<u8>,
    /// True while frames are requested.
    pub streaming: bool,
    /// Data frames received.
    pub frames: u64,
    /// Frames missing between consecutive frame numbers (skipped by QTM or lost).
    pub missed_frames: u64,
    /// Frame number of the newest frame.
    pub last_frame_number: Option<u32>,
    /// NoMoreData packets seen (no measurement running).
    pub no_data: u64,
    /// Last error, if any.
    pub last_error: Option<String>,
}
