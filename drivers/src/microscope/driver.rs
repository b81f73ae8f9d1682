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
#[derive(Debug, Clone, Copy, PartialEq)]
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
