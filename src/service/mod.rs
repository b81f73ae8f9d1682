//! The job service: validates and persists submissions, keeps the run queue, runs jobs on
//! a bounded pool of blocking workers, and publishes state and progress events. The HTTP
//! API, the scheduler and tests talk to it through [`Service`]; it knows jobs and the
//! store, not models.

mod cells;
mod events;
mod fleet;
mod queue;
mod storage;
mod types;
mod worker;

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use serde_json::Value;
use tokio::sync::{Notify, broadcast, mpsc};
use tokio_util::sync::CancellationToken;

pub use events::Event;
pub use fleet::FleetConfig;
pub use queue::{Entry, Queue};
pub use storage::open as open_store;
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

    /// Validate, persist and queue a job; returns its id.
    pub async fn submit(
        &self,
        doc: Value,
        priority: i64,
        who: Submitter,
        origin: Origin,
    ) -> Result<i64, ServiceError> {
        self.submit_once(doc, priority, who, origin)
            .await
            .map(|(id, _)| id)
    }

    /// [`Service::submit`], returning also whether the job is new: `false` when the
    /// origin's idempotency key was already used for the same request (the first job's id
    /// is returned and nothing is queued again).
    pub async fn submit_once(
        &self,
        doc: Value,
        priority: i64,
        who: Submitter,
        origin: Origin,
    ) -> Result<(i64, bool), ServiceError> {
        let waiting = lock(&self.shared.queue).len();
        if waiting >= self.shared.config.max_queued {
            return Err(ServiceError::QueueFull(waiting));
        }
        let store = self.shared.store.clone();
        let lab = self.shared.lab.clone();
        let (id, created, job) = blocking(move || {
            let job = jobs::prepare(&doc, &StoreResolver(store.clone())).map_err(|e| {
                if e.is_invalid_input() {
                    ServiceError::Invalid(e)
                } else {
                    ServiceError::Internal(e.to_string())
                }
            })?;
            let devices = job.devices();
            if !devices.is_empty() && !who.may_drive_devices {
                return Err(ServiceError::Forbidden(format!(
                    "a `{}` job drives devices ({}): it needs the operator role",
                    job.kind,
                    devices.join(", ")
                )));
            }
            if let Some(reason) = lab.unavailable_for(&devices) {
                return Err(ServiceError::Conflict(reason));
            }
            let idempotency = origin.idempotency_key.map(|key| {
                let mut request = serde_json::to_vec(&doc).unwrap_or_default();
                request.extend_from_slice(format!("\npriority={priority}").as_bytes());
                IdempotencyKey {
                    key,
                    request_sha256: crate::jobs::input::sha256_hex(&request),
                }
            });
            let new = NewJob {
                kind: job.kind.clone(),
                doc,
                priority,
                devices,
                inputs_sha256: serde_json::to_value(&job.inputs_sha256).unwrap_or(Value::Null),
                submitted_by: who.name,
                schedule_id: origin.schedule.as_ref().map(|s| s.id),
                rerun_of: origin.rerun_of,
                schedule_run: origin.schedule.map(|s| (s.due, s.outcome, s.message)),
                idempotency,
            };
            let (id, created) = store.insert_job_once(&new)?;
            Ok((id, created, job))
        })
        .await?;
        if !created {
            return Ok((id, false));
        }
        let kind = job.kind.clone();
        if self.is_fleet() {
            // In the database's queue: a worker of any daemon claims it.
            self.shared.wake.notify_one();
        } else {
            lock(&self.shared.queue).push(Entry {
                id,
                priority,
                devices: job.devices(),
                job: Some(Arc::new(job)),
            });
        }
        metrics::counter!("calibd_jobs_submitted_total", "kind" => kind.clone()).increment(1);
        self.update_gauges();
        self.publish(Event::State {
            id,
            kind,
            state: JobState::Queued,
            error: None,
        });
        self.shared.wake.notify_one();
        Ok((id, true))
    }

    /// Validate a job document without submitting it (for schedules); returns its kind.
    pub async fn validate(&self, doc: Value) -> Result<String, ServiceError> {
        let store = self.shared.store.clone();
        blocking(move || {
            jobs::prepare(&doc, &StoreResolver(store))
                .map(|j| j.kind)
                .map_err(ServiceError::Invalid)
        })
        .await
    }

    /// Submit the same document as job `id` again.
    pub async fn rerun(&self, id: i64, who: Submitter) -> Result<i64, ServiceError> {
        let store = self.shared.store.clone();
        let (doc, rec) = blocking(move || Ok((store.job_doc(id)?, store.job(id)?))).await?;
        let (Some(doc), Some(rec)) = (doc, rec) else {
            return Err(ServiceError::NotFound(id));
        };
        self.submit(
            doc,
            rec.priority,
            who,
            Origin {
                rerun_of: Some(id),
                ..Default::default()
            },
        )
        .await
    }

    /// A job that drives devices (a campaign) is stopped only by an operator or by its own
    /// submitter: a submitter must not abort another person's run on the robot.
    async fn may_stop(&self, id: i64, who: &Submitter) -> Result<(), ServiceError> {
        if who.may_drive_devices {
            return Ok(());
        }
        let store = self.shared.store.clone();
        let rec = blocking(move || Ok(store.job(id)?))
            .await?
            .ok_or(ServiceError::NotFound(id))?;
        if rec.devices.is_empty() || (rec.submitted_by.is_some() && rec.submitted_by == who.name) {
            return Ok(());
        }
        Err(ServiceError::Forbidden(format!(
            "job {id} is a `{}` job that drives devices ({}) submitted by {}: stopping it \
             needs the operator role or being its submitter",
            rec.kind,
            rec.devices.join(", "),
            rec.submitted_by.as_deref().unwrap_or("a schedule")
        )))
    }

    /// Cancel a job: a queued job ends at once, a running one at its next cancellation
    /// check. Returns the state after the request (`cancelled`, or `running` while the job
    /// winds down). A final job is a conflict.
    pub async fn cancel(&self, id: i64, who: &Submitter) -> Result<JobState, ServiceError> {
        self.may_stop(id, who).await?;
        if self.cancel_running(id) {
            return Ok(JobState::Running);
        }
        if self.is_fleet() {
            return self.cancel_in_fleet(id).await;
        }
        let was_queued = lock(&self.shared.queue).remove(id);
        let store = self.shared.store.clone();
        let (ended, rec) = blocking(move || {
            let ended = store.end_job(id, JobState::Cancelled, None)?;
            Ok((ended, store.job(id)?))
        })
        .await?;
        let Some(rec) = rec else {
            return Err(ServiceError::NotFound(id));
        };
        if ended {
            self.update_gauges();
            self.publish(Event::State {
                id,
                kind: rec.kind,
                state: JobState::Cancelled,
                error: None,
            });
            return Ok(JobState::Cancelled);
        }
        if was_queued {
            return Ok(rec.state);
        }
        // It may have just started: try the running map once more.
        if self.cancel_running(id) {
            return Ok(JobState::Running);
        }
        Err(ServiceError::Conflict(format!(
            "job {id} is already {}",
            rec.state.as_str()
        )))
    }

    /// Ask job `id` to stop if it runs here (an operator's cancel); false if it does not.
    fn cancel_running(&self, id: i64) -> bool {
        match lock(&self.shared.running).get_mut(&id) {
            Some(r) => {
                r.user_cancelled = true;
                r.cancel.store(true, Ordering::Relaxed);
                true
            }
            None => false,
        }
    }

    /// Cancel in a fleet a job that does not run here: the store ends it if it waits, or
    /// flags it for the daemon that runs it.
    async fn cancel_in_fleet(&self, id: i64) -> Result<JobState, ServiceError> {
        use crate::store::CancelRequest;
        match storage::call(&self.shared.store, move |st| st.request_cancel(id)).await? {
            CancelRequest::Ended => {
                let kind = self.job(id).await.map(|r| r.kind).unwrap_or_default();
                self.update_gauges();
                self.publish(Event::State {
                    id,
                    kind,
                    state: JobState::Cancelled,
                    error: None,
                });
                Ok(JobState::Cancelled)
            }
            CancelRequest::Requested => Ok(JobState::Running),
            CancelRequest::Final(state) => Err(ServiceError::Conflict(format!(
                "job {id} is already {}",
                state.as_str()
            ))),
            CancelRequest::Missing => Err(ServiceError::NotFound(id)),
        }
    }

    /// One job, with the live progress of a running job.
    pub async fn job(&self, id: i64) -> Result<JobRecord, ServiceError> {
        let store = self.shared.store.clone();
        let rec = blocking(move || Ok(store.job(id)?)).await?;
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
mod tests;
