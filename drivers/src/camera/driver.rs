//! The network camera driver: one actor owning the `calibd-frames/1` connection
//! (reconnecting with back-off, sending the exposure and frame rate after every connect), a
//! cloneable [`CameraHandle`]. A frame whose counter did not grow is refused as stale.

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio::sync::mpsc;

use super::codec::{CameraCodec, Frame, Reply, Request};
use super::{FrameSource, RawFrame};
use crate::actor::{Reply as Answer, call};
use crate::error::DriverError;
use crate::link::{Backoff, BoxFuture, Connect, Link};

const DEVICE: &str = "camera";

/// Settings of the network camera.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraConfig {
    /// Reply timeout of one request (a frame's transfer included).
    pub timeout: Duration,
    /// Reconnection back-off.
    pub backoff: Backoff,
    /// Exposure time sent to the camera (us).
    pub exposure_us: f64,
    /// Frame rate sent to the camera (Hz).
    pub frame_rate_hz: f64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(2),
            backoff: Backoff::default(),
            exposure_us: 1000.0,
            frame_rate_hz: 25.0,
        }
    }
}

struct Call {
    request: Request,
    reply: Answer<Reply>,
}

/// Cheap, cloneable handle to the camera actor.
#[derive(Debug, Clone)]
pub struct CameraHandle {
    tx: mpsc::Sender<Call>,
}

impl CameraHandle {
    /// Start the actor (it connects on the first request).
    pub fn connect<C: Connect>(connector: C, cfg: CameraConfig) -> Self {
        let (tx, mut rx) = mpsc::channel::<Call>(4);
        let mut link = Link::new(DEVICE, connector, CameraCodec, cfg.backoff);
        tokio::spawn(async move {
            let mut last_seq: Option<u64> = None;
            while let Some(c) = rx.recv().await {
                let r = exchange(&mut link, c.request, &cfg)
                    .await
                    .and_then(|r| fresh(r, &mut last_seq));
                if let Err(e) = &r
                    && e.breaks_link()
                {
                    link.reset();
                }
                let _ = c.reply.send(r);
            }
        });
        Self { tx }
    }

    async fn ask(&self, request: Request) -> Result<Reply, DriverError> {
        match call(&self.tx, DEVICE, |reply| Call { request, reply }).await? {
            Reply::Err { code, text } => Err(DriverError::Device {
                device: DEVICE,
                code,
                message: text,
            }),
            other => Ok(other),
        }
    }

    /// The identification line.
    pub async fn id(&self) -> Result<String, DriverError> {
        match self.ask(Request::Id).await? {
            Reply::Id(t) => Ok(t),
            other => Err(unexpected(&Request::Id, &other)),
        }
    }

    /// A fresh frame.
    pub async fn frame(&self) -> Result<Frame, DriverError> {
        match self.ask(Request::Frame).await? {
            Reply::Frame(f) => Ok(f),
            other => Err(unexpected(&Request::Frame, &other)),
        }
    }

    /// The `ID?` line and one fresh frame's size (an error the camera reports for the frame
    /// is kept in [`CameraIdentity::frame_error`]; link errors are returned).
    pub async fn identity(&self) -> Result<CameraIdentity, DriverError> {
        let id = self.id().await?;
        let (frame, frame_error) = match self.frame().await {
            Ok(f) => (
                Some(FrameInfo {
                    seq: f.seq,
                    width_px: f.width,
                    height_px: f.height,
                    bit_depth: f.bit_depth,
                    exposure_us: f.exposure_us,
                }),
                None,
            ),
            Err(DriverError::Device { code, message, .. }) => {
                (None, Some(format!("error {code}: {message}")))
            }
            Err(e) => return Err(e),
        };
        Ok(CameraIdentity {
            id,
            frame,
            frame_error,
        })
    }
}

impl FrameSource for CameraHandle {
    fn grab(&self) -> BoxFuture<'_, Result<RawFrame, DriverError>> {
        Box::pin(async move { self.frame().await.map(RawFrame::Pixels) })
    }
}

