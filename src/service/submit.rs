//! Submission: a job document validated, persisted (once per idempotency key) and queued,
//! and a finished job run again.

use super::*;

impl Service {
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
            let job = jobs::prepare(&doc, &StoreResolver(store.clone()))?;
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
                    request_sha256: crate::run::input::sha256_hex(&request),
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
}
