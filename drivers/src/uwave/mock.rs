//! U-WAVE-R mock: streams `DT1` lines for each indicator from an [`IndicatorModel`] (event
//! mode), answers the documented info requests (`IR1000gg0`, `IR11ccgg1`) and an optional
//! configured data request; serves on a pseudo-terminal or TCP.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};

use super::codec::{ReceiverInfo, Unit, UwaveLine};

/// Receiver id the mock reports in its `RI1` line.
pub const RECEIVER_ID: &str = "0000123456";

/// Noise values of the mock's `RI1` line: low on its band (15), higher on the others.
const NOISE: [u16; 16] = [12, 8, 15, 3, 21, 9, 4, 0, 2, 5, 11, 7, 6, 14, 1, 10];
use crate::mock_kit::fault::Fate;
use crate::mock_kit::{BoxIo, Conn, Faults, Handler};

/// What the indicators read: the hook for a digital twin of the centring fixture.
pub trait IndicatorModel: Send + 'static {
    /// Channels of the registered transmitters.
    fn channels(&self) -> Vec<u8>;
    /// Reading of `channel` in mm at time `t_s` since start (None = no data).
    fn read_mm(&mut self, channel: u8, t_s: f64) -> Option<f64>;
}

/// Default model: three ID-C112XB indicators near mid-range with a slow µm-level drift.
#[derive(Debug, Clone, Default)]
pub struct DriftingIndicators;

impl IndicatorModel for DriftingIndicators {
    fn channels(&self) -> Vec<u8> {
        vec![0, 1, 2]
    }
    fn read_mm(&mut self, channel: u8, t_s: f64) -> Option<f64> {
        let c = f64::from(channel);
        Some(6.35 + 0.1 * c + 0.002 * (0.5 * t_s + c).sin())
    }
}

/// Options of the U-WAVE mock (`calibd mock uwave --rate-hz --uwave-request`).
#[derive(Debug, Clone)]
pub struct UwaveOptions {
    /// Readings per second and channel; 0 streams none (readings on request only).
    pub rate_hz: f64,
    /// Data-request template answered with a reading (`{cc}`, `{gg}` placeholders); empty:
    /// readings only stream.
    pub request: String,
}

/// Builds the simulate-mode handler with the default model.
pub(crate) fn handler(opts: impl Into<UwaveOptions>, faults: Faults) -> Handler {
    let model: Arc<Mutex<dyn IndicatorModel>> = Arc::new(Mutex::new(DriftingIndicators));
    handler_with(model, opts, faults)
}

/// Builds a simulate-mode handler around any indicator model (`opts`: [`UwaveOptions`], or
/// the `calibd mock` arguments).
pub fn handler_with(
    model: Arc<Mutex<dyn IndicatorModel>>,
    opts: impl Into<UwaveOptions>,
    faults: Faults,
) -> Handler {
    let UwaveOptions { rate_hz, request } = opts.into();
    // A rate of 0 streams nothing: the receiver only answers requests.
    let period = (rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / rate_hz.clamp(0.1, 1000.0)));
    let start = tokio::time::Instant::now();
    Arc::new(move |io, conn| {
        let s = Session {
            model: model.clone(),
            faults: faults.clone(),
            period,
            request: request.clone(),
            start,
        };
        Box::pin(s.run(io, conn))
    })
}

struct Session {
    model: Arc<Mutex<dyn IndicatorModel>>,
    faults: Faults,
    period: Option<Duration>,
    request: String,
    start: tokio::time::Instant,
}

enum Next {
    Go,
    Stop,
}

