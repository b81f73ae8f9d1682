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
enum LabCommand {
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

#[derive(Debug, Subcommand)]
enum StoreCommand {
    /// Copy every job, result, dataset, schedule and journal into an empty database.
    Copy {
        /// Source: `sqlite:FOLDER` (the daemon's data folder).
        #[arg(long)]
        from: String,
        /// Target: a `postgres://USER@HOST:PORT/DB` URL (no password in it).
        #[arg(long)]
        to: String,
        /// File holding the target's password (else CALIBD_STORE_PASSWORD).
        #[arg(long)]
        password_file: Option<PathBuf>,
    },
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a job file in-process, without a daemon, and print or write its result.
    ///
    /// An identification (serial.identify, tree.identify, humanoid.identify, pcr.identify)
    /// ends with a verdict, printed on stderr with its reasons, and the exit code says it:
    /// 0 accepted, 3 review (usable after a person read the reasons), 4 rejected (nothing
    /// usable was made: no calibrated_model* is written, rejected_model* instead). Jobs that
    /// are not identifications exit 0. Errors (invalid job, failed run) exit 1.
    Run {
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
    },
    /// Run the benchmarks of an area and print the figures.
    Bench {
        /// Area: `serial`, `pcr`, `humanoid`, `identify` (identification from 90 to 100,000
        /// measurements), `all` (those four), `serial.fk` (only the `serial.fk` table
        /// figures of `serial`), `identify:N` (one size), `kernels` (nalgebra against faer
        /// and the crossovers), `drivers` or `api` (the daemon under many concurrent
        /// clients).
        area: String,
        /// Also write every figure (median, min, max, peak memory) of `serial`, `pcr`,
        /// `humanoid`, `identify` or `all` to this JSON file, to compare a run with an earlier one.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// List the job kinds.
    Kinds,
    /// Print an example job (IRB 120 twin data, inline) to stdout; without NAME, list them.
    Example {
        /// Example name.
        name: Option<String>,
    },
    /// Run the daemon: job queue, workers, REST API, web page, schedules.
    Serve {
        /// Address to listen on (default 127.0.0.1:8750).
        #[arg(long)]
        listen: Option<String>,
        /// Data folder: database and generated operator token (default ./calibd-data).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Settings file (TOML); every setting can also come from a CALIBD_* variable.
        #[arg(long, env = "CALIBD_CONFIG")]
        config: Option<PathBuf>,
        /// Workers only (a fleet on a PostgreSQL store): no HTTP listener, no lab, no
        /// schedules; claim numerical jobs from the shared queue.
        #[arg(long)]
        workers_only: bool,
        /// Append the log to this file instead of the terminal (a daemon started with `&`
        /// then leaves the terminal to `calibd submit --watch`).
        #[arg(long, env = "CALIBD_LOG_FILE", value_name = "FILE")]
        log_file: Option<PathBuf>,
    },
    /// The store: `calibd store copy --from sqlite:FOLDER --to postgres://…` moves a lab's
    /// history into an empty PostgreSQL database (password: CALIBD_STORE_PASSWORD or
    /// --password-file).
    Store {
        #[command(subcommand)]
        command: StoreCommand,
    },
    /// The lab: `calibd lab check` connects to every configured device and prints who
    /// answered, and what to fix where one did not.
    Lab {
        #[command(subcommand)]
        command: LabCommand,
    },
    /// Submit a job file to a daemon (files it names are uploaded as datasets).
    Submit {
        /// The job file.
        job: PathBuf,
        /// Follow the job with a progress bar and print the result summary.
        #[arg(long)]
        watch: bool,
        /// Priority (higher runs first).
        #[arg(long, default_value_t = 0)]
        priority: i64,
        #[command(flatten)]
        remote: Remote,
    },
    /// Follow a job until it ends.
    Watch {
        /// Job id.
        id: i64,
        #[command(flatten)]
        remote: Remote,
    },
    /// List jobs, newest first.
    Jobs {
        /// Only jobs in this state.
        #[arg(long, value_parser = ["queued", "running", "paused", "succeeded", "failed", "cancelled", "interrupted"])]
        state: Option<String>,
        /// Only jobs of this kind.
        #[arg(long)]
        kind: Option<String>,
        /// How many.
        #[arg(long, default_value_t = 20)]
        limit: usize,
        #[command(flatten)]
        remote: Remote,
    },
    /// Cancel a job.
    Cancel {
        /// Job id.
        id: i64,
        #[command(flatten)]
        remote: Remote,
    },
    /// Print a job's result, or write it with its artefacts into a folder.
    Result {
        /// Job id.
        id: i64,
        /// Folder for result.json, the artefacts and the main table.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write the printable HTML report (self-contained: open it in a browser, print
        /// it, sign it off) to this file.
        #[arg(long, value_name = "FILE")]
        report: Option<PathBuf>,
        #[command(flatten)]
        remote: Remote,
    },
    /// Resume a paused or interrupted campaign from its journal (operator role).
    Resume {
        /// Job id.
        id: i64,
        /// Follow it until it ends and print the summary.
        #[arg(long)]
        watch: bool,
        #[command(flatten)]
        remote: Remote,
    },
    /// Run a job's document again as a new job (same inputs, new id).
    Rerun {
        /// Job id.
        id: i64,
        /// Follow the new job until it ends and print the summary.
        #[arg(long)]
        watch: bool,
        #[command(flatten)]
        remote: Remote,
    },
    /// Write a job's printable HTML report (self-contained: open, print, sign off).
    Report {
        /// Job id.
        id: i64,
        /// The HTML file to write.
        #[arg(long, value_name = "FILE", default_value = "report.html")]
        out: PathBuf,
        #[command(flatten)]
        remote: Remote,
    },
    /// Check that a daemon answers `GET /v1/health` with 200 (no token needed).
    ///
    /// Prints one line, exits 0 when healthy and 1 otherwise. The container image's
    /// HEALTHCHECK.
    Health {
        /// The daemon's URL.
        #[arg(long, env = "CALIBD_URL", default_value = "http://127.0.0.1:8750")]
        server: String,
        /// Seconds to wait for the answer.
        #[arg(long, default_value_t = 5.0)]
        timeout: f64,
    },
    /// Make a new API token and print it with the config line that grants it.
    Token {
        /// Name recorded with what the token does.
        #[arg(long, default_value = "user")]
        name: String,
        /// viewer, submitter or operator.
        #[arg(long, default_value = "viewer")]
        role: String,
    },
    /// Run a mock device server (QTM, ABB RWS, U-WAVE, SmarAct MCS/MCS2, CAN, microscope, joint
    /// interface) until Ctrl-C. `calibd mock lab --config LAB.toml [--cell NAME]` serves the
    /// devices of a lab file's cells from the digital twins instead (`calibd mock lab --help`).
    Mock(calibd_drivers::mock::MockArgs),
    /// Write a digital twin's data set (CSV tables and the model file) into a folder, for
    /// examples and experiments.
    Twin {
        /// Which twin: `serial` (IRB 120 ball-centring cell), `pcr` (3-PF robot under its
        /// microscope), `pattern` (microscope frames of the platform's pattern, PNG, with
        /// their true poses and a `pcr.pattern_pose` job).
        which: String,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Seed of the true parameters and of the data.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[command(flatten)]
        pattern: PatternArgs,
    },
}

/// Options of `calibd twin pattern`.
#[derive(Debug, clap::Args)]
#[command(next_help_heading = "twin pattern")]
struct PatternArgs {
    /// `periodic` (cosine grid, position modulo the period) or `encoded` (dots with missing
    /// ones coding the period's index: absolute position).
    #[arg(long, default_value = "periodic")]
    kind: String,
    /// Number of frames.
    #[arg(long, default_value_t = 10)]
    count: usize,
    /// Side of the square frames (px).
    #[arg(long, default_value_t = 1024)]
    size_px: usize,
    /// Period of the pattern (um).
    #[arg(long, default_value_t = 10.0)]
    period_um: f64,
    /// Pixel size in the object plane (um).
    #[arg(long, default_value_t = 1.0)]
    pixel_um: f64,
    /// 8 or 16 bits per pixel.
    #[arg(long, default_value_t = 16)]
    bits: u8,
    /// Gaussian noise, standard deviation as a fraction of full scale.
    #[arg(long, default_value_t = 0.01)]
    noise: f64,
}

/// Where the daemon is and how to authenticate.
#[derive(Debug, clap::Args)]
struct Remote {
    /// The daemon's URL.
    #[arg(long, env = "CALIBD_URL", default_value = "http://127.0.0.1:8750")]
    server: String,
    /// Bearer token (default: DATA/operator.token). A token on the command line is
    /// visible to every user of the machine in `ps`: prefer CALIBD_TOKEN or the file.
    #[arg(long, env = "CALIBD_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// The daemon's data folder, to find operator.token.
    #[arg(long, env = "CALIBD_DATA", default_value = "calibd-data")]
    data: PathBuf,
}

impl Remote {
    fn client(&self) -> calibd::client::Client {
        let token = calibd::client::Client::find_token(self.token.clone(), &self.data);
        let found = token.is_some();
        let c = calibd::client::Client::new(&self.server, token);
        if found {
            c
        } else {
            c.with_token_search(calibd::client::Client::token_places(&self.data))
        }
    }
}

fn init_tracing(json: bool) {
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

/// The daemon's log appended to `path` (its folder created), without terminal colours.
fn init_tracing_to_file(json: bool, path: &std::path::Path) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .with_context(|| format!("opening the log file {}", path.display()))?;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,tower_http=info"));
    let b = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(false)
        .with_writer(std::sync::Mutex::new(file));
    if json {
        b.json().init();
    } else {
        b.init();
    }
    Ok(())
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?)
}

async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! { _ = ctrl_c => {}, _ = term => {} }
    tracing::info!("shutting down");
}

