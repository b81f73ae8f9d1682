//! Who the U-WAVE driver talks to: the receiver (`IR1000gg0` → `RI1…`), the registered
//! transmitters (the search in `search`) and the latest cached reading of each configured
//! indicator with its age.

use serde::Serialize;
use tokio::time::Instant;

use super::{Actor, DEVICE, Transmitter};
use crate::actor::Reply;
use crate::error::DriverError;
use crate::identity::Identity;
use crate::link::Connect;
use crate::uwave::codec::ReceiverInfo;

/// The latest reading of one configured indicator, as cached (not refreshed).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelReading {
    /// U-WAVE channel.
    pub channel: u8,
    /// Id of the transmitter registered on this channel (None: none registered).
    pub transmitter_id: Option<String>,
    /// Transmitter state (`connected`, `disconnected`, ...; None: none registered).
    pub transmitter_state: Option<&'static str>,
    /// Latest value in millimetres (None: no reading since the port was opened).
    pub value_mm: Option<f64>,
    /// Age of that value in milliseconds.
    pub age_ms: Option<u64>,
}

/// Identity of a U-WAVE-R receiver and its indicators.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UwaveIdentity {
    /// The receiver's `RI1` reply.
    pub receiver: ReceiverInfo,
    /// Every registered transmitter (`TI1` replies of the search).
    pub transmitters: Vec<Transmitter>,
    /// The configured indicators (tool axes x, y, z).
    pub channels: Vec<ChannelReading>,
}

/// Name of a `TI1` transmitter state (devices.md §2).
pub fn transmitter_state_text(state: u8) -> &'static str {
    match state {
        0 => "unregistered",
        1 => "disconnected",
        2 => "connected",
        3 => "editing",
        4 => "editing source",
        5 => "editing destination",
        _ => "unknown state",
    }
}

impl UwaveIdentity {
    /// Joins the search result with the cached readings of `channels`.
    pub(crate) fn new(
        receiver: ReceiverInfo,
        transmitters: Vec<Transmitter>,
        cached: Cached,
    ) -> Self {
        let channels = cached
            .into_iter()
            .map(|(channel, r)| {
                let t = transmitters.iter().find(|t| t.channel == channel);
                ChannelReading {
                    channel,
                    transmitter_id: t.map(|t| t.id.clone()),
                    transmitter_state: t.map(|t| transmitter_state_text(t.state)),
                    value_mm: r.map(|r| r.0),
                    age_ms: r.map(|r| r.1),
                }
            })
            .collect();
        UwaveIdentity {
            receiver,
            transmitters,
            channels,
        }
    }
}

impl Identity for UwaveIdentity {
    const DEVICE_KIND: &'static str = DEVICE;

    fn fingerprint(&self) -> String {
        let t: Vec<String> = self
            .transmitters
            .iter()
            .map(|t| format!("ch{:02} {}", t.channel, t.id))
            .collect();
        format!(
            "U-WAVE-R {} group {:02}; transmitters {}",
            self.receiver.receiver_id,
            self.receiver.group,
            t.join(", ")
        )
    }

    fn summary(&self) -> String {
        let ch: Vec<String> = self
            .channels
            .iter()
            .map(|c| match (c.value_mm, c.age_ms) {
                (Some(v), Some(a)) => format!("ch{:02} {v:.3} mm ({a} ms ago)", c.channel),
                _ => format!("ch{:02} no reading", c.channel),
            })
            .collect();
        format!(
            "U-WAVE-R {} group {:02} band {}, {} transmitters; {}",
            self.receiver.receiver_id,
            self.receiver.group,
            self.receiver.band,
            self.transmitters.len(),
            ch.join(", ")
        )
    }

    fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        for c in &self.channels {
            match c.transmitter_state {
                None => p.push(format!(
                    "no transmitter registered on channel {:02}: register the indicator's \
                     U-WAVE-T on this channel (U-WAVEPAK) or fix the channel in the lab config",
                    c.channel
                )),
                Some("connected") => {}
                Some(s) => p.push(format!(
                    "transmitter on channel {:02} is {s}: check its battery and that it is in range",
                    c.channel
                )),
            }
            if c.value_mm.is_none() {
                p.push(format!(
                    "no reading from channel {:02} yet: press DATA on its U-WAVE-T or set it to event mode",
                    c.channel
                ));
            }
        }
        p
    }
}

/// Cached readings per channel: (value mm, age ms), None when there is none.
pub(super) type Cached = Vec<(u8, Option<(f64, u64)>)>;

/// Receiver-info requests waiting for the `RI1` line.
pub(super) type InfoWaiters = Vec<(Instant, Reply<ReceiverInfo>)>;

impl<C: Connect> Actor<C> {
    /// Sends `IR1000gg0` unless a request is already out, and waits for `RI1`.
    pub(super) async fn start_receiver_info(&mut self, reply: Reply<ReceiverInfo>) {
        if let Err(e) = self.reconnect().await {
            let _ = reply.send(Err(e));
            return;
        }
        if self.info_waiters.is_empty() {
            self.queue(format!("IR1000{:02}0\r", self.cfg.group).into_bytes());
        }
        self.info_waiters
            .push((Instant::now() + self.cfg.timeout, reply));
    }

    /// Answers the receiver-info waiters with an `RI1` line's text.
    pub(super) fn on_receiver_info(&mut self, raw: &str) {
        let r = ReceiverInfo::parse(raw);
        for (_, w) in self.info_waiters.drain(..) {
            let _ = w.send(match &r {
                Ok(i) => Ok(i.clone()),
                Err(e) => Err(DriverError::Protocol {
                    device: DEVICE,
                    detail: e.to_string(),
                }),
            });
        }
    }

    /// Fails the receiver-info waiters whose deadline passed (all of them when `all`).
    pub(super) fn expire_receiver_info(&mut self, now: Instant, all: Option<&DriverError>) {
        let after_ms = self.cfg.timeout.as_millis() as u64;
        let (gone, keep): (Vec<_>, Vec<_>) = self
            .info_waiters
            .drain(..)
            .partition(|(d, _)| all.is_some() || *d <= now);
        self.info_waiters = keep;
        for (_, w) in gone {
            let _ = w.send(Err(match all {
                Some(e) => e.duplicate(),
                None => DriverError::Timeout {
                    device: DEVICE,
                    what: "the RI1 receiver info line".into(),
                    after_ms,
                },
            }));
        }
    }

    /// The cached reading of each channel: (value mm, age ms), never refused as stale.
    pub(super) fn cached(&self, channels: &[u8]) -> Cached {
        channels
            .iter()
            .map(|c| {
                let r = self.cache.get(c).map(|r| {
                    (
                        r.value_mm(),
                        r.received_at
                            .elapsed()
                            .as_millis()
                            .try_into()
                            .unwrap_or(u64::MAX),
                    )
                });
                (*c, r)
            })
            .collect()
    }
}
