//! Small helpers for the handle/actor pattern used by every driver: a request carries a
//! oneshot reply; a gone actor becomes `DriverError::ActorGone`.

use tokio::sync::{mpsc, oneshot};

use crate::error::DriverError;

/// Reply channel carried inside a request.
pub type Reply<T> = oneshot::Sender<Result<T, DriverError>>;

/// Sends a request built by `make` and waits for its reply.
pub(crate) async fn call<R, T>(
    tx: &mpsc::Sender<R>,
    device: &'static str,
    make: impl FnOnce(Reply<T>) -> R,
) -> Result<T, DriverError> {
    let (rtx, rrx) = oneshot::channel();
    tx.send(make(rtx))
        .await
        .map_err(|_| DriverError::ActorGone { device })?;
    rrx.await.map_err(|_| DriverError::ActorGone { device })?
}

/// Waits for the next item of an optional stream; pending forever when there is none, so
/// it can sit in a `select!` while the link is down.
pub(crate) async fn next_or_pending<S>(s: Option<&mut S>) -> Option<S::Item>
where
    S: futures_util::Stream + Unpin,
{
    use futures_util::StreamExt;
    match s {
        Some(s) => s.next().await,
        None => std::future::pending().await,
    }
}