/// `calibd lab check`: build the lab, probe every device, print, exit 1 on any failure.
fn lab_check(config: Option<PathBuf>, timeout_s: f64, json: bool) -> Result<()> {
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

fn store_copy(from: &str, to: &str, password_file: Option<&Path>) -> Result<()> {
    use calibd::store::{Location, Store};
    let password = match password_file {
        Some(p) => Some(
            std::fs::read_to_string(p)
                .with_context(|| format!("reading {}", p.display()))?
                .lines()
                .next()
                .unwrap_or("")
                .to_string(),
        ),
        None => std::env::var("CALIBD_STORE_PASSWORD").ok(),
    };
    let src = Location::parse(from, None)?;
    match &src {
        Location::Sqlite(dir) if dir.join("calibd.sqlite3").exists() => {}
        Location::Sqlite(dir) => bail!("no calibd.sqlite3 in {}", dir.display()),
        Location::Postgres(_) => bail!("--from must be sqlite:FOLDER"),
    }
    let dst = Location::parse(to, password)?;
    let src = Store::open_location(&src)?;
    let dst = Store::open_location(&dst)?;
    for (table, n) in src.copy_to(&dst)? {
        println!("{table}: {n} rows");
    }
    Ok(())
}

fn serve(
    listen: Option<String>,
    data: Option<PathBuf>,
    config: Option<PathBuf>,
    workers_only: bool,
    log_file: Option<PathBuf>,
) -> Result<()> {
    let mut cfg = calibd::config::Config::load(config.as_deref(), &|k| std::env::var(k).ok())?;
    if let Some(l) = listen {
        cfg.listen = l;
    }
    if let Some(d) = data {
        cfg.data = d;
    }
    let json = cfg.log_format == calibd::config::LogFormat::Json;
    match &log_file {
        Some(p) => init_tracing_to_file(json, p)?,
        None => init_tracing(json),
    }
    if workers_only {
        return runtime()?.block_on(async move {
            calibd::server::run_workers(&cfg, shutdown_signal(), |_| {
                tracing::info!(
                    workers = cfg.worker_count(),
                    "calibd {} workers ready",
                    env!("CARGO_PKG_VERSION")
                );
                println!("calibd workers ready");
            })
            .await?;
            Ok(())
        });
    }
    runtime()?.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&cfg.listen)
            .await
            .with_context(|| format!("binding {}", cfg.listen))?;
        let addr = listener.local_addr()?;
        calibd::server::run(listener, &cfg, shutdown_signal(), |s| {
            if let Some(p) = &s.operator_token_file {
                tracing::info!(file = %p.display(), "no token configured: the operator token is in this file");
            }
            tracing::info!(data = %cfg.data.display(), workers = cfg.worker_count(), "calibd {} ready", env!("CARGO_PKG_VERSION"));
            // One plain line on stdout that scripts can wait for.
            println!("calibd listening on http://{addr}");
        })
        .await?;
        Ok(())
    })
}

