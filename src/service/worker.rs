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
use super::storage::call;
use super::{Entry, Event, Running, Service, StoreResolver, lock};
use crate::jobs::{self, JobError};
use crate::store::{JobState, MainTableCsv, Run, StoreError};
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
                let (entry, claimed) = tokio::select! {
                    biased;
                    _ = stop.cancelled() => break,
                    e = next_any(&svc) => e,
                };
                if stop.is_cancelled() {
                    if let Some(f) = svc.shared.fleet.get() {
                        // Claimed just as the daemon stops: back to the shared queue.
                        let name = f.config.name.clone();
                        let _ = call(&svc.shared.store, move |st| st.release_owned(&name)).await;
                        lock(&svc.shared.queue).release(&entry.devices);
                        break;
                    }
                    // Taken just as the daemon stops: leave it queued for the next start.
                    let mut q = lock(&svc.shared.queue);
                    q.release(&entry.devices);
                    q.push(entry);
                    break;
                }
                run_one(&svc, entry, claimed).await;
            }
        }));
    }
    Workers { tasks }
}

/// The next job: claimed from the shared store in a fleet (with the claim's run token),
/// else from the local queue.
async fn next_any(svc: &Service) -> (Entry, Option<Run>) {
    match svc.shared.fleet.get() {
        Some(f) => {
            let (e, run) = super::fleet::next(svc, f).await;
            (e, Some(run))
        }
        None => (next(svc).await, None),
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
    /// Paused on a device fault (the reason): the cell may resume it by itself.
    PausedOnFault(String),
    /// The job was taken from this run (its lease expired and it was queued or claimed
    /// again): nothing of this run is stored, and its end is not announced.
    Stale(StoreError),
}

async fn run_one(svc: &Service, entry: Entry, claimed: Option<Run>) {
    let id = entry.id;
    let store = svc.shared.store.clone();
    let cancel = Arc::new(AtomicBool::new(false));
    let job = match entry.job.clone() {
        Some(j) => Ok(j),
        None => call(&store, move |st| {
            let doc = st
                .job_doc(id)?
                .ok_or_else(|| StoreError::Internal("the job's document is missing".into()))?;
            Ok(jobs::prepare(&doc, &StoreResolver(st.clone())).map_err(|e| e.to_string()))
        })
        .await
        .unwrap_or_else(|e| Err(e.to_string()))
        .map(Arc::new),
    };
    let job = match job {
        Ok(j) => j,
        Err(e) => {
            let msg = format!("the job is no longer valid: {e}");
            let m = msg.clone();
            let ended = call(&store, move |st| match claimed {
                Some(run) => st.end_run(run, JobState::Failed, Some(&m)),
                None => st.end_job(id, JobState::Failed, Some(&m)),
            })
            .await;
            if let Err(e) = ended {
                tracing::warn!(job = id, error = %e, "could not record the job as failed");
            }
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
            run: claimed,
            stale: None,
        },
    );
    let run = match claimed {
        // Claimed: already `running`, leased to this daemon.
        Some(run) => Some(run),
        None => call(&store, move |st| st.start_job(id))
            .await
            .ok()
            .flatten(),
    };
    if let Some(r) = lock(&svc.shared.running).get_mut(&id) {
        r.run = run;
    }
    let Some(run) = run else {
        // Cancelled (or failed to record) between queue and start.
        lock(&svc.shared.running).remove(&id);
        lock(&svc.shared.queue).release(&entry.devices);
        svc.shared.wake.notify_one();
        svc.update_gauges();
        return;
    };
    svc.update_gauges();
    // What each device was at the start: a paused job resumes by itself only on the same.
    let before = svc.shared.lab.fingerprints(&entry.devices);
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
        Arc::new(super::storage::RunJournal(crate::store::StoreJournal {
            store: store.clone(),
            job: id,
        }))
    } else {
        Arc::new(crate::procedures::MemoryJournal::default())
    };
    let cx = jobs::Cx::new(svc.shared.lab.clone(), journal, monitor);
    let svc2 = svc.clone();
    let job2 = job.clone();
    let mut handle = tokio::spawn(
        async move {
            tracing::info!("started");
            let r = if job2.large_main_table() {
                // A table read from a large file goes to a file row by row, never whole.
                let dir = svc2.shared.store.spool_dir();
                match std::fs::create_dir_all(&dir) {
                    Ok(()) => {
                        let path = dir.join(format!("job-{id}-{}.csv", run.attempt));
                        job2.run_streamed_in(cx, path).await
                    }
                    Err(e) => Err(JobError::io(
                        "cannot create the spool folder",
                        Some(&dir),
                        e,
                    )),
                }
            } else {
                job2.run_in(cx).await
            };
            let outcome = conclude(&svc2, run, r).await;
            crate::util::release_memory();
            outcome
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
    let mut fault = false;
    let (state, error) = match outcome {
        Outcome::Succeeded(decision) => {
            if let Some(d) = decision {
                super::cells::adopt(svc, id, &d).await;
            }
            (JobState::Succeeded, None)
        }
        Outcome::Ended(s, e) => (s, e),
        Outcome::PausedOnFault(e) => {
            fault = true;
            (JobState::Paused, Some(e))
        }
        Outcome::Stale(e) => return drop_stale(svc, run, &entry.devices, &e),
    };
    let e2 = error.clone();
    let stored = match (state, svc.shared.fleet.get()) {
        (JobState::Succeeded, _) => Ok(()),
        (JobState::Paused, _) => {
            call(&store, move |st| {
                st.pause_job(run, e2.as_deref().unwrap_or_default())
                    .map(drop)
            })
            .await
        }
        (JobState::Interrupted, Some(f)) => {
            // The daemon stops: the job goes back to the shared queue for another daemon.
            let name = f.config.name.clone();
            call(&store, move |st| st.release_owned(&name).map(drop)).await
        }
        _ => {
            call(&store, move |st| {
                st.end_run(run, state, e2.as_deref()).map(drop)
            })
            .await
        }
    };
    match stored {
        Err(e @ StoreError::Stale { .. }) => return drop_stale(svc, run, &entry.devices, &e),
        Err(e) => tracing::error!(job = id, error = %e, "recording the job's end failed"),
        Ok(()) => {}
    }
    tracing::info!(parent: None, job = id, kind = %job.kind, state = state.as_str(), seconds = t0.elapsed().as_secs_f64(), "job finished");
    if fault && let Some(e) = &error {
        super::resume::watch(svc, id, entry.devices.clone(), before, e.clone());
    }
    finish(
        svc,
        id,
        &job.kind,
        &entry.devices,
        state,
        error,
        Some(t0.elapsed()),
    );
    if state == JobState::Succeeded && job.kind == "cell.verify" {
        super::drift::after_verify(svc, id).await;
    }
}

/// Store a run's outcome: a result with its artefacts, and the cell's model decision, all in
/// the transaction that marks the job succeeded.
async fn conclude(svc: &Service, run: Run, ran: Result<jobs::Completed, JobError>) -> Outcome {
    let id = run.job;
    let stale = lock(&svc.shared.running)
        .get_mut(&id)
        .filter(|r| r.run == Some(run))
        .and_then(|r| r.stale.take());
    if let Some(e) = stale {
        return Outcome::Stale(e);
    }
    match ran {
        Ok(done) => {
            let artefacts = done.artefacts;
            let decision = done.candidate.as_ref().map(|c| svc.shared.lab.decide(c));
            let csv = done.main_table.as_ref().map(|t| t.to_csv());
            let file = done.main_csv_file.clone();
            let d = decision.clone();
            // An accepted model is the cell's in memory before the job's end is stored, so
            // whoever sees the job succeeded sees the cell on its new model; undone below if
            // the store refuses the result.
            let previous = decision
                .as_ref()
                .and_then(|d| super::cells::apply(svc, run.job, d));
            let stored = call(&svc.shared.store, move |st| {
                let main = match (&csv, &file) {
                    (Some(t), _) => Some(MainTableCsv::Text(t)),
                    (None, Some(f)) => Some(MainTableCsv::File(f)),
                    (None, None) => None,
                };
                st.finish_job(run, &done.result, main, &artefacts, d.as_ref())
            })
            .await;
            if let Some(f) = &done.main_csv_file {
                let _ = std::fs::remove_file(f);
            }
            if !matches!(stored, Ok(true))
                && let (Some(d), Some(prev)) = (&decision, previous)
            {
                super::cells::restore(svc, &d.cell, prev);
            }
            match stored {
                Ok(true) => Outcome::Succeeded(decision),
                Ok(false) => Outcome::Ended(
                    JobState::Failed,
                    Some("the job was no longer running".into()),
                ),
                Err(e @ StoreError::Stale { .. }) => Outcome::Stale(e),
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
        Err(e @ JobError::Paused { .. }) => Outcome::PausedOnFault(e.to_string()),
        Err(e @ JobError::Waiting { .. }) => Outcome::Ended(JobState::Paused, Some(e.to_string())),
        Err(e) => {
            if e.is_internal() {
                tracing::error!(job = id, error = %e, "the job failed on an internal or storage fault");
            }
            Outcome::Ended(JobState::Failed, Some(e.to_string()))
        }
    }
}

/// A run whose job was taken from it: log it, free its devices and forget it, without
/// announcing an end (the run that took the job announces its own).
fn drop_stale(svc: &Service, run: Run, devices: &[String], e: &StoreError) {
    tracing::warn!(job = run.job, attempt = run.attempt, error = %e, "this run's result and end were not stored: its job was taken over");
    metrics::counter!("calibd_stale_runs_total").increment(1);
    let mut running = lock(&svc.shared.running);
    if running.get(&run.job).is_some_and(|r| r.run == Some(run)) {
        running.remove(&run.job);
    }
    drop(running);
    lock(&svc.shared.queue).release(devices);
    svc.shared.wake.notify_one();
    svc.update_gauges();
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
        let run = match lock(&svc.shared.running).get_mut(&id) {
            Some(r) => {
                r.progress = Some((fraction, stage.clone()));
                r.run
            }
            None => None,
        };
        let Some(run) = run else {
            last_history.remove(&id);
            continue;
        };
        let history = match last_history.get(&id) {
            Some((s, t)) => s != stage || t.elapsed() >= Duration::from_secs(1),
            None => true,
        };
        if history {
            last_history.insert(id, (stage.clone(), Instant::now()));
        }
        svc.publish(ev.clone());
        let (stage, message) = (stage.clone(), message.clone());
        let stored = call(&svc.shared.store, move |st| {
            st.record_progress(run, fraction, &stage, message.as_deref(), history)
        })
        .await;
        if let Err(e @ StoreError::Stale { .. }) = stored {
            // Taken over: stop computing for nothing; the run ends without writing.
            if let Some(r) = lock(&svc.shared.running)
                .get_mut(&id)
                .filter(|r| r.run == Some(run))
            {
                r.cancel.store(true, Ordering::Relaxed);
                r.stale = Some(e);
            }
        }
    }
}
