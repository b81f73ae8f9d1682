//! QTM RT driver actor: negotiates the protocol version, answers commands FIFO (skipping
//! events), parses the 3D parameters, streams frames over TCP or UDP to a broadcast channel
//! with frame-number gap accounting, and resumes the stream after a reconnect.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio::net::UdpSocket;
use tokio::sync::{broadcast, mpsc, watch};
use tokio::time::Instant;

use super::codec::QtmCodec;
use super::identity::{QtmIdentity, after};
use super::packet::{self, DataFrame, Packet};
use super::params::{Settings3d, SettingsGeneral, parse_3d, parse_general};
use crate::actor::{Reply, call, next_or_pending};
use crate::error::{CodecError, DriverError};
use crate::link::{Connect, Link, Once};

pub use super::state::{QtmConfig, QtmState, StreamTransport};

const DEVICE: &str = "qtm";
const WELCOME: &str = "QTM RT Interface connected";

enum Request {
    Command(String, Reply<String>),
    State(Reply<u8>),
    Params3d(Reply<Settings3d>),
    ParamsGeneral(Reply<SettingsGeneral>),
    Stream(String, StreamTransport, Reply<()>),
    Stop(Reply<()>),
}

impl std::fmt::Debug for Request {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Request::Command(c, _) => write!(f, "Command({c:?})"),
            Request::State(_) => write!(f, "State"),
            Request::Params3d(_) => write!(f, "Params3d"),
            Request::ParamsGeneral(_) => write!(f, "ParamsGeneral"),
            Request::Stream(c, t, _) => write!(f, "Stream({c:?}, {t:?})"),
            Request::Stop(_) => write!(f, "Stop"),
        }
    }
}

enum Pending {
    Text(Reply<String>),
    Event(Reply<u8>),
    Xml(Reply<Settings3d>),
    General(Reply<SettingsGeneral>),
}

impl Pending {
    fn fail(self, e: DriverError) {
        match self {
            Pending::Text(r) => drop(r.send(Err(e))),
            Pending::Event(r) => drop(r.send(Err(e))),
            Pending::Xml(r) => drop(r.send(Err(e))),
            Pending::General(r) => drop(r.send(Err(e))),
        }
    }
}

/// Cheap, cloneable handle to the QTM actor.
#[derive(Debug, Clone)]
pub struct QtmHandle {
    tx: mpsc::Sender<Request>,
    state: watch::Receiver<QtmState>,
    frames: broadcast::Sender<Arc<DataFrame>>,
}

impl QtmHandle {
    /// Starts the actor on an open transport (no reconnection).
    pub fn attach<T>(io: T, cfg: QtmConfig) -> Self
    where
        T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
    {
        Self::connect(Once::new(io), cfg)
    }

    /// Starts the actor with a connector (reconnects with back-off).
    pub fn connect<C: Connect>(connector: C, cfg: QtmConfig) -> Self {
        let (tx, rx) = mpsc::channel(32);
        let (stx, srx) = watch::channel(QtmState::default());
        let (ftx, _) = broadcast::channel(cfg.frame_buffer.max(16));
        let actor = Actor {
            link: Link::new(DEVICE, connector, QtmCodec, cfg.backoff),
            cfg,
            rx,
            state: stx,
            frames: ftx.clone(),
            pending: VecDeque::new(),
            stream: None,
            udp: None,
        };
        tokio::spawn(actor.run());
        QtmHandle {
            tx,
            state: srx,
            frames: ftx,
        }
    }

    /// Sends a raw command and returns the text reply (a QTM error packet is a device error).
    pub async fn command(&self, cmd: &str) -> Result<String, DriverError> {
        call(&self.tx, DEVICE, |r| Request::Command(cmd.to_string(), r)).await
    }

    /// `GetState`: the current state as an event id.
    pub async fn get_state(&self) -> Result<u8, DriverError> {
        call(&self.tx, DEVICE, Request::State).await
    }

    /// `GetParameters 3D`: labels and axis convention.
    pub async fn parameters_3d(&self) -> Result<Settings3d, DriverError> {
        call(&self.tx, DEVICE, Request::Params3d).await
    }

    /// `GetParameters General`: the capture frequency (`General/Frequency`).
    pub async fn parameters_general(&self) -> Result<SettingsGeneral, DriverError> {
        call(&self.tx, DEVICE, Request::ParamsGeneral).await
    }

