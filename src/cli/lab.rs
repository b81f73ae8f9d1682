//! `calibd lab ...`: the configured lab's devices.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::Subcommand;

use super::runtime;

#[derive(Debug, Subcommand)]
pub(crate) enum LabCommand {
    /// Connect to every device of the lab and print a table: device, address, identity or
    /// error and what to fix. Exits non-zero if any device fails.
    Check {
        /// The lab file (default: the `lab` of the daemon's settings: CALIBD_CONFIG and
        /// CALIBD_* variables; `sim` checks the simulated lab).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Longest wait for each device (s).
        #[arg(long, default_value_t = 5.0)]
        timeout_s: f64,
        /// Print the check as JSON (as `GET /v1/lab`) instead of a table.
        #[arg(long)]
        json: bool,
    },
}

/// Run a `calibd lab` subcommand.
pub(crate) fn lab(command: LabCommand) -> Result<()> {
    match command {
        LabCommand::Check {
            config,
            timeout_s,
            json,
        } => check(config, timeout_s, json),
    }
}

/// `calibd lab check`: build the lab, probe every device, print, exit 1 on any failure.
fn check(config: Option<PathBuf>, timeout_s: f64, json: bool) -> Result<()> {
    let lab_path = match config {
        Some(p) => p.display().to_string(),
        None => {
            let file = std::env::var_os("CALIBD_CONFIG").map(PathBuf::from);
            calibd::config::Config::load(file.as_deref(), &|k| std::env::var(k).ok())?.lab
        }
    };
    if !(timeout_s > 0.0 && timeout_s.is_finite()) {
        bail!("--timeout-s must be positive");
    }
    let timeout = std::time::Duration::from_secs_f64(timeout_s);
    let simulated = lab_path == "sim";
    let rt = runtime()?;
    let reports = rt.block_on(async {
        let lab = match lab_path.as_str() {
            "none" => bail!("the settings say lab = \"none\": name a lab file with --config"),
            "sim" => calibd::lab::Lab::simulated(&calibd::sim::SimOptions::default()).await?,
            file => {
                let cells =
                    calibd::lab::config::load(Path::new(file), &calibd::lab::config::ProcessEnv)?;
                calibd::lab::Lab::connect(cells)?
            }
        };
        let r = lab.check(timeout).await;
        lab.stop().await;
        Ok(r)
    })?;
    if simulated {
        // On stderr with --json, so the JSON stays the reports array.
        let banner = "SIMULATED LAB: digital twins behind mock devices on loopback (lab = \"sim\"), not your robots; name a lab file (--config FILE) to check real devices";
        if json {
            eprintln!("{banner}");
        } else {
            println!("{banner}");
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    } else {
        print!("{}", calibd::lab::devices::table(&reports));
    }
    let failed = reports
        .iter()
        .filter(|r| !matches!(r.status, calibd::lab::DeviceStatus::Ok { .. }))
        .count();
    if failed > 0 {
        bail!("{failed} of {} devices failed the check", reports.len());
    }
    Ok(())
}
