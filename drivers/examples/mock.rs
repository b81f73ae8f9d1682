//! Stand-alone `mock` runner (same arguments as `calibd mock`), used by the conformance
//! checks in `.ci/checks/20-drivers-conformance.sh`:
//! `cargo run -p calibd-drivers --example mock -- qtm --listen 127.0.0.1:0`.

use calibd_drivers::mock::{MockArgs, run};
use clap::Parser;

/// Runs one mock device server until Ctrl-C or SIGTERM.
#[derive(Debug, Parser)]
struct Cli {
    #[command(flatten)]
    args: MockArgs,
}

#[tokio::main]
async fn main() {
    let cli = Cli::parse();
    let shutdown = async {
        let mut term =
            match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(s) => s,
                Err(_) => return std::future::pending().await,
            };
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
    };
    if let Err(e) = run(cli.args, shutdown).await {
        eprintln!("{e}");
        std::process::exit(1);
    }
}
