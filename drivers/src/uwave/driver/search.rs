//! Transmitter search: `IR11<cc><gg>1` asks for the next registered transmitter with channel
//! ≥ cc; the receiver answers `TI1…` (then we ask from channel + 1) or `ST1 … 51` (end of
//! search); `ST1 … 50` is a malformed request (devices.md §2).

use futures_util::SinkExt;
use tokio::time::Instant;

use super::{Actor, DEVICE};
use crate::actor::Reply;
use crate::error::DriverError;
use crate::link::Connect;
use crate::uwave::codec::UwaveLine;

/// A registered transmitter as reported by a `TI1` line.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Transmitter {
    /// Channel (00-99).
    pub channel: u8,
    /// Group.
    pub group: u8,
    /// 10-digit transmitter id.
    pub id: String,
    /// State 0-5 (2 = connected).
    pub state: u8,
    /// Radio band 11-25.
    pub band: u8,
    /// 0 button mode, 1 event mode.
    pub mode: u8,
}

/// A search in progress.
pub(super) struct Search {
    found: Vec<Transmitter>,
    pub(super) deadline: Instant,
    reply: Reply<Vec<Transmitter>>,
}

impl<C: Connect> Actor<C> {
    fn search_request(&self, from: u8) -> Vec<u8> {
        format!("IR11{from:02}{:02}1\r", self.cfg.group).into_bytes()
    }

    pub(super) async fn start_search(&mut self, reply: Reply<Vec<Transmitter>>) {
        if self.search.is_some() {
            let _ = reply.send(Err(DriverError::InvalidRequest {
                device: DEVICE,
                detail: "a transmitter search is already running".into(),
            }));
            return;
        }
        if let Err(e) = self.reconnect().await {
            let _ = reply.send(Err(e));
            return;
        }
        self.queue(self.search_request(0));
        self.search = Some(Search {
            found: Vec::new(),
            deadline: Instant::now() + self.cfg.timeout,
            reply,
        });
    }

    /// Queues request bytes for [`Actor::flush`] (after those already queued).
    pub(super) fn queue(&mut self, bytes: Vec<u8>) {
        self.to_send.get_or_insert_with(Vec::new).extend(bytes);
    }

    /// Sends the pending request bytes, if any.
    pub(super) async fn flush(&mut self) {
        let Some(bytes) = self.to_send.take() else {
            return;
        };
        let r = match self.link.current() {
            Some(f) => f.send(bytes).await,
            None => return,
        };
        if let Err(e) = r {
            let e = DriverError::from_codec(DEVICE, e);
            self.drop_link(&e);
        }
    }

    /// Takes the lines that belong to a running search; true if consumed.
    pub(super) fn on_search_line(&mut self, line: &UwaveLine) -> bool {
        let Some(s) = self.search.as_mut() else {
            return false;
        };
        match line {
            UwaveLine::TransmitterInfo {
                state,
                channel,
                group,
                transmitter,
                band,
                mode,
            } => {
                s.found.push(Transmitter {
                    channel: *channel,
                    group: *group,
                    id: transmitter.clone(),
                    state: *state,
                    band: *band,
                    mode: *mode,
                });
                s.deadline = Instant::now() + self.cfg.timeout;
                if *channel >= 99 {
                    self.finish_search(Ok(()));
                } else {
                    self.queue(self.search_request(channel + 1));
                }
                true
            }
            UwaveLine::Status { code: 51, .. } => {
                self.finish_search(Ok(()));
                true
            }
            UwaveLine::Status {
                code: 50,
                channel: None,
                ..
            } => {
                self.finish_search(Err(DriverError::Device {
                    device: DEVICE,
                    code: 50,
                    message: "request packet error during the transmitter search".into(),
                }));
                true
            }
            _ => false,
        }
    }

    fn finish_search(&mut self, r: Result<(), DriverError>) {
        if let Some(s) = self.search.take() {
            let _ = s.reply.send(r.map(|()| s.found));
        }
    }

    pub(super) fn fail_search(&mut self, e: DriverError) {
        self.finish_search(Err(e));
    }

    pub(super) fn expire_search(&mut self, now: Instant) {
        if self.search.as_ref().is_some_and(|s| s.deadline <= now) {
            let after_ms = self.cfg.timeout.as_millis() as u64;
            self.fail_search(DriverError::Timeout {
                device: DEVICE,
                what: "the next transmitter info line".into(),
                after_ms,
            });
        }
    }
}
