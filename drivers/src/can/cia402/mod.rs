//! CiA 402 drive over CANopen SDO: an actor owning a [`FrameTransport`] (socketcand in tests,
//! SocketCAN in the lab) that reads/writes objects, runs the power state machine and
//! profile-position moves, and implements [`crate::smaract::Stage`] (one channel, pm per
//! count configurable; in `stage`).

mod identity;
mod stage;

pub use identity::{Cia402Identity, power_state};

use std::time::Duration;

use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use super::canopen::{
    SDO_RX, SDO_TX, SdoResponse, UploadSegment, abort_text, download_request, obj, parse_response,
    parse_upload_segment, upload_request, upload_segment_request,
};
use super::frame::{CanConnect, CanFrame, FrameTransport};
use crate::actor::{Reply, call};
use crate::error::DriverError;
use crate::link::Backoff;

const DEVICE: &str = "can";

/// Driver configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Cia402Config {
    /// CANopen node id (1-127).
    pub node: u8,
    /// SDO reply timeout.
    pub timeout: Duration,
    /// Timeout of a whole move.
    pub move_timeout: Duration,
    /// Statusword poll period while moving.
    pub poll: Duration,
    /// Picometres per position count (scale for the [`Stage`] interface).
    pub pm_per_count: i64,
    /// Reconnection back-off.
    pub backoff: Backoff,
}

impl Default for Cia402Config {
    fn default() -> Self {
        Cia402Config {
            node: 1,
            timeout: Duration::from_millis(500),
            move_timeout: Duration::from_secs(30),
            poll: Duration::from_millis(10),
            pm_per_count: 1000,
            backoff: Backoff::default(),
        }
    }
}

/// Link state on the watch channel.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Cia402State {
    /// True while the bus is open.
    pub connected: bool,
    /// Successful (re)connections.
    pub connects: u64,
    /// Last statusword read.
    pub statusword: Option<u16>,
    /// Last error.
    pub last_error: Option<String>,
}

enum Op {
    Read(u16, u8, Reply<Vec<u8>>),
    Write(u16, u8, Vec<u8>, Reply<()>),
}

impl std::fmt::Debug for Op {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Op::Read(i, s, _) => write!(f, "Read({i:#06x}:{s})"),
            Op::Write(i, s, d, _) => write!(f, "Write({i:#06x}:{s}, {d:02x?})"),
        }
    }
}

/// Cheap, cloneable handle to a CiA 402 drive.
#[derive(Debug, Clone)]
pub struct Cia402Handle {
    tx: mpsc::Sender<Op>,
    state: watch::Receiver<Cia402State>,
    cfg: Cia402Config,
}

struct Actor<C: CanConnect> {
    connector: C,
    bus: Option<C::Bus>,
    cfg: Cia402Config,
    state: watch::Sender<Cia402State>,
}

impl<C: CanConnect> Actor<C> {
    async fn ensure(&mut self) -> Result<&mut C::Bus, DriverError> {
        if self.bus.is_none() {
            let mut last = None;
            for n in 0..self.cfg.backoff.attempts.max(1) {
                tokio::time::sleep(self.cfg.backoff.delay(n)).await;
                match self.connector.connect().await {
                    Ok(b) => {
                        self.bus = Some(b);
                        last = None;
                        break;
                    }
                    Err(e) => last = Some(e),
                }
            }
            if let Some(source) = last {
                return Err(DriverError::Unreachable {
                    device: DEVICE,
                    attempts: self.cfg.backoff.attempts.max(1),
                    source,
                });
            }
            self.state.send_modify(|s| {
                s.connected = true;
                s.connects += 1;
            });
        }
        self.bus
            .as_mut()
            .ok_or(DriverError::Closed { device: DEVICE })
    }

