//! Connection management shared by the drivers: a `Connect` trait that opens a fresh
//! transport, exponential back-off, and a `Link` that owns the current framed transport.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpStream;
use tokio_util::codec::Framed;

use crate::error::DriverError;
use crate::tee::{Side, Tee};
use crate::transcript::Recorder;

/// Boxed future used by object-safe async traits in this crate.
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// Opens a new transport to a device (TCP socket, serial port, in-memory pipe, ...).
///
/// Drivers never name the transport type: they ask their connector for one whenever the
/// link is down, which is how reconnection works for every device.
pub trait Connect: Send + 'static {
    /// The byte stream produced.
    type Io: AsyncRead + AsyncWrite + Unpin + Send + 'static;
    /// Opens one connection.
    fn connect(&mut self) -> BoxFuture<'_, io::Result<Self::Io>>;
    /// False when a closed transport cannot be opened again (an attached one): drivers then
    /// do not close a silent link on purpose.
    fn can_reopen(&self) -> bool {
        true
    }
}

/// A connector that hands out one already-open transport and then refuses: used by
/// `attach(transport)` constructors (tests, pipes) where reconnecting is impossible.
#[derive(Debug)]
pub struct Once<T>(Option<T>);

impl<T> Once<T> {
    /// Wraps an open transport.
    pub fn new(io: T) -> Self {
        Once(Some(io))
    }
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> Connect for Once<T> {
    type Io = T;
    fn can_reopen(&self) -> bool {
        false
    }
    fn connect(&mut self) -> BoxFuture<'_, io::Result<T>> {
        let io = self.0.take();
        Box::pin(async move {
            io.ok_or_else(|| {
                io::Error::new(
                    io::ErrorKind::NotConnected,
                    "attached transport is gone and cannot be reopened",
                )
            })
        })
    }
}

/// Connects over TCP (with `TCP_NODELAY`), optionally teeing traffic to a transcript.
#[derive(Debug, Clone)]
pub struct TcpConnector {
    /// `host:port` of the device.
    pub addr: String,
    /// Where to record the traffic, if anywhere.
    pub recorder: Option<Recorder>,
}

impl TcpConnector {
    /// A connector to `addr` without recording.
    pub fn new(addr: impl Into<String>) -> Self {
        TcpConnector {
            addr: addr.into(),
            recorder: None,
        }
    }
}

impl Connect for TcpConnector {
    type Io = Tee<TcpStream>;
    fn connect(&mut self) -> BoxFuture<'_, io::Result<Self::Io>> {
        Box::pin(async move {
            let s = TcpStream::connect(&self.addr).await?;
            s.set_nodelay(true)?;
            Ok(Tee::new(
                s,
                self.recorder.as_ref().map(Recorder::connection),
                Side::Client,
            ))
        })
    }
}

/// Exponential back-off between connection attempts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Backoff {
    /// First delay after a failed attempt.
    pub initial: Duration,
    /// Largest delay.
    pub max: Duration,
    /// Attempts per request before giving up with `DriverError::Unreachable`.
    pub attempts: u32,
}

impl Default for Backoff {
    fn default() -> Self {
        Backoff {
            initial: Duration::from_millis(50),
            max: Duration::from_secs(2),
            attempts: 5,
        }
    }
}

impl Backoff {
    /// Delay before attempt number `n` (0-based; attempt 0 has no delay).
    pub fn delay(&self, n: u32) -> Duration {
        if n == 0 {
            return Duration::ZERO;
        }
        let factor = 1u32 << (n - 1).min(16);
        self.initial.saturating_mul(factor).min(self.max)
    }
}

/// The current framed transport of a driver plus how to get a new one.
pub(crate) struct Link<C: Connect, K> {
    connector: C,
    codec: K,
    backoff: Backoff,
    device: &'static str,
    framed: Option<Framed<C::Io, K>>,
    /// Successful connections so far (1 after the first connect).
    pub(crate) connects: u64,
}

impl<C: Connect, K: Clone> Link<C, K> {
    /// A link that is not yet connected.
    pub(crate) fn new(device: &'static str, connector: C, codec: K, backoff: Backoff) -> Self {
        Link {
            connector,
            codec,
            backoff,
            device,
            framed: None,
            connects: 0,
        }
    }

    /// Whether the connector can open a new transport after this one is closed.
    pub(crate) fn can_reopen(&self) -> bool {
        self.connector.can_reopen()
    }

    /// True when a transport is open.
    pub(crate) fn is_up(&self) -> bool {
        self.framed.is_some()
    }

    /// Returns the open transport, connecting with back-off if needed. The flag is true when
    /// the connection is new (the caller must redo its handshake).
    pub(crate) async fn ensure(&mut self) -> Result<(&mut Framed<C::Io, K>, bool), DriverError> {
        let fresh = self.framed.is_none();
        if fresh {
            let mut last = None;
            for n in 0..self.backoff.attempts.max(1) {
                tokio::time::sleep(self.backoff.delay(n)).await;
                match self.connector.connect().await {
                    Ok(io) => {
                        self.framed = Some(Framed::new(io, self.codec.clone()));
                        self.connects += 1;
                        last = None;
                        break;
                    }
                    Err(e) => {
                        tracing::debug!(device = self.device, attempt = n, error = %e, "connect failed");
                        let permanent = e.kind() == io::ErrorKind::NotConnected;
                        last = Some(e);
                        if permanent {
                            break;
                        }
                    }
                }
            }
            if let Some(source) = last {
                return Err(DriverError::Unreachable {
                    device: self.device,
                    attempts: self.backoff.attempts.max(1),
                    source,
                });
            }
        }
        match self.framed.as_mut() {
            Some(f) => Ok((f, fresh)),
            None => Err(DriverError::Closed {
                device: self.device,
            }),
        }
    }

    /// Returns the open transport without connecting.
    pub(crate) fn current(&mut self) -> Option<&mut Framed<C::Io, K>> {
        self.framed.as_mut()
    }

    /// Drops the transport; the next `ensure` reconnects.
    pub(crate) fn reset(&mut self) {
        self.framed = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_and_saturates() {
        let b = Backoff {
            initial: Duration::from_millis(10),
            max: Duration::from_millis(70),
            attempts: 6,
        };
        let d: Vec<u128> = (0..6).map(|n| b.delay(n).as_millis()).collect();
        assert_eq!(d, vec![0, 10, 20, 40, 70, 70]);
    }
}
