//! The worker pool: `workers` tasks each take the next runnable job from the queue and run
//! it as a task with its context (numerical work goes to the blocking pool through
//! [`jobs::Cx::compute`]), then store the result, its plots, the cell's model decision and
//! the final state in one transaction. A sink task turns progress reports into
//! live state, SSE events and the stored progress history.

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::events::JobMonitor;
use super::{Entry, Event, Running, Service, StoreResolver, lock};
use crate::jobs::{self, JobError};
use crate::store::JobState;
use tracing::Instrument;

/// The running worker tasks; [`Workers::join`] waits for them after shutdown.
#[derive(Debug)]
pub struct Workers {
    tasks: Vec<JoinHandle<()>>,
}

impl Workers {
    /// Wait until every worker has finished (after the shutdown token is cancelled, a
    /// running job is asked to stop and recorded as `interrupted`).
    pub async fn join(self) {
        for t in self.tasks {
            let _ = t.await;
        }
    }
}

pub(super) fn start(svc: Service, progress: mpsc::UnboundedReceiver<Event>, n: usize) -> Workers {
    let mut tasks = vec![tokio::spawn(sink(svc.clone(), progress))];
    for _ in 0..n {
        let svc = svc.clone();
        tasks.push(tokio::spawn(async move {
            let stop = svc.shared.shutdown.clone();
            loop {
                let entry = tokio::select! {
                    biased;
                    _ = stop.cancelled() => break,
                    e = next_any(&svc) => e,
                };
                if stop.is_cancelled() {
                    if let Some(f) = svc.shared.fleet.get() {
                        // Claimed just as the daemon stops: back to the shared queue.
                        let (st, name) = (svc.shared.store.clone(), f.config.name.clone());
                        let _ = tokio::task::spawn_blocking(move || st.release_owned(&name)).await;
                        lock(&svc.shared.queue).release(&entry.devices);
                        break;
                    }
                    // Taken just as the daemon stops: leave it queued for the next start.
                    let mut q = lock(&svc.shared.queue);
                    q.release(&entry.devices);
                    q.push(entry);
                    break;
                }
                run_one(&svc, entry).await;
            }
        }));
    }
    Workers { tasks }
}

/// The next job: claimed from the shared store in a fleet, else from the local queue.
async fn next_any(svc: &Service) -> Entry {
    match svc.shared.fleet.get() {
        Some(f) => super::fleet::next(svc, f).await,
        None => next(svc).await,
    }
}

/// Wait for the next runnable job.
async fn next(svc: &Service) -> Entry {
    loop {
        let notified = svc.shared.wake.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        let taken = {
            let mut q = lock(&svc.shared.queue);
            let e = q.take();
            (e, q.is_empty())
        };
        if let (Some(e), empty) = taken {
            if !empty {
                // Another worker may be able to take the next one.
                svc.shared.wake.notify_one();
            }
            return e;
        }
        notified.await;
    }
}

/// What became of a job.
enum Outcome {
    Succeeded(Option<crate::lab::Decision>),
    Ended(JobState, Option<String>),
}