impl Session {
    async fn run(self, mut io: BoxIo, conn: Conn) {
        let streams = self.period.is_some();
        let mut tick = tokio::time::interval(self.period.unwrap_or(Duration::from_secs(3600)));
        let mut inbuf: Vec<u8> = Vec::new();
        loop {
            let mut buf = [0u8; 256];
            let next = tokio::select! {
                _ = conn.token.cancelled() => return,
                _ = tick.tick(), if streams => {
                    let channels = self.model.lock().map(|m| m.channels()).unwrap_or_default();
                    let mut n = Next::Go;
                    for c in channels {
                        n = self.emit(&mut io, c, &conn).await;
                        if matches!(n, Next::Stop) { break; }
                    }
                    n
                }
                r = io.read(&mut buf) => match r {
                    Ok(0) | Err(_) => return,
                    Ok(k) => {
                        inbuf.extend_from_slice(&buf[..k]);
                        let mut n = Next::Go;
                        while let Some(p) = inbuf.iter().position(|b| *b == b'\r') {
                            let line: Vec<u8> = inbuf.drain(..=p).collect();
                            let text = String::from_utf8_lossy(&line[..p]).trim().to_string();
                            n = self.answer(&mut io, &text, &conn).await;
                            if matches!(n, Next::Stop) { break; }
                        }
                        n
                    }
                },
            };
            if matches!(next, Next::Stop) {
                return;
            }
        }
    }

    fn data_line(&self, channel: u8) -> Option<String> {
        let t = self.start.elapsed().as_secs_f64();
        let v = self.model.lock().ok()?.read_mm(channel, t)?;
        let line = UwaveLine::Data {
            group: 0,
            channel,
            value: (v * 1000.0).round() / 1000.0,
            unit: Unit::Millimetre,
            decimals: 3,
        };
        Some(line.render() + "\r")
    }

    /// Sends one reading of `channel`, applying a planned fault.
    async fn emit(&self, io: &mut BoxIo, channel: u8, conn: &Conn) -> Next {
        let Some(line) = self.data_line(channel) else {
            return Next::Go;
        };
        let error = |_| {
            let status = UwaveLine::Status {
                group: Some(0),
                channel: Some(channel),
                transmitter: Some(format!("{:010}", 9_233_800 + u32::from(channel))),
                code: 1,
            };
            status.render() + "\r"
        };
        let fate = self
            .faults
            .apply(io, &conn.token, line, |l| l.clone().into_bytes(), error)
            .await;
        match fate {
            Fate::Send(line) if io.write_all(line.as_bytes()).await.is_ok() => Next::Go,
            Fate::Skipped => Next::Go,
            Fate::Send(_) | Fate::Close => Next::Stop,
        }
    }

    /// Answers one request line.
    async fn answer(&self, io: &mut BoxIo, text: &str, conn: &Conn) -> Next {
        let channels = self.model.lock().map(|m| m.channels()).unwrap_or_default();
        let reply = if text.len() == 9 && text.starts_with("IR1000") {
            let info = ReceiverInfo {
                group: text.get(6..8).and_then(|g| g.parse().ok()).unwrap_or(0),
                receiver_id: RECEIVER_ID.into(),
                band: 15,
                l: '0',
                d: '1',
                noise_raw: NOISE.to_vec(),
            };
            Some(UwaveLine::ReceiverInfo { raw: info.render() })
        } else if text.len() == 9 && text.starts_with("IR11") {
            let from: u8 = text.get(4..6).and_then(|c| c.parse().ok()).unwrap_or(0);
            Some(match channels.iter().find(|c| **c >= from) {
                Some(c) => UwaveLine::TransmitterInfo {
                    state: 2,
                    channel: *c,
                    group: 0,
                    transmitter: format!("{:010}", 9_233_800 + u32::from(*c)),
                    band: 15,
                    mode: 1,
                },
                None => end_of_search(51),
            })
        } else if !self.request.is_empty() {
            let hit = channels.iter().find(|c| {
                self.request
                    .replace("{cc}", &format!("{c:02}"))
                    .replace("{gg}", "00")
                    == text
            });
            match hit {
                Some(c) => return self.emit(io, *c, conn).await,
                None => Some(end_of_search(50)),
            }
        } else {
            Some(end_of_search(50))
        };
        if let Some(r) = reply
            && io.write_all((r.render() + "\r").as_bytes()).await.is_err()
        {
            return Next::Stop;
        }
        Next::Go
    }
}

fn end_of_search(code: u8) -> UwaveLine {
    UwaveLine::Status {
        group: None,
        channel: None,
        transmitter: None,
        code,
    }
}
