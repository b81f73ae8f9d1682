//! Who the QTM driver talks to: the RT protocol version in use (`Version`), the QTM version
//! (`QTMVersion`), the capture frequency (`GetParameters General`, `General/Frequency`) and
//! the labelled markers (`GetParameters 3D`).

use serde::Serialize;

use crate::error::DriverError;
use crate::identity::Identity;

/// Identity of a QTM RT server.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct QtmIdentity {
    /// RT protocol version in use, from `Version` (`Version is 1.25` → `1.25`).
    pub protocol_version: String,
    /// QTM version, from `QTMVersion` (`QTM Version is 2.3 (build 464)` → `2.3 (build 464)`).
    pub qtm_version: String,
    /// Capture frequency, Hz.
    pub frequency_hz: u32,
    /// `AxisUpwards` of the 3D settings, e.g. `+Z`.
    pub axis_upwards: String,
    /// Labelled markers (3D labels) in data order.
    pub labels: Vec<String>,
    /// Number of labelled markers.
    pub labelled_marker_count: usize,
}

/// The text after `prefix` in a command reply (case-insensitive prefix), else a protocol
/// error quoting the reply.
pub(crate) fn after(
    reply: &str,
    prefix: &str,
    device: &'static str,
) -> Result<String, DriverError> {
    let n = prefix.len();
    match reply.get(..n) {
        Some(p) if p.eq_ignore_ascii_case(prefix) => Ok(reply[n..].trim().to_string()),
        _ => Err(DriverError::Protocol {
            device,
            detail: format!("expected a reply starting {prefix:?}, got {reply:?}"),
        }),
    }
}

impl Identity for QtmIdentity {
    const DEVICE_KIND: &'static str = "qtm";

    fn fingerprint(&self) -> String {
        format!(
            "QTM {}, RT protocol {}, {} Hz, {} up",
            self.qtm_version, self.protocol_version, self.frequency_hz, self.axis_upwards
        )
    }

    fn summary(&self) -> String {
        format!(
            "QTM {}, RT protocol {}, {} Hz, {} labelled markers ({})",
            self.qtm_version,
            self.protocol_version,
            self.frequency_hz,
            self.labelled_marker_count,
            self.labels.join(", ")
        )
    }

    fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        if self.labels.is_empty() {
            p.push(
                "no labelled markers in the 3D settings: apply the AIM model (or label the \
                 tool markers) in QTM"
                    .to_string(),
            );
        }
        if self.frequency_hz == 0 {
            p.push("capture frequency is 0 Hz: set it in QTM's project options".to_string());
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn version_replies() {
        assert_eq!(
            after("Version is 1.25", "Version is ", "qtm").unwrap(),
            "1.25"
        );
        assert_eq!(
            after("QTM Version is 2.3 (build 464)", "QTM Version is ", "qtm").unwrap(),
            "2.3 (build 464)"
        );
        assert!(after("Parse Error", "Version is ", "qtm").is_err());
        assert!(after("V", "Version is ", "qtm").is_err());
    }
}
