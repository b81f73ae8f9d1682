//! Several daemons on one database (PostgreSQL only): daemon registration and cell
//! ownership, claiming queued jobs, leases and their heartbeat, re-queueing the jobs of a
//! daemon that died. On the embedded SQLite store these calls are refused: one daemon owns
//! the file, and its in-memory queue is the queue.

use std::time::Duration;

use serde_json::Value;

use super::{Run, Store, StoreError};

/// A job a daemon claimed: it is `running` and leased to that daemon.
#[derive(Debug, Clone, PartialEq)]
pub struct Claimed {
    /// Job id.
    pub id: i64,
    /// Priority.
    pub priority: i64,
    /// The job document.
    pub doc: Value,
    /// Devices it holds while it runs.
    pub devices: Vec<String>,
    /// The run's token: its writes count only while the job is still this attempt.
    pub run: Run,
}

/// What an operator's cancel did to a job in the shared store.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CancelRequest {
    /// It was queued or paused: it is `cancelled` now.
    Ended,
    /// It runs on a daemon (named in the store): that daemon is asked to stop it.
    Requested,
    /// It had already ended in this state.
    Final(crate::store::JobState),
    /// There is no such job.
    Missing,
}

impl Store {
    /// True when several daemons can share this store (PostgreSQL).
    pub fn is_shared(&self) -> bool {
        self.backend.is_shared()
    }

    /// Record daemon `name` (or refresh its heartbeat) and take `cells` for it; a cell held
    /// by a daemon whose heartbeat is older than `stale` is taken over, one held by a live
    /// daemon is a [`StoreError::Conflict`].
    pub fn register_daemon(
        &self,
        name: &str,
        cells: &[String],
        stale: Duration,
    ) -> Result<(), StoreError> {
        self.backend.register_daemon(name, cells, stale)
    }

    /// Each cell and the daemon holding it, by cell name.
    pub fn cell_owners(&self) -> Result<Vec<(String, String)>, StoreError> {
        self.backend.cell_owners()
    }

    /// Claim the next queued job daemon `owner` can run (all its devices among `devices`;
    /// numerical jobs need none): it becomes `running`, leased to `owner` for `lease`.
    pub fn claim(
        &self,
        owner: &str,
        devices: &[String],
        lease: Duration,
    ) -> Result<Option<Claimed>, StoreError> {
        self.backend.claim(owner, devices, lease)
    }

    /// Renew `owner`'s heartbeat and the leases of its running jobs; returns how many it holds.
    pub fn heartbeat(&self, owner: &str, lease: Duration) -> Result<u64, StoreError> {
        self.backend.heartbeat(owner, lease)
    }

    /// Re-queue running jobs whose lease expired; returns their ids.
    pub fn requeue_expired(&self) -> Result<Vec<i64>, StoreError> {
        self.backend.requeue_expired()
    }

    /// The daemon holding a job (none when it is not running on a shared store).
    pub fn job_owner(&self, id: i64) -> Result<Option<String>, StoreError> {
        self.backend.job_owner(id)
    }

    /// Put `owner`'s running jobs back in the queue; returns their ids.
    pub fn release_owned(&self, owner: &str) -> Result<Vec<i64>, StoreError> {
        self.backend.release_owned(owner)
    }

    /// An operator's cancel in a fleet: a queued or paused job ends at once; a running one
    /// is flagged for the daemon that runs it (told by `NOTIFY calibd_cancel`; its
    /// heartbeat also reads the flag).
    pub fn request_cancel(&self, id: i64) -> Result<CancelRequest, StoreError> {
        self.backend.request_cancel(id)
    }

    /// The running jobs of daemon `owner` whose cancel an operator requested.
    pub fn cancel_requests(&self, owner: &str) -> Result<Vec<i64>, StoreError> {
        self.backend.cancel_requests(owner)
    }

    /// Send a notification to every daemon listening on `channel`.
    pub fn notify(&self, channel: &str, payload: &str) -> Result<(), StoreError> {
        self.backend.notify(channel, payload)
    }

    /// Listen on `channels` (identifiers) and call `on(channel, payload)` for each
    /// notification until `stop()` is true (checked at least every `tick`). Blocking.
    pub fn listen(
        &self,
        channels: &[&str],
        tick: Duration,
        stop: &dyn Fn() -> bool,
        on: &mut dyn FnMut(&str, &str),
    ) -> Result<(), StoreError> {
        self.backend.listen(channels, tick, stop, on)
    }
}