    async fn sdo(&mut self, req: [u8; 8], index: u16, sub: u8) -> Result<SdoResponse, DriverError> {
        let node = u16::from(self.cfg.node);
        let timeout = self.cfg.timeout;
        let bus = self.ensure().await?;
        let work = async {
            bus.send(CanFrame::new(SDO_RX + node, &req))
                .await
                .map_err(io_err)?;
            loop {
                let f = bus.recv().await.map_err(io_err)?;
                if f.extended || f.id != u32::from(SDO_TX + node) {
                    continue; // heartbeats, PDOs, other nodes
                }
                let r = parse_response(&f.data).map_err(|e| DriverError::from_codec(DEVICE, e))?;
                let (i, s) = match &r {
                    SdoResponse::Upload { index, sub, .. }
                    | SdoResponse::UploadSegmented { index, sub, .. }
                    | SdoResponse::DownloadAck { index, sub }
                    | SdoResponse::Abort { index, sub, .. } => (*index, *sub),
                };
                if (i, s) == (index, sub) {
                    return Ok(r);
                }
            }
        };
        let r = tokio::time::timeout(timeout, work)
            .await
            .unwrap_or(Err(DriverError::Timeout {
                device: DEVICE,
                what: format!("SDO reply for {index:#06x}:{sub}"),
                after_ms: timeout.as_millis() as u64,
            }));
        self.note_error(&r);
        r
    }

    /// Reads the segments of an upload the server initiated as segmented (e.g. 0x1008
    /// device name); `size` is the indicated total, checked at the end.
    async fn segments(
        &mut self,
        index: u16,
        sub: u8,
        size: Option<u32>,
    ) -> Result<Vec<u8>, DriverError> {
        const MAX: usize = 4096;
        let node = u16::from(self.cfg.node);
        let timeout = self.cfg.timeout;
        let bus = self.ensure().await?;
        let work = async {
            let mut out = Vec::new();
            let mut toggle = false;
            loop {
                bus.send(CanFrame::new(
                    SDO_RX + node,
                    &upload_segment_request(toggle),
                ))
                .await
                .map_err(io_err)?;
                let f = loop {
                    let f = bus.recv().await.map_err(io_err)?;
                    if !f.extended && f.id == u32::from(SDO_TX + node) {
                        break f;
                    }
                };
                match parse_upload_segment(&f.data, toggle)
                    .map_err(|e| DriverError::from_codec(DEVICE, e))?
                {
                    UploadSegment::Abort { code } => return Err(abort(index, sub, code)),
                    UploadSegment::Data { data, last } => {
                        out.extend_from_slice(&data);
                        if out.len() > MAX {
                            return Err(DriverError::Protocol {
                                device: DEVICE,
                                detail: format!(
                                    "segmented upload of {index:#06x}:{sub} exceeds {MAX} bytes"
                                ),
                            });
                        }
                        if last {
                            return Ok(out);
                        }
                    }
                }
                toggle = !toggle;
            }
        };
        let r = tokio::time::timeout(timeout, work)
            .await
            .unwrap_or(Err(DriverError::Timeout {
                device: DEVICE,
                what: format!("SDO upload segment of {index:#06x}:{sub}"),
                after_ms: timeout.as_millis() as u64,
            }))
            .and_then(|d| match size {
                Some(n) if usize::try_from(n).ok() != Some(d.len()) => Err(DriverError::Protocol {
                    device: DEVICE,
                    detail: format!(
                        "segmented upload of {index:#06x}:{sub} announced {n} bytes, got {}",
                        d.len()
                    ),
                }),
                _ => Ok(d),
            });
        self.note_error(&r);
        r
    }

    /// Drops the bus after an error that breaks the link, and publishes it.
    fn note_error<T>(&mut self, r: &Result<T, DriverError>) {
        if let Err(e) = r
            && e.breaks_link()
        {
            self.bus = None;
            let msg = e.to_string();
            self.state.send_modify(|s| {
                s.connected = false;
                s.last_error = Some(msg);
            });
        }
    }