async fn run_one(svc: &Service, entry: Entry) {
    let id = entry.id;
    let store = svc.shared.store.clone();
    let cancel = Arc::new(AtomicBool::new(false));
    let job = match entry.job.clone() {
        Some(j) => Ok(j),
        None => {
            let st = store.clone();
            tokio::task::spawn_blocking(move || -> Result<jobs::Job, String> {
                let doc = st
                    .job_doc(id)
                    .map_err(|e| e.to_string())?
                    .ok_or_else(|| "the job's document is missing".to_string())?;
                jobs::prepare(&doc, &StoreResolver(st)).map_err(|e| e.to_string())
            })
            .await
            .unwrap_or_else(|e| Err(e.to_string()))
            .map(Arc::new)
        }
    };
    let job = match job {
        Ok(j) => j,
        Err(e) => {
            let msg = format!("the job is no longer valid: {e}");
            let st = store.clone();
            let m = msg.clone();
            let _ = tokio::task::spawn_blocking(move || st.end_job(id, JobState::Failed, Some(&m)))
                .await;
            finish(
                svc,
                id,
                "",
                &entry.devices,
                JobState::Failed,
                Some(msg),
                None,
            );
            return;
        }
    };
    lock(&svc.shared.running).insert(
        id,
        Running {
            kind: job.kind.clone(),
            cancel: cancel.clone(),
            user_cancelled: false,
            devices: entry.devices.clone(),
            progress: None,
        },
    );
    let st = store.clone();
    let started = if svc.is_fleet() {
        // Claimed: already `running`, leased to this daemon.
        Ok(Ok(true))
    } else {
        tokio::task::spawn_blocking(move || st.start_job(id)).await
    };
    if !matches!(started, Ok(Ok(true))) {
        // Cancelled (or failed to record) between queue and start.
        lock(&svc.shared.running).remove(&id);
        lock(&svc.shared.queue).release(&entry.devices);
        svc.shared.wake.notify_one();
        svc.update_gauges();
        return;
    }
    svc.update_gauges();
    svc.publish(Event::State {
        id,
        kind: job.kind.clone(),
        state: JobState::Running,
        error: None,
    });
    let t0 = Instant::now();
    let span = tracing::info_span!("job", id, kind = %job.kind);
    let monitor = Arc::new(JobMonitor::new(
        id,
        svc.shared.progress_tx.clone(),
        cancel.clone(),
    ));
    let journal: Arc<dyn crate::procedures::Journal> = if job.resumable() {
        Arc::new(crate::store::StoreJournal {
            store: store.clone(),
            job: id,
        })
    } else {
        Arc::new(crate::procedures::MemoryJournal::default())
    };
    let cx = jobs::Cx::new(svc.shared.lab.clone(), journal, monitor);
    let svc2 = svc.clone();
    let job2 = job.clone();
    let mut handle = tokio::spawn(
        async move {
            tracing::info!("started");
            let r = job2.run_in(cx).await;
            conclude(&svc2, id, r).await
        }
        .instrument(span),
    );
    let stop = svc.shared.shutdown.clone();
    let joined = tokio::select! {
        r = &mut handle => r,
        _ = stop.cancelled() => {
            cancel.store(true, Ordering::Relaxed);
            handle.await
        }
    };
    let outcome = joined.unwrap_or_else(|e| {
        Outcome::Ended(
            JobState::Failed,
            Some(format!("internal error: the job panicked ({e})")),
        )
    });
    let (state, error) = match outcome {
        Outcome::Succeeded(decision) => {
            if let Some(d) = decision {
                super::cells::adopt(svc, id, &d);
            }
            (JobState::Succeeded, None)
        }
        Outcome::Ended(s, e) => (s, e),
    };
    if state == JobState::Paused {
        let st = store.clone();
        let e2 = error.clone().unwrap_or_default();
        let _ = tokio::task::spawn_blocking(move || st.pause_job(id, &e2)).await;
    } else if let (JobState::Interrupted, Some(f)) = (state, svc.shared.fleet.get()) {
        // The daemon stops: the job goes back to the shared queue for another daemon.
        let (st, name) = (store.clone(), f.config.name.clone());
        let _ = tokio::task::spawn_blocking(move || st.release_owned(&name)).await;
    } else if state != JobState::Succeeded {
        let st = store.clone();
        let e2 = error.clone();
        let _ = tokio::task::spawn_blocking(move || st.end_job(id, state, e2.as_deref())).await;
    }
    tracing::info!(parent: None, job = id, kind = %job.kind, state = state.as_str(), seconds = t0.elapsed().as_secs_f64(), "job finished");
    finish(
        svc,
        id,
        &job.kind,
        &entry.devices,
        state,
        error,
        Some(t0.elapsed()),
    );
}

