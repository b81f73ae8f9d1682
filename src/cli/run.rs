//! `calibd run`, `calibd kinds` and `calibd example`: jobs in-process, without a daemon.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

/// Options of `calibd run`.
#[derive(Debug, clap::Args)]
pub(crate) struct RunArgs {
    /// The job file (JSON); relative paths inside it are relative to its folder.
    job: PathBuf,
    /// Write the result here: `.csv` writes the job's main table, anything else the
    /// whole result JSON. A `serial.fk` over a joints CSV file streams its poses to
    /// `.csv` row by row (memory flat in the number of rows; no result JSON).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write the job's artefacts (calibrated model, CSV tables) into this folder.
    #[arg(long)]
    artefacts: Option<PathBuf>,
}

/// Options of `calibd example`.
#[derive(Debug, clap::Args)]
pub(crate) struct ExampleArgs {
    /// Example name.
    name: Option<String>,
}

/// `calibd run`: exits with the verdict's code (0 accepted or no verdict, 3 review,
/// 4 rejected).
pub(crate) fn run(a: RunArgs) -> Result<()> {
    match run_job(&a.job, a.out.as_deref(), a.artefacts.as_deref())? {
        0 => Ok(()),
        code => std::process::exit(code),
    }
}

/// `calibd kinds`: every job kind with its description.
pub(crate) fn kinds() -> Result<()> {
    for k in calibd::jobs::KINDS {
        println!("{:<20} {}", k.name, k.description);
    }
    Ok(())
}

/// `calibd example [NAME]`: the example job NAME, or the list of examples.
pub(crate) fn example(a: ExampleArgs) -> Result<()> {
    match a.name {
        None => {
            for (n, d) in calibd::jobs::examples::EXAMPLES {
                println!("{n:<20} {d}");
            }
            Ok(())
        }
        Some(n) => {
            let doc = calibd::jobs::examples::example(&n)
                .with_context(|| format!("no example named `{n}` (see `calibd example`)"))?;
            println!("{}", serde_json::to_string_pretty(&doc)?);
            Ok(())
        }
    }
}

/// Prints stage changes of a job to stderr.
struct StderrMonitor {
    last: std::sync::Mutex<String>,
}

impl calibd::util::Monitor for StderrMonitor {
    fn progress(&self, fraction: f64, stage: &str) {
        if let Ok(mut last) = self.last.lock()
            && *last != stage
        {
            eprintln!("[{:>5.1}%] {stage}", 100.0 * fraction);
            *last = stage.to_string();
        }
    }
    fn is_cancelled(&self) -> bool {
        false
    }
    fn report(&self, fraction: f64, stage: &str, message: &str) {
        eprintln!("[{:>5.1}%] {stage}: {message}", 100.0 * fraction);
    }
}

/// Run a job file; the exit code of its verdict (0 for jobs without one).
fn run_job(job: &Path, out: Option<&Path>, artefacts: Option<&Path>) -> Result<i32> {
    let text =
        std::fs::read_to_string(job).with_context(|| format!("reading {}", job.display()))?;
    let doc: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{} is not valid JSON", job.display()))?;
    let dir = job.parent().map(Path::to_path_buf).unwrap_or_default();
    let prepared = calibd::jobs::prepare(&doc, &calibd::jobs::DirResolver { dir })?;
    if let Some(folder) = out
        .and_then(Path::parent)
        .filter(|d| !d.as_os_str().is_empty())
    {
        std::fs::create_dir_all(folder)
            .with_context(|| format!("creating {}", folder.display()))?;
    }
    let monitor = StderrMonitor {
        last: std::sync::Mutex::new(String::new()),
    };
    let csv_out = out.filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")));
    if let Some(p) = csv_out
        && artefacts.is_none()
        && prepared.streams_main_csv()
    {
        // The main table row by row: no result JSON, no table in memory.
        calibd::offline::write_main_csv(&prepared, p, &monitor)?;
        return Ok(0);
    }
    let mut decision = None;
    let done = if prepared.devices().is_empty() {
        prepared.run(&monitor)?
    } else {
        // A device-driven kind offline: drive the simulated lab over the real protocols.
        eprintln!(
            "`{}` drives devices: starting the simulated lab on loopback",
            prepared.kind
        );
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()?;
        let lab = std::sync::Arc::new(rt.block_on(calibd::lab::Lab::simulated(
            &calibd::sim::SimOptions::default(),
        ))?);
        let r = calibd::offline::run_on(
            rt.handle(),
            &prepared,
            lab.clone(),
            std::sync::Arc::new(calibd::procedures::MemoryJournal::default()),
            &monitor,
        );
        rt.block_on(lab.stop());
        let done = r?;
        decision = done.candidate.as_ref().map(|c| lab.decide(c));
        done
    };
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
    // The summary on stderr (stdout may be the result JSON): headline figures, the
    // verdict with its reasons, warnings (never only buried in the JSON) and, for a
    // campaign, what its cell would decide.
    for l in calibd::client::commands::summary_lines(&done.result) {
        eprintln!("{l}");
    }
    if let Some(d) = &decision {
        eprintln!(
            "decision (offline run, not stored; no cell changes its model): cell {}: model {}: {}",
            d.cell,
            if d.accepted { "accepted" } else { "rejected" },
            d.reason
        );
    }
    Ok(exit_code(&done.result))
}

/// An identification's exit code (0 without a verdict); says what a rejection leaves.
fn exit_code(result: &serde_json::Value) -> i32 {
    use calibd::identify::Verdict;
    let Some(v) = Verdict::of_result(result) else {
        return 0;
    };
    if v == Verdict::Rejected {
        eprintln!("  no calibrated model was written (rejected_model* holds it for inspection)");
    }
    v.exit_code()
}
