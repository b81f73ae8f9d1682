//! U-WAVE-R driver actor: parses every line into a per-channel latest-reading cache,
//! answers "latest" (with a staleness limit) and "fresh" (wait for the next reading after an
//! optional configurable request) and maps three indicators onto the tool axes. The
//! transmitter search (`IR11ccgg1` → `TI1` lines until `ST1 … 51`) is in `search`.

mod search;
pub use search::Transmitter;

use std::collections::HashMap;
use std::time::Duration;

use futures_util::SinkExt;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use super::codec::{Unit, UwaveCodec, UwaveLine};
use crate::actor::{Reply, call, next_or_pending};
use crate::error::DriverError;
use crate::link::{Backoff, BoxFuture, Connect, Link, Once};
use crate::tee::{Side, Tee};
use crate::transcript::Recorder;

const DEVICE: &str = "uwave";

/// One indicator's mapping onto a tool axis: `axis_mm = sign * (reading_mm - zero_mm)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisMap {
    /// U-WAVE channel of the indicator.
    pub channel: u8,
    /// +1 or -1: direction of the plunger relative to the tool axis.
    pub sign: f64,
    /// Reading (mm) that corresponds to the axis zero.
    pub zero_mm: f64,
}

/// Driver configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct UwaveConfig {
    /// Receiver group (00 until known).
    pub group: u8,
    /// Data-request template sent before waiting for a fresh reading; `{cc}` and `{gg}` are
    /// replaced by channel and group, a CR is appended. Empty = wait for the next
    /// spontaneous `DT` (button/event mode). UNVERIFIED on real hardware (devices.md §2).
    pub request_template: String,
    /// How long to wait for a fresh reading.
    pub timeout: Duration,
    /// Cached readings older than this are refused.
    pub staleness: Duration,
    /// The three indicators, in tool axis order x, y, z.
    pub axes: [AxisMap; 3],
    /// Reconnection back-off.
    pub backoff: Backoff,
}

impl Default for UwaveConfig {
    fn default() -> Self {
        let ax = |c| AxisMap {
            channel: c,
            sign: 1.0,
            zero_mm: 0.0,
        };
        UwaveConfig {
            group: 0,
            request_template: String::new(),
            timeout: Duration::from_secs(3),
            staleness: Duration::from_millis(500),
            axes: [ax(0), ax(1), ax(2)],
            backoff: Backoff::default(),
        }
    }
}

/// One measurement from one indicator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Channel it came from.
    pub channel: u8,
    /// Value in `unit`.
    pub value: f64,
    /// Unit as sent by the receiver.
    pub unit: Unit,
    /// When the line was parsed.
    pub received_at: Instant,
}

impl Reading {
    /// The value converted to millimetres.
    pub fn value_mm(&self) -> f64 {
        self.value * self.unit.to_mm()
    }
}

/// Link state published on the watch channel.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UwaveState {
    /// True while the port is open.
    pub connected: bool,
    /// Successful (re)connections.
    pub connects: u64,
    /// Lines parsed.
    pub lines: u64,
    /// Last error seen on the link, if any.
    pub last_error: Option<String>,
}

/// Opens a serial port at 57600 8N1 (or a pty slave in tests).
#[derive(Debug, Clone)]
pub struct SerialConnector {
    /// Port path, e.g. `/dev/ttyUSB0`.
    pub path: String,
    /// Baud rate (57600 for the U-WAVE-R).
    pub baud: u32,
    /// Optional traffic recorder.
    pub recorder: Option<Recorder>,
}

impl Connect for SerialConnector {
    type Io = Tee<tokio_serial::SerialStream>;
    fn connect(&mut self) -> BoxFuture<'_, std::io::Result<Self::Io>> {
        Box::pin(async move {
            use tokio_serial::SerialPortBuilderExt;
            let s = tokio_serial::new(&self.path, self.baud)
                .data_bits(tokio_serial::DataBits::Eight)
                .parity(tokio_serial::Parity::None)
                .stop_bits(tokio_serial::StopBits::One)
                .flow_control(tokio_serial::FlowControl::None)
                .open_native_async()
                .map_err(std::io::Error::other)?;
            Ok(Tee::new(s, self.recorder.clone(), Side::Client))
        })
    }
}

enum Request {
    Latest(u8, Reply<Reading>),
    Fresh(u8, Reply<Reading>),
    Search(Reply<Vec<Transmitter>>),
}

struct Waiter {
    channel: u8,
    deadline: Instant,
    reply: Reply<Reading>,
}

/// Cheap, cloneable handle to the U-WAVE actor.
#[derive(Debug, Clone)]
pub struct UwaveHandle {
    tx: mpsc::Sender<Request>,
    state: watch::Receiver<UwaveState>,
    axes: [AxisMap; 3],
}

