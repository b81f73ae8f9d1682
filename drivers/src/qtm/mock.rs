//! QTM RT mock (protocol 1.25, little endian): welcome, version negotiation, GetState,
//! GetParameters 3D / General / All, StreamFrames over TCP or UDP, GetCurrentFrame; commands compared
//! case-insensitively (qtm-rt sends lower case). Markers come from a [`MarkerModel`].

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bytes::BytesMut;
use futures_util::StreamExt;
use tokio::io::AsyncWriteExt;
use tokio::net::UdpSocket;
use tokio_util::codec::FramedRead;

use super::codec::QtmCodec;
use super::packet::{self, Component, DataFrame, Packet, event};
use super::params::{Settings3d, SettingsGeneral, write_parameters};
use crate::mock_kit::fault::Fate;
use crate::mock_kit::{BoxIo, Conn, FaultKind, Faults, Handler};

/// Highest protocol version the mock accepts.
pub const MAX_VERSION: (u32, u32) = (1, 25);

/// Marker positions over time: the hook for a TALOS/humanoid twin.
pub trait MarkerModel: Send + 'static {
    /// Labels in data order.
    fn labels(&self) -> Vec<String>;
    /// Positions (mm) at time `t_s`; NaN for occluded markers. `out` has `labels().len()`.
    fn sample(&mut self, t_s: f64, out: &mut Vec<[f32; 3]>);
}

/// Default model: `n` labelled markers on circles around a tool; marker 3 (if present) is
/// occluded for 0.1 s every second.
#[derive(Debug, Clone)]
pub struct CircleMarkers {
    n: usize,
}

impl CircleMarkers {
    /// `n` markers (4 by default in the mock, 60 in the benchmark).
    pub fn new(n: usize) -> Self {
        CircleMarkers { n }
    }
}

impl MarkerModel for CircleMarkers {
    fn labels(&self) -> Vec<String> {
        (0..self.n)
            .map(|i| match i {
                0 => "tool_a".to_string(),
                1 => "tool_b".to_string(),
                2 => "tool_c".to_string(),
                3 => "base".to_string(),
                _ => format!("m{i:02}"),
            })
            .collect()
    }
    fn sample(&mut self, t: f64, out: &mut Vec<[f32; 3]>) {
        out.clear();
        for i in 0..self.n {
            let ph = t + i as f64 * 0.7;
            let r = 50.0 + 10.0 * i as f64;
            let mut p = [
                (500.0 + r * ph.cos()) as f32,
                (200.0 + r * ph.sin()) as f32,
                (1000.0 + 20.0 * i as f64) as f32,
            ];
            if i == 3 && t.fract() < 0.1 {
                p = [f32::NAN; 3];
            }
            out.push(p);
        }
    }
}

/// Options of the QTM mock (`calibd mock qtm --rate-hz`).
#[derive(Debug, Clone, Copy)]
pub struct QtmOptions {
    /// Capture rate: frames per second.
    pub rate_hz: f64,
}

/// Builds the simulate-mode handler with four moving markers.
pub(crate) fn handler(opts: impl Into<QtmOptions>, faults: Faults) -> Handler {
    handler_with(Arc::new(Mutex::new(CircleMarkers::new(4))), opts, faults)
}

