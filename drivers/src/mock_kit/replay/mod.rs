//! Replay mode: serve a recorded transcript. Device chunks are sent with their recorded
//! gaps; client chunks are awaited by byte count (the client may split or coalesce writes)
//! and compared (ASCII case and redacted bytes ignored). A lab recording's connections are
//! served in order: the n-th client connection gets the chunks recorded on connection n (a
//! pty is one stream: it gets them all). A mismatch is logged; in strict mode it also ends
//! the replay, and every later connection is refused.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::sync::CancellationToken;

use super::serve::{BoxIo, Conn, Handler};
use crate::transcript::{Chunk, Direction, Transcript};

/// Longest pause honoured between two recorded device chunks.
const MAX_GAP: Duration = Duration::from_secs(2);

/// How a replay treats the client.
#[derive(Debug, Clone, Default)]
pub(crate) struct ReplayOptions {
    /// Names the transcript in messages (its file).
    pub label: String,
    /// A client that departs from the recording ends the replay (connection closed, error
    /// logged, later connections refused) instead of being logged and served on.
    pub strict: bool,
}

/// Shared by the connections of one replay.
struct Replay {
    t: Transcript,
    opts: ReplayOptions,
    connections: AtomicU32,
    failed: AtomicBool,
}

/// A handler that plays `t` to its clients.
pub(crate) fn handler(t: Transcript, opts: ReplayOptions) -> Handler {
    let r = Arc::new(Replay {
        t,
        opts,
        connections: AtomicU32::new(0),
        failed: AtomicBool::new(false),
    });
    Arc::new(move |io, conn: Conn| {
        let r = r.clone();
        Box::pin(async move { r.serve(io, conn).await })
    })
}

impl Replay {
    /// Serves one client connection its part of the recording.
    async fn serve(&self, io: BoxIo, conn: Conn) {
        let label = &self.opts.label;
        let n = self.connections.fetch_add(1, Ordering::SeqCst);
        if self.opts.strict && self.failed.load(Ordering::SeqCst) {
            tracing::error!(
                "replay {label}: connection {n} refused: the replay stopped at a mismatch"
            );
            return;
        }
        let per_conn = conn.peer.is_some() && self.t.has_connections();
        let chunks: Vec<&Chunk> = self
            .t
            .chunks
            .iter()
            .filter(|c| !c.udp && (!per_conn || c.conn == Some(n)))
            .collect();
        if per_conn && chunks.is_empty() {
            let recorded = self.t.chunks.iter().filter_map(|c| c.conn).max();
            let msg = format!(
                "replay {label}: connection {n} was not recorded (the recording has {})",
                recorded.map_or(0, |m| m + 1)
            );
            self.mismatch(msg);
            if self.opts.strict {
                return;
            }
        }
        self.play(io, &chunks, conn.token).await;
    }

    /// Logs a departure from the recording (an error in strict mode, which also stops).
    fn mismatch(&self, message: String) {
        if self.opts.strict {
            self.failed.store(true, Ordering::SeqCst);
            tracing::error!("{message}");
        } else {
            tracing::warn!("{message}");
        }
    }

    /// Plays `chunks` to one client; returns when done, on EOF, a strict mismatch or
    /// shutdown.
    async fn play(&self, mut io: BoxIo, chunks: &[&Chunk], token: CancellationToken) {
        let mut pending: Vec<u8> = Vec::new();
        let mut last_t = 0u64;
        for c in chunks {
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
                    if !read_at_least(&mut io, &mut pending, bytes.len(), &token).await {
                        return;
                    }
                    let got: Vec<u8> = pending.drain(..bytes.len()).collect();
                    if let Some(at) = c.first_difference(&bytes, &got) {
                        self.mismatch(describe(&self.opts.label, c, &bytes, &got, at));
                        if self.opts.strict {
                            return;
                        }
                    }
                }
            }
            last_t = c.t_us;
        }
        // Transcript finished: keep the connection open until the client leaves; in strict
        // mode anything more the client sends was not recorded.
        if self.opts.strict {
            if read_at_least(&mut io, &mut pending, 1, &token).await {
                let extra = String::from_utf8_lossy(&pending).escape_debug().to_string();
                self.mismatch(format!(
                    "replay {}: the client sent more than was recorded: {:.200}",
                    self.opts.label, extra
                ));
            }
            return;
        }
        super::serve::stall(&mut io, &token).await;
    }
}

/// Reads into `pending` until it holds `n` bytes; false on EOF, error or shutdown.
async fn read_at_least(
    io: &mut BoxIo,
    pending: &mut Vec<u8>,
    n: usize,
    token: &CancellationToken,
) -> bool {
    while pending.len() < n {
        let mut buf = [0u8; 4096];
        let k = tokio::select! {
            r = io.read(&mut buf) => r.unwrap_or(0),
            _ = token.cancelled() => return false,
        };
        if k == 0 {
            return false;
        }
        pending.extend_from_slice(&buf[..k]);
    }
    true
}

/// The mismatch message: which line of which recording, the recorded chunk's first line
/// (an HTTP request line names the command), and both sides around the first differing byte.
fn describe(label: &str, c: &Chunk, recorded: &[u8], got: &[u8], at: usize) -> String {
    let head: Vec<u8> = recorded
        .iter()
        .copied()
        .take_while(|b| *b != b'\r' && *b != b'\n')
        .take(120)
        .collect();
    let window = |b: &[u8]| {
        let from = at.saturating_sub(60);
        let to = (at + 60).min(b.len());
        b.get(from..to)
            .map(|s| s.escape_ascii().to_string())
            .unwrap_or_default()
    };
    format!(
        "replay {label}: the client's bytes differ from the recording at line {} (byte {at} \
         of {} in \"{}\"): recorded \"{}\", the client sent \"{}\"",
        c.line,
        recorded.len(),
        head.escape_ascii(),
        window(recorded),
        window(got)
    )
}

#[cfg(test)]
mod tests;
