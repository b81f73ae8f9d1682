//! The subcommands of the `calibd` binary, one file per group; `main.rs` only parses and
//! dispatches.

pub(crate) mod bench;
pub(crate) mod daemon;
pub(crate) mod jobs;
pub(crate) mod lab;
pub(crate) mod mock;
pub(crate) mod run;
pub(crate) mod store;
pub(crate) mod twin;

use anyhow::Result;

/// The multi-threaded runtime a subcommand's async work runs on.
pub(crate) fn runtime() -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?)
}

/// The log on stderr (`RUST_LOG`, default `info`), as text or JSON lines.
pub(crate) fn init_tracing(json: bool) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,tower_http=info"));
    let b = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    if json {
        b.json().init();
    } else {
        b.init();
    }
}

/// Resolves on Ctrl-C or SIGTERM: the daemon's and the mocks' signal to shut down (a mock
/// then removes its pty symlinks). SIGTERM is caught from the call on (inside a runtime).
pub(crate) fn shutdown_signal() -> impl std::future::Future<Output = ()> {
    #[cfg(unix)]
    let term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
    async move {
        let ctrl_c = async {
            let _ = tokio::signal::ctrl_c().await;
        };
        #[cfg(unix)]
        let term = async move {
            match term {
                Some(mut s) => {
                    s.recv().await;
                }
                None => std::future::pending::<()>().await,
            }
        };
        #[cfg(not(unix))]
        let term = std::future::pending::<()>();
        tokio::select! { _ = ctrl_c => {}, _ = term => {} }
        tracing::info!("shutting down");
    }
}
