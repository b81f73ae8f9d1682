//! The CAN mock: a socketcand hub (TCP, raw mode) that forwards every `send` to all other
//! clients as a `frame`, with one simulated CiA 402 drive (node 1) attached to the bus.

use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use futures_util::{SinkExt, StreamExt};
use tokio::sync::broadcast;
use tokio_util::codec::Framed;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use super::canopen::{SDO_TX, SdoResponse, response};
use super::frame::CanFrame;
use super::node::{Drive, DriveModel, LinearAxis};
use super::socketcand::{SocketcandCodec, frame_body, parse_send};
use crate::mock_kit::fault::Fate;
use crate::mock_kit::{BoxIo, Conn, Faults, Handler};

/// Bus id of the simulated drive (clients get ids from 1).
const NODE_ID: u64 = 0;

/// Builds the hub handler with one drive (node 1) and starts the drive's task.
pub(crate) fn handler(faults: Faults, tracker: &TaskTracker, token: &CancellationToken) -> Handler {
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
                if let Some(r) = reply
                    && f.send(r).await.is_err() { return; }
            }
            m = rx.recv(), if raw => match m {
                Ok((from, frame)) if from != id => {
                    let wire = |fr: &CanFrame| format!("< {} >", frame_body(fr, now())).into_bytes();
                    match faults.apply(f.get_mut(), &conn.token, frame, wire, sdo_abort).await {
                        Fate::Send(frame) => if f.send(frame_body(&frame, now())).await.is_err() { return },
                        Fate::Skipped => continue,
                        Fate::Close => return,
                    }
                }
                Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(_) => return,
            },
        }
    }
}

/// The `device-error` fault: an SDO response becomes an abort (not in the present device
/// state); other frames pass unchanged.
fn sdo_abort(mut frame: CanFrame) -> CanFrame {
    if (frame.id & !0x7f) == u32::from(SDO_TX) && frame.data.len() == 8 {
        let d = &frame.data;
        let a = SdoResponse::Abort {
            index: u16::from_le_bytes([d[1], d[2]]),
            sub: d[3],
            code: 0x0800_0022,
        };
        frame.data = response(&a).to_vec();
    }
    frame
}
