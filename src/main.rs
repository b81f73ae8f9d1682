//! The calibd command line: a thin layer of clap over the library.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};

/// calibd: calibration service for precision robots.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a job file in-process, without a daemon, and print or write its result.
    Run {
        /// The job file (JSON); relative paths inside it are relative to its folder.
        job: PathBuf,
        /// Write the result here: `.csv` writes the job's main table, anything else the
        /// whole result JSON.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Also write the job's artefacts (calibrated model, CSV tables) into this folder.
        #[arg(long)]
        artefacts: Option<PathBuf>,
    },
    /// Run the benchmarks of an area and print the figures.
    Bench {
        /// Area: `serial`, `pcr`, `drivers`.
        area: String,
    },
    /// List the job kinds.
    Kinds,
    /// Run a mock device server (QTM, ABB RWS, U-WAVE, SmarAct MCS/MCS2, CAN) until Ctrl-C.
    Mock(calibd_drivers::mock::MockArgs),
    /// Write a digital twin's data set (CSV tables and the model file) into a folder, for
    /// examples and experiments.
    Twin {
        /// Which twin: `serial` (IRB 120 ball-centring cell), `pcr` (3-PF robot under its
        /// microscope).
        which: String,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Seed of the true parameters and of the data.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

/// Prints stage changes of a job to stderr.
struct StderrMonitor {
    last: std::sync::Mutex<String>,
}

impl calibd::util::Monitor for StderrMonitor {
    fn progress(&self, fraction: f64, stage: &str) {
        if let Ok(mut last) = self.last.lock() {
            if *last != stage {
                eprintln!("[{:>5.1}%] {stage}", 100.0 * fraction);
                *last = stage.to_string();
            }
        }
    }
    fn is_cancelled(&self) -> bool {
        false
    }
}

fn run_job(job: &Path, out: Option<&Path>, artefacts: Option<&Path>) -> Result<()> {
    let text =
        std::fs::read_to_string(job).with_context(|| format!("reading {}", job.display()))?;
    let doc: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{} is not valid JSON", job.display()))?;
    let dir = job.parent().map(Path::to_path_buf).unwrap_or_default();
    let prepared = calibd::jobs::prepare(&doc, &calibd::jobs::DirResolver { dir })?;
    let monitor = StderrMonitor {
        last: std::sync::Mutex::new(String::new()),
    };
    let done = prepared.run(&monitor)?;
    match out {
        Some(p) if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) => {
            let Some(t) = &done.main_table else {
                bail!(
                    "job kind `{}` has no main table to write as CSV",
                    prepared.kind
                )
            };
            std::fs::write(p, t.to_csv()).with_context(|| format!("writing {}", p.display()))?;
        }
        Some(p) => std::fs::write(p, serde_json::to_string_pretty(&done.result)?)
            .with_context(|| format!("writing {}", p.display()))?,
        None => println!("{}", serde_json::to_string_pretty(&done.result)?),
    }
    if let Some(dir) = artefacts {
        std::fs::create_dir_all(dir)?;
        for a in &done.artefacts {
            std::fs::write(dir.join(&a.name), &a.content)
                .with_context(|| format!("writing artefact {}", a.name))?;
        }
    }
    Ok(())
}

fn write_twin(which: &str, out: &Path, seed: u64) -> Result<()> {
    if which == "pcr" {
        std::fs::create_dir_all(out)?;
        for (name, text) in calibd::jobs::pcr::twin_files(seed)? {
            std::fs::write(out.join(&name), text).with_context(|| format!("writing {name}"))?;
        }
        eprintln!(
            "wrote pcr3pf.json, pcr3pf_true.json, calibration.csv (99 rows), validation.csv (56 rows), joints.csv (20 rows) and poses.csv (16 rows) to {}",
            out.display()
        );
        return Ok(());
    }
    if which != "serial" {
        bail!("unknown twin `{which}` (known: serial, pcr)");
    }
    let twin = calibd::twin::SerialTwin::irb120(seed);
    std::fs::create_dir_all(out)?;
    let dof = twin.nominal.dof();
    let centring = calibd::jobs::serial::measurement_table(&twin.centring(120, seed + 1), dof);
    let tracker = calibd::jobs::serial::measurement_table(&twin.tracker(200, seed + 2), dof);
    std::fs::write(out.join("centring.csv"), centring.to_csv())?;
    std::fs::write(out.join("tracker.csv"), tracker.to_csv())?;
    std::fs::write(
        out.join("irb120.json"),
        serde_json::to_string_pretty(&twin.file)?,
    )?;
    let truth = twin.file.with_chain(&twin.truth);
    std::fs::write(
        out.join("irb120_true.json"),
        serde_json::to_string_pretty(&truth)?,
    )?;
    eprintln!(
        "wrote centring.csv (360 rows), tracker.csv (200 rows), irb120.json and irb120_true.json to {}",
        out.display()
    );
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Run {
            job,
            out,
            artefacts,
        } => run_job(&job, out.as_deref(), artefacts.as_deref()),
        Command::Bench { area } => {
            let figs = match area.as_str() {
                "serial" => calibd::bench::serial::run(),
                "pcr" => calibd::bench::pcr::run(),
                "drivers" => {
                    return Ok(calibd_drivers::bench::run_and_print(&mut std::io::stdout())?);
                }
                other => bail!("unknown benchmark area `{other}` (known: serial, pcr, drivers)"),
            };
            calibd::bench::print(&mut std::io::stdout(), &figs)?;
            Ok(())
        }
        Command::Mock(args) => {
            let rt = tokio::runtime::Runtime::new()?;
            let shutdown = async {
                let _ = tokio::signal::ctrl_c().await;
            };
            Ok(rt.block_on(calibd_drivers::mock::run(args, shutdown))?)
        }
        Command::Twin { which, out, seed } => write_twin(&which, &out, seed),
        Command::Kinds => {
            for (k, d) in calibd::jobs::KINDS {
                println!("{k:<20} {d}");
            }
            Ok(())
        }
    }
}
