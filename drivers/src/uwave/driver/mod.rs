//! U-WAVE-R driver actor: parses every line into a per-channel latest-reading cache,
//! answers "latest" (with a staleness limit) and "fresh" (wait for the next reading after an
//! optional configurable request) and maps three indicators onto the tool axes. The
//! transmitter search (`IR11ccgg1` → `TI1` lines until `ST1 … 51`) is in `search`.
//!
//! A fresh reading is one produced after its request: lines already buffered on the link are
//! read and put aside before a request is sent, and with a data-request template at most one
//! request per channel is on the wire. A request that timed out still owes its reply; that
//! late reply (the receiver answers in order) is discarded, not given to the next request,
//! which is held back until the late reply came or `late_reply_grace` ran out. After
//! `reopen_after_timeouts` consecutive timeouts the port is closed and reopened.

mod identity;
mod search;
pub use identity::{ChannelReading, UwaveIdentity, transmitter_state_text};
pub use search::Transmitter;

use std::collections::{HashMap, VecDeque};
use std::time::Duration;

use futures_util::{FutureExt, SinkExt, StreamExt};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use super::codec::{ReceiverInfo, Unit, UwaveCodec, UwaveLine};
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
    /// Close and reopen the link after this many consecutive timed-out readings (any
    /// channel) with no line received in between (0 = never).
    pub reopen_after_timeouts: u32,
    /// With a request template: how long a timed-out request's reply is still expected
    /// (and discarded when it comes); the next request on that channel waits for it.
    pub late_reply_grace: Duration,
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
            reopen_after_timeouts: 3,
            late_reply_grace: Duration::from_secs(2),
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
    /// Reading timeouts since the last line received.
    pub consecutive_timeouts: u32,
    /// Times the link was closed and reopened after `reopen_after_timeouts` timeouts.
    pub reopens: u64,
    /// Late replies to timed-out requests that were discarded.
    pub late_replies_discarded: u64,
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
            // Bytes the OS buffered before this open are not fresh readings.
            {
                use tokio_serial::SerialPort;
                if let Err(e) = s.clear(tokio_serial::ClearBuffer::Input) {
                    tracing::debug!(device = DEVICE, error = %e, "cannot clear the input buffer");
                }
            }
            Ok(Tee::new(
                s,
                self.recorder.as_ref().map(Recorder::connection),
                Side::Client,
            ))
        })
    }
}

enum Request {
    Latest(u8, Reply<Reading>),
    Fresh(u8, Reply<Reading>),
    Search(Reply<Vec<Transmitter>>),
    ReceiverInfo(Reply<ReceiverInfo>),
    Cached(Vec<u8>, Reply<identity::Cached>),
}

struct Waiter {
    channel: u8,
    deadline: Instant,
    reply: Reply<Reading>,
}

/// A `Fresh` request not sent yet because its channel is busy (request mode).
struct Held {
    channel: u8,
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
            Request::ReceiverInfo(_) => write!(f, "ReceiverInfo"),
            Request::Cached(c, _) => write!(f, "Cached({c:?})"),
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
            link: Link::new(DEVICE, connector, UwaveCodec::default(), cfg.backoff),
            cfg,
            rx,
            state: stx,
            cache: HashMap::new(),
            waiters: Vec::new(),
            held: VecDeque::new(),
            owed: HashMap::new(),
            timeouts: 0,
            reopen_due: false,
            search: None,
            info_waiters: Vec::new(),
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

    /// Receiver info: sends `IR1000gg0` and parses the `RI1` reply.
    pub async fn receiver_info(&self) -> Result<ReceiverInfo, DriverError> {
        call(&self.tx, DEVICE, Request::ReceiverInfo).await
    }

