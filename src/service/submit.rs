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
            refuse_plan(&job, &lab)?;
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
                inputs_sha256: job.inputs_sha256.clone(),
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

    /// A dry run: the job validated and, for a campaign on a cell of this lab, its plan
    /// checked against the cell's envelope with the estimated duration; nothing is stored,
    /// queued or moved.
    pub async fn dry_run(&self, doc: Value) -> Result<DryRun, ServiceError> {
        let store = self.shared.store.clone();
        let lab = self.shared.lab.clone();
        blocking(move || {
            let job = jobs::prepare(&doc, &StoreResolver(store)).map_err(invalid)?;
            let devices = job.devices();
            let preflight = match job.preflight(&lab, &crate::util::NoMonitor) {
                Some(p) => Some(p.map_err(invalid)?),
                // A campaign of this lab without a plan to check (the 3-PF campaign draws its
                // poses inside the model's joint box): validated, nothing more to show.
                None if devices.iter().all(|d| lab.device_names().contains(d)) => None,
                None if !devices.is_empty() => {
                    return Err(ServiceError::Invalid(crate::run::JobError::invalid(
                        "cell",
                        format!(
                            "this daemon drives none of {}: a dry run plans on the cell's model and envelope",
                            devices.join(", ")
                        ),
                    )));
                }
                None => None,
            };
            Ok(DryRun {
                dry_run: true,
                kind: job.kind.clone(),
                unavailable: lab.unavailable_for(&devices),
                devices,
                preflight,
            })
        })
        .await
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

/// What `POST /v1/jobs?dry_run=true` answers.
#[derive(Debug, Clone, serde::Serialize)]
pub struct DryRun {
    /// Always true: nothing was stored, queued or moved.
    pub dry_run: bool,
    /// The job kind.
    pub kind: String,
    /// Devices the job would drive.
    pub devices: Vec<String>,
    /// Why its cell cannot run it now (a device failed its last check), if so.
    pub unavailable: Option<String>,
    /// A campaign's plan, envelope check and estimated duration.
    #[serde(flatten)]
    pub preflight: Option<crate::run::Preflight>,
}

fn invalid(e: crate::run::JobError) -> ServiceError {
    if e.is_invalid_input() {
        ServiceError::Invalid(e)
    } else {
        ServiceError::Internal(e.to_string())
    }
}

/// Refuse a campaign whose plan leaves its cell's envelope, with every offending
/// configuration (a plan that cannot be made fails when the job runs, as before).
fn refuse_plan(job: &jobs::Job, lab: &crate::lab::Lab) -> Result<(), ServiceError> {
    match job.preflight(lab, &crate::util::NoMonitor) {
        Some(Ok(p)) => match p.refusal() {
            Some(refused) => Err(ServiceError::Invalid(refused)),
            None => Ok(()),
        },
        Some(Err(e)) if e.is_invalid_input() => Err(ServiceError::Invalid(e)),
        Some(Err(_)) | None => Ok(()),
    }
}
