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
        /// Area: `serial`, `humanoid`.
        area: String,
    },
    /// List the job kinds.
    Kinds,
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
                "humanoid" => calibd::bench::humanoid::run(),
                other => bail!("unknown benchmark area `{other}` (known: serial, humanoid)"),
            };
            calibd::bench::print(&mut std::io::stdout(), &figs)?;
            Ok(())
        }
        Command::Kinds => {
            for (k, d) in calibd::jobs::KINDS {
                println!("{k:<20} {d}");
            }
            Ok(())
        }
    }
}
