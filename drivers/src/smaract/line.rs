//! A line-protocol actor shared by the SmarAct backends: it owns the connection, sends a
//! command line, optionally waits for one reply line, with timeouts and reconnection.

use std::time::Duration;

use bytes::{BufMut, BytesMut};
use futures_util::{SinkExt, StreamExt};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, watch};
use tokio_util::codec::{Decoder, Encoder, Framed};

use crate::actor::{Reply, call};
use crate::error::{CodecError, DriverError, quote};
use crate::link::{Backoff, Connect, Link};

/// Splits on LF (a CR before it is dropped); lines must be printable ASCII.
#[derive(Debug, Clone, Copy)]
pub struct LineCodec {
    /// Longest line accepted.
    pub max: usize,
}

impl Default for LineCodec {
    fn default() -> Self {
        LineCodec { max: 256 }
    }
}

impl Decoder for LineCodec {
    type Item = String;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<String>, CodecError> {
        let Some(p) = src.iter().position(|b| *b == b'\n') else {
            if src.len() > self.max {
                return Err(CodecError::malformed(format!(
                    "no LF within {} bytes: {}",
                    self.max,
                    quote(src)
                )));
            }
            return Ok(None);
        };
        let line = src.split_to(p + 1);
        let body = line[..p].strip_suffix(b"\r").unwrap_or(&line[..p]);
        if !body.iter().all(|b| (0x20..0x7f).contains(b)) {
            return Err(CodecError::malformed(format!(
                "non-printable bytes in line {}",
                quote(&line)
            )));
        }
        Ok(Some(String::from_utf8_lossy(body).into_owned()))
    }
}

impl Encoder<String> for LineCodec {
    type Error = CodecError;
    fn encode(&mut self, item: String, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(item.as_bytes());
        dst.put_u8(b'\n');
        Ok(())
    }
}

/// Link state shared by the line-protocol drivers.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LineState {
    /// True while connected.
    pub connected: bool,
    /// Successful (re)connections.
    pub connects: u64,
    /// Last error.
    pub last_error: Option<String>,
    /// Errors found in the controller's error queue that no command of ours caused (left
    /// by another client or before a reconnect), drained and logged.
    pub stale_errors_drained: u64,
}

/// A controller that reports errors through a queue (MCS2: `:SYST:ERR:COUN?` and
/// `:SYST:ERR?`, SCPI style, code 0 = no error).
#[derive(Debug, Clone, Copy)]
pub(crate) struct ErrorQueue {
    /// Query for the number of queued errors.
    pub(crate) count: &'static str,
    /// Query that pops the oldest error.
    pub(crate) next: &'static str,
    /// Parses a `next` reply into code and text.
    pub(crate) parse: fn(&str) -> Result<(i64, String), DriverError>,
}

/// Most queue entries read in one drain (a controller that never says 0 cannot hang us).
const MAX_DRAIN: usize = 64;

pub(crate) struct Exchange {
    line: String,
    want_reply: bool,
    /// Attribute the errors queued by this command to it (needs an `ErrorQueue`).
    checked: bool,
    reply: Reply<Option<String>>,
}

impl std::fmt::Debug for Exchange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Exchange({:?}, reply: {})", self.line, self.want_reply)
    }
}

/// Handle to a line actor.
#[derive(Debug, Clone)]
pub(crate) struct LineClient {
    tx: mpsc::Sender<Exchange>,
    state: watch::Receiver<LineState>,
    device: &'static str,
}

impl LineClient {
    /// Starts the actor; `hello` lines are sent (each awaiting one reply) after every connect.
    /// With an error `queue`, it is drained after every connect and before a checked
    /// command when an unchecked one may have left errors; a checked command gets the
    /// errors queued after it.
    pub(crate) fn start<C: Connect>(
        device: &'static str,
        connector: C,
        timeout: Duration,
        backoff: Backoff,
        hello: Vec<String>,
        queue: Option<ErrorQueue>,
    ) -> Self {
        let (tx, mut rx) = mpsc::channel::<Exchange>(16);
        let (stx, srx) = watch::channel(LineState::default());
        let mut link = Link::new(device, connector, LineCodec::default(), backoff);
        tokio::spawn(async move {
            let mut s = Session {
                device,
                timeout,
                hello,
                queue,
                dirty: true,
                stale: 0,
            };
            while let Some(ex) = rx.recv().await {
                let r = s.run_one(&mut link, &ex).await;
                if r.is_err() {
                    // Whatever the command left in the queue is not known to be read.
                    s.dirty = true;
                }
                let stale = s.stale;
                stx.send_modify(|st| st.stale_errors_drained = stale);
                if let Err(e) = &r {
                    if e.breaks_link() {
                        link.reset();
                    }
                    let msg = e.to_string();
                    stx.send_modify(|s| s.last_error = Some(msg));
                }
                let (up, n) = (link.is_up(), link.connects);
                stx.send_modify(|s| {
                    s.connected = up;
                    s.connects = n;
                });
                let _ = ex.reply.send(r);
            }
        });
        LineClient {
            tx,
            state: srx,
            device,
        }
    }

    /// Sends `line`; returns the reply line if `want_reply`.
    pub(crate) async fn exchange(
        &self,
        line: String,
        want_reply: bool,
    ) -> Result<Option<String>, DriverError> {
        self.send(line, want_reply, false).await
    }

    /// Sends `line` (and reads its reply if `want_reply`), then reads the error queue: an
    /// error queued after this line is returned as a device error naming it.
    pub(crate) async fn checked(
        &self,
        line: String,
        want_reply: bool,
    ) -> Result<Option<String>, DriverError> {
        self.send(line, want_reply, true).await
    }

