//! Fleet mode: several daemons on one PostgreSQL store. Workers claim jobs from the
//! database (`FOR UPDATE SKIP LOCKED`) instead of the in-memory queue; a heartbeat renews
//! this daemon's leases and re-queues jobs whose daemon died; state and progress events
//! go out with `NOTIFY calibd_events` and come in from the other daemons by `LISTEN`, so
//! an SSE client on any daemon sees every job; an operator's cancel of a job that runs on
//! another daemon reaches it by `NOTIFY calibd_cancel` (and its heartbeat reads the flag).
//! Blocking store calls go through the service's storage module, or run on the listener's
//! and notifier's own threads.

use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::{Entry, Event, Service, lock};

/// Settings of a daemon in a fleet.
#[derive(Debug, Clone)]
pub struct FleetConfig {
    /// This daemon's name (unique in the fleet; stable across restarts).
    pub name: String,
    /// Cells this daemon holds (their device jobs run only here).
    pub cells: Vec<String>,
    /// How long a claim lasts without a heartbeat.
    pub lease: Duration,
    /// How often idle workers look for work when no notification came.
    pub poll: Duration,
}

impl FleetConfig {
    /// A daemon named `name` with the default lease (15 s) and poll interval (250 ms).
    pub fn named(name: &str) -> FleetConfig {
        FleetConfig {
            name: name.to_string(),
            cells: Vec::new(),
            lease: Duration::from_secs(15),
            poll: Duration::from_millis(250),
        }
    }
}

/// The fleet state of a running service.
#[derive(Debug)]
pub(super) struct Fleet {
    pub(super) config: FleetConfig,
    /// One claim at a time per daemon: the free devices are computed and taken atomically.
    claiming: tokio::sync::Mutex<()>,
    /// Events to send to the other daemons.
    outbox: std::sync::mpsc::Sender<String>,
}

