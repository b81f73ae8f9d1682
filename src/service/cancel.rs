//! Cancellation: who may stop a job, and stopping it whether it is queued, running here or
//! running on another daemon of the fleet.

use super::*;

impl Service {
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
    pub(super) fn cancel_running(&self, id: i64) -> bool {
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
}
