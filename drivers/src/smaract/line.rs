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
const MAX_DRAIN: usize = 256;

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
    /// With an error `queue`, it is drained after every connect, and a checked command gets
    /// the errors it added to the queue, not those queued before it (see `Session::window`).
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
                stale: 0,
            };
            while let Some(ex) = rx.recv().await {
                let r = s.run_one(&mut link, &ex).await;
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

    /// Sends `line` (and reads its reply if `want_reply`) with the error queue's length read
    /// before and after it: an error it queued is returned as a device error naming it.
    /// `line` may be sent again (another client reading the queue): it must be idempotent.
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
    /// Stale errors drained so far.
    stale: u64,
}

/// Most queue reads (`:SYST:ERR?`) sent on one line.
const POPS_PER_LINE: usize = 16;

/// Times a checked command is sent when the error queue changed under it in a way that
/// makes its errors impossible to attribute (another client read the queue meanwhile).
const ATTEMPTS: usize = 3;

/// What one checked exchange found in the error queue.
struct Window {
    /// The command's reply, if it has one.
    reply: Option<String>,
    /// Errors queued by this command: those after the entries that were already there.
    ours: Vec<(i64, String)>,
    /// False when the queue changed in a way only another client's reads explain, so
    /// positions in it do not say whose an error is.
    attributable: bool,
}

impl Session {
    async fn run_one<C: Connect>(
        &mut self,
        link: &mut Link<C, LineCodec>,
        ex: &Exchange,
    ) -> Result<Option<String>, DriverError> {
        let (f, fresh) = link.ensure().await?;
        if fresh {
            for h in &self.hello {
                round(self.device, f, h, true, self.timeout).await?;
            }
            if let Some(q) = self.queue {
                // Whatever is queued on connect was left by another client or before a
                // reconnect.
                let n = self.count(f, q).await?;
                let (stale, _) = self.pop(f, q, n).await?;
                self.foreign(&stale, "on connect", &ex.line);
            }
        }
        let Some(q) = self.queue.filter(|_| ex.checked) else {
            return round(self.device, f, &ex.line, ex.want_reply, self.timeout).await;
        };
        let mut last = None;
        for attempt in 1..=ATTEMPTS {
            let w = self.window(f, q, ex).await?;
            if w.attributable {
                return self.verdict(ex, w.reply, &w.ours);
            }
            tracing::warn!(
                device = self.device,
                command = %ex.line,
                attempt,
                candidates = w.ours.len(),
                "the error queue changed under the command (another client reads it): sent again"
            );
            if w.ours.is_empty() {
                // Nothing in the command's window: no error of its own was queued.
                return Ok(w.reply);
            }
            last = Some(w);
        }
        let w = last.ok_or(DriverError::Closed {
            device: self.device,
        })?;
        let mut r = self.verdict(ex, w.reply, &w.ours);
        if let Err(DriverError::Device { message, .. }) = &mut r {
            message.push_str(&format!(
                " (after {ATTEMPTS} attempts; another client was reading the error queue, so \
                 this error may be its)"
            ));
        }
        r
    }

    /// Sends the command between two reads of the queue's length on one line (the
    /// controller runs a line's commands in order: nothing of ours runs between them),
    /// then reads the queue: the entries already there before the command are another
    /// client's (drained and logged, never the command's); the ones it added are its own.
    async fn window<T: AsyncRead + AsyncWrite + Unpin>(
        &mut self,
        f: &mut Framed<T, LineCodec>,
        q: ErrorQueue,
        ex: &Exchange,
    ) -> Result<Window, DriverError> {
        let line = format!("{};{};{}", q.count, ex.line, q.count);
        let n = 2 + usize::from(ex.want_reply);
        let mut replies = rounds(self.device, f, &line, n, self.timeout).await?;
        let after = self.parse_count(q, &replies[n - 1])?;
        let before = self.parse_count(q, &replies[0])?;
        let reply = ex.want_reply.then(|| std::mem::take(&mut replies[1]));
        let (popped, complete) = self.pop(f, q, after.max(before)).await?;
        let split = before.min(popped.len());
        self.foreign(&popped[..split], "before the command", &ex.line);
        let ours = popped[split..].to_vec();
        // The queue shrank during the line, or ran dry before all the entries counted were
        // read: someone else read it, and positions no longer tell whose an entry is.
        let attributable = after >= before && complete;
        Ok(Window {
            reply,
            ours,
            attributable,
        })
    }