    /// RT protocol version (`Version`), QTM version (`QTMVersion`), capture frequency
    /// (`GetParameters General`) and labelled markers (`GetParameters 3D`).
    pub async fn identity(&self) -> Result<QtmIdentity, DriverError> {
        let protocol_version = after(&self.command("Version").await?, "Version is ", DEVICE)?;
        let qtm_version = after(
            &self.command("QTMVersion").await?,
            "QTM Version is ",
            DEVICE,
        )?;
        let general = self.parameters_general().await?;
        let s3d = self.parameters_3d().await?;
        Ok(QtmIdentity {
            protocol_version,
            qtm_version,
            frequency_hz: general.frequency_hz,
            axis_upwards: s3d.axis_upwards,
            labelled_marker_count: s3d.labels.len(),
            labels: s3d.labels,
        })
    }

    /// Starts `StreamFrames AllFrames <components>` (e.g. `"3D"`, `"3D 3DNoLabels"`); frames
    /// arrive on [`QtmHandle::frames`] (subscribe first).
    pub async fn stream(&self, components: &str, t: StreamTransport) -> Result<(), DriverError> {
        call(&self.tx, DEVICE, |r| {
            Request::Stream(components.to_string(), t, r)
        })
        .await
    }

    /// `StreamFrames Stop`.
    pub async fn stop_stream(&self) -> Result<(), DriverError> {
        call(&self.tx, DEVICE, Request::Stop).await
    }

    /// A new subscription to streamed frames.
    pub fn frames(&self) -> broadcast::Receiver<Arc<DataFrame>> {
        self.frames.subscribe()
    }

    /// Watch channel with link and stream state.
    pub fn state(&self) -> watch::Receiver<QtmState> {
        self.state.clone()
    }
}

struct Actor<C: Connect> {
    link: Link<C, QtmCodec>,
    cfg: QtmConfig,
    rx: mpsc::Receiver<Request>,
    state: watch::Sender<QtmState>,
    frames: broadcast::Sender<Arc<DataFrame>>,
    pending: VecDeque<(Instant, Pending)>,
    /// Stream command and transport to resume after a reconnect.
    stream: Option<(String, StreamTransport)>,
    udp: Option<UdpSocket>,
}

async fn recv_udp(s: Option<&UdpSocket>, buf: &mut [u8]) -> std::io::Result<usize> {
    match s {
        Some(s) => s.recv(buf).await,
        None => std::future::pending().await,
    }
}

impl<C: Connect> Actor<C> {
    async fn run(mut self) {
        let mut buf = vec![0u8; 65536];
        loop {
            let deadline = self
                .pending
                .front()
                .map_or_else(|| Instant::now() + Duration::from_secs(3600), |p| p.0);
            tokio::select! {
                req = self.rx.recv() => match req {
                    Some(r) => self.handle(r).await,
                    None => break,
                },
                p = next_or_pending(self.link.current()) => self.on_packet(p),
                n = recv_udp(self.udp.as_ref(), &mut buf) => {
                    if let Ok(n) = n {
                        if let Some(r) = &self.cfg.udp_recorder {
                            r.record(crate::transcript::Direction::FromDevice, &buf[..n], true);
                        }
                        match packet::decode_whole(&buf[..n]) {
                            Ok(Packet::Data(f)) => self.on_frame(f),
                            Ok(_) => {}
                            Err(e) => self.state.send_modify(|s| s.last_error = Some(e.to_string())),
                        }
                    }
                }
                _ = tokio::time::sleep_until(deadline) => {
                    let after_ms = self.cfg.timeout.as_millis() as u64;
                    self.drop_link(DriverError::Timeout { device: DEVICE, what: "a reply".into(), after_ms });
                }
            }
            if self.stream.is_some() && !self.link.is_up() {
                self.resume().await;
            }
        }
    }

