//! `calibd mock ...`: mock device servers, one device or the cells of a lab file.

use std::ffi::OsString;
use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;
use tokio::io::AsyncBufReadExt;

use super::{init_tracing, runtime};

/// `calibd mock DEVICE ...`: one mock device server until Ctrl-C.
pub(crate) fn device(args: calibd_drivers::mock::MockArgs) -> Result<()> {
    // The log on stderr: requests at debug level, a replay's mismatches as errors.
    init_tracing(false);
    let rt = tokio::runtime::Runtime::new()?;
    Ok(rt.block_on(async { calibd_drivers::mock::run(args, super::shutdown_signal()).await })?)
}

/// The arguments of `calibd mock lab ...` when `argv` is that command (it takes a lab file
/// rather than one device, so it has its own parser); `None` for every other command.
pub(crate) fn lab_args(argv: &[OsString]) -> Option<MockLabCli> {
    if argv.get(1).is_some_and(|a| a == "mock") && argv.get(2).is_some_and(|a| a == "lab") {
        Some(MockLabCli::parse_from(argv.iter().skip(2)))
    } else {
        None
    }
}

/// `calibd mock lab`: serve the devices of a lab file's cells from the digital twins; the
/// operator's hands on standard input, one a line: `mate CELL` (the centring device on its
/// coupling platform), `unmate CELL` (back on the flange), `set CELL` (the set buttons).
#[derive(Debug, Parser)]
#[command(name = "calibd mock lab")]
pub(crate) struct MockLabCli {
    /// The lab file whose cells to serve (at its addresses; serial ports become symlinks
    /// to pseudo-terminals).
    #[arg(long)]
    config: PathBuf,
    /// Serve only this cell (repeatable; default every cell).
    #[arg(long = "cell")]
    cells: Vec<String>,
    /// Seed of the twins (the daemon's `lab_seed` for the same twins as `lab = "sim"`).
    #[arg(long, default_value_t = 7)]
    seed: u64,
}

/// `calibd mock lab ...`: the twins of a lab file, until interrupted.
pub(crate) fn lab(args: MockLabCli) -> Result<()> {
    init_tracing(false);
    let rt = runtime()?;
    rt.block_on(async move {
        // Ctrl-C or SIGTERM: stop the servers, which removes the pty symlinks.
        let stop = super::shutdown_signal();
        tokio::pin!(stop);
        let lab = calibd::sim::lab::serve(
            &args.config,
            &args.cells,
            args.seed,
            &calibd::lab::config::ProcessEnv,
        )
        .await?;
        for d in &lab.devices {
            println!("mock {} ready on {}", d.device, d.address);
        }
        println!("mock lab ready");
        // The operator's hands, one action a line on standard input (until it closes).
        let mut lines = tokio::io::BufReader::new(tokio::io::stdin()).lines();
        let mut open = true;
        loop {
            tokio::select! {
                _ = &mut stop => break,
                l = lines.next_line(), if open => match l {
                    Ok(Some(l)) if l.trim().is_empty() => {}
                    Ok(Some(l)) => match lab.command(&l) {
                        Ok(done) => println!("mock {done}"),
                        Err(e) => println!("mock refused: {e}"),
                    },
                    _ => open = false,
                },
            }
        }
        lab.stop().await;
        Ok(())
    })
}