    async fn send(
        &self,
        line: String,
        want_reply: bool,
        checked: bool,
    ) -> Result<Option<String>, DriverError> {
        call(&self.tx, self.device, |reply| Exchange {
            line,
            want_reply,
            checked,
            reply,
        })
        .await
    }

    /// Sends `line` and returns its reply.
    pub(crate) async fn query(&self, line: String) -> Result<String, DriverError> {
        self.exchange(line, true).await?.ok_or(DriverError::Closed {
            device: self.device,
        })
    }

    /// Link state.
    pub(crate) fn state(&self) -> watch::Receiver<LineState> {
        self.state.clone()
    }
}

/// The actor's side of one connection-independent session.
struct Session {
    device: &'static str,
    timeout: Duration,
    hello: Vec<String>,
    queue: Option<ErrorQueue>,
    /// The error queue may hold errors no checked command has read.
    dirty: bool,
    /// Stale errors drained so far.
    stale: u64,
}

impl Session {
    async fn run_one<C: Connect>(
        &mut self,
        link: &mut Link<C, LineCodec>,
        ex: &Exchange,
    ) -> Result<Option<String>, DriverError> {
        let (f, fresh) = link.ensure().await?;
        if fresh {
            self.dirty = true;
            for h in &self.hello {
                round(self.device, f, h, true, self.timeout).await?;
            }
        }
        let Some(q) = self.queue.filter(|_| ex.checked || fresh) else {
            self.dirty = true;
            return round(self.device, f, &ex.line, ex.want_reply, self.timeout).await;
        };
        if self.dirty {
            let why = if fresh {
                "on connect"
            } else {
                "before a command"
            };
            for (code, message) in self.drain(f, q).await? {
                self.stale += 1;
                tracing::warn!(
                    device = self.device,
                    code,
                    message = %message,
                    when = why,
                    before = %ex.line,
                    "drained an error this client did not cause from the controller's queue"
                );
            }
            self.dirty = false;
        }
        let reply = round(self.device, f, &ex.line, ex.want_reply, self.timeout).await?;
        if !ex.checked {
            self.dirty = true;
            return Ok(reply);
        }
        let errors = self.drain(f, q).await?;
        let Some((code, text)) = errors.first() else {
            return Ok(reply);
        };
        let mut message = format!("{text} (caused by {:?})", ex.line);
        if errors.len() > 1 {
            let more: Vec<String> = errors[1..]
                .iter()
                .map(|(c, t)| format!("{c} {t}"))
                .collect();
            message.push_str(&format!("; also queued: {}", more.join("; ")));
        }
        tracing::debug!(device = self.device, code, command = %ex.line, "device error");
        Err(DriverError::Device {
            device: self.device,
            code: *code,
            message,
        })
    }

    /// Reads the queue until it reports code 0; returns the real errors (never code 0).
    async fn drain<T: AsyncRead + AsyncWrite + Unpin>(
        &self,
        f: &mut Framed<T, LineCodec>,
        q: ErrorQueue,
    ) -> Result<Vec<(i64, String)>, DriverError> {
        let device = self.device;
        let n = round(device, f, q.count, true, self.timeout).await?;
        let n = n.unwrap_or_default();
        let n: i64 = n.trim().parse().map_err(|_| DriverError::Protocol {
            device,
            detail: format!("{}: {n:?} is not an integer", q.count),
        })?;
        let mut errors = Vec::new();
        if n <= 0 {
            return Ok(errors);
        }
        for _ in 0..MAX_DRAIN {
            let line = round(device, f, q.next, true, self.timeout).await?;
            let (code, text) = (q.parse)(line.as_deref().unwrap_or_default())?;
            if code == 0 {
                return Ok(errors);
            }
            errors.push((code, text));
        }
        tracing::warn!(device, "error queue not empty after {MAX_DRAIN} reads");
        Ok(errors)
    }
}

/// Sends one line and, if `want`, reads one reply line, within `timeout`.
async fn round<T: AsyncRead + AsyncWrite + Unpin>(
    device: &'static str,
    f: &mut Framed<T, LineCodec>,
    line: &str,
    want: bool,
    timeout: Duration,
) -> Result<Option<String>, DriverError> {
    let work = async {
        // Anything unread belongs to an earlier, abandoned exchange.
        f.read_buffer_mut().clear();
        f.send(line.to_string())
            .await
            .map_err(|e| DriverError::from_codec(device, e))?;
        if !want {
            return Ok(None);
        }
        match f.next().await {
            Some(Ok(l)) => Ok(Some(l)),
            Some(Err(e)) => Err(DriverError::from_codec(device, e)),
            None => Err(DriverError::Closed { device }),
        }
    };
    tokio::time::timeout(timeout, work)
        .await
        .unwrap_or(Err(DriverError::Timeout {
            device,
            what: format!("a reply to {line:?}"),
            after_ms: timeout.as_millis() as u64,
        }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_partial_and_garbage() {
        let mut c = LineCodec::default();
        let mut b = BytesMut::from(&b":P0,1499998\r\n:E0,"[..]);
        assert_eq!(c.decode(&mut b).unwrap(), Some(":P0,1499998".into()));
        assert_eq!(c.decode(&mut b).unwrap(), None);
        b.extend_from_slice(b"0\n");
        assert_eq!(c.decode(&mut b).unwrap(), Some(":E0,0".into()));
        let mut g = BytesMut::from(&b"\xff\xfe\x00garbage\r\n"[..]);
        assert!(c.decode(&mut g).is_err());
        let mut g = BytesMut::from(&[b'1'; 300][..]);
        assert!(c.decode(&mut g).is_err());
    }
}
