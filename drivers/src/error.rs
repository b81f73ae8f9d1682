//! Error types shared by every driver: transport, protocol and device-reported faults are
//! separate variants so callers can tell "the stage said no" from "the cable fell out".

use std::io;

/// Error returned by driver handles.
///
/// `Device` is what the instrument itself reported; everything else is a transport,
/// protocol, timing or local-policy failure.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DriverError {
    /// The byte stream failed (I/O error on the socket, serial port or CAN bus).
    #[error("calibd-drivers: {device}: transport error: {source}")]
    Transport {
        /// Device family (`qtm`, `rws`, `uwave`, `mcs`, `mcs2`, `can`).
        device: &'static str,
        /// Underlying I/O error.
        #[source]
        source: io::Error,
    },
    /// The peer closed the connection.
    #[error("calibd-drivers: {device}: connection closed by peer")]
    Closed {
        /// Device family.
        device: &'static str,
    },
    /// Bytes arrived that do not follow the protocol.
    #[error("calibd-drivers: {device}: protocol error: {detail}")]
    Protocol {
        /// Device family.
        device: &'static str,
        /// What was wrong, quoting the offending bytes when short.
        detail: String,
    },
    /// The device answered with an error of its own.
    #[error("calibd-drivers: {device}: device reported error {code}: {message}")]
    Device {
        /// Device family.
        device: &'static str,
        /// Device error code (HTTP status, SmarAct code, SDO abort code, ...).
        code: i64,
        /// Device error text or our description of the code.
        message: String,
    },
    /// No reply in time.
    #[error("calibd-drivers: {device}: timed out after {after_ms} ms waiting for {what}")]
    Timeout {
        /// Device family.
        device: &'static str,
        /// What we were waiting for.
        what: String,
        /// Timeout that expired, in milliseconds.
        after_ms: u64,
    },
    /// Connecting failed repeatedly (exponential back-off exhausted).
    #[error("calibd-drivers: {device}: unreachable after {attempts} connection attempts: {source}")]
    Unreachable {
        /// Device family.
        device: &'static str,
        /// Attempts made.
        attempts: u32,
        /// Last connection error.
        #[source]
        source: io::Error,
    },
    /// A request was refused locally by a safety limit before anything was sent.
    #[error("calibd-drivers: {device}: refused by safety limit: {reason}")]
    Safety {
        /// Device family.
        device: &'static str,
        /// Which limit and by how much it was exceeded.
        reason: String,
    },
    /// The newest cached reading is older than the staleness limit (or none exists).
    #[error("calibd-drivers: {device}: no reading on channel {channel} newer than {limit_ms} ms")]
    Stale {
        /// Device family.
        device: &'static str,
        /// Channel number.
        channel: u8,
        /// Staleness limit in milliseconds.
        limit_ms: u64,
    },
    /// The request was malformed (bad argument from the caller).
    #[error("calibd-drivers: {device}: invalid request: {detail}")]
    InvalidRequest {
        /// Device family.
        device: &'static str,
        /// What was wrong.
        detail: String,
    },
    /// The driver task stopped (all handles are gone or it panicked).
    #[error("calibd-drivers: {device}: driver task is not running")]
    ActorGone {
        /// Device family.
        device: &'static str,
    },
}

impl DriverError {
    /// True when the device itself reported the error (not the link or our code).
    pub fn is_device_error(&self) -> bool {
        matches!(self, DriverError::Device { .. })
    }

    /// True when the link is probably broken and the next request should reconnect.
    pub fn breaks_link(&self) -> bool {
        matches!(
            self,
            DriverError::Transport { .. }
                | DriverError::Closed { .. }
                | DriverError::Protocol { .. }
                | DriverError::Timeout { .. }
        )
    }

    /// A copy for fanning one failure out to several waiters (an I/O source keeps its kind
    /// and text; variants without a cheap copy become `Protocol` with their message).
    pub fn duplicate(&self) -> DriverError {
        match self {
            DriverError::Closed { device } => DriverError::Closed { device },
            DriverError::Timeout {
                device,
                what,
                after_ms,
            } => DriverError::Timeout {
                device,
                what: what.clone(),
                after_ms: *after_ms,
            },
            DriverError::Transport { device, source } => DriverError::Transport {
                device,
                source: io::Error::new(source.kind(), source.to_string()),
            },
            DriverError::Protocol { device, detail } => DriverError::Protocol {
                device,
                detail: detail.clone(),
            },
            DriverError::Device {
                device,
                code,
                message,
            } => DriverError::Device {
                device,
                code: *code,
                message: message.clone(),
            },
            other => DriverError::Protocol {
                device: "driver",
                detail: other.to_string(),
            },
        }
    }

    /// Wraps a codec error for `device`.
    pub(crate) fn from_codec(device: &'static str, e: CodecError) -> Self {
        match e {
            CodecError::Io(source) => DriverError::Transport { device, source },
            CodecError::Malformed { detail } => DriverError::Protocol { device, detail },
        }
    }
}

/// Error of a wire codec: I/O below it, or bytes that cannot be a frame.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CodecError {
    /// I/O error of the underlying stream.
    #[error("i/o: {0}")]
    Io(#[from] io::Error),
    /// The bytes cannot be a valid frame.
    #[error("malformed frame: {detail}")]
    Malformed {
        /// What was wrong, quoting the offending bytes when short.
        detail: String,
    },
}

impl CodecError {
    /// Builds a `Malformed` error.
    pub(crate) fn malformed(detail: impl Into<String>) -> Self {
        CodecError::Malformed {
            detail: detail.into(),
        }
    }
}

/// Quotes at most 64 bytes of `b` for error messages (escaped ASCII).
pub(crate) fn quote(b: &[u8]) -> String {
    let n = b.len().min(64);
    let mut s: String = b[..n].escape_ascii().to_string();
    if b.len() > n {
        s.push_str("...");
    }
    format!("\"{s}\"")
}
