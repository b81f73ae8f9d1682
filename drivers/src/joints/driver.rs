//! The joint-interface driver: one actor owning the connection (reconnecting with back-off),
//! a cheap cloneable [`JointsHandle`] whose calls are requests with a oneshot reply, and the
//! last known state on a `watch` channel. A `stop` jumps the queue: it is sent at once, even
//! while a move waits for its reply. A move that gets no reply in time is followed by a
//! best-effort `stop` before the link is dropped, so a lost reply never leaves a move running.

use std::collections::BTreeMap;
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio::sync::{mpsc, watch};
use tokio_util::codec::Framed;

use super::PROTOCOL;
use super::codec::{Identity, JointsCodec, Reply, Request};
use crate::actor::{Reply as Answer, call};
use crate::error::DriverError;
use crate::link::{Backoff, Connect, Link};

const DEVICE: &str = "joints";

/// Settings of the joint-interface driver.
#[derive(Debug, Clone, PartialEq)]
pub struct JointsConfig {
    /// Reply timeout of `hello`, `read` and `stop`, and the margin added to a move's.
    pub timeout: Duration,
    /// A move of duration `d` may take `d * move_slack + timeout` before it times out
    /// (controllers follow a trajectory a little late; >= 1).
    pub move_slack: f64,
    /// Reconnection back-off.
    pub backoff: Backoff,
}

impl Default for JointsConfig {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(2),
            move_slack: 1.5,
            backoff: Backoff::default(),
        }
    }
}

impl JointsConfig {
    /// Reply timeout of a move that takes `duration`.
    pub fn move_timeout(&self, duration: Duration) -> Duration {
        duration.mul_f64(self.move_slack.max(1.0)) + self.timeout
    }
}

/// The answer to `read`.
#[derive(Debug, Clone, PartialEq)]
pub struct JointsReading {
    /// Position of every joint (rad).
    pub positions_rad: BTreeMap<String, f64>,
    /// True while a move runs.
    pub moving: bool,
}

/// What the driver last knew of the robot (published on a `watch` channel).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JointsState {
    /// A connection is open.
    pub connected: bool,
    /// A move is under way: this driver's, or any move as the last `read` reported it.
    pub moving: bool,
    /// Last positions read or reached (rad); empty before the first.
    pub positions_rad: BTreeMap<String, f64>,
    /// The robot's `hello`, once asked.
    pub identity: Option<Identity>,
    /// Successful connections so far.
    pub connects: u64,
}

struct Call {
    request: Request,
    timeout: Duration,
    reply: Answer<Reply>,
}

/// Cheap, cloneable handle to the joint-interface actor.
#[derive(Debug, Clone)]
pub struct JointsHandle {
    tx: mpsc::Sender<Call>,
    stop_tx: mpsc::Sender<Answer<Reply>>,
    state: watch::Receiver<JointsState>,
    cfg: JointsConfig,
}

type Wire<C> = Framed<<C as Connect>::Io, JointsCodec>;

impl JointsHandle {
    /// Start the actor (it connects on the first request).
    pub fn connect<C: Connect>(connector: C, cfg: JointsConfig) -> Self {
        let (tx, mut rx) = mpsc::channel::<Call>(16);
        let (stop_tx, mut stop_rx) = mpsc::channel::<Answer<Reply>>(4);
        let (state_tx, state) = watch::channel(JointsState::default());
        let mut link = Link::new(DEVICE, connector, JointsCodec, cfg.backoff);
        let stop_timeout = cfg.timeout;
        tokio::spawn(async move {
            loop {
                let (request, timeout, reply) = tokio::select! {
                    biased;
                    Some(reply) = stop_rx.recv() => (Request::Stop, stop_timeout, reply),
                    c = rx.recv() => match c {
                        Some(c) => (c.request, c.timeout, c.reply),
                        None => break,
                    },
                };
                let op = request.op();
                if matches!(request, Request::Move { .. }) {
                    state_tx.send_modify(|s| s.moving = true);
                }
                let r = exchange(&mut link, &request, timeout, &mut stop_rx, stop_timeout).await;
                if let Err(e) = &r {
                    tracing::debug!(device = DEVICE, op, error = %e, "request failed");
                    if e.breaks_link() {
                        link.reset();
                    }
                }
                let connects = link.connects;
                let up = link.is_up();
                state_tx.send_modify(|s| {
                    s.connected = up;
                    s.connects = connects;
                    if op == "move" {
                        s.moving = false;
                    }
                    match &r {
                        Ok(Reply::State {
                            positions_rad,
                            moving,
                        }) => {
                            s.positions_rad = positions_rad.clone();
                            s.moving = *moving;
                        }
                        Ok(Reply::Reached { positions_rad }) => {
                            s.positions_rad = positions_rad.clone()
                        }
                        Ok(Reply::Hello(id)) => s.identity = Some(id.clone()),
                        _ => {}
                    }
                });
                let _ = reply.send(r);
            }
        });
        Self {
            tx,
            stop_tx,
            state,
            cfg,
        }
    }

    /// The driver's last known state (connection, moving, positions, identity).
    pub fn state(&self) -> watch::Receiver<JointsState> {
        self.state.clone()
    }

    async fn ask(&self, request: Request, timeout: Duration) -> Result<Reply, DriverError> {
        let r = call(&self.tx, DEVICE, |reply| Call {
            request,
            timeout,
            reply,
        })
        .await?;
        device_reply(r)
    }

    /// Identity, joints and limits of the robot; refuses a server of another protocol.
    pub async fn hello(&self) -> Result<Identity, DriverError> {
        match self.ask(Request::Hello, self.cfg.timeout).await? {
            Reply::Hello(id) if id.protocol == PROTOCOL => Ok(id),
            Reply::Hello(id) => Err(DriverError::Protocol {
                device: DEVICE,
                detail: format!("server speaks {:?}, not {PROTOCOL}", id.protocol),
            }),
            other => Err(unexpected("hello", &other)),
        }
    }