    async fn handle(&mut self, op: Op) {
        match op {
            Op::Read(i, s, reply) => {
                let r = match self.sdo(upload_request(i, s), i, s).await {
                    Ok(SdoResponse::Upload { data, .. }) => Ok(data),
                    Ok(SdoResponse::UploadSegmented { size, .. }) => {
                        self.segments(i, s, size).await
                    }
                    Ok(SdoResponse::Abort { code, .. }) => Err(abort(i, s, code)),
                    Ok(other) => Err(DriverError::Protocol {
                        device: DEVICE,
                        detail: format!("expected upload data, got {other:?}"),
                    }),
                    Err(e) => Err(e),
                };
                if let (Ok(d), obj::STATUSWORD) = (&r, i)
                    && d.len() >= 2
                {
                    let sw = u16::from_le_bytes([d[0], d[1]]);
                    self.state.send_modify(|s| s.statusword = Some(sw));
                }
                let _ = reply.send(r);
            }
            Op::Write(i, s, data, reply) => {
                let r = match download_request(i, s, &data) {
                    None => Err(DriverError::InvalidRequest {
                        device: DEVICE,
                        detail: format!("expedited SDO carries 1-4 bytes, not {}", data.len()),
                    }),
                    Some(req) => match self.sdo(req, i, s).await {
                        Ok(SdoResponse::DownloadAck { .. }) => Ok(()),
                        Ok(SdoResponse::Abort { code, .. }) => Err(abort(i, s, code)),
                        Ok(other) => Err(DriverError::Protocol {
                            device: DEVICE,
                            detail: format!("expected a download acknowledge, got {other:?}"),
                        }),
                        Err(e) => Err(e),
                    },
                };
                let _ = reply.send(r);
            }
        }
    }
}

fn io_err(source: std::io::Error) -> DriverError {
    match source.kind() {
        std::io::ErrorKind::UnexpectedEof => DriverError::Closed { device: DEVICE },
        std::io::ErrorKind::InvalidData => DriverError::Protocol {
            device: DEVICE,
            detail: source.to_string(),
        },
        _ => DriverError::Transport {
            device: DEVICE,
            source,
        },
    }
}

fn abort(index: u16, sub: u8, code: u32) -> DriverError {
    DriverError::Device {
        device: DEVICE,
        code: i64::from(code),
        message: format!(
            "SDO abort {code:#010x} on {index:#06x}:{sub}: {}",
            abort_text(code)
        ),
    }
}

/// Statusword bits.
pub(crate) mod sw {
    pub(super) const FAULT: u16 = 1 << 3;
    pub(super) const TARGET_REACHED: u16 = 1 << 10;
    pub(super) const SETPOINT_ACK: u16 = 1 << 12;
    pub(super) const FOLLOWING_ERROR: u16 = 1 << 13;
}

impl Cia402Handle {
    /// Starts the actor with a bus connector (reconnects with back-off).
    pub fn connect<C: CanConnect>(connector: C, cfg: Cia402Config) -> Self {
        let (tx, mut rx) = mpsc::channel::<Op>(16);
        let (stx, srx) = watch::channel(Cia402State::default());
        let mut actor = Actor {
            connector,
            bus: None,
            cfg: cfg.clone(),
            state: stx,
        };
        tokio::spawn(async move {
            while let Some(op) = rx.recv().await {
                actor.handle(op).await;
            }
        });
        Cia402Handle {
            tx,
            state: srx,
            cfg,
        }
    }

    /// SDO upload of object `index:sub` (expedited, or segmented when the drive says so).
    pub async fn read(&self, index: u16, sub: u8) -> Result<Vec<u8>, DriverError> {
        call(&self.tx, DEVICE, |r| Op::Read(index, sub, r)).await
    }

    /// Expedited SDO download of 1-4 bytes.
    pub async fn write(&self, index: u16, sub: u8, data: &[u8]) -> Result<(), DriverError> {
        call(&self.tx, DEVICE, |r| {
            Op::Write(index, sub, data.to_vec(), r)
        })
        .await
    }

