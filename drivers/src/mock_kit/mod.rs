//! The plumbing every mock device server shares, and nothing device-specific: accept loops
//! on TCP and pseudo-terminals ([`serve`]), the fault plan and the one place faults are
//! applied to a reply ([`fault`]), transcript replay, and the start functions around any
//! [`Handler`]. This module names no device: the device mocks (`<device>::mock`) import it,
//! and the registry ([`crate::mock`]) imports both.

pub mod fault;
pub(crate) mod replay;
pub mod serve;

use std::path::PathBuf;

use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

pub use fault::{DELAY_FAULT, FaultKind, FaultSpec, Faults};
pub use serve::{BoxIo, Conn, Handler};

use crate::transcript::TranscriptError;

/// Error starting a mock.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MockError {
    /// The listen address could not be bound.
    #[error("calibd-drivers: mock: cannot listen on {addr}: {source}")]
    Bind {
        /// Address asked for.
        addr: String,
        /// Bind error.
        #[source]
        source: std::io::Error,
    },
    /// The pseudo-terminal could not be created or linked.
    #[error("calibd-drivers: mock: pty: {0}")]
    Pty(String),
    /// The replay transcript is unreadable.
    #[error("calibd-drivers: mock: {0}")]
    Transcript(#[from] TranscriptError),
    /// The options do not fit the device.
    #[error("calibd-drivers: mock: {0}")]
    Usage(String),
}

/// A started mock.
#[derive(Debug)]
pub struct RunningMock {
    /// Where clients connect: `ip:port`, or a pty path for `uwave --pty`.
    pub addr: String,
    token: CancellationToken,
    tracker: TaskTracker,
    /// The symlink made to the pty, removed when the mock stops or is dropped (a dangling
    /// link would look like a configured serial port that vanished).
    link: Option<PathBuf>,
}

impl RunningMock {
    /// Stops accepting, closes every connection and waits for the tasks.
    pub async fn stop(mut self) {
        self.remove_link();
        self.token.cancel();
        self.tracker.close();
        self.tracker.wait().await;
    }

    fn remove_link(&mut self) {
        if let Some(p) = self.link.take()
            && std::fs::symlink_metadata(&p).is_ok_and(|m| m.file_type().is_symlink())
        {
            let _ = std::fs::remove_file(&p);
        }
    }
}

impl Drop for RunningMock {
    fn drop(&mut self) {
        self.remove_link();
    }
}

/// The tasks of one mock: every task a handler spawns (e.g. the CAN mock's drive) belongs to
/// `tracker` and stops with `token`; [`MockTasks::serve_tcp`] / [`MockTasks::serve_pty`]
/// turn them into a [`RunningMock`].
#[derive(Debug, Clone, Default)]
pub struct MockTasks {
    /// Tracks the mock's tasks.
    pub tracker: TaskTracker,
    /// Cancelled when the mock stops.
    pub token: CancellationToken,
}

impl MockTasks {
    /// Fresh tasks.
    pub fn new() -> Self {
        MockTasks::default()
    }

    /// Serves `handler` on a TCP listener bound to `listen`.
    pub async fn serve_tcp(self, listen: &str, handler: Handler) -> Result<RunningMock, MockError> {
        let bind = |source| MockError::Bind {
            addr: listen.to_string(),
            source,
        };
        let listener = TcpListener::bind(listen).await.map_err(bind)?;
        let addr = listener.local_addr().map_err(bind)?.to_string();
        self.tracker
            .spawn(serve::serve_tcp(listener, self.token.clone(), handler));
        Ok(self.running(addr))
    }

    /// Serves `handler` on a new pseudo-terminal; the address is the slave path, or `link`
    /// (a symlink to it) if given.
    pub fn serve_pty(
        self,
        handler: Handler,
        link: Option<PathBuf>,
    ) -> Result<RunningMock, MockError> {
        let addr = serve::serve_pty(handler, link.clone(), &self.tracker, &self.token)?;
        let mut running = self.running(addr);
        running.link = link;
        Ok(running)
    }

    fn running(self, addr: String) -> RunningMock {
        RunningMock {
            addr,
            token: self.token,
            tracker: self.tracker,
            link: None,
        }
    }
}

/// Starts a TCP mock around any handler (e.g. one built with a digital-twin model through
/// `qtm::mock::handler_with`, `rws::mock::handler_with`, ...).
pub async fn start_with(listen: &str, handler: Handler) -> Result<RunningMock, MockError> {
    MockTasks::new().serve_tcp(listen, handler).await
}

/// Starts a serial mock on a new pseudo-terminal around any handler (e.g. the U-WAVE
/// receiver of a digital-twin fixture through `uwave::mock::handler_with`); `addr` of the
/// result is the pty path clients open.
pub fn start_pty_with(handler: Handler) -> Result<RunningMock, MockError> {
    MockTasks::new().serve_pty(handler, None)
}

/// [`start_pty_with`], with `link` (if given) a symlink to the pty that clients open as
/// the configured serial port (an existing file there is replaced).
pub fn start_pty_at(handler: Handler, link: Option<PathBuf>) -> Result<RunningMock, MockError> {
    MockTasks::new().serve_pty(handler, link)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;

    #[tokio::test]
    async fn a_stopped_pty_mock_leaves_no_dangling_link() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("ttyUWAVE");
        let handler: Handler = Arc::new(|_io, _conn| Box::pin(async {}));
        let m = start_pty_at(handler.clone(), Some(link.clone())).unwrap();
        assert_eq!(m.addr, link.display().to_string());
        assert!(std::fs::symlink_metadata(&link).is_ok(), "the link is made");
        m.stop().await;
        assert!(
            std::fs::symlink_metadata(&link).is_err(),
            "the link is gone"
        );
        // Dropped without stop (an early return): gone too.
        let m = start_pty_at(handler, Some(link.clone())).unwrap();
        drop(m);
        assert!(std::fs::symlink_metadata(&link).is_err());
    }
}