    /// Connects and negotiates if needed.
    async fn ready(&mut self) -> Result<(), DriverError> {
        let fresh = match self.link.ensure().await {
            Ok((_, fresh)) => fresh,
            Err(e) => {
                self.state
                    .send_modify(|s| s.last_error = Some(e.to_string()));
                return Err(e);
            }
        };
        if fresh {
            let timeout = self.cfg.timeout;
            let r = tokio::time::timeout(timeout, self.handshake())
                .await
                .unwrap_or(Err(DriverError::Timeout {
                    device: DEVICE,
                    what: "welcome and version reply".into(),
                    after_ms: timeout.as_millis() as u64,
                }));
            if let Err(e) = r {
                self.link.reset();
                self.state.send_modify(|s| {
                    s.connected = false;
                    s.last_error = Some(e.to_string());
                });
                return Err(e);
            }
        }
        Ok(())
    }

    async fn handshake(&mut self) -> Result<(), DriverError> {
        let (maj, min) = self.cfg.version;
        let Some(f) = self.link.current() else {
            return Err(DriverError::Closed { device: DEVICE });
        };
        let next_text = async |f: &mut tokio_util::codec::Framed<C::Io, QtmCodec>| loop {
            match f.next().await {
                None => return Err(DriverError::Closed { device: DEVICE }),
                Some(Err(e)) => return Err(DriverError::from_codec(DEVICE, e)),
                Some(Ok(Packet::Command(s))) => return Ok(Ok(s)),
                Some(Ok(Packet::Error(s))) => return Ok(Err(s)),
                Some(Ok(_)) => {}
            }
        };
        match next_text(f).await? {
            Ok(s) if s == WELCOME => {}
            other => {
                return Err(DriverError::Protocol {
                    device: DEVICE,
                    detail: format!("expected welcome {WELCOME:?}, got {other:?}"),
                });
            }
        }
        // Negotiate down from the configured version to the oldest acceptable one.
        let (min_maj, min_min) = self.cfg.min_version;
        let mut minor = min;
        loop {
            f.send(Packet::Command(format!("Version {maj}.{minor}")))
                .await
                .map_err(|e| DriverError::from_codec(DEVICE, e))?;
            match next_text(f).await? {
                Ok(s) if s == format!("Version set to {maj}.{minor}") => break,
                Ok(s) => {
                    return Err(DriverError::Protocol {
                        device: DEVICE,
                        detail: format!("unexpected version reply {s:?}"),
                    });
                }
                Err(s) if maj == min_maj && minor > min_min => {
                    tracing::debug!(device = DEVICE, version = %format!("{maj}.{minor}"), reply = %s, "version refused, trying older");
                    minor -= 1;
                }
                Err(s) => return Err(device_error(s)),
            }
        }
        let min = minor;
        let connects = self.link.connects;
        self.state.send_modify(|s| {
            s.connected = true;
            s.connects = connects;
            s.version = Some((maj, min));
        });
        Ok(())
    }

    async fn send(&mut self, cmd: String) -> Result<(), DriverError> {
        self.ready().await?;
        let r = match self.link.current() {
            Some(f) => f
                .send(Packet::Command(cmd))
                .await
                .map_err(|e| DriverError::from_codec(DEVICE, e)),
            None => Err(DriverError::Closed { device: DEVICE }),
        };
        if let Err(e) = &r {
            self.drop_link(e.duplicate());
        }
        r
    }

    async fn handle(&mut self, req: Request) {
        let deadline = Instant::now() + self.cfg.timeout;
        match req {
            Request::Command(c, r) => match self.send(c).await {
                Ok(()) => self.pending.push_back((deadline, Pending::Text(r))),
                Err(e) => drop(r.send(Err(e))),
            },
            Request::State(r) => match self.send("GetState".into()).await {
                Ok(()) => self.pending.push_back((deadline, Pending::Event(r))),
                Err(e) => drop(r.send(Err(e))),
            },
            Request::Params3d(r) => match self.send("GetParameters 3D".into()).await {
                Ok(()) => self.pending.push_back((deadline, Pending::Xml(r))),
                Err(e) => drop(r.send(Err(e))),
            },
            Request::ParamsGeneral(r) => match self.send("GetParameters General".into()).await {
                Ok(()) => self.pending.push_back((deadline, Pending::General(r))),
                Err(e) => drop(r.send(Err(e))),
            },
            Request::Stream(comps, t, r) => {
                let res = self.start_stream(&comps, t).await;
                if res.is_ok() {
                    self.stream = Some((comps, t));
                    self.state.send_modify(|s| s.streaming = true);
                }
                let _ = r.send(res);
            }
            Request::Stop(r) => {
                self.stream = None;
                self.state.send_modify(|s| s.streaming = false);
                let res = self.send("StreamFrames Stop".into()).await;
                self.udp = None;
                let _ = r.send(res);
            }
        }
    }