    async fn read_u16(&self, index: u16) -> Result<u16, DriverError> {
        let d = self.read(index, 0).await?;
        d.get(..2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .ok_or_else(|| short(index, &d))
    }

    async fn read_i32(&self, index: u16) -> Result<i32, DriverError> {
        let d = self.read(index, 0).await?;
        d.get(..4)
            .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| short(index, &d))
    }

    /// The statusword (0x6041).
    pub async fn statusword(&self) -> Result<u16, DriverError> {
        self.read_u16(obj::STATUSWORD).await
    }

    /// Position actual value (0x6064), counts.
    pub async fn position_counts(&self) -> Result<i32, DriverError> {
        self.read_i32(obj::POSITION_ACTUAL).await
    }

    async fn controlword(&self, cw: u16) -> Result<(), DriverError> {
        self.write(obj::CONTROLWORD, 0, &cw.to_le_bytes()).await
    }

    /// Runs the power state machine to "operation enabled" (fault reset first if needed).
    pub async fn enable(&self) -> Result<(), DriverError> {
        if self.statusword().await? & sw::FAULT != 0 {
            self.controlword(0x0000).await?;
            self.controlword(0x0080).await?;
        }
        for (cw, mask, want, name) in [
            (0x0006, 0x6F, 0x21, "ready to switch on"),
            (0x0007, 0x6F, 0x23, "switched on"),
            (0x000F, 0x6F, 0x27, "operation enabled"),
        ] {
            self.controlword(cw).await?;
            let s = self.statusword().await?;
            if s & mask != want {
                return Err(DriverError::Device {
                    device: DEVICE,
                    code: i64::from(s),
                    message: format!("drive did not reach {name} (statusword {s:#06x})"),
                });
            }
        }
        Ok(())
    }

    /// Sets a new set-point in `mode` (1 profile position, 6 homing) and waits for
    /// "target reached" (statusword bit 10).
    pub(crate) async fn run_setpoint(
        &self,
        mode: i8,
        target: Option<i32>,
    ) -> Result<u16, DriverError> {
        self.enable().await?;
        self.write(obj::MODES, 0, &mode.to_le_bytes()).await?;
        if let Some(t) = target {
            self.write(obj::TARGET_POSITION, 0, &t.to_le_bytes())
                .await?;
        }
        self.controlword(0x001F).await?;
        let deadline = Instant::now() + self.cfg.move_timeout;
        let mut acked = false;
        loop {
            let s = self.statusword().await?;
            if s & (sw::FAULT | sw::FOLLOWING_ERROR) != 0 {
                return Err(DriverError::Device {
                    device: DEVICE,
                    code: i64::from(s),
                    message: format!("drive fault or following error (statusword {s:#06x})"),
                });
            }
            if !acked && s & sw::SETPOINT_ACK != 0 {
                acked = true;
                self.controlword(0x000F).await?;
            } else if acked && s & sw::TARGET_REACHED != 0 {
                return Ok(s);
            }
            if Instant::now() >= deadline {
                return Err(DriverError::Timeout {
                    device: DEVICE,
                    what: "target reached".into(),
                    after_ms: self.cfg.move_timeout.as_millis() as u64,
                });
            }
            tokio::time::sleep(self.cfg.poll).await;
        }
    }

    /// Profile-position move to `counts`; returns the actual position reached.
    pub async fn move_to_counts(&self, counts: i32) -> Result<i32, DriverError> {
        self.run_setpoint(1, Some(counts)).await?;
        self.position_counts().await
    }

    /// Link state.
    pub fn state(&self) -> watch::Receiver<Cia402State> {
        self.state.clone()
    }
}

fn short(index: u16, d: &[u8]) -> DriverError {
    DriverError::Protocol {
        device: DEVICE,
        detail: format!("object {index:#06x} returned {} bytes", d.len()),
    }
}
