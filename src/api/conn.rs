//! The connection loop: hyper's HTTP/1 server under the axum router, with the limits that
//! keep a hostile or broken client from exhausting the daemon (`axum::serve` sets none):
//! a bound on open connections, a fair share of them per peer address (one more is closed
//! at once), a reserve of slots only operators' requests may use, a time limit for a
//! request's headers that also closes idle keep-alive connections, a bound on the header
//! size, and a time limit for a client that takes none of the bytes sent to it (an event
//! stream nobody reads). Graceful shutdown: open connections finish their request in
//! flight, then close.

use std::collections::HashMap;
use std::future::Future;
use std::hash::Hash;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

/// Connection limits of the HTTP server.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServeLimits {
    /// Most open connections, the operators' reserve included.
    pub max_connections: usize,
    /// Most open connections from one peer address.
    pub max_connections_per_address: usize,
    /// Slots of `max_connections` (at most half) only operators' requests may use: a
    /// request without an operator token on one of them is answered 503 and the
    /// connection closed.
    pub operator_reserve: usize,
    /// Most event streams (`/v1/events`, `/v1/jobs/{id}/events`) open at once per token
    /// (per address without a token).
    pub max_event_streams_per_token: usize,
    /// Time to send a request's headers (and the longest idle keep-alive).
    pub header_read_timeout: Duration,
    /// Largest request head (request line and headers), bytes; hyper answers 431 above.
    pub max_header_bytes: usize,
    /// Longest a client may take none of the bytes sent to it before it is disconnected.
    pub send_timeout: Duration,
}

impl Default for ServeLimits {
    fn default() -> Self {
        Self {
            max_connections: 512,
            max_connections_per_address: 64,
            operator_reserve: 32,
            max_event_streams_per_token: 16,
            header_read_timeout: Duration::from_secs(10),
            max_header_bytes: 64 * 1024,
            send_timeout: Duration::from_secs(60),
        }
    }
}

/// What a request knows of its connection (a request extension).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Peer {
    /// The client's address.
    pub addr: SocketAddr,
    /// The connection holds one of the operators' reserved slots.
    pub reserved: bool,
}

/// Counts per key (peer address, token) with a limit each: a [`Share`] is held while the
/// thing counted is open and given back when dropped.
#[derive(Debug)]
pub(crate) struct Shares<K: Eq + Hash> {
    limit: usize,
    held: Mutex<HashMap<K, usize>>,
}

/// One unit of a key's share; given back on drop.
#[derive(Debug)]
pub(crate) struct Share<K: Eq + Hash + Clone> {
    shares: Arc<Shares<K>>,
    key: K,
}

impl<K: Eq + Hash + Clone> Shares<K> {
    pub(crate) fn new(limit: usize) -> Arc<Self> {
        Arc::new(Shares {
            limit,
            held: Mutex::new(HashMap::new()),
        })
    }

    /// The limit per key.
    pub(crate) fn limit(&self) -> usize {
        self.limit
    }

    /// One more for `key`, unless it already holds its limit.
    pub(crate) fn take(self: &Arc<Self>, key: K) -> Option<Share<K>> {
        let mut held = self.held.lock().unwrap_or_else(|p| p.into_inner());
        let n = held.entry(key.clone()).or_insert(0);
        if *n >= self.limit {
            return None;
        }
        *n += 1;
        Some(Share {
            shares: self.clone(),
            key,
        })
    }
}

impl<K: Eq + Hash + Clone> Drop for Share<K> {
    fn drop(&mut self) {
        let mut held = self.shares.held.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = held.get_mut(&self.key) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                held.remove(&self.key);
            }
        }
    }
}

/// The answer to a connection refused at accept (written if the socket takes it at once).
const REFUSED: &[u8] = b"HTTP/1.1 503 Service Unavailable\r\nconnection: close\r\n\
retry-after: 5\r\ncontent-length: 0\r\n\r\n";

/// Refuse `stream`: a best-effort 503, then close.
fn refuse(stream: TcpStream, peer: SocketAddr, why: &'static str, limit: usize) {
    metrics::counter!("calibd_http_connections_refused_total", "reason" => why).increment(1);
    tracing::debug!(%peer, reason = why, limit, "connection refused");
    let _ = stream.try_write(REFUSED);
}

