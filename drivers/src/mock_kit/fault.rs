//! Fault injection for the mocks: `--fault KIND@N` makes the N-th reply (counted over the
//! mock's lifetime, across connections) misbehave once.

use std::fmt;
use std::str::FromStr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use tokio::io::AsyncWriteExt;
use tokio_util::sync::CancellationToken;

use super::serve::{BoxIo, stall};

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

/// What becomes of one reply once the fault plan has had its say ([`Faults::apply`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Fate<T> {
    /// Send this: the reply (maybe [`DELAY_FAULT`] late) or the device's error in its place.
    Send(T),
    /// Garbage went out instead of the reply; the session goes on.
    Skipped,
    /// The connection is over (drop, stall until the client left, truncate, write error).
    Close,
}

impl Faults {
    /// [`Faults::apply`], then send what survives on the session's framing `f`: whether
    /// the session goes on.
    pub(crate) async fn send<C, T>(
        &self,
        f: &mut tokio_util::codec::Framed<BoxIo, C>,
        token: &CancellationToken,
        reply: T,
        wire: impl FnOnce(&T) -> Vec<u8>,
        device_error: impl FnOnce(T) -> T,
    ) -> bool
    where
        C: tokio_util::codec::Encoder<T>,
    {
        use futures_util::SinkExt;
        match self
            .apply(f.get_mut(), token, reply, wire, device_error)
            .await
        {
            Fate::Send(r) => f.send(r).await.is_ok(),
            Fate::Skipped => true,
            Fate::Close => false,
        }
    }

    /// Counts one reply and applies the fault planned for it, the same way in every mock:
    /// `delay` waits [`DELAY_FAULT`] then sends, `drop` closes, `stall` reads and discards
    /// until the client leaves, `garbage` writes [`GARBAGE`] instead, `truncate` writes the
    /// first half of `wire(&reply)` and closes, `device-error` sends
    /// `device_error(reply)`. `io` is the connection under the session's framing (nothing
    /// may be buffered in it for writing).
    pub(crate) async fn apply<T>(
        &self,
        io: &mut BoxIo,
        token: &CancellationToken,
        reply: T,
        wire: impl FnOnce(&T) -> Vec<u8>,
        device_error: impl FnOnce(T) -> T,
    ) -> Fate<T> {
        match self.next() {
            None => Fate::Send(reply),
            Some(FaultKind::Delay) => tokio::select! {
                _ = tokio::time::sleep(DELAY_FAULT) => Fate::Send(reply),
                _ = token.cancelled() => Fate::Close,
            },
            Some(FaultKind::Drop) => Fate::Close,
            Some(FaultKind::Stall) => {
                stall(io, token).await;
                Fate::Close
            }
            Some(FaultKind::Garbage) => match io.write_all(GARBAGE).await {
                Ok(()) => Fate::Skipped,
                Err(_) => Fate::Close,
            },
            Some(FaultKind::Truncate) => {
                let bytes = wire(&reply);
                let _ = io.write_all(&bytes[..bytes.len() / 2]).await;
                let _ = io.flush().await;
                Fate::Close
            }
            Some(FaultKind::DeviceError) => Fate::Send(device_error(reply)),
        }
    }
}

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
