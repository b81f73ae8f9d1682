//! `calibd serve`: wires the store, the job service, the scheduler and the HTTP API
//! together and runs them until shutdown (mini-redis shape: `run(listener, shutdown)`
//! takes an already-bound listener, so tests bind port 0).

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

use crate::api::{self, AppState, Auth, Role, auth::AuthError};
use crate::config::Config;
use crate::schedule::{Clock, Scheduler};
use crate::service::{Service, ServiceConfig, ServiceError};
use crate::store::{DataLock, Store, StoreError};

/// Why the daemon could not start or stopped with an error.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServeError {
    /// Storage.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// Tokens.
    #[error(transparent)]
    Auth(#[from] AuthError),
    /// The job service.
    #[error(transparent)]
    Service(#[from] ServiceError),
    /// The listener.
    #[error("serve: {0}")]
    Io(#[from] std::io::Error),
    /// The lab's devices.
    #[error("lab: {0}")]
    Lab(String),
    /// The settings (the store location).
    #[error("{0}")]
    Config(String),
}

impl From<crate::lab::LabError> for ServeError {
    fn from(e: crate::lab::LabError) -> Self {
        ServeError::Lab(e.to_string())
    }
}

/// What the daemon set up, for logging by the binary.
#[derive(Debug, Clone)]
pub struct Startup {
    /// The generated operator token's file, when no token is configured.
    pub operator_token_file: Option<PathBuf>,
}

/// How long running jobs get to stop at shutdown before the process exits anyway.
const STOP_GRACE: Duration = Duration::from_secs(20);

/// Build the application state and start the service and the scheduler. Returns the
/// router state plus what must be awaited at shutdown.
pub async fn start(
    config: &Config,
    clock: Clock,
    shutdown: CancellationToken,
) -> Result<(AppState, crate::service::Workers, Startup), ServeError> {
    crate::util::tune_allocator();
    // The recorder first, so the service's gauges are recorded from the start.
    let metrics = api::metrics_handle();
    let mut data_lock = None;
    let store = match &config.store {
        // The default, exactly as before: the SQLite file in the data folder.
        None => {
            data_lock = Some(DataLock::take(&config.data)?);
            Store::open(&config.data)?
        }
        Some(_) => {
            let location = config
                .store_location(&|k| std::env::var(k).ok())
                .map_err(|e| ServeError::Config(e.to_string()))?;
            if let crate::store::Location::Sqlite(dir) = &location {
                data_lock = Some(DataLock::take(dir)?);
            }
            tracing::info!(store = %location.display(), "opening the store");
            // Connecting blocks (and PostgreSQL's client runs its own small runtime).
            crate::service::open_store(location).await?
        }
    };
    let mut auth = Auth::new(&config.auth.tokens, config.auth.anonymous_read)?;
    let mut startup = Startup {
        operator_token_file: None,
    };
    if auth.is_empty() {
        let (path, token) = api::auth::operator_token_file(&config.data)?;
        auth.add_token("operator", Role::Operator, &token);
        startup.operator_token_file = Some(path);
    }
    let lab = match config.lab.as_str() {
        "none" => None,
        "sim" => {
            if config.record.is_some() {
                // Its devices listen on ports picked at each start: nothing to replay at.
                tracing::warn!(
                    "record: the simulated lab is not recorded; record a lab file's cells \
                     served by `calibd mock lab` instead"
                );
            }
            let opts = crate::sim::SimOptions {
                seed: config.lab_seed,
                ..Default::default()
            };
            let lab = crate::lab::Lab::simulated(&opts).await?;
            tracing::info!(devices = ?lab.device_names(), addresses = ?lab.mock_addresses(), "simulated lab started on loopback");
            Some(Arc::new(lab))
        }
        file => {
            if !std::path::Path::new(file).exists() {
                return Err(ServeError::Lab(format!(
                    "the lab file {file} does not exist: copy the example there \
                     (/etc/calibd/lab.example.toml when installed, deploy/lab.example.toml in the \
                     repository) and describe your cells in it, or set lab = \"sim\" to rehearse \
                     on the simulated lab, lab = \"none\" to run numerical jobs only"
                )));
            }
            let mut cells = crate::lab::config::load(
                std::path::Path::new(file),
                &crate::lab::config::ProcessEnv,
            )
            .map_err(|e| ServeError::Lab(e.to_string()))?;
            let record = recording_session(config.record.as_deref(), &mut cells);
            let lab = crate::lab::Lab::connect_recording(cells, record.as_deref())?;
            // Addresses only: the lab file's secrets never reach the log.
            tracing::info!(file, devices = ?lab.device_names(), "lab connecting in the background");
            Some(Arc::new(lab))
        }
    };
    if let Some(lab) = &lab {
        // The background lab check: availability of every cell, `GET /v1/lab`.
        tokio::spawn(lab.clone().watch(
            Duration::from_secs(config.lab_check_interval_s.max(1)),
            Duration::from_secs(2),
            shutdown.clone(),
        ));
    }
    let service_config = ServiceConfig {
        workers: config.worker_count(),
        max_queued: config.max_queued,
        devices: config.devices.clone(),
    };
    let fleet = store.is_shared();
    let (service, workers) = if fleet {
        let mut fc = crate::service::FleetConfig::named(&config.daemon_name());
        fc.lease = Duration::from_secs(config.fleet_lease_s.max(1));
        fc.cells = lab.as_ref().map(|l| l.cell_names()).unwrap_or_default();
        tracing::info!(name = %fc.name, cells = ?fc.cells, "joining the fleet on the shared store");
        Service::start_fleet(store, service_config, lab, fc, shutdown.clone()).await?
    } else {
        Service::start_with_lab(store, service_config, lab, shutdown.clone()).await?
    };
    let scheduler = Scheduler::new(clock);
    if !fleet || config.fleet_scheduler {
        tokio::spawn(scheduler.clone().run(service.clone(), shutdown.clone()));
    }
    let limits = api::ServeLimits {
        max_connections: config.max_connections.max(1),
        max_connections_per_address: config.max_connections_per_address.max(1),
        operator_reserve: config.operator_reserved_connections,
        max_event_streams_per_token: config.max_event_streams_per_token.max(1),
        header_read_timeout: Duration::from_secs(config.header_read_timeout_s.max(1)),
        send_timeout: Duration::from_secs(config.send_timeout_s.max(1)),
        ..Default::default()
    };
    let state = AppState::new(api::AppShared {
        service,
        scheduler,
        auth: Arc::new(auth),
        max_body_bytes: config.max_body_bytes,
        body_budget: api::budget::BodyBudget::new(config.max_body_bytes_in_flight),
        request_timeout: Duration::from_secs(config.request_timeout_s.max(1)),
        limits,
        event_streams: api::event_stream_shares(&limits),
        allowed_hosts: config
            .allowed_hosts
            .iter()
            .map(|h| {
                if h == "*" {
                    h.clone()
                } else {
                    api::host_name(h)
                }
            })
            .collect(),
        min_schedule_interval: Duration::from_secs(config.min_schedule_interval_s),
        metrics,
        shutdown,
        _data_lock: data_lock,
    });
    Ok((state, workers, startup))
}

/// This start's recording folders: a subfolder named by the start time (UTC) in `record`
/// (`--record`) and in each cell's own `record` folder, so a restart never overwrites the
/// previous session's transcripts. Returns the lab-wide one.
fn recording_session(
    record: Option<&std::path::Path>,
    cells: &mut [crate::lab::CellLink],
) -> Option<PathBuf> {
    let session = chrono::Utc::now().format("%Y%m%dT%H%M%SZ").to_string();
    for c in cells.iter_mut() {
        if let Some(dir) = c.record_mut() {
            *dir = dir.join(&session);
            tracing::info!(folder = %dir.display(), "recording this cell's device traffic");
        }
    }
    let dir = record.map(|r| r.join(&session));
    if let Some(d) = &dir {
        tracing::info!(folder = %d.display(), "recording every device's traffic");
    }
    dir
}

/// Run a workers-only daemon (`calibd serve --workers-only`): no HTTP listener, no lab,
/// no schedules; its workers claim numerical jobs from the shared store until `signal`.
pub async fn run_workers(
    config: &Config,
    signal: impl Future<Output = ()> + Send + 'static,
    on_start: impl FnOnce(&Startup),
) -> Result<(), ServeError> {
    let mut config = config.clone();
    config.lab = "none".into();
    config.fleet_scheduler = false;
    if config.store.is_none() {
        return Err(ServeError::Config(
            "--workers-only needs a shared store: set `store` to a postgres:// URL".into(),
        ));
    }
    let token = CancellationToken::new();
    let (_state, workers, startup) = start(&config, Clock::system(), token.clone()).await?;
    on_start(&startup);
    signal.await;
    token.cancel();
    if tokio::time::timeout(STOP_GRACE, workers.join())
        .await
        .is_err()
    {
        tracing::warn!("jobs did not stop within {STOP_GRACE:?}");
    }
    Ok(())
}

/// Run the daemon on `listener` until `signal` completes, then stop: event streams close,
/// running jobs are asked to stop (and recorded as `interrupted`), the server drains.
pub async fn run(
    listener: TcpListener,
    config: &Config,
    signal: impl Future<Output = ()> + Send + 'static,
    on_start: impl FnOnce(&Startup),
) -> Result<(), ServeError> {
    let token = CancellationToken::new();
    let (state, workers, startup) = start(config, Clock::system(), token.clone()).await?;
    on_start(&startup);
    let stop = token.clone();
    tokio::spawn(async move {
        signal.await;
        stop.cancel();
    });
    let t = token.clone();
    api::run(listener, state, async move { t.cancelled().await }).await?;
    token.cancel();
    if tokio::time::timeout(STOP_GRACE, workers.join())
        .await
        .is_err()
    {
        tracing::warn!(
            "jobs did not stop within {STOP_GRACE:?}; they will be marked interrupted at the next start"
        );
    }
    Ok(())
}