impl std::fmt::Debug for Request {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Request::Latest(c, _) => write!(f, "Latest({c})"),
            Request::Fresh(c, _) => write!(f, "Fresh({c})"),
            Request::Search(_) => write!(f, "Search"),
        }
    }
}

impl UwaveHandle {
    /// Starts the actor on an already-open transport (no reconnection possible).
    pub fn attach<T>(io: T, cfg: UwaveConfig) -> Self
    where
        T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
    {
        Self::connect(Once::new(io), cfg)
    }

    /// Starts the actor with a connector; it reconnects with back-off when the link drops.
    pub fn connect<C: Connect>(connector: C, cfg: UwaveConfig) -> Self {
        let (tx, rx) = mpsc::channel(32);
        let (stx, srx) = watch::channel(UwaveState::default());
        let axes = cfg.axes;
        let actor = Actor {
            link: Link::new(DEVICE, connector, UwaveCodec, cfg.backoff),
            cfg,
            rx,
            state: stx,
            cache: HashMap::new(),
            waiters: Vec::new(),
            search: None,
            to_send: None,
        };
        tokio::spawn(actor.run());
        UwaveHandle {
            tx,
            state: srx,
            axes,
        }
    }

    /// The latest cached reading of `channel`, refused when older than the staleness limit.
    pub async fn latest(&self, channel: u8) -> Result<Reading, DriverError> {
        call(&self.tx, DEVICE, |r| Request::Latest(channel, r)).await
    }

    /// Sends the configured request (if any) and waits for the next reading of `channel`.
    pub async fn fresh(&self, channel: u8) -> Result<Reading, DriverError> {
        call(&self.tx, DEVICE, |r| Request::Fresh(channel, r)).await
    }

    /// Fresh readings of the three indicators mapped to tool axes x, y, z (mm).
    pub async fn tool_axes_mm(&self) -> Result<[f64; 3], DriverError> {
        let [a, b, c] = self.axes;
        let (ra, rb, rc) = tokio::join!(
            self.fresh(a.channel),
            self.fresh(b.channel),
            self.fresh(c.channel)
        );
        let m = |m: AxisMap, r: Reading| m.sign * (r.value_mm() - m.zero_mm);
        Ok([m(a, ra?), m(b, rb?), m(c, rc?)])
    }

    /// Lists the registered transmitters (`IR11ccgg1` scan until end of search).
    pub async fn transmitters(&self) -> Result<Vec<Transmitter>, DriverError> {
        call(&self.tx, DEVICE, Request::Search).await
    }

    /// Watch channel with the link state.
    pub fn state(&self) -> watch::Receiver<UwaveState> {
        self.state.clone()
    }
}

struct Actor<C: Connect> {
    link: Link<C, UwaveCodec>,
    cfg: UwaveConfig,
    rx: mpsc::Receiver<Request>,
    state: watch::Sender<UwaveState>,
    cache: HashMap<u8, Reading>,
    waiters: Vec<Waiter>,
    /// A transmitter search in progress.
    search: Option<search::Search>,
    /// Request bytes to send after handling a line (next search step).
    to_send: Option<Vec<u8>>,
}

impl<C: Connect> Actor<C> {
    async fn run(mut self) {
        self.reconnect().await.ok();
        loop {
            let deadline = self
                .waiters
                .iter()
                .map(|w| w.deadline)
                .chain(self.search.as_ref().map(|s| s.deadline))
                .min()
                .unwrap_or_else(|| Instant::now() + Duration::from_secs(3600));
            tokio::select! {
                req = self.rx.recv() => match req {
                    Some(r) => self.handle(r).await,
                    None => break,
                },
                line = next_or_pending(self.link.current()) => self.on_line(line),
                _ = tokio::time::sleep_until(deadline) => self.expire(),
            }
            self.flush().await;
        }
    }

    async fn reconnect(&mut self) -> Result<(), DriverError> {
        let r = self.link.ensure().await.map(|_| ());
        let connects = self.link.connects;
        let connected = self.link.is_up();
        self.state.send_modify(|s| {
            s.connected = connected;
            s.connects = connects;
            if let Err(e) = &r {
                s.last_error = Some(e.to_string());
            }
        });
        r
    }