fn remote<F, Fut>(r: &Remote, f: F) -> Result<()>
where
    F: FnOnce(calibd::client::Client) -> Fut,
    Fut: std::future::Future<Output = Result<(), calibd::client::ClientError>>,
{
    let c = r.client();
    runtime()?.block_on(f(c))?;
    Ok(())
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
        r?
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
    // Warnings of the result (e.g. unused table columns) also on stderr, never only buried
    // in the JSON.
    for w in done.result["warnings"].as_array().into_iter().flatten() {
        eprintln!("warning: {}", w.as_str().unwrap_or_default());
    }
    if let Some(dir) = artefacts {
        std::fs::create_dir_all(dir)?;
        for a in &done.artefacts {
            std::fs::write(dir.join(&a.name), &a.content)
                .with_context(|| format!("writing artefact {}", a.name))?;
        }
    }
    Ok(report_verdict(&done.result))
}

/// Print an identification's verdict and reasons on stderr; its exit code (0 without one).
fn report_verdict(result: &serde_json::Value) -> i32 {
    use calibd::identify::Verdict;
    let Some(v) = Verdict::of_result(result) else {
        return 0;
    };
    eprintln!("verdict: {}", v.as_str());
    for r in result["reasons"].as_array().into_iter().flatten() {
        eprintln!(
            "  {} ({}): {}",
            r["code"].as_str().unwrap_or_default(),
            r["severity"].as_str().unwrap_or_default(),
            r["message"].as_str().unwrap_or_default()
        );
    }
    if v == Verdict::Rejected {
        eprintln!("  no calibrated model was written (rejected_model* holds it for inspection)");
    }
    v.exit_code()
}

