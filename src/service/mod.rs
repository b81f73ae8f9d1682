//! The job service: validates and persists submissions, keeps the run queue, runs jobs on
//! a bounded pool of blocking workers, and publishes state and progress events. The HTTP
//! API, the scheduler and tests talk to it through [`Service`]; it knows jobs and the
//! store, not models.

mod cancel;
mod cells;
mod drift;
mod events;
mod fleet;
mod queue;
mod resume;
mod storage;
mod submit;
mod types;
mod worker;

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use serde_json::Value;
use tokio::sync::{Notify, broadcast, mpsc};
use tokio_util::sync::CancellationToken;

pub use drift::{DriftHistory, DriftPoint};
pub use events::{DriftEvent, Event};
pub use fleet::FleetConfig;
pub use queue::{Entry, Queue};
pub use storage::open as open_store;
pub use submit::DryRun;
pub use types::{
    DeviceStatus, Origin, ScheduleOrigin, ServiceConfig, ServiceError, StoreResolver, Submitter,
};
pub use worker::Workers;

use crate::jobs;
use crate::store::{IdempotencyKey, JobFilter, JobRecord, JobState, NewJob, Store};

/// Live state of a running job.
#[derive(Debug)]
struct Running {
    kind: String,
    cancel: Arc<AtomicBool>,
    user_cancelled: bool,
    devices: Vec<String>,
    progress: Option<(f64, String)>,
    /// The run's token once the job started (claimed, in a fleet).
    run: Option<crate::store::Run>,
    /// Set when a write found the job taken from this run: it stops and stores nothing.
    stale: Option<crate::store::StoreError>,
}

#[derive(Debug)]
struct Shared {
    store: Store,
    config: ServiceConfig,
    queue: Mutex<Queue>,
    wake: Notify,
    running: Mutex<HashMap<i64, Running>>,
    events: broadcast::Sender<Event>,
    progress_tx: mpsc::UnboundedSender<Event>,
    shutdown: CancellationToken,
    lab: Arc<crate::lab::Lab>,
    /// Set when several daemons share a PostgreSQL store.
    fleet: std::sync::OnceLock<fleet::Fleet>,
}

/// Handle to the job service; cheap to clone.
#[derive(Debug, Clone)]
pub struct Service {
    shared: Arc<Shared>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

use storage::blocking;

impl Service {
    /// Start the service over `store`: recover from the last run (running jobs become
    /// `interrupted`, queued ones are queued again), then start the workers. Everything
    /// stops when `shutdown` is cancelled; [`Service::stopped`] waits for that.
    pub async fn start(
        store: Store,
        config: ServiceConfig,
        shutdown: CancellationToken,
    ) -> Result<(Service, worker::Workers), ServiceError> {
        Self::start_with_lab(store, config, None, shutdown).await
    }

    /// [`Service::start`] with a lab whose cells the campaign kinds drive. Campaigns that
    /// were running when the daemon stopped are queued again and resume from their journal;
    /// each cell gets its current model from the store.
    pub async fn start_with_lab(
        store: Store,
        config: ServiceConfig,
        lab: Option<Arc<crate::lab::Lab>>,
        shutdown: CancellationToken,
    ) -> Result<(Service, worker::Workers), ServiceError> {
        Self::start_inner(store, config, lab, None, shutdown).await
    }

    /// [`Service::start_with_lab`] as one daemon of a fleet on a shared (PostgreSQL) store:
    /// workers claim jobs from the database, and events travel between the daemons. No
    /// recovery pass: the jobs of a daemon that died are re-queued when its lease expires.
    pub async fn start_fleet(
        store: Store,
        config: ServiceConfig,
        lab: Option<Arc<crate::lab::Lab>>,
        fleet: FleetConfig,
        shutdown: CancellationToken,
    ) -> Result<(Service, worker::Workers), ServiceError> {
        if !store.is_shared() {
            return Err(ServiceError::Store(crate::store::StoreError::Unsupported(
                "a fleet needs a PostgreSQL store",
            )));
        }
        Self::start_inner(store, config, lab, Some(fleet), shutdown).await
    }