/// Builds a simulate-mode handler around any marker model (`opts`: [`QtmOptions`], or the
/// `calibd mock` arguments).
pub fn handler_with(
    model: Arc<Mutex<dyn MarkerModel>>,
    opts: impl Into<QtmOptions>,
    faults: Faults,
) -> Handler {
    let rate = opts.into().rate_hz.clamp(1.0, 10_000.0);
    Arc::new(move |io, conn| {
        let s = Session {
            model: model.clone(),
            faults: faults.clone(),
            rate,
            stream: None,
            udp: None,
            frame: 0,
            buf: Vec::new(),
        };
        Box::pin(s.run(io, conn))
    })
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Components {
    labelled: bool,
    unlabelled: bool,
}

struct Stream {
    comps: Components,
    period: Duration,
    udp_to: Option<SocketAddr>,
}

struct Session {
    model: Arc<Mutex<dyn MarkerModel>>,
    faults: Faults,
    rate: f64,
    stream: Option<Stream>,
    udp: Option<UdpSocket>,
    frame: u32,
    buf: Vec<[f32; 3]>,
}

enum Step {
    Go,
    Stop,
}

impl Session {
    async fn run(mut self, io: BoxIo, conn: Conn) {
        let mut rd = FramedRead::new(io, QtmCodec);
        let welcome = encode(&Packet::Command("QTM RT Interface connected".into()));
        if rd.get_mut().write_all(&welcome).await.is_err() {
            return;
        }
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        loop {
            let streaming = self.stream.is_some();
            let step = tokio::select! {
                _ = conn.token.cancelled() => return,
                p = rd.next() => match p {
                    Some(Ok(Packet::Command(c))) => self.command(&c, rd.get_mut(), &conn, &mut tick).await,
                    Some(Ok(_)) => self.reply(rd.get_mut(), Packet::Error("Parse Error".into()), &conn).await,
                    _ => return,
                },
                _ = tick.tick(), if streaming => self.send_frame(rd.get_mut(), &conn).await,
            };
            if matches!(step, Step::Stop) {
                let _ = rd.get_mut().shutdown().await;
                return;
            }
        }
    }

    fn frame_packet(&mut self, comps: Components) -> Packet {
        self.frame = self.frame.wrapping_add(1);
        let t = f64::from(self.frame) / self.rate;
        if let Ok(mut m) = self.model.lock() {
            m.sample(t, &mut self.buf);
        }
        let mut components = Vec::new();
        if comps.labelled {
            components.push(Component::Markers3d {
                drop_rate: 0,
                out_of_sync_rate: 0,
                markers: self.buf.clone(),
            });
        }
        if comps.unlabelled {
            components.push(Component::Markers3dNoLabels {
                drop_rate: 0,
                out_of_sync_rate: 0,
                markers: (0..self.buf.len())
                    .filter(|i| !self.buf[*i][0].is_nan())
                    .map(|i| (self.buf[i], i as u32 + 1))
                    .collect(),
            });
        }
        Packet::Data(DataFrame {
            timestamp_us: (t * 1e6) as i64,
            frame_number: self.frame,
            components,
        })
    }

    async fn send_frame(&mut self, wr: &mut BoxIo, conn: &Conn) -> Step {
        let Some(s) = &self.stream else {
            return Step::Go;
        };
        let (comps, udp_to) = (s.comps, s.udp_to);
        let p = self.frame_packet(comps);
        match (udp_to, &self.udp) {
            (Some(to), Some(sock)) => {
                let b = encode(&p);
                if let Some(FaultKind::Drop) = self.faults.next() {
                    return Step::Go; // a lost datagram
                }
                let _ = sock.send_to(&b, to).await;
                Step::Go
            }
            _ => self.reply(wr, p, conn).await,
        }
    }

    /// Sends a reply or data packet, applying a planned fault.
    async fn reply(&mut self, wr: &mut BoxIo, p: Packet, conn: &Conn) -> Step {
        let error = |_| Packet::Error("Injected device error".into());
        let p = match self.faults.apply(wr, &conn.token, p, encode, error).await {
            Fate::Send(p) => p,
            Fate::Skipped => return Step::Go,
            Fate::Close => return Step::Stop,
        };
        match wr.write_all(&encode(&p)).await {
            Ok(()) => Step::Go,
            Err(_) => Step::Stop,
        }
    }

    async fn command(
        &mut self,
        cmd: &str,
        wr: &mut BoxIo,
        conn: &Conn,
        tick: &mut tokio::time::Interval,
    ) -> Step {
        let lower = cmd.trim().to_ascii_lowercase();
        let words: Vec<&str> = lower.split_whitespace().collect();
        let reply = match words.as_slice() {
            ["version"] => Packet::Command("Version is 1.25".into()),
            ["version", v] => match parse_version(v) {
                Some(ver) if ver >= (1, 8) && ver <= MAX_VERSION => {
                    Packet::Command(format!("Version set to {}.{}", ver.0, ver.1))
                }
                _ => Packet::Error("Version NOT supported".into()),
            },
            ["qtmversion"] => Packet::Command("QTM Version is 2.3 (build 464)".into()),
            ["byteorder"] => Packet::Command("Byte order is little endian".into()),
            ["getstate"] | ["getlastevent"] => Packet::Event(event::CONNECTED),
            ["getparameters", rest @ ..]
                if rest.iter().any(|w| matches!(*w, "3d" | "general" | "all")) =>
            {
                let all = rest.contains(&"all");
                let general = (all || rest.contains(&"general")).then(|| SettingsGeneral {
                    frequency_hz: self.rate.round() as u32,
                });
                let three_d = (all || rest.contains(&"3d")).then(|| Settings3d {
                    axis_upwards: "+Z".into(),
                    labels: self.model.lock().map(|m| m.labels()).unwrap_or_default(),
                });
                Packet::Xml(write_parameters("1.25", general.as_ref(), three_d.as_ref()))
            }
            ["getparameters", ..] => Packet::Error("Parameters not available".into()),
            ["takecontrol", ..] => Packet::Command("You are now master".into()),
            ["releasecontrol"] => Packet::Command("You are now a regular client".into()),
            ["streamframes", "stop"] => {
                self.stream = None;
                return Step::Go;
            }
            ["streamframes", rest @ ..] => match self.parse_stream(rest, conn.peer).await {
                Ok(s) => {
                    *tick = tokio::time::interval(s.period);
                    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
                    self.stream = Some(s);
                    return Step::Go;
                }
                Err(e) => Packet::Error(e),
            },
            ["getcurrentframe", rest @ ..] => match components(rest) {
                Some(c) => self.frame_packet(c),
                None => Packet::Error("No valid components".into()),
            },
            _ => Packet::Error("Parse Error".into()),
        };
        self.reply(wr, reply, conn).await
    }

    async fn parse_stream(
        &mut self,
        words: &[&str],
        peer: Option<SocketAddr>,
    ) -> Result<Stream, String> {
        let mut period = Duration::from_secs_f64(1.0 / self.rate);
        let mut udp_to = None;
        let mut rest = Vec::new();
        for w in words {
            if *w == "allframes" {
            } else if let Some(f) = w.strip_prefix("frequency:") {
                let f: f64 = f.parse().map_err(|_| "Parse Error".to_string())?;
                period = Duration::from_secs_f64(1.0 / f.clamp(1.0, 10_000.0));
            } else if let Some(d) = w.strip_prefix("frequencydivisor:") {
                let d: f64 = d.parse().map_err(|_| "Parse Error".to_string())?;
                period = Duration::from_secs_f64(d.max(1.0) / self.rate);
            } else if let Some(u) = w.strip_prefix("udp:") {
                let (host, port) = match u.rsplit_once(':') {
                    Some((h, p)) => (Some(h.to_string()), p),
                    None => (None, u),
                };
                let port: u16 = port
                    .parse()
                    .ok()
                    .filter(|p| *p >= 1023)
                    .ok_or_else(|| "Invalid UDP port".to_string())?;
                let ip = match host {
                    Some(h) => h.parse().map_err(|_| "Invalid UDP address".to_string())?,
                    None => peer.map(|p| p.ip()).ok_or("No client address")?,
                };
                if self.udp.is_none() {
                    self.udp = Some(
                        UdpSocket::bind("127.0.0.1:0")
                            .await
                            .map_err(|e| e.to_string())?,
                    );
                }
                udp_to = Some(SocketAddr::new(ip, port));
            } else {
                rest.push(*w);
            }
        }
        let comps = components(&rest).ok_or_else(|| "No valid components".to_string())?;
        Ok(Stream {
            comps,
            period,
            udp_to,
        })
    }
}

fn encode(p: &Packet) -> Vec<u8> {
    let mut b = BytesMut::new();
    packet::encode(p, &mut b);
    b.to_vec()
}

fn components(words: &[&str]) -> Option<Components> {
    let mut c = Components {
        labelled: false,
        unlabelled: false,
    };
    for w in words {
        match *w {
            "3d" => c.labelled = true,
            "3dnolabels" => c.unlabelled = true,
            _ => return None,
        }
    }
    (c.labelled || c.unlabelled).then_some(c)
}

fn parse_version(v: &str) -> Option<(u32, u32)> {
    let (a, b) = v.split_once('.')?;
    Some((a.parse().ok()?, b.parse().ok()?))
}