fn write_twin(which: &str, out: &Path, seed: u64, pattern: &PatternArgs) -> Result<()> {
    if which == "pattern" {
        use calibd::jobs::pcr::pattern_pose::{PatternTwin, twin_files};
        use calibd::measure::pattern::PatternKind;
        let kind = match pattern.kind.as_str() {
            "periodic" => PatternKind::Periodic,
            "encoded" => PatternKind::Encoded,
            k => bail!("unknown pattern kind `{k}` (known: periodic, encoded)"),
        };
        let files = twin_files(&PatternTwin {
            kind,
            count: pattern.count,
            size_px: pattern.size_px,
            period_um: pattern.period_um,
            pixel_um: pattern.pixel_um,
            bit_depth: pattern.bits,
            noise_frac: pattern.noise,
            seed,
        })?;
        std::fs::create_dir_all(out)?;
        for (name, bytes) in &files {
            std::fs::write(out.join(name), bytes).with_context(|| format!("writing {name}"))?;
        }
        eprintln!(
            "wrote {} frames (frame_000.png ...), truth.csv and pattern_pose.json to {}",
            pattern.count,
            out.display()
        );
        return Ok(());
    }
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
        bail!("unknown twin `{which}` (known: serial, pcr, pattern)");
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

/// `calibd mock lab`: serve the devices of a lab file's cells from the digital twins.
#[derive(Debug, Parser)]
#[command(name = "calibd mock lab")]
struct MockLabCli {
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
fn mock_lab(args: MockLabCli) -> Result<()> {
    init_tracing(false);
    let rt = runtime()?;
    rt.block_on(async move {
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
        let _ = tokio::signal::ctrl_c().await;
        lab.stop().await;
        Ok(())
    })
}

fn main() -> Result<()> {
    // `calibd mock lab` takes a lab file rather than one device: its own arguments.
    let argv: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if argv.get(1).is_some_and(|a| a == "mock") && argv.get(2).is_some_and(|a| a == "lab") {
        return mock_lab(MockLabCli::parse_from(argv.iter().skip(2)));
    }
    let cli = Cli::parse();
    match cli.command {
        Command::Run {
            job,
            out,
            artefacts,
        } => match run_job(&job, out.as_deref(), artefacts.as_deref())? {
            0 => Ok(()),
            code => std::process::exit(code),
        },
        Command::Bench { area, json } => {
            let numerical = |a: &str| match a {
                "serial" => Some(calibd::bench::serial::run()),
                "serial.fk" => Some(calibd::bench::serial::fk_tables()),
                "serial.compensate" => Some(calibd::bench::serial::compensate_figures()),
                "humanoid" => Some(calibd::bench::humanoid::run()),
                "pcr" => Some(calibd::bench::pcr::run()),
                "identify" => Some(calibd::bench::identify::run()),
                "kernels" => Some(calibd::bench::kernels::run()),
                other => other
                    .strip_prefix("identify:")
                    .and_then(|n| n.parse::<usize>().ok())
                    .map(|n| calibd::bench::identify::sweep(&[n])),
            };
            let areas: Vec<&str> = match area.as_str() {
                "all" => vec!["serial", "pcr", "humanoid", "identify"],
                "api" => {
                    let report =
                        runtime()?.block_on(calibd::bench::api::run(Default::default()))?;
                    println!("{report}");
                    return Ok(());
                }
                "drivers" => {
                    return Ok(calibd_drivers::bench::run_and_print(&mut std::io::stdout())?);
                }
                other if numerical_area(other) => vec![other],
                other => {
                    bail!(
                        "unknown benchmark area `{other}` (known: serial, serial.fk, serial.compensate, pcr, humanoid, identify, identify:N, kernels, all, drivers, api)"
                    )
                }
            };
            let mut report = Vec::new();
            for a in areas {
                let figures = numerical(a).unwrap_or_default();
                println!("== {a}");
                calibd::bench::print(&mut std::io::stdout(), &figures)?;
                report.push(calibd::bench::Area {
                    area: a.to_string(),
                    figures,
                });
            }
            if let Some(path) = json {
                let text = serde_json::to_string_pretty(&calibd::bench::Report::new(report))?;
                std::fs::write(&path, text + "\n")
                    .with_context(|| format!("cannot write {}", path.display()))?;
                eprintln!("figures written to {}", path.display());
            }
            Ok(())
        }
        Command::Mock(args) => {
            let rt = tokio::runtime::Runtime::new()?;
            let shutdown = async {
                let _ = tokio::signal::ctrl_c().await;
            };
            Ok(rt.block_on(calibd_drivers::mock::run(args, shutdown))?)
        }
        Command::Twin {
            which,
            out,
            seed,
            pattern,
        } => write_twin(&which, &out, seed, &pattern),
        Command::Kinds => {
            for k in calibd::jobs::KINDS {
                println!("{:<20} {}", k.name, k.description);
            }
            Ok(())
        }
        Command::Example { name: None } => {
            for (n, d) in calibd::jobs::examples::EXAMPLES {
                println!("{n:<20} {d}");
            }
            Ok(())
        }
        Command::Example { name: Some(n) } => {
            let doc = calibd::jobs::examples::example(&n)
                .with_context(|| format!("no example named `{n}` (see `calibd example`)"))?;
            println!("{}", serde_json::to_string_pretty(&doc)?);
            Ok(())
        }
        Command::Serve {
            listen,
            data,
            config,
            workers_only,
            log_file,
        } => serve(listen, data, config, workers_only, log_file),
        Command::Store {
            command:
                StoreCommand::Copy {
                    from,
                    to,
                    password_file,
                },
        } => store_copy(&from, &to, password_file.as_deref()),
        Command::Lab {
            command:
                LabCommand::Check {
                    config,
                    timeout_s,
                    json,
                },
        } => lab_check(config, timeout_s, json),
        Command::Submit {
            job,
            watch,
            priority,
            remote: r,
        } => remote(&r, |c| async move {
            calibd::client::commands::submit(&c, &job, priority, watch)
                .await
                .map(|_| ())
        }),
        Command::Watch { id, remote: r } => remote(&r, |c| async move {
            calibd::client::commands::watch(&c, id).await.map(|_| ())
        }),
        Command::Jobs {
            state,
            kind,
            limit,
            remote: r,
        } => remote(&r, |c| async move {
            calibd::client::commands::jobs(&c, state.as_deref(), kind.as_deref(), limit).await
        }),
        Command::Cancel { id, remote: r } => remote(&r, |c| async move {
            calibd::client::commands::cancel(&c, id).await
        }),
        Command::Result {
            id,
            out,
            report,
            remote: r,
        } => remote(&r, |c| async move {
            if let Some(file) = &report {
                calibd::client::commands::report(&c, id, file).await?;
                if out.is_none() {
                    return Ok(());
                }
            }
            calibd::client::commands::result(&c, id, out.as_deref()).await
        }),
        Command::Resume {
            id,
            watch,
            remote: r,
        } => remote(&r, |c| async move {
            calibd::client::commands::resume(&c, id).await?;
            if watch {
                calibd::client::commands::watch(&c, id).await?;
            }
            Ok(())
        }),
        Command::Rerun {
            id,
            watch,
            remote: r,
        } => remote(&r, |c| async move {
            let new = calibd::client::commands::rerun(&c, id).await?;
            if watch {
                calibd::client::commands::watch(&c, new).await?;
            }
            Ok(())
        }),
        Command::Report { id, out, remote: r } => remote(&r, |c| async move {
            calibd::client::commands::report(&c, id, &out).await
        }),
        Command::Health { server, timeout } => {
            let timeout = std::time::Duration::try_from_secs_f64(timeout)
                .context("--timeout: seconds, a positive number")?;
            let c = calibd::client::Client::new(&server, None);
            let (line, ok) = runtime()?.block_on(calibd::client::commands::health(&c, timeout));
            println!("{line}");
            std::process::exit(if ok { 0 } else { 1 })
        }
        Command::Token { name, role } => {
            let role = calibd::api::Role::parse(&role)
                .with_context(|| format!("unknown role `{role}` (viewer, submitter, operator)"))?;
            let token = calibd::api::auth::new_token()?;
            println!("token (give it to the user; it is not stored): {token}");
            println!("config (add to the daemon's TOML file):");
            println!(
                "[[auth.tokens]]\nname = \"{name}\"\nrole = \"{}\"\nsha256 = \"{}\"",
                role.as_str(),
                calibd::api::auth::hash_token(&token)
            );
            Ok(())
        }
    }
}

/// The benchmark areas whose figures `--json` can write.
fn numerical_area(a: &str) -> bool {
    matches!(
        a,
        "serial" | "serial.fk" | "serial.compensate" | "pcr" | "humanoid" | "identify" | "kernels"
    ) || a
        .strip_prefix("identify:")
        .is_some_and(|n| n.parse::<usize>().is_ok())
}