    async fn handle(&mut self, req: Request) {
        match req {
            Request::Search(reply) => self.start_search(reply).await,
            Request::Latest(ch, reply) => {
                let limit = self.cfg.staleness;
                let r = match self.cache.get(&ch) {
                    Some(r) if r.received_at.elapsed() <= limit => Ok(*r),
                    _ => Err(DriverError::Stale {
                        device: DEVICE,
                        channel: ch,
                        limit_ms: limit.as_millis() as u64,
                    }),
                };
                let _ = reply.send(r);
            }
            Request::Fresh(ch, reply) => {
                if let Err(e) = self.reconnect().await {
                    let _ = reply.send(Err(e));
                    return;
                }
                if !self.cfg.request_template.is_empty() {
                    let mut bytes = self
                        .cfg
                        .request_template
                        .replace("{cc}", &format!("{ch:02}"))
                        .replace("{gg}", &format!("{:02}", self.cfg.group))
                        .into_bytes();
                    bytes.push(b'\r');
                    let sent = match self.link.current() {
                        Some(f) => f.send(bytes).await,
                        None => Ok(()),
                    };
                    if let Err(e) = sent {
                        let e = DriverError::from_codec(DEVICE, e);
                        self.drop_link(&e);
                        let _ = reply.send(Err(e));
                        return;
                    }
                }
                self.waiters.push(Waiter {
                    channel: ch,
                    deadline: Instant::now() + self.cfg.timeout,
                    reply,
                });
            }
        }
    }

    fn on_line(&mut self, line: Option<Result<UwaveLine, crate::error::CodecError>>) {
        match line {
            None => self.drop_link(&DriverError::Closed { device: DEVICE }),
            Some(Err(e)) => {
                let e = DriverError::from_codec(DEVICE, e);
                self.drop_link(&e)
            }
            Some(Ok(l)) => {
                self.state.send_modify(|s| s.lines += 1);
                self.apply(l)
            }
        }
    }

    fn apply(&mut self, line: UwaveLine) {
        if self.on_search_line(&line) {
            return;
        }
        match line {
            UwaveLine::Data {
                channel,
                value,
                unit,
                ..
            } => {
                let r = Reading {
                    channel,
                    value,
                    unit,
                    received_at: Instant::now(),
                };
                self.cache.insert(channel, r);
                self.fail_where(|w| w.channel == channel, |_| Ok(r));
            }
            // 51 = end of an info scan (normal); 99 = the last value was retracted.
            UwaveLine::Status { code: 51, .. } => {}
            UwaveLine::Status {
                code: 99,
                channel: Some(c),
                ..
            } => {
                self.cache.remove(&c);
            }
            UwaveLine::Status { channel, code, .. } => {
                let err = |c: u8| DriverError::Device {
                    device: DEVICE,
                    code: i64::from(code),
                    message: format!("{} (channel {c})", status_text(code)),
                };
                match channel {
                    Some(c) => self.fail_where(|w| w.channel == c, |c| Err(err(c))),
                    None => self.fail_where(|_| true, |c| Err(err(c))),
                }
            }
            UwaveLine::TransmitterInfo { .. } | UwaveLine::ReceiverInfo { .. } => {}
        }
    }

    fn fail_where(
        &mut self,
        pick: impl Fn(&Waiter) -> bool,
        result: impl Fn(u8) -> Result<Reading, DriverError>,
    ) {
        let (hit, keep): (Vec<_>, Vec<_>) = self.waiters.drain(..).partition(|w| pick(w));
        self.waiters = keep;
        for w in hit {
            let _ = w.reply.send(result(w.channel));
        }
    }

    fn drop_link(&mut self, e: &DriverError) {
        tracing::warn!(device = DEVICE, error = %e, "link dropped");
        self.fail_search(e.duplicate());
        self.link.reset();
        self.state.send_modify(|s| {
            s.connected = false;
            s.last_error = Some(e.to_string());
        });
        let msg = e.to_string();
        let is_protocol = matches!(e, DriverError::Protocol { .. });
        self.fail_where(
            |_| true,
            |_| {
                Err(if is_protocol {
                    DriverError::Protocol {
                        device: DEVICE,
                        detail: msg.clone(),
                    }
                } else {
                    DriverError::Closed { device: DEVICE }
                })
            },
        );
    }

    fn expire(&mut self) {
        let now = Instant::now();
        self.expire_search(now);
        let after_ms = self.cfg.timeout.as_millis() as u64;
        self.fail_where(
            |w| w.deadline <= now,
            |c| {
                Err(DriverError::Timeout {
                    device: DEVICE,
                    what: format!("a reading on channel {c}"),
                    after_ms,
                })
            },
        );
    }
}

/// Meaning of a U-WAVE status code (devices.md §2).
pub fn status_text(code: u8) -> &'static str {
    match code {
        0 => "battery low",
        1 => "instrument not responding",
        2 => "unregistered transmitter",
        3 => "measurement data loss",
        4 => "transmitter disconnected",
        5 => "no data",
        50 => "request packet error",
        51 => "end of search",
        99 => "data cancel",
        _ => "unknown status code",
    }
}