/// What a frame looked like, for `calibd lab check`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FrameInfo {
    /// Frame counter.
    pub seq: u64,
    /// Columns.
    pub width_px: u32,
    /// Rows.
    pub height_px: u32,
    /// Bits per pixel.
    pub bit_depth: u8,
    /// Exposure (us).
    pub exposure_us: f64,
}

/// Identity of a network camera: its `ID?` line and one fresh frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CameraIdentity {
    /// The identification line.
    pub id: String,
    /// The fresh frame (None when the camera answered with an error).
    pub frame: Option<FrameInfo>,
    /// The camera's `ERR <code> <text>` to `FRAME?`.
    pub frame_error: Option<String>,
}

impl crate::identity::Identity for CameraIdentity {
    const DEVICE_KIND: &'static str = DEVICE;

    /// The camera's identification line (never a frame's counter or exposure, which change
    /// while the same camera runs, nor whether a frame came: a camera between acquisitions
    /// is the same unit).
    fn fingerprint(&self) -> String {
        self.id.clone()
    }

    fn summary(&self) -> String {
        match (&self.frame, &self.frame_error) {
            (Some(f), _) => format!(
                "{}; frame {}: {} x {} px, {} bit, exposure {} us",
                self.id, f.seq, f.width_px, f.height_px, f.bit_depth, f.exposure_us
            ),
            (None, Some(e)) => format!("{}; no frame: {e}", self.id),
            (None, None) => format!("{}; no frame", self.id),
        }
    }

    fn problems(&self) -> Vec<String> {
        match &self.frame_error {
            Some(e) => vec![format!(
                "no frame from the camera ({e}): start its acquisition, check the bridge"
            )],
            None => Vec::new(),
        }
    }
}

/// Refuse a frame whose counter did not grow.
fn fresh(r: Reply, last: &mut Option<u64>) -> Result<Reply, DriverError> {
    if let Reply::Frame(f) = &r {
        if let Some(prev) = *last
            && f.seq <= prev
        {
            return Err(DriverError::Protocol {
                device: DEVICE,
                detail: format!("stale frame: counter {} after {prev}", f.seq),
            });
        }
        *last = Some(f.seq);
    }
    Ok(r)
}

fn unexpected(req: &Request, got: &Reply) -> DriverError {
    let what = match got {
        Reply::Id(_) => "ID",
        Reply::Ok => "OK",
        Reply::Frame(_) => "FRAME",
        Reply::Err { .. } => "ERR",
    };
    DriverError::Protocol {
        device: DEVICE,
        detail: format!("reply {what} to {:?}", req.text()),
    }
}

/// One request and its reply, after the settings on a new connection.
async fn exchange<C: Connect>(
    link: &mut Link<C, CameraCodec>,
    request: Request,
    cfg: &CameraConfig,
) -> Result<Reply, DriverError> {
    let (f, fresh) = link.ensure().await?;
    let work = async {
        f.read_buffer_mut().clear();
        let mut one = async |q: Request| {
            f.send(q)
                .await
                .map_err(|e| DriverError::from_codec(DEVICE, e))?;
            match f.next().await {
                Some(Ok(r)) => Ok(r),
                Some(Err(e)) => Err(DriverError::from_codec(DEVICE, e)),
                None => Err(DriverError::Closed { device: DEVICE }),
            }
        };
        if fresh {
            let set = Request::Set {
                exposure_us: cfg.exposure_us,
                frame_rate_hz: cfg.frame_rate_hz,
            };
            match one(set).await? {
                Reply::Ok => {}
                Reply::Err { code, text } => {
                    return Err(DriverError::Device {
                        device: DEVICE,
                        code,
                        message: format!("settings refused: {text}"),
                    });
                }
                other => return Err(unexpected(&set, &other)),
            }
        }
        one(request).await
    };
    let r = tokio::time::timeout(cfg.timeout, work)
        .await
        .unwrap_or(Err(DriverError::Timeout {
            device: DEVICE,
            what: format!("a reply to {:?}", request.text()),
            after_ms: cfg.timeout.as_millis() as u64,
        }));
    // Refused settings leave the camera unconfigured: set them again on the next request.
    if let Err(DriverError::Device { message, .. }) = &r
        && fresh
        && message.starts_with("settings refused")
    {
        link.reset();
    }
    r
}
