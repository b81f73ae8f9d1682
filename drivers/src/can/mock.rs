//! The CAN mock: a socketcand hub (TCP, raw mode) that forwards every `send` to all other
//! clients as a `frame`, with one simulated CiA 402 drive (node 1) attached to the bus.

use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use futures_util::{SinkExt, StreamExt};
use tokio::io::AsyncWriteExt;
use tokio::sync::broadcast;
use tokio_util::codec::Framed;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use super::canopen::{SDO_TX, SdoResponse, response};
use super::frame::CanFrame;
use super::node::{Drive, DriveModel, LinearAxis};
use super::socketcand::{SocketcandCodec, frame_body, parse_send};
use crate::mock::fault::{DELAY_FAULT, GARBAGE};
use crate::mock::{BoxIo, Conn, FaultKind, Faults, Handler, MockArgs, serve};

/// Bus id of the simulated drive (clients get ids from 1).
const NODE_ID: u64 = 0;

/// Builds the hub handler with one drive (node 1) and starts the drive's task.
pub(crate) fn handler(
    args: &MockArgs,
    faults: Faults,
    tracker: &TaskTracker,
    token: &CancellationToken,
) -> Handler {
    let _ = args;
    handler_with(Box::new(LinearAxis), faults, tracker, token)
}

/// Hub handler around any drive model.
pub fn handler_with(
    model: Box<dyn DriveModel>,
    faults: Faults,
    tracker: &TaskTracker,
    token: &CancellationToken,
) -> Handler {
    let (bus, _) = broadcast::channel::<(u64, CanFrame)>(4096);
    let drive = Arc::new(Mutex::new(Drive::new(1, model)));
    // The drive: answers SDO requests, integrates motion every millisecond.
    let (b2, d2, t2) = (bus.clone(), drive.clone(), token.clone());
    let mut rx = bus.subscribe();
    tracker.spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(1));
        let mut last = tokio::time::Instant::now();
        loop {
            tokio::select! {
                _ = t2.cancelled() => return,
                _ = tick.tick() => {
                    let now = tokio::time::Instant::now();
                    if let Ok(mut d) = d2.lock() { d.tick((now - last).as_secs_f64()); }
                    last = now;
                }
                m = rx.recv() => match m {
                    Ok((from, f)) if from != NODE_ID => {
                        let reply = d2.lock().ok().and_then(|mut d| d.on_frame(&f));
                        if let Some(r) = reply {
                            let _ = b2.send((NODE_ID, r));
                        }
                    }
                    Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(_) => return,
                },
            }
        }
    });
    let next_id = Arc::new(std::sync::atomic::AtomicU64::new(1));
    Arc::new(move |io, conn| {
        let id = next_id.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        Box::pin(client(io, conn, id, bus.clone(), faults.clone()))
    })
}

fn now() -> Duration {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default()
}

async fn client(
    io: BoxIo,
    conn: Conn,
    id: u64,
    bus: broadcast::Sender<(u64, CanFrame)>,
    faults: Faults,
) {
    let mut f = Framed::new(io, SocketcandCodec);
    // Each greeting/ack is its own write: python-can reads `< hi >` with one recv().
    if f.send("hi".to_string()).await.is_err() {
        return;
    }
    let mut raw = false;
    let mut rx = bus.subscribe();
    loop {
        tokio::select! {
            _ = conn.token.cancelled() => return,
            m = f.next() => {
                let words = match m { Some(Ok(w)) => w, _ => return };
                let reply = match words.first().map(String::as_str) {
                    Some("open") if words.len() == 2 => Some("ok".to_string()),
                    Some("rawmode") => { raw = true; Some("ok".to_string()) }
                    Some("echo") => Some("echo".to_string()),
                    Some("send") if raw => match parse_send(&words) {
                        Ok(frame) => { let _ = bus.send((id, frame)); None }
                        Err(_) => Some("error could not parse send".to_string()),
                    },
                    _ => Some("error unknown command".to_string()),
                };
                if let Some(r) = reply {
                    if f.send(r).await.is_err() { return; }
                }
            }
            m = rx.recv(), if raw => match m {
                Ok((from, frame)) if from != id => {
                    let mut frame = frame;
                    match faults.next() {
                        None => {}
                        Some(FaultKind::Delay) => tokio::time::sleep(DELAY_FAULT).await,
                        Some(FaultKind::Drop) => return,
                        Some(FaultKind::Stall) => {
                            let mut io = f.into_inner();
                            serve::stall(&mut io, &conn.token).await;
                            return;
                        }
                        Some(FaultKind::Garbage) => {
                            if f.get_mut().write_all(GARBAGE).await.is_err() { return; }
                            continue;
                        }
                        Some(FaultKind::Truncate) => {
                            let text = format!("< {} >", frame_body(&frame, now()));
                            let _ = f.get_mut().write_all(&text.as_bytes()[..text.len() / 2]).await;
                            return;
                        }
                        Some(FaultKind::DeviceError) => {
                            // An SDO response becomes an abort: not in the present device state.
                            if (frame.id & !0x7f) == u32::from(SDO_TX) && frame.data.len() == 8 {
                                let d = &frame.data;
                                let a = SdoResponse::Abort { index: u16::from_le_bytes([d[1], d[2]]), sub: d[3], code: 0x0800_0022 };
                                frame.data = response(&a).to_vec();
                            }
                        }
                    }
                    if f.send(frame_body(&frame, now())).await.is_err() { return; }
                }
                Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(_) => return,
            },
        }
    }
}