    async fn start_inner(
        store: Store,
        mut config: ServiceConfig,
        lab: Option<Arc<crate::lab::Lab>>,
        fleet: Option<FleetConfig>,
        shutdown: CancellationToken,
    ) -> Result<(Service, worker::Workers), ServiceError> {
        for d in lab.iter().flat_map(|l| l.device_names()) {
            if !config.devices.contains(&d) {
                config.devices.push(d);
            }
        }
        // Spooled inputs and tables are a cache of the last run: start empty.
        let spool = store.spool_dir();
        if let Err(e) = std::fs::remove_dir_all(&spool)
            && e.kind() != std::io::ErrorKind::NotFound
        {
            tracing::warn!(path = %spool.display(), error = %e, "cannot empty the spool folder");
        }
        let (events, _) = broadcast::channel(4096);
        let (progress_tx, progress_rx) = mpsc::unbounded_channel();
        let svc = Service {
            shared: Arc::new(Shared {
                store: store.clone(),
                config: config.clone(),
                queue: Mutex::new(Queue::default()),
                wake: Notify::new(),
                running: Mutex::new(HashMap::new()),
                events,
                progress_tx,
                shutdown,
                lab: lab.unwrap_or_default(),
                fleet: std::sync::OnceLock::new(),
            }),
        };
        cells::load_current_models(&svc).await;
        if let Some(fc) = fleet {
            let f = fleet::join(&svc, fc).await?;
            let _ = svc.shared.fleet.set(f);
            svc.update_gauges();
            let workers = worker::start(svc.clone(), progress_rx, config.workers.max(1));
            return Ok((svc, workers));
        }
        let recovered = storage::call(&store, |st| st.recover()).await?;
        for id in &recovered.interrupted {
            tracing::warn!(
                job = id,
                "job was running when the daemon stopped: marked interrupted"
            );
        }
        let mut queued: Vec<i64> = recovered.queued.iter().map(|q| q.0).collect();
        for id in recovered.interrupted {
            if cells::resumable(&store, id).await {
                let ok = storage::call(&store, move |st| {
                    st.resume_job(
                        id,
                        "the daemon restarted: the campaign continues from its journal",
                    )
                })
                .await?;
                if ok {
                    tracing::info!(job = id, "resuming campaign after restart");
                    queued.push(id);
                }
            }
        }
        let records = storage::call(&store, move |st| {
            queued
                .into_iter()
                .map(|id| st.job(id))
                .collect::<Result<Vec<_>, _>>()
        })
        .await?;
        for rec in records.into_iter().flatten() {
            lock(&svc.shared.queue).push(Entry {
                id: rec.id,
                priority: rec.priority,
                devices: rec.devices,
                job: None,
            });
        }
        svc.update_gauges();
        let workers = worker::start(svc.clone(), progress_rx, config.workers.max(1));
        Ok((svc, workers))
    }

    /// The store, for tests and tools that call it directly (blocking). The API and the
    /// scheduler never do: they use the service's async storage methods.
    pub fn store(&self) -> &Store {
        &self.shared.store
    }

    /// The service's settings.
    pub fn config(&self) -> &ServiceConfig {
        &self.shared.config
    }

    /// Subscribe to every event.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.shared.events.subscribe()
    }

    /// True when this daemon is one of a fleet on a shared store.
    pub fn is_fleet(&self) -> bool {
        self.shared.fleet.get().is_some()
    }

    fn publish(&self, e: Event) {
        if let Some(f) = self.shared.fleet.get() {
            f.send(&e);
        }
        // No subscriber is fine.
        let _ = self.shared.events.send(e);
    }

    /// One job, with the live progress of a running job.
    pub async fn job(&self, id: i64) -> Result<JobRecord, ServiceError> {
        let rec = storage::job(&self.shared.store, id).await?;
        let mut rec = rec.ok_or(ServiceError::NotFound(id))?;
        self.overlay(&mut rec);
        Ok(rec)
    }

    /// Jobs matching `filter`, newest first, with live progress.
    pub async fn jobs(&self, filter: JobFilter) -> Result<Vec<JobRecord>, ServiceError> {
        let store = self.shared.store.clone();
        let mut recs = blocking(move || Ok(store.jobs(&filter)?)).await?;
        for r in &mut recs {
            self.overlay(r);
        }
        Ok(recs)
    }

    fn overlay(&self, rec: &mut JobRecord) {
        if rec.state != JobState::Running {
            return;
        }
        if let Some(Running {
            progress: Some((f, s)),
            ..
        }) = lock(&self.shared.running).get(&rec.id)
        {
            rec.progress = *f;
            rec.stage = Some(s.clone());
        }
    }

    /// Jobs waiting in the queue.
    pub fn queue_depth(&self) -> usize {
        lock(&self.shared.queue).len()
    }

    /// Jobs running now.
    pub fn running_count(&self) -> usize {
        lock(&self.shared.running).len()
    }

    /// The lab's devices and who holds them.
    pub fn devices(&self) -> Vec<DeviceStatus> {
        let q = lock(&self.shared.queue);
        let running = lock(&self.shared.running);
        let mut names: Vec<String> = self.shared.config.devices.clone();
        for r in running.values() {
            for d in &r.devices {
                if !names.contains(d) {
                    names.push(d.clone());
                }
            }
        }
        names
            .into_iter()
            .map(|name| {
                let job = running
                    .iter()
                    .find(|(_, r)| r.devices.contains(&name))
                    .map(|(id, _)| *id);
                let busy = q.is_held(&name);
                metrics::gauge!("calibd_device_busy", "device" => name.clone()).set(if busy {
                    1.0
                } else {
                    0.0
                });
                DeviceStatus {
                    state: if busy { "busy" } else { "idle" },
                    job,
                    waiting: q.waiting_for(&name),
                    name,
                }
            })
            .collect()
    }

    fn update_gauges(&self) {
        metrics::gauge!("calibd_queue_depth").set(self.queue_depth() as f64);
        metrics::gauge!("calibd_jobs_running").set(self.running_count() as f64);
    }
}

#[cfg(test)]
mod error_tests;
#[cfg(test)]
mod tests;
