//! Accept loops for the mocks: TCP listeners and pseudo-terminals, one task per connection,
//! all stopped by one cancellation token.

use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::Arc;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite};
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use super::MockError;

/// A byte stream a mock can serve on (TCP socket or pty master).
pub trait MockIo: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> MockIo for T {}

/// Boxed connection handed to a device handler.
pub type BoxIo = Box<dyn MockIo>;

/// Per-connection context.
#[derive(Debug, Clone)]
pub struct Conn {
    /// Client address (None on a pty).
    pub peer: Option<SocketAddr>,
    /// Cancelled when the mock shuts down.
    pub token: CancellationToken,
}

/// A device's connection handler.
pub type Handler =
    Arc<dyn Fn(BoxIo, Conn) -> Pin<Box<dyn Future<Output = ()> + Send>> + Send + Sync>;

/// A connection whose received bytes are logged at debug level (`RUST_LOG=debug` shows
/// every request a mock serves, as escaped text cut at 200 bytes).
struct Logged<T> {
    inner: T,
    peer: String,
}

impl<T: AsyncRead + Unpin> AsyncRead for Logged<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let r = Pin::new(&mut self.inner).poll_read(cx, buf);
        let got = &buf.filled()[before..];
        if !got.is_empty() && tracing::enabled!(tracing::Level::DEBUG) {
            let shown: String = got
                .iter()
                .take(200)
                .flat_map(|b| b.escape_ascii())
                .map(char::from)
                .collect();
            tracing::debug!(peer = %self.peer, bytes = got.len(), request = %shown, "mock received");
        }
        r
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for Logged<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }
    fn poll_flush(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// Accepts connections until `token` is cancelled; waits for the handlers to finish.
pub(crate) async fn serve_tcp(listener: TcpListener, token: CancellationToken, handler: Handler) {
    let tracker = TaskTracker::new();
    loop {
        tokio::select! {
            r = listener.accept() => match r {
                Ok((sock, peer)) => {
                    let _ = sock.set_nodelay(true);
                    let h = handler.clone();
                    let conn = Conn { peer: Some(peer), token: token.child_token() };
                    tracing::debug!(%peer, "mock connection");
                    let io = Logged { inner: sock, peer: peer.to_string() };
                    tracker.spawn(h(Box::new(io), conn));
                }
                Err(e) => {
                    tracing::warn!(error = %e, "accept failed");
                    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                }
            },
            _ = token.cancelled() => break,
        }
    }
    tracker.close();
    tracker.wait().await;
}

/// Keeps reading and discarding until the client leaves or shutdown: the `stall` fault.
pub(crate) async fn stall(io: &mut BoxIo, token: &CancellationToken) {
    let mut buf = [0u8; 1024];
    loop {
        tokio::select! {
            r = io.read(&mut buf) => if !matches!(r, Ok(n) if n > 0) { return },
            _ = token.cancelled() => return,
        }
    }
}

/// Serves `handler` on a new pseudo-terminal; returns the slave path (or `link` if given, a
/// symlink to it).
pub(crate) fn serve_pty(
    handler: Handler,
    link: Option<PathBuf>,
    tracker: &TaskTracker,
    token: &CancellationToken,
) -> Result<String, MockError> {
    use tokio_serial::SerialPort;
    let (master, slave) =
        tokio_serial::SerialStream::pair().map_err(|e| MockError::Pty(e.to_string()))?;
    let slave_path = slave
        .name()
        .ok_or_else(|| MockError::Pty("pty slave has no name".into()))?;
    let addr = match link {
        Some(p) => {
            let _ = std::fs::remove_file(&p);
            std::os::unix::fs::symlink(&slave_path, &p)
                .map_err(|e| MockError::Pty(format!("symlink {}: {e}", p.display())))?;
            p.display().to_string()
        }
        None => slave_path,
    };
    let conn = Conn {
        peer: None,
        token: token.child_token(),
    };
    tracker.spawn(async move {
        // Keep the slave open so the master does not see EIO between client opens.
        let _slave = slave;
        let io = Logged {
            inner: master,
            peer: "pty".into(),
        };
        handler(Box::new(io), conn).await;
    });
    Ok(addr)
}