    /// Current positions and whether a move runs.
    pub async fn read(&self) -> Result<JointsReading, DriverError> {
        match self.ask(Request::Read, self.cfg.timeout).await? {
            Reply::State {
                positions_rad,
                moving,
            } => Ok(JointsReading {
                positions_rad,
                moving,
            }),
            other => Err(unexpected("read", &other)),
        }
    }

    /// Move the named joints to `positions_rad` in `duration` and return the positions
    /// reached once the robot is there. Times out after [`JointsConfig::move_timeout`].
    pub async fn move_to(
        &self,
        positions_rad: BTreeMap<String, f64>,
        duration: Duration,
    ) -> Result<BTreeMap<String, f64>, DriverError> {
        if let Some((k, v)) = positions_rad.iter().find(|(_, v)| !v.is_finite()) {
            return Err(DriverError::InvalidRequest {
                device: DEVICE,
                detail: format!("target of {k} is {v}, not a finite number"),
            });
        }
        let timeout = self.cfg.move_timeout(duration);
        tracing::debug!(
            device = DEVICE,
            joints = positions_rad.len(),
            duration_s = duration.as_secs_f64(),
            "move"
        );
        let request = Request::Move {
            positions_rad,
            duration_s: duration.as_secs_f64(),
        };
        match self.ask(request, timeout).await? {
            Reply::Reached { positions_rad } => Ok(positions_rad),
            other => Err(unexpected("move", &other)),
        }
    }

    /// Halt any move in progress (sent at once, ahead of queued requests).
    pub async fn stop(&self) -> Result<(), DriverError> {
        let r = call(&self.stop_tx, DEVICE, |reply| reply).await?;
        match device_reply(r)? {
            Reply::Done => Ok(()),
            other => Err(unexpected("stop", &other)),
        }
    }
}

/// The server's error reply as `DriverError::Device` (code numbers as in the protocol).
fn device_reply(r: Reply) -> Result<Reply, DriverError> {
    match r {
        Reply::Error { code, message } => Err(DriverError::Device {
            device: DEVICE,
            code: code.number(),
            message: format!("{}: {message}", code.as_str()),
        }),
        other => Ok(other),
    }
}

fn unexpected(op: &str, got: &Reply) -> DriverError {
    DriverError::Protocol {
        device: DEVICE,
        detail: format!("reply {} to {op}", got.text()),
    }
}

async fn next_reply<C: Connect>(f: &mut Wire<C>) -> Result<Reply, DriverError> {
    match f.next().await {
        Some(Ok(r)) => Ok(r),
        Some(Err(e)) => Err(DriverError::from_codec(DEVICE, e)),
        None => Err(DriverError::Closed { device: DEVICE }),
    }
}

async fn send<C: Connect>(f: &mut Wire<C>, r: Request) -> Result<(), DriverError> {
    f.send(r)
        .await
        .map_err(|e| DriverError::from_codec(DEVICE, e))
}

/// One request and its reply. While a move waits for its reply, a `stop` asked for meanwhile
/// is sent at once; its own reply follows the move's and is delivered here.
async fn exchange<C: Connect>(
    link: &mut Link<C, JointsCodec>,
    request: &Request,
    timeout: Duration,
    stops: &mut mpsc::Receiver<Answer<Reply>>,
    stop_timeout: Duration,
) -> Result<Reply, DriverError> {
    let (f, fresh) = link.ensure().await?;
    if fresh {
        tracing::debug!(device = DEVICE, "connected");
    }
    let is_move = matches!(request, Request::Move { .. });
    let mut stopping: Vec<Answer<Reply>> = Vec::new();
    let work = async {
        // Anything unread belongs to an earlier, abandoned exchange.
        f.read_buffer_mut().clear();
        send::<C>(f, request.clone()).await?;
        loop {
            let stop = tokio::select! {
                r = next_reply::<C>(f) => return r,
                Some(s) = stops.recv(), if is_move => s,
            };
            tracing::info!(device = DEVICE, "stop during a move");
            stopping.push(stop);
            send::<C>(f, Request::Stop).await?;
        }
    };
    let r = tokio::time::timeout(timeout, work).await;
    let r = match r {
        Ok(r) => r,
        Err(_) => {
            if is_move {
                // The robot may still be moving: ask it to stop, without waiting for more.
                let _ = tokio::time::timeout(stop_timeout, send::<C>(f, Request::Stop)).await;
                tracing::warn!(
                    device = DEVICE,
                    after_ms = timeout.as_millis() as u64,
                    "move timed out; stop sent"
                );
            }
            Err(DriverError::Timeout {
                device: DEVICE,
                what: format!("a reply to {}", request.op()),
                after_ms: timeout.as_millis() as u64,
            })
        }
    };
    // The stops' replies follow the move's, in order.
    let mut broken = false;
    for s in stopping {
        let sr = if r.is_ok() || matches!(&r, Err(e) if !e.breaks_link()) {
            tokio::time::timeout(stop_timeout, next_reply::<C>(f))
                .await
                .unwrap_or(Err(DriverError::Timeout {
                    device: DEVICE,
                    what: "a reply to stop".into(),
                    after_ms: stop_timeout.as_millis() as u64,
                }))
        } else {
            Err(r.as_ref().err().map_or(
                DriverError::Closed { device: DEVICE },
                DriverError::duplicate,
            ))
        };
        broken |= matches!(&sr, Err(e) if e.breaks_link());
        let _ = s.send(sr);
    }
    if broken {
        link.reset();
    }
    r
}
