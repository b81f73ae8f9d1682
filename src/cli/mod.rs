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
