//! `calibd serve`, `calibd health` and `calibd token`: running a daemon, asking whether one
//! is up, and granting access to it.

use std::path::PathBuf;

use anyhow::{Context, Result};

use super::{init_tracing, runtime};

/// Options of `calibd serve`.
#[derive(Debug, clap::Args)]
pub(crate) struct ServeArgs {
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
    /// Record every device's traffic to DIR as replayable transcripts
    /// (`DIR/<start time>/<cell>.<device>.jsonl`; the setting `record`).
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
}

/// Options of `calibd health`.
#[derive(Debug, clap::Args)]
pub(crate) struct HealthArgs {
    /// The daemon's URL.
    #[arg(long, env = "CALIBD_URL", default_value = "http://127.0.0.1:8750")]
    server: String,
    /// Seconds to wait for the answer.
    #[arg(long, default_value_t = 5.0)]
    timeout: f64,
}

/// Options of `calibd token`.
#[derive(Debug, clap::Args)]
pub(crate) struct TokenArgs {
    /// Name recorded with what the token does.
    #[arg(long, default_value = "user")]
    name: String,
    /// viewer, submitter or operator.
    #[arg(long, default_value = "viewer")]
    role: String,
}

/// `calibd health`: one line, exit 0 when the daemon answers 200 and 1 otherwise.
pub(crate) fn health(a: HealthArgs) -> Result<()> {
    let timeout = std::time::Duration::try_from_secs_f64(a.timeout)
        .context("--timeout: seconds, a positive number")?;
    let c = calibd::client::Client::new(&a.server, None);
    let (line, ok) = runtime()?.block_on(calibd::client::commands::health(&c, timeout));
    println!("{line}");
    std::process::exit(if ok { 0 } else { 1 })
}

/// `calibd token`: a new token and the settings lines that grant it.
pub(crate) fn token(a: TokenArgs) -> Result<()> {
    let TokenArgs { name, role } = a;
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

/// `calibd serve`: the daemon (or its workers only) until Ctrl-C or SIGTERM.
pub(crate) fn serve(a: ServeArgs) -> Result<()> {
    let ServeArgs {
        listen,
        data,
        config,
        workers_only,
        log_file,
        record,
    } = a;
    let mut cfg = calibd::config::Config::load(config.as_deref(), &|k| std::env::var(k).ok())?;
    if let Some(l) = listen {
        cfg.listen = l;
    }
    if let Some(d) = data {
        cfg.data = d;
    }
    if record.is_some() {
        cfg.record = record;
    }
    let json = cfg.log_format == calibd::config::LogFormat::Json;
    match &log_file {
        Some(p) => init_tracing_to_file(json, p)?,
        None => init_tracing(json),
    }
    if workers_only {
        return runtime()?.block_on(async move {
            calibd::server::run_workers(&cfg, super::shutdown_signal(), |_| {
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
        calibd::server::run(listener, &cfg, super::shutdown_signal(), |s| {
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
