//! Replay mode: serve a recorded transcript on one connection. Device chunks are sent with
//! their recorded gaps; client chunks are awaited by byte count (the client may split or
//! coalesce writes), compared, and a mismatch is logged, not fatal.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::sync::CancellationToken;

use super::serve::{BoxIo, Conn, Handler};
use crate::transcript::{Direction, Transcript};

/// Longest pause honoured between two recorded device chunks.
const MAX_GAP: Duration = Duration::from_secs(2);

/// A handler that plays `t` to every client.
pub(crate) fn handler(t: Transcript) -> Handler {
    let t = Arc::new(t);
    Arc::new(move |io, conn: Conn| {
        let t = t.clone();
        Box::pin(async move { replay(io, &t, conn.token).await })
    })
}

/// Plays `t` to one client; returns when done, on EOF or on shutdown.
async fn replay(mut io: BoxIo, t: &Transcript, token: CancellationToken) {
    let mut pending: Vec<u8> = Vec::new();
    let mut last_t = 0u64;
    for c in t.chunks.iter().filter(|c| !c.udp) {
        let Ok(bytes) = c.bytes() else { return };
        match c.dir {
            Direction::FromDevice => {
                let gap = Duration::from_micros(c.t_us.saturating_sub(last_t)).min(MAX_GAP);
                tokio::select! {
                    _ = tokio::time::sleep(gap) => {}
                    _ = token.cancelled() => return,
                }
                if io.write_all(&bytes).await.is_err() {
                    return;
                }
                let _ = io.flush().await;
            }
            Direction::ToDevice => {
                while pending.len() < bytes.len() {
                    let mut buf = [0u8; 4096];
                    let n = tokio::select! {
                        r = io.read(&mut buf) => match r { Ok(n) => n, Err(_) => 0 },
                        _ = token.cancelled() => return,
                    };
                    if n == 0 {
                        return;
                    }
                    pending.extend_from_slice(&buf[..n]);
                }
                let got: Vec<u8> = pending.drain(..bytes.len()).collect();
                if !got.eq_ignore_ascii_case(&bytes) {
                    tracing::warn!(
                        expected = %bytes.escape_ascii(),
                        got = %got.escape_ascii(),
                        "replay: client sent different bytes than recorded"
                    );
                }
            }
        }
        last_t = c.t_us;
    }
    // Transcript finished: keep the connection open until the client leaves.
    super::serve::stall(&mut io, &token).await;
}
