//! A line-protocol actor shared by the SmarAct backends: it owns the connection, sends a
//! command line, optionally waits for one reply line, with timeouts and reconnection.

use std::time::Duration;

use bytes::{BufMut, BytesMut};
use futures_util::{SinkExt, StreamExt};
use tokio::sync::{mpsc, watch};
use tokio_util::codec::{Decoder, Encoder};

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
}

pub(crate) struct Exchange {
    line: String,
    want_reply: bool,
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
    pub(crate) fn start<C: Connect>(
        device: &'static str,
        connector: C,
        timeout: Duration,
        backoff: Backoff,
        hello: Vec<String>,
    ) -> Self {
        let (tx, mut rx) = mpsc::channel::<Exchange>(16);
        let (stx, srx) = watch::channel(LineState::default());
        let mut link = Link::new(device, connector, LineCodec::default(), backoff);
        tokio::spawn(async move {
            while let Some(ex) = rx.recv().await {
                let r = run_one(device, &mut link, &ex, timeout, &hello).await;
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
        call(&self.tx, self.device, |reply| Exchange {
            line,
            want_reply,
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

async fn run_one<C: Connect>(
    device: &'static str,
    link: &mut Link<C, LineCodec>,
    ex: &Exchange,
    timeout: Duration,
    hello: &[String],
) -> Result<Option<String>, DriverError> {
    let (f, fresh) = link.ensure().await?;
    let lines: Vec<(String, bool)> = if fresh {
        hello
            .iter()
            .map(|h| (h.clone(), true))
            .chain([(ex.line.clone(), ex.want_reply)])
            .collect()
    } else {
        vec![(ex.line.clone(), ex.want_reply)]
    };
    let mut last = None;
    for (line, want) in lines {
        let work = async {
            // Anything unread belongs to an earlier, abandoned exchange.
            f.read_buffer_mut().clear();
            f.send(line.clone())
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
        last = tokio::time::timeout(timeout, work)
            .await
            .unwrap_or(Err(DriverError::Timeout {
                device,
                what: format!("a reply to {line:?}"),
                after_ms: timeout.as_millis() as u64,
            }))?;
    }
    Ok(last)
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