/// Store a run's outcome: a result with its artefacts, and the cell's model decision, all in
/// the transaction that marks the job succeeded.
async fn conclude(svc: &Service, id: i64, run: Result<jobs::Completed, JobError>) -> Outcome {
    match run {
        Ok(done) => {
            let artefacts = done.artefacts;
            let decision = done.candidate.as_ref().map(|c| svc.shared.lab.decide(c));
            let csv = done.main_table.as_ref().map(|t| t.to_csv());
            let st = svc.shared.store.clone();
            let d = decision.clone();
            let stored = tokio::task::spawn_blocking(move || {
                st.finish_job(id, &done.result, csv.as_deref(), &artefacts, d.as_ref())
            })
            .await
            .unwrap_or_else(|e| Err(crate::store::StoreError::Internal(e.to_string())));
            match stored {
                Ok(true) => Outcome::Succeeded(decision),
                Ok(false) => Outcome::Ended(
                    JobState::Failed,
                    Some("the job was no longer running".into()),
                ),
                Err(e) => {
                    tracing::error!(error = %e, "storing the result failed");
                    Outcome::Ended(
                        JobState::Failed,
                        Some(format!("storing the result failed: {e}")),
                    )
                }
            }
        }
        Err(JobError::Cancelled) => {
            let by_user = lock(&svc.shared.running)
                .get(&id)
                .is_some_and(|r| r.user_cancelled);
            if by_user {
                Outcome::Ended(JobState::Cancelled, None)
            } else {
                Outcome::Ended(
                    JobState::Interrupted,
                    Some("the daemon shut down while the job was running".into()),
                )
            }
        }
        Err(e @ (JobError::Paused { .. } | JobError::Waiting { .. })) => {
            Outcome::Ended(JobState::Paused, Some(e.to_string()))
        }
        Err(e) => Outcome::Ended(JobState::Failed, Some(e.to_string())),
    }
}

fn finish(
    svc: &Service,
    id: i64,
    kind: &str,
    devices: &[String],
    state: JobState,
    error: Option<String>,
    took: Option<Duration>,
) {
    let kind = lock(&svc.shared.running)
        .remove(&id)
        .map(|r| r.kind)
        .unwrap_or_else(|| kind.to_string());
    lock(&svc.shared.queue).release(devices);
    svc.shared.wake.notify_one();
    if let Some(t) = took {
        metrics::histogram!("calibd_job_duration_seconds", "kind" => kind.clone(), "state" => state.as_str())
            .record(t.as_secs_f64());
    }
    metrics::counter!("calibd_jobs_finished_total", "kind" => kind.clone(), "state" => state.as_str()).increment(1);
    svc.update_gauges();
    svc.publish(Event::State {
        id,
        kind,
        state,
        error,
    });
}

/// Progress reports -> live state, events and (sparser) stored history.
async fn sink(svc: Service, mut rx: mpsc::UnboundedReceiver<Event>) {
    let mut last_history: HashMap<i64, (String, Instant)> = HashMap::new();
    let stop = svc.shared.shutdown.clone();
    loop {
        let ev = tokio::select! {
            _ = stop.cancelled() => break,
            e = rx.recv() => match e { Some(e) => e, None => break },
        };
        let Event::Progress {
            id,
            fraction,
            ref stage,
            ref message,
        } = ev
        else {
            continue;
        };
        let alive = match lock(&svc.shared.running).get_mut(&id) {
            Some(r) => {
                r.progress = Some((fraction, stage.clone()));
                true
            }
            None => false,
        };
        if !alive {
            last_history.remove(&id);
            continue;
        }
        let history = match last_history.get(&id) {
            Some((s, t)) => s != stage || t.elapsed() >= Duration::from_secs(1),
            None => true,
        };
        if history {
            last_history.insert(id, (stage.clone(), Instant::now()));
        }
        svc.publish(ev.clone());
        let st = svc.shared.store.clone();
        let (stage, message) = (stage.clone(), message.clone());
        let _ = tokio::task::spawn_blocking(move || {
            st.record_progress(id, fraction, &stage, message.as_deref(), history)
        })
        .await;
    }
}