/// An event on the wire, with the daemon that sent it.
#[derive(Debug, Serialize, Deserialize)]
struct Wire {
    from: String,
    event: WireEvent,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
enum WireEvent {
    State {
        id: i64,
        kind: String,
        state: crate::store::JobState,
        error: Option<String>,
    },
    Progress {
        id: i64,
        fraction: f64,
        stage: String,
        message: Option<String>,
    },
    Drift(super::events::DriftEvent),
}

impl From<&Event> for WireEvent {
    fn from(e: &Event) -> Self {
        match e.clone() {
            Event::State {
                id,
                kind,
                state,
                error,
            } => WireEvent::State {
                id,
                kind,
                state,
                error,
            },
            Event::Progress {
                id,
                fraction,
                stage,
                message,
            } => WireEvent::Progress {
                id,
                fraction,
                stage,
                message,
            },
            Event::Drift(d) => WireEvent::Drift(d),
        }
    }
}

impl From<WireEvent> for Event {
    fn from(e: WireEvent) -> Self {
        match e {
            WireEvent::State {
                id,
                kind,
                state,
                error,
            } => Event::State {
                id,
                kind,
                state,
                error,
            },
            WireEvent::Progress {
                id,
                fraction,
                stage,
                message,
            } => Event::Progress {
                id,
                fraction,
                stage,
                message,
            },
            WireEvent::Drift(d) => Event::Drift(d),
        }
    }
}

impl Fleet {
    /// Send `e` to the other daemons (best effort: an SSE client also reads stored state).
    pub(super) fn send(&self, e: &Event) {
        let wire = Wire {
            from: self.config.name.clone(),
            event: e.into(),
        };
        if let Ok(text) = serde_json::to_string(&wire) {
            let _ = self.outbox.send(text);
        }
    }
}

/// Join the fleet: register, take the cells, re-queue what an earlier life of this daemon
/// held, start the heartbeat, the notifier and the listener. Returns the fleet state.
pub(super) async fn join(svc: &Service, config: FleetConfig) -> Result<Fleet, super::ServiceError> {
    let svc_store = svc.shared.store.clone();
    let shutdown = svc.shared.shutdown.clone();
    let (st, c) = (svc_store.clone(), config.clone());
    super::blocking(move || {
        st.register_daemon(&c.name, &c.cells, c.lease * 2)?;
        let released = st.release_owned(&c.name)?;
        if !released.is_empty() {
            tracing::warn!(jobs = ?released, "re-queued the jobs this daemon held before it restarted");
        }
        Ok(())
    })
    .await?;
    // Heartbeat: renew leases, re-queue the jobs of dead daemons, stop cancelled jobs.
    let (st, c, stop) = (svc_store.clone(), config.clone(), shutdown.clone());
    let hb_svc = svc.clone();
    tokio::spawn(async move {
        let svc = hb_svc;
        let every = c.lease / 3;
        loop {
            tokio::select! {
                _ = stop.cancelled() => break,
                _ = tokio::time::sleep(every) => {}
            }
            let c = c.clone();
            let r = super::storage::call(&st, move |st| {
                st.heartbeat(&c.name, c.lease)?;
                st.register_daemon(&c.name, &[], c.lease * 2)?;
                Ok((st.requeue_expired()?, st.cancel_requests(&c.name)?))
            })
            .await;
            match r {
                Ok((requeued, cancels)) => {
                    if !requeued.is_empty() {
                        tracing::warn!(jobs = ?requeued, "re-queued jobs whose daemon's lease expired");
                    }
                    // Cancels whose notification this daemon missed.
                    for id in cancels {
                        svc.cancel_running(id);
                    }
                }
                Err(e) => tracing::warn!(error = %e, "fleet heartbeat failed"),
            }
        }
    });
    // Notifier: one thread sends this daemon's events.
    let (outbox, rx) = std::sync::mpsc::channel::<String>();
    let st = svc_store.clone();
    std::thread::Builder::new()
        .name("calibd-notify".into())
        .spawn(move || {
            for text in rx {
                if let Err(e) = st.notify("calibd_events", &text) {
                    tracing::warn!(error = %e, "could not send an event to the fleet");
                }
            }
        })
        .map_err(|e| super::ServiceError::Internal(e.to_string()))?;
    // Listener: the other daemons' events and queue changes.
    let (st, me, stop, svc) = (svc_store, config.name.clone(), shutdown, svc.clone());
    std::thread::Builder::new()
        .name("calibd-listen".into())
        .spawn(move || {
            while !stop.is_cancelled() {
                let r = st.listen(
                    &["calibd_events", "calibd_queue", "calibd_cancel"],
                    Duration::from_millis(500),
                    &|| stop.is_cancelled(),
                    &mut |channel, payload| {
                        if channel == "calibd_queue" {
                            svc.shared.wake.notify_waiters();
                            svc.shared.wake.notify_one();
                        } else if channel == "calibd_cancel" {
                            if let Ok(id) = payload.parse::<i64>() {
                                svc.cancel_running(id);
                            }
                        } else if let Ok(w) = serde_json::from_str::<Wire>(payload)
                            && w.from != me
                        {
                            let _ = svc.shared.events.send(w.event.into());
                        }
                    },
                );
                if let Err(e) = r {
                    tracing::warn!(error = %e, "fleet listener lost its connection; retrying");
                    std::thread::sleep(Duration::from_secs(1));
                }
            }
        })
        .map_err(|e| super::ServiceError::Internal(e.to_string()))?;
    Ok(Fleet {
        config,
        claiming: tokio::sync::Mutex::new(()),
        outbox,
    })
}

/// Wait for the next job this daemon can run, claimed from the database.
pub(super) async fn next(svc: &Service, fleet: &Fleet) -> (Entry, crate::store::Run) {
    loop {
        let notified = svc.shared.wake.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        {
            let _one = fleet.claiming.lock().await;
            let free: Vec<String> = {
                let q = lock(&svc.shared.queue);
                svc.shared
                    .config
                    .devices
                    .iter()
                    .filter(|d| !q.is_held(d))
                    .cloned()
                    .collect()
            };
            let (name, lease) = (fleet.config.name.clone(), fleet.config.lease);
            let claimed =
                super::storage::call(&svc.shared.store, move |st| st.claim(&name, &free, lease))
                    .await;
            match claimed {
                Ok(Some(c)) => {
                    let entry = Entry {
                        id: c.id,
                        priority: c.priority,
                        devices: c.devices,
                        job: None,
                    };
                    lock(&svc.shared.queue).hold(&entry.devices);
                    // Another worker may find the next one.
                    svc.shared.wake.notify_one();
                    return (entry, c.run);
                }
                Ok(None) => {}
                Err(e) => tracing::warn!(error = %e, "claiming a job failed"),
            }
        }
        tokio::select! {
            _ = notified => {}
            _ = tokio::time::sleep(fleet.config.poll) => {}
        }
    }
}