    /// Receiver info, the registered transmitters and the latest cached reading (with its
    /// age, never refused as stale) of each configured indicator ([`UwaveConfig::axes`]).
    pub async fn identity(&self) -> Result<UwaveIdentity, DriverError> {
        let receiver = self.receiver_info().await?;
        let transmitters = self.transmitters().await?;
        let channels: Vec<u8> = self.axes.iter().map(|a| a.channel).collect();
        let cached = call(&self.tx, DEVICE, |r| Request::Cached(channels, r)).await?;
        Ok(UwaveIdentity::new(receiver, transmitters, cached))
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
    /// Fresh requests waiting for their channel to be free (request mode).
    held: VecDeque<Held>,
    /// Channels whose last request timed out and still owes its reply, until the grace ends.
    owed: HashMap<u8, Instant>,
    /// Consecutive reading timeouts with no line received.
    timeouts: u32,
    /// Reopen the link at the end of this turn.
    reopen_due: bool,
    /// A transmitter search in progress.
    search: Option<search::Search>,
    /// Receiver-info requests waiting for `RI1`.
    info_waiters: identity::InfoWaiters,
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
                .chain(self.info_waiters.iter().map(|w| w.0))
                .chain(self.owed.values().copied())
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
            if self.reopen_due {
                self.reopen_due = false;
                self.reopen().await;
            }
            self.dispatch_held().await;
        }
    }

    /// With a request template, one request per channel is on the wire at a time.
    fn busy(&self, ch: u8) -> bool {
        !self.cfg.request_template.is_empty()
            && (self.owed.contains_key(&ch) || self.waiters.iter().any(|w| w.channel == ch))
    }

    /// Sends the held requests whose channel became free.
    async fn dispatch_held(&mut self) {
        let mut i = 0;
        while i < self.held.len() {
            if self.busy(self.held[i].channel) {
                i += 1;
                continue;
            }
            let Some(h) = self.held.remove(i) else { break };
            self.send_request(h.channel, h.reply).await;
        }
    }

    /// Reads and applies every line already buffered on the link, so that none of them can
    /// be taken as the answer to a request sent after this.
    fn drain_buffered(&mut self) {
        for _ in 0..4096 {
            let Some(f) = self.link.current() else { return };
            match f.next().now_or_never() {
                Some(line) => {
                    if let Some(Ok(l)) = &line {
                        tracing::debug!(device = DEVICE, line = ?l, "buffered before the request");
                    }
                    self.on_line(line);
                }
                None => return,
            }
        }
    }

    /// Closes the link after too many consecutive timeouts and opens it again.
    async fn reopen(&mut self) {
        let n = self.timeouts;
        tracing::warn!(
            device = DEVICE,
            timeouts = n,
            "no reply: reopening the link"
        );
        self.drop_link(&DriverError::Timeout {
            device: DEVICE,
            what: format!("{n} consecutive readings; reopening the link"),
            after_ms: self.cfg.timeout.as_millis() as u64,
        });
        self.timeouts = 0;
        self.state.send_modify(|s| {
            s.reopens += 1;
            s.consecutive_timeouts = 0;
        });
        if let Err(e) = self.reconnect().await {
            tracing::warn!(device = DEVICE, error = %e, "reopen failed");
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
            Request::ReceiverInfo(reply) => self.start_receiver_info(reply).await,
            Request::Cached(channels, reply) => {
                let _ = reply.send(Ok(self.cached(&channels)));
            }
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
                self.drain_buffered();
                if self.busy(ch) || self.held.iter().any(|h| h.channel == ch) {
                    self.held.push_back(Held { channel: ch, reply });
                    return;
                }
                self.send_request(ch, reply).await;
            }
        }
    }

    /// Sends the data request of `ch` (if configured) and waits for its reading.
    async fn send_request(&mut self, ch: u8, reply: Reply<Reading>) {
        if let Err(e) = self.reconnect().await {
            let _ = reply.send(Err(e));
            return;
        }
        self.drain_buffered();
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

    fn on_line(&mut self, line: Option<Result<UwaveLine, crate::error::CodecError>>) {
        match line {
            None => self.drop_link(&DriverError::Closed { device: DEVICE }),
            Some(Err(e)) => {
                let e = DriverError::from_codec(DEVICE, e);
                self.drop_link(&e)
            }
            Some(Ok(l)) => {
                self.timeouts = 0;
                self.state.send_modify(|s| {
                    s.lines += 1;
                    s.consecutive_timeouts = 0;
                });
                self.apply(l)
            }
        }
    }

    fn apply(&mut self, line: UwaveLine) {
        if self.on_search_line(&line) {
            return;
        }
        // The receiver answers requests in order: the first line on a channel whose request
        // timed out is that request's late reply.
        let late = match &line {
            UwaveLine::Data { channel, .. }
            | UwaveLine::Status {
                channel: Some(channel),
                ..
            } => self.owed.remove(channel).is_some(),
            _ => false,
        };
        if late {
            tracing::info!(device = DEVICE, line = ?line, "discarding a late reply to a timed-out request");
            self.state.send_modify(|s| s.late_replies_discarded += 1);
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
            UwaveLine::ReceiverInfo { raw } => self.on_receiver_info(&raw),
            UwaveLine::TransmitterInfo { .. } => {}
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
        self.expire_receiver_info(Instant::now(), Some(e));
        self.link.reset();
        // Replies owed on the old link will not come on a new one.
        self.owed.clear();
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
        self.expire_receiver_info(now, None);
        self.owed.retain(|ch, until| {
            let keep = *until > now;
            if !keep {
                tracing::debug!(device = DEVICE, channel = *ch, "late reply never came");
            }
            keep
        });
        let timed_out: Vec<u8> = self
            .waiters
            .iter()
            .filter(|w| w.deadline <= now)
            .map(|w| w.channel)
            .collect();
        if !timed_out.is_empty() {
            if !self.cfg.request_template.is_empty() {
                let until = now + self.cfg.late_reply_grace;
                for ch in &timed_out {
                    self.owed.insert(*ch, until);
                }
            }
            // Every timed-out reading counts (a stalled tool-axes read is three).
            let k = u32::try_from(timed_out.len()).unwrap_or(u32::MAX);
            self.timeouts = self.timeouts.saturating_add(k);
            let n = self.timeouts;
            self.state.send_modify(|s| s.consecutive_timeouts = n);
            let limit = self.cfg.reopen_after_timeouts;
            if limit > 0 && n >= limit && self.link.can_reopen() {
                self.reopen_due = true;
            }
        }
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
