//! The microscope driver: one actor owning the connection (reconnecting with back-off), a
//! cheap cloneable [`MicroscopeHandle`] whose calls are requests with a oneshot reply.
//! A pose whose image counter did not grow is refused as stale.

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio::sync::mpsc;

use super::codec::{MicroscopeCodec, Reply, Request};
use crate::actor::{Reply as Answer, call};
use crate::error::DriverError;
use crate::link::{Backoff, Connect, Link};

const DEVICE: &str = "microscope";

/// Settings of the microscope driver.
#[derive(Debug, Clone, PartialEq)]
pub struct MicroscopeConfig {
    /// Reply timeout of one request (an image takes a few tens of ms).
    pub timeout: Duration,
    /// Reconnection back-off.
    pub backoff: Backoff,
}

impl Default for MicroscopeConfig {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(2),
            backoff: Backoff::default(),
        }
    }
}

/// One pose read by the microscope (pattern frame in the camera frame).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PoseReading {
    /// Image counter.
    pub seq: u64,
    /// x (m).
    pub x_m: f64,
    /// y (m).
    pub y_m: f64,
    /// Angle (rad).
    pub theta_rad: f64,
}

struct Call {
    request: Request,
    reply: Answer<Reply>,
}

/// Cheap, cloneable handle to the microscope actor.
#[derive(Debug, Clone)]
pub struct MicroscopeHandle {
    tx: mpsc::Sender<Call>,
}

impl MicroscopeHandle {
    /// Start the actor (it connects on the first request).
    pub fn connect<C: Connect>(connector: C, cfg: MicroscopeConfig) -> Self {
        let (tx, mut rx) = mpsc::channel::<Call>(16);
        let mut link = Link::new(DEVICE, connector, MicroscopeCodec, cfg.backoff);
        tokio::spawn(async move {
            let mut last_seq: Option<u64> = None;
            while let Some(c) = rx.recv().await {
                let r = exchange(&mut link, c.request, cfg.timeout)
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
        let r = call(&self.tx, DEVICE, |reply| Call { request, reply }).await?;
        match r {
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
            other => Err(unexpected(Request::Id, &other)),
        }
    }

    /// The pose in a fresh image.
    pub async fn pose(&self) -> Result<PoseReading, DriverError> {
        match self.ask(Request::Pose).await? {
            Reply::Pose {
                seq,
                x_m,
                y_m,
                theta_rad,
            } => Ok(PoseReading {
                seq,
                x_m,
                y_m,
                theta_rad,
            }),
            other => Err(unexpected(Request::Pose, &other)),
        }
    }
}

/// Identity of the microscope's pose server: its `ID?` line and one fresh `POSE?`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MicroscopeIdentity {
    /// The identification line (`ID <text>`).
    pub id: String,
    /// A fresh pose (None when the server answered `POSE?` with an error).
    pub pose: Option<PoseReading>,
    /// The server's `ERR <code> <text>` to `POSE?`, e.g. pattern not found.
    pub pose_error: Option<String>,
}

impl crate::identity::Identity for MicroscopeIdentity {
    const DEVICE_KIND: &'static str = DEVICE;

    fn fingerprint(&self) -> String {
        self.id.clone()
    }

    fn summary(&self) -> String {
        match (&self.pose, &self.pose_error) {
            (Some(p), _) => format!(
                "{}; image {}: x {:.1} um, y {:.1} um, theta {:.3} mrad",
                self.id,
                p.seq,
                p.x_m * 1e6,
                p.y_m * 1e6,
                p.theta_rad * 1e3
            ),
            (None, Some(e)) => format!("{}; no pose: {e}", self.id),
            (None, None) => format!("{}; no pose", self.id),
        }
    }

    fn problems(&self) -> Vec<String> {
        match &self.pose_error {
            Some(e) => vec![format!(
                "no pose from the microscope ({e}): put the pattern under the camera, check \
                 focus and lighting"
            )],
            None => Vec::new(),
        }
    }
}

impl MicroscopeHandle {
    /// The `ID?` line and one fresh `POSE?` reading. An error the server reports for the
    /// pose (code 2 pattern not found, 3 camera busy, ...) is kept in
    /// [`MicroscopeIdentity::pose_error`]; link errors are returned.
    pub async fn identity(&self) -> Result<MicroscopeIdentity, DriverError> {
        let id = self.id().await?;
        let (pose, pose_error) = match self.pose().await {
            Ok(p) => (Some(p), None),
            Err(DriverError::Device { code, message, .. }) => {
                (None, Some(format!("error {code}: {message}")))
            }
            Err(e) => return Err(e),
        };
        Ok(MicroscopeIdentity {
            id,
            pose,
            pose_error,
        })
    }
}

/// Refuse a pose whose image counter did not grow (the same image read twice).
fn fresh(r: Reply, last: &mut Option<u64>) -> Result<Reply, DriverError> {
    if let Reply::Pose { seq, .. } = r {
        if let Some(prev) = *last
            && seq <= prev
        {
            return Err(DriverError::Protocol {
                device: DEVICE,
                detail: format!("stale image: counter {seq} after {prev}"),
            });
        }
        *last = Some(seq);
    }
    Ok(r)
}

fn unexpected(req: Request, got: &Reply) -> DriverError {
    DriverError::Protocol {
        device: DEVICE,
        detail: format!("reply {:?} to {:?}", got.text(), req.text()),
    }
}

/// One request and its reply; a `POSE` whose counter did not grow is a protocol error.
async fn exchange<C: Connect>(
    link: &mut Link<C, MicroscopeCodec>,
    request: Request,
    timeout: Duration,
) -> Result<Reply, DriverError> {
    let (f, _fresh) = link.ensure().await?;
    let work = async {
        // Anything unread belongs to an earlier, abandoned exchange.
        f.read_buffer_mut().clear();
        f.send(request)
            .await
            .map_err(|e| DriverError::from_codec(DEVICE, e))?;
        match f.next().await {
            Some(Ok(r)) => Ok(r),
            Some(Err(e)) => Err(DriverError::from_codec(DEVICE, e)),
            None => Err(DriverError::Closed { device: DEVICE }),
        }
    };
    tokio::time::timeout(timeout, work)
        .await
        .unwrap_or(Err(DriverError::Timeout {
            device: DEVICE,
            what: format!("a reply to {:?}", request.text()),
            after_ms: timeout.as_millis() as u64,
        }))
}
