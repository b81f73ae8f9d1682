//! Fault injection for the mocks: `--fault KIND@N` makes the N-th reply (counted over the
//! mock's lifetime, across connections) misbehave once.

use std::fmt;
use std::str::FromStr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// What the mock does instead of a normal reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// Close the connection.
    Drop,
    /// Stop answering but keep the connection open.
    Stall,
    /// Send bytes that are not the protocol.
    Garbage,
    /// Send the first part of the reply, then close.
    Truncate,
    /// Reply with an error of the device's own kind.
    DeviceError,
    /// Send the reply, unchanged, [`DELAY_FAULT`] late (it arrives after a client's timeout).
    Delay,
}

/// How late the `delay` fault sends its reply.
pub const DELAY_FAULT: std::time::Duration = std::time::Duration::from_secs(1);

/// One planned fault: `kind` at reply number `at` (1-based).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultSpec {
    /// What happens.
    pub kind: FaultKind,
    /// Which reply (1-based, over the mock's lifetime).
    pub at: u64,
}

impl FromStr for FaultSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (k, n) = s
            .split_once('@')
            .ok_or_else(|| format!("fault {s:?}: expected KIND@N, e.g. drop@3"))?;
        let kind = match k {
            "drop" => FaultKind::Drop,
            "stall" => FaultKind::Stall,
            "garbage" => FaultKind::Garbage,
            "truncate" => FaultKind::Truncate,
            "device-error" | "device_error" => FaultKind::DeviceError,
            "delay" => FaultKind::Delay,
            _ => {
                return Err(format!(
                    "fault kind {k:?}: expected drop, stall, garbage, truncate, device-error or delay"
                ));
            }
        };
        let at = n
            .parse::<u64>()
            .ok()
            .filter(|n| *n >= 1)
            .ok_or_else(|| format!("fault {s:?}: N must be an integer >= 1"))?;
        Ok(FaultSpec { kind, at })
    }
}

impl fmt::Display for FaultSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let k = match self.kind {
            FaultKind::Drop => "drop",
            FaultKind::Stall => "stall",
            FaultKind::Garbage => "garbage",
            FaultKind::Truncate => "truncate",
            FaultKind::DeviceError => "device-error",
            FaultKind::Delay => "delay",
        };
        write!(f, "{k}@{}", self.at)
    }
}

/// Shared fault plan and reply counter of one mock.
#[derive(Debug, Clone, Default)]
pub struct Faults {
    specs: Arc<Vec<FaultSpec>>,
    count: Arc<AtomicU64>,
}

impl Faults {
    /// A plan from specs.
    pub fn new(specs: Vec<FaultSpec>) -> Self {
        Faults {
            specs: Arc::new(specs),
            count: Arc::new(AtomicU64::new(0)),
        }
    }

    /// Counts one reply and returns the fault planned for it, if any.
    pub fn next(&self) -> Option<FaultKind> {
        if self.specs.is_empty() {
            return None;
        }
        let n = self.count.fetch_add(1, Ordering::SeqCst) + 1;
        self.specs.iter().find(|s| s.at == n).map(|s| s.kind)
    }
}

/// Bytes used by the `garbage` fault: not valid in any of our protocols.
pub(crate) const GARBAGE: &[u8] = b"\xff\xfe\x00garbage<<>>\xff\xff\xff\xff\xff\xff\xff\xff\r\n";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_fires_once() {
        let f: FaultSpec = "device-error@2".parse().unwrap();
        assert_eq!(f.to_string(), "device-error@2");
        assert!("drop@0".parse::<FaultSpec>().is_err());
        assert!("melt@1".parse::<FaultSpec>().is_err());
        assert_eq!(
            "delay@3".parse::<FaultSpec>().unwrap().to_string(),
            "delay@3"
        );
        let p = Faults::new(vec![f, "drop@4".parse().unwrap()]);
        let seen: Vec<_> = (0..5).map(|_| p.next()).collect();
        assert_eq!(
            seen,
            vec![
                None,
                Some(FaultKind::DeviceError),
                None,
                Some(FaultKind::Drop),
                None
            ]
        );
    }
}
