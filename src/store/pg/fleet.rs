//! The shared queue on PostgreSQL: daemons claim queued jobs with
//! `SELECT … FOR UPDATE SKIP LOCKED` (no job is claimed twice, none waits on a locked
//! row), hold them under a lease their heartbeat renews, and re-queue the jobs of a daemon
//! whose lease expired (killed, or cut off). Cells belong to one daemon, recorded in
//! `cells`; a job that needs devices is claimed only by a daemon that holds all of them.

use std::time::Duration;

use super::Pg;
use super::jobs::log_tx;
use crate::store::backend::Fleet;
use crate::store::{CancelRequest, Claimed, JobState, Run, StoreError};

fn secs(d: Duration) -> f64 {
    d.as_secs_f64()
}

impl Fleet for Pg {
    fn is_shared(&self) -> bool {
        true
    }

    /// Record (or refresh) daemon `name` and take the cells in `cells` for it. A cell held
    /// by another daemon whose heartbeat is older than `stale` is taken over; one held by a
    /// live daemon is refused (returned in the error).
    fn register_daemon(
        &self,
        name: &str,
        cells: &[String],
        stale: Duration,
    ) -> Result<(), StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        tx.execute(
            "INSERT INTO daemons (name, started_at, heartbeat) VALUES ($1, now(), now()) \
             ON CONFLICT (name) DO UPDATE SET heartbeat = now()",
            &[&name],
        )?;
        for cell in cells {
            let n = tx.execute(
                "INSERT INTO cells (name, owner, since) VALUES ($1, $2, now()) \
                 ON CONFLICT (name) DO UPDATE SET owner = $2, since = now() \
                 WHERE cells.owner = $2 OR NOT EXISTS (SELECT 1 FROM daemons d \
                   WHERE d.name = cells.owner AND d.heartbeat > now() - make_interval(secs => $3))",
                &[cell, &name, &secs(stale)],
            )?;
            if n == 0 {
                return Err(StoreError::Conflict(format!(
                    "cell `{cell}` is held by another live daemon"
                )));
            }
        }
        tx.commit()?;
        Ok(())
    }

    /// The daemon holding each cell.
    fn cell_owners(&self) -> Result<Vec<(String, String)>, StoreError> {
        let rows = self
            .conn()?
            .query("SELECT name, owner FROM cells ORDER BY name", &[])?;
        rows.iter()
            .map(|r| Ok((r.try_get(0)?, r.try_get(1)?)))
            .collect()
    }

    /// Claim the next queued job `owner` can run (highest priority, then oldest): its
    /// devices must all be among `devices` (numerical jobs need none). The job becomes
    /// `running`, leased to `owner` for `lease`.
    fn claim(
        &self,
        owner: &str,
        devices: &[String],
        lease: Duration,
    ) -> Result<Option<Claimed>, StoreError> {
        let held = serde_json::to_string(devices)?;
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let row = tx.query_opt(
            "UPDATE jobs SET state = 'running', started_at = COALESCE(started_at, $4), progress = 0, owner = $1, \
             lease_until = now() + make_interval(secs => $3), attempt = attempt + 1 \
             WHERE id = (SELECT id FROM jobs WHERE state = 'queued' AND devices::jsonb <@ $2::TEXT::jsonb \
                         ORDER BY priority DESC, id FOR UPDATE SKIP LOCKED LIMIT 1) \
             RETURNING id, priority, doc, devices, attempt",
            &[&owner, &held, &secs(lease), &super::now()],
        )?;
        let Some(r) = row else {
            return Ok(None);
        };
        let id: i64 = r.try_get(0)?;
        let claimed = Claimed {
            id,
            priority: r.try_get(1)?,
            doc: serde_json::from_str(r.try_get(2)?)?,
            devices: serde_json::from_str(r.try_get(3)?)?,
            run: Run {
                job: id,
                attempt: r.try_get(4)?,
            },
        };
        log_tx(&mut tx, Some(id), "info", &format!("started on {owner}"))?;
        tx.commit()?;
        Ok(Some(claimed))
    }

    /// Renew the leases of `owner`'s running jobs and its heartbeat; returns how many jobs
    /// it still holds.
    fn heartbeat(&self, owner: &str, lease: Duration) -> Result<u64, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        tx.execute(
            "UPDATE daemons SET heartbeat = now() WHERE name = $1",
            &[&owner],
        )?;
        let n = tx.execute(
            "UPDATE jobs SET lease_until = now() + make_interval(secs => $2) \
             WHERE owner = $1 AND state = 'running'",
            &[&owner, &secs(lease)],
        )?;
        tx.commit()?;
        Ok(n)
    }

    /// Put running jobs whose lease expired back in the queue (their daemon died or lost
    /// the database); returns their ids. A campaign's journal stays, so it resumes where it
    /// was on the daemon that holds its cell.
    fn requeue_expired(&self) -> Result<Vec<i64>, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        cancel_requested_tx(&mut tx, None)?;
        let rows = tx.query(
            "UPDATE jobs SET state = 'queued', started_at = NULL, owner = NULL, lease_until = NULL \
             WHERE id IN (SELECT id FROM jobs WHERE state = 'running' AND lease_until < now() \
                          FOR UPDATE SKIP LOCKED) RETURNING id",
            &[],
        )?;
        requeued(
            tx,
            &rows,
            "re-queued: its daemon's lease expired",
            "requeued",
        )
    }

    /// The daemon holding a running job.
    fn job_owner(&self, id: i64) -> Result<Option<String>, StoreError> {
        let r = self
            .conn()?
            .query_opt("SELECT owner FROM jobs WHERE id = $1", &[&id])?;
        Ok(match r {
            Some(r) => r.try_get(0)?,
            None => None,
        })
    }

    /// Put the running jobs of `owner` back in the queue (a daemon restarting under the
    /// same name, or stopping); returns their ids.
    fn release_owned(&self, owner: &str) -> Result<Vec<i64>, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        cancel_requested_tx(&mut tx, Some(owner))?;
        let rows = tx.query(
            "UPDATE jobs SET state = 'queued', started_at = NULL, owner = NULL, lease_until = NULL \
             WHERE owner = $1 AND state = 'running' RETURNING id",
            &[&owner],
        )?;
        requeued(
            tx,
            &rows,
            &format!("re-queued: released by {owner}"),
            "released",
        )
    }

    /// An operator's cancel: a queued or paused job ends now; a running one is flagged and
    /// its daemon told (`NOTIFY calibd_cancel`, and its heartbeat reads the flag).
    fn request_cancel(&self, id: i64) -> Result<CancelRequest, StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        let Some(r) = tx.query_opt("SELECT state FROM jobs WHERE id = $1 FOR UPDATE", &[&id])?
        else {
            return Ok(CancelRequest::Missing);
        };
        let state: String = r.try_get(0)?;
        let state = JobState::parse(&state).ok_or(StoreError::Corrupt {
            column: "jobs.state",
            value: state,
        })?;
        let out = match state {
            JobState::Queued | JobState::Paused => {
                tx.execute(
                    "UPDATE jobs SET state = 'cancelled', finished_at = $2, error = NULL, owner = NULL, \
                     lease_until = NULL WHERE id = $1",
                    &[&id, &super::now()],
                )?;
                log_tx(&mut tx, Some(id), "info", "cancelled")?;
                CancelRequest::Ended
            }
            JobState::Running => {
                tx.execute("UPDATE jobs SET cancel_requested = 1 WHERE id = $1", &[&id])?;
                log_tx(&mut tx, Some(id), "info", "cancel requested")?;
                tx.execute("SELECT pg_notify('calibd_cancel', $1)", &[&id.to_string()])?;
                CancelRequest::Requested
            }
            other => CancelRequest::Final(other),
        };
        tx.commit()?;
        Ok(out)
    }

    /// The running jobs of `owner` an operator asked to cancel.
    fn cancel_requests(&self, owner: &str) -> Result<Vec<i64>, StoreError> {
        let rows = self.conn()?.query(
            "SELECT id FROM jobs WHERE owner = $1 AND state = 'running' AND cancel_requested = 1",
            &[&owner],
        )?;
        rows.iter().map(|r| Ok(r.try_get(0)?)).collect()
    }

    /// Send `payload` on notification channel `channel`.
    fn notify(&self, channel: &str, payload: &str) -> Result<(), StoreError> {
        self.conn()?
            .execute("SELECT pg_notify($1, $2)", &[&channel, &payload])?;
        Ok(())
    }

    /// Listen on `channels` on a connection of its own and call `on(channel, payload)` for
    /// each notification, until `stop()` is true (checked at least every `tick`).
    fn listen(
        &self,
        channels: &[&str],
        tick: Duration,
        stop: &dyn Fn() -> bool,
        on: &mut dyn FnMut(&str, &str),
    ) -> Result<(), StoreError> {
        let mut c = self.conn()?;
        for ch in channels {
            // Channel names are ours (identifiers), never input.
            c.batch_execute(&format!("LISTEN {ch}"))?;
        }
        while !stop() {
            let mut n = c.notifications();
            let mut it = n.timeout_iter(tick);
            while let Some(m) = fallible_next(&mut it)? {
                on(m.channel(), m.payload());
                if stop() {
                    break;
                }
            }
        }
        c.batch_execute("UNLISTEN *")?;
        Ok(())
    }
}