    async fn start_stream(&mut self, comps: &str, t: StreamTransport) -> Result<(), DriverError> {
        let cmd = match t {
            StreamTransport::Tcp => format!("StreamFrames AllFrames {comps}"),
            StreamTransport::Udp => {
                if self.udp.is_none() {
                    let s = UdpSocket::bind(&self.cfg.udp_bind)
                        .await
                        .map_err(|source| DriverError::Transport {
                            device: DEVICE,
                            source,
                        })?;
                    self.udp = Some(s);
                }
                let port = self
                    .udp
                    .as_ref()
                    .and_then(|s| s.local_addr().ok())
                    .map_or(0, |a| a.port());
                format!("StreamFrames AllFrames UDP:{port} {comps}")
            }
        };
        self.send(cmd).await
    }

    async fn resume(&mut self) {
        let Some((comps, t)) = self.stream.clone() else {
            return;
        };
        if let Err(e) = self.start_stream(&comps, t).await {
            tracing::warn!(device = DEVICE, error = %e, "could not resume the stream");
            self.stream = None;
            self.state.send_modify(|s| {
                s.streaming = false;
                s.last_error = Some(e.to_string());
            });
        }
    }

    fn on_frame(&mut self, f: DataFrame) {
        let n = f.frame_number;
        self.state.send_modify(|s| {
            s.frames += 1;
            if let Some(l) = s.last_frame_number
                && n > l.wrapping_add(1)
                && n > l
            {
                s.missed_frames += u64::from(n - l - 1);
            }
            s.last_frame_number = Some(n);
        });
        let _ = self.frames.send(Arc::new(f));
    }

    fn on_packet(&mut self, p: Option<Result<Packet, CodecError>>) {
        let p = match p {
            None => return self.drop_link(DriverError::Closed { device: DEVICE }),
            Some(Err(e)) => return self.drop_link(DriverError::from_codec(DEVICE, e)),
            Some(Ok(p)) => p,
        };
        match p {
            Packet::Data(f) => self.on_frame(f),
            Packet::NoMoreData => self.state.send_modify(|s| s.no_data += 1),
            Packet::Event(e) => {
                self.state.send_modify(|s| s.last_event = Some(e));
                if matches!(self.pending.front(), Some((_, Pending::Event(_))))
                    && let Some((_, Pending::Event(r))) = self.pending.pop_front()
                {
                    let _ = r.send(Ok(e));
                }
            }
            Packet::Command(s) => match self.pending.pop_front() {
                Some((_, Pending::Text(r))) => drop(r.send(Ok(s))),
                Some((_, other)) => other.fail(protocol(format!("unexpected command reply {s:?}"))),
                None => tracing::debug!(device = DEVICE, reply = %s, "unsolicited reply"),
            },
            Packet::Xml(x) => match self.pending.pop_front() {
                Some((_, Pending::Xml(r))) => {
                    let _ = r.send(parse_3d(&x).map_err(|e| DriverError::from_codec(DEVICE, e)));
                }
                Some((_, Pending::General(r))) => {
                    let _ =
                        r.send(parse_general(&x).map_err(|e| DriverError::from_codec(DEVICE, e)));
                }
                Some((_, other)) => other.fail(protocol("unexpected XML reply".into())),
                None => {}
            },
            Packet::Error(s) => match self.pending.pop_front() {
                Some((_, p)) => p.fail(device_error(s)),
                None => self.state.send_modify(|st| st.last_error = Some(s)),
            },
            Packet::Other { .. } => {}
        }
    }

    fn drop_link(&mut self, e: DriverError) {
        tracing::warn!(device = DEVICE, error = %e, "link dropped");
        self.link.reset();
        self.state.send_modify(|s| {
            s.connected = false;
            s.last_error = Some(e.to_string());
        });
        for (_, p) in self.pending.drain(..) {
            p.fail(e.duplicate());
        }
    }
}

fn protocol(detail: String) -> DriverError {
    DriverError::Protocol {
        device: DEVICE,
        detail,
    }
}

fn device_error(message: String) -> DriverError {
    DriverError::Device {
        device: DEVICE,
        code: 0,
        message,
    }
}