    /// The command's result: its reply, or a device error naming it with its errors.
    fn verdict(
        &self,
        ex: &Exchange,
        reply: Option<String>,
        errors: &[(i64, String)],
    ) -> Result<Option<String>, DriverError> {
        let Some((code, text)) = errors.first() else {
            return Ok(reply);
        };
        let mut message = format!("{text} (caused by {:?})", ex.line);
        if errors.len() > 1 {
            let more: Vec<String> = errors[1..]
                .iter()
                .map(|(c, t)| format!("{c} {t}"))
                .collect();
            message.push_str(&format!("; also queued by it: {}", more.join("; ")));
        }
        tracing::debug!(device = self.device, code, command = %ex.line, "device error");
        Err(DriverError::Device {
            device: self.device,
            code: *code,
            message,
        })
    }

    /// Logs and counts errors another client caused.
    fn foreign(&mut self, errors: &[(i64, String)], when: &str, before: &str) {
        for (code, message) in errors {
            self.stale += 1;
            tracing::warn!(
                device = self.device,
                code,
                message = %message,
                when,
                before = %before,
                "drained an error this client did not cause from the controller's queue"
            );
        }
    }

    fn parse_count(&self, q: ErrorQueue, n: &str) -> Result<usize, DriverError> {
        let v: i64 = n.trim().parse().map_err(|_| DriverError::Protocol {
            device: self.device,
            detail: format!("{}: {n:?} is not an integer", q.count),
        })?;
        Ok(usize::try_from(v).unwrap_or(0))
    }

    /// The queue's length.
    async fn count<T: AsyncRead + AsyncWrite + Unpin>(
        &self,
        f: &mut Framed<T, LineCodec>,
        q: ErrorQueue,
    ) -> Result<usize, DriverError> {
        let n = round(self.device, f, q.count, true, self.timeout).await?;
        self.parse_count(q, n.as_deref().unwrap_or_default())
    }

    /// Pops up to `n` entries (at most [`MAX_DRAIN`]), oldest first, several per line;
    /// returns the errors (never code 0) and whether all `n` were read (false when the
    /// queue answered "no error" early, or when `n` is over the bound).
    async fn pop<T: AsyncRead + AsyncWrite + Unpin>(
        &self,
        f: &mut Framed<T, LineCodec>,
        q: ErrorQueue,
        n: usize,
    ) -> Result<(Vec<(i64, String)>, bool), DriverError> {
        let capped = n > MAX_DRAIN;
        let n = if capped {
            tracing::warn!(
                device = self.device,
                queued = n,
                "error queue longer than {MAX_DRAIN}: the rest is read later"
            );
            MAX_DRAIN
        } else {
            n
        };
        let mut errors = Vec::new();
        let mut left = n;
        while left > 0 {
            let k = left.min(POPS_PER_LINE);
            let line = vec![q.next; k].join(";");
            for r in rounds(self.device, f, &line, k, self.timeout).await? {
                let (code, text) = (q.parse)(&r)?;
                if code == 0 {
                    return Ok((errors, false));
                }
                errors.push((code, text));
            }
            left -= k;
        }
        Ok((errors, !capped))
    }
}

/// Sends one line and reads `n` reply lines, within `timeout` in all.
async fn rounds<T: AsyncRead + AsyncWrite + Unpin>(
    device: &'static str,
    f: &mut Framed<T, LineCodec>,
    line: &str,
    n: usize,
    timeout: Duration,
) -> Result<Vec<String>, DriverError> {
    let work = async {
        f.read_buffer_mut().clear();
        f.send(line.to_string())
            .await
            .map_err(|e| DriverError::from_codec(device, e))?;
        let mut out = Vec::with_capacity(n);
        while out.len() < n {
            match f.next().await {
                Some(Ok(l)) => out.push(l),
                Some(Err(e)) => return Err(DriverError::from_codec(device, e)),
                None => return Err(DriverError::Closed { device }),
            }
        }
        Ok(out)
    };
    tokio::time::timeout(timeout, work)
        .await
        .unwrap_or(Err(DriverError::Timeout {
            device,
            what: format!("{n} replies to {line:?}"),
            after_ms: timeout.as_millis() as u64,
        }))
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