/// Running jobs whose cancel was requested end `cancelled` instead of going back to the
/// queue: those of `owner` (it lets go), or with none those whose lease expired.
fn cancel_requested_tx(
    tx: &mut postgres::Transaction<'_>,
    owner: Option<&str>,
) -> Result<(), StoreError> {
    let rows = tx.query(
        "UPDATE jobs SET state = 'cancelled', finished_at = $1, owner = NULL, lease_until = NULL \
         WHERE state = 'running' AND cancel_requested = 1 \
         AND (($2::TEXT IS NULL AND lease_until < now()) OR owner = $2) RETURNING id",
        &[&super::now(), &owner],
    )?;
    for r in rows {
        log_tx(tx, Some(r.try_get(0)?), "info", "cancelled")?;
    }
    Ok(())
}

fn fallible_next(
    it: &mut impl postgres::fallible_iterator::FallibleIterator<
        Item = postgres::Notification,
        Error = postgres::Error,
    >,
) -> Result<Option<postgres::Notification>, StoreError> {
    Ok(it.next()?)
}

/// The jobs an `UPDATE ... RETURNING id` put back in the queue: log `why` on each, wake the
/// daemons' queue listeners with `NOTIFY calibd_queue, payload` when there is any, commit,
/// and return their ids.
fn requeued(
    mut tx: postgres::Transaction<'_>,
    rows: &[postgres::Row],
    why: &str,
    payload: &str,
) -> Result<Vec<i64>, StoreError> {
    let ids: Vec<i64> = rows
        .iter()
        .map(|r| r.try_get(0))
        .collect::<Result<_, _>>()?;
    for id in &ids {
        log_tx(&mut tx, Some(*id), "warn", why)?;
    }
    if !ids.is_empty() {
        tx.execute("SELECT pg_notify('calibd_queue', $1)", &[&payload])?;
    }
    tx.commit()?;
    Ok(ids)
}