/// Serve `router` on `listener` until `shutdown` completes, then drain open connections.
pub(super) async fn serve(
    listener: TcpListener,
    router: Router,
    limits: ServeLimits,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let max = limits.max_connections.max(1);
    // At most half the slots: a small limit keeps a general pool.
    let reserve = limits.operator_reserve.min(max / 2);
    let general = Arc::new(Semaphore::new(max - reserve));
    let reserved = Arc::new(Semaphore::new(reserve));
    let per_address = Shares::<IpAddr>::new(limits.max_connections_per_address.max(1));
    let tracker = TaskTracker::new();
    let stop = CancellationToken::new();
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout)
        .max_header_size(limits.max_header_bytes)
        .max_buf_size(limits.max_header_bytes.max(8192));
    let service = TowerToHyperService::new(router);
    tokio::pin!(shutdown);
    loop {
        let (stream, peer) = tokio::select! {
            r = listener.accept() => match r {
                Ok(x) => x,
                Err(e) => {
                    // Out of file descriptors and the like: back off instead of spinning.
                    tracing::warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        let Some(share) = per_address.take(peer.ip().to_canonical()) else {
            refuse(stream, peer, "per_address", per_address.limit());
            continue;
        };
        // The general slots first; beyond them, the operators' reserve.
        let (slot, in_reserve) = match general.clone().try_acquire_owned() {
            Ok(s) => (s, false),
            Err(_) => match reserved.clone().try_acquire_owned() {
                Ok(s) => (s, true),
                Err(_) => {
                    refuse(stream, peer, "limit", max);
                    continue;
                }
            },
        };
        let _ = stream.set_nodelay(true);
        set_user_timeout(&stream, limits.send_timeout);
        let since = Arc::new(AtomicU64::new(0));
        let epoch = Instant::now();
        let io = Watched {
            io: stream,
            epoch,
            blocked_since: since.clone(),
        };
        let info = Peer {
            addr: peer,
            reserved: in_reserve,
        };
        let inner = service.clone();
        let svc =
            hyper::service::service_fn(move |mut req: hyper::Request<hyper::body::Incoming>| {
                req.extensions_mut().insert(info);
                hyper::service::Service::call(&inner, req)
            });
        let conn = builder.serve_connection(TokioIo::new(io), svc);
        let stop = stop.clone();
        let send_timeout = limits.send_timeout;
        tracker.spawn(async move {
            let _slot = (slot, share);
            tokio::pin!(conn);
            let r = tokio::select! {
                r = conn.as_mut() => r,
                () = stop.cancelled() => {
                    conn.as_mut().graceful_shutdown();
                    conn.await
                }
                () = stalled(&since, epoch, send_timeout) => {
                    metrics::counter!("calibd_http_stalled_clients_closed_total").increment(1);
                    tracing::info!(%peer, timeout_s = send_timeout.as_secs_f64(),
                        "client disconnected: it took none of the bytes sent to it");
                    return;
                }
            };
            if let Err(e) = r {
                tracing::debug!(%peer, error = %e, "connection ended with an error");
            }
        });
    }
    stop.cancel();
    tracker.close();
    tracker.wait().await;
    Ok(())
}

/// Completes once a write has been waiting for `timeout` for the client to take bytes
/// (`since`: as [`Watched`] notes it, from `epoch`).
async fn stalled(since: &AtomicU64, epoch: Instant, timeout: Duration) {
    let check = (timeout / 4).clamp(Duration::from_millis(10), Duration::from_secs(1));
    let limit = timeout.as_millis() as u64;
    loop {
        tokio::time::sleep(check).await;
        let s = since.load(Ordering::Relaxed);
        let now = epoch.elapsed().as_millis() as u64 + 1;
        if s != 0 && now.saturating_sub(s) >= limit {
            return;
        }
    }
}

/// The kernel's own bound on bytes the client leaves unacknowledged or untaken (a zero
/// receive window): the connection is reset after `timeout`, even while the daemon's
/// send buffer still has room (TCP_USER_TIMEOUT, Linux).
#[cfg(target_os = "linux")]
fn set_user_timeout(stream: &TcpStream, timeout: Duration) {
    use std::os::fd::AsRawFd;
    let ms = libc::c_uint::try_from(timeout.as_millis()).unwrap_or(libc::c_uint::MAX);
    // SAFETY: a valid socket descriptor and a c_uint option value of the right size.
    let r = unsafe {
        libc::setsockopt(
            stream.as_raw_fd(),
            libc::IPPROTO_TCP,
            libc::TCP_USER_TIMEOUT,
            (&ms as *const libc::c_uint).cast(),
            std::mem::size_of::<libc::c_uint>() as libc::socklen_t,
        )
    };
    if r != 0 {
        tracing::debug!(error = %std::io::Error::last_os_error(), "TCP_USER_TIMEOUT not set");
    }
}

#[cfg(not(target_os = "linux"))]
fn set_user_timeout(_: &TcpStream, _: Duration) {}

/// The socket, noting since when (ms after `epoch`, plus one; 0 = not waiting) a write
/// has been waiting for the client to take bytes.
struct Watched {
    io: TcpStream,
    epoch: Instant,
    blocked_since: Arc<AtomicU64>,
}

impl Watched {
    fn note<T>(&self, r: &Poll<std::io::Result<T>>) {
        match r {
            Poll::Pending => {
                let now = self.epoch.elapsed().as_millis() as u64 + 1;
                let _ = self.blocked_since.compare_exchange(
                    0,
                    now,
                    Ordering::Relaxed,
                    Ordering::Relaxed,
                );
            }
            Poll::Ready(_) => self.blocked_since.store(0, Ordering::Relaxed),
        }
    }
}

impl AsyncRead for Watched {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_read(cx, buf)
    }
}

impl AsyncWrite for Watched {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let r = Pin::new(&mut self.io).poll_write(cx, buf);
        self.note(&r);
        r
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let r = Pin::new(&mut self.io).poll_write_vectored(cx, bufs);
        self.note(&r);
        r
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_are_bounded_per_key_and_given_back() {
        let s = Shares::<u8>::new(2);
        let a = s.take(1).unwrap();
        let b = s.take(1).unwrap();
        assert!(s.take(1).is_none(), "a third over the limit of 2");
        assert!(s.take(2).is_some(), "another key has its own share");
        drop(a);
        let c = s.take(1);
        assert!(c.is_some(), "a share given back is taken again");
        drop((b, c));
        assert!(s.held.lock().unwrap().is_empty(), "no key is kept at zero");
    }
}
