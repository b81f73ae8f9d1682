//! The service's side of the lab: which stored jobs are resumable campaigns, resuming a
//! paused or interrupted campaign, and each cell's model history: a TriCal campaign's
//! calibrated model becomes the cell's current model only if its validation improved on
//! the model the campaign started from; otherwise it is kept as a rejected candidate.

use serde_json::{Value, json};

use super::{Entry, Event, Service, ServiceError, StoreResolver, blocking, lock};
use crate::model::dh::DhFile;
use crate::store::{CellModel, JobState, Store};

/// Whether stored job `id` is a campaign that can continue from its journal.
pub(super) async fn resumable(store: &Store, id: i64) -> bool {
    let st = store.clone();
    tokio::task::spawn_blocking(move || {
        st.job_doc(id)
            .ok()
            .flatten()
            .and_then(|d| crate::jobs::prepare(&d, &StoreResolver(st.clone())).ok())
            .is_some_and(|j| j.resumable())
    })
    .await
    .unwrap_or(false)
}

/// Give each cell of the lab its current model from the store.
pub(super) async fn load_current_models(svc: &Service) {
    let Some(cell) = svc.shared.lab.as_ref().and_then(|l| l.trical.as_ref()) else {
        return;
    };
    let st = svc.shared.store.clone();
    let name = cell.name.clone();
    let current = tokio::task::spawn_blocking(move || st.current_cell_model(&name)).await;
    if let Ok(Ok(Some(m))) = current {
        match serde_json::from_value::<DhFile>(m.model.clone()) {
            Ok(f) => {
                tracing::info!(cell = %cell.name, model = m.id, "current model loaded");
                cell.set_model(f);
            }
            Err(e) => {
                tracing::error!(cell = %cell.name, error = %e, "stored current model unreadable; using the nominal model")
            }
        }
    }
}

/// Smallest gain of the mean validation error (mm) that replaces a model: below it (and
/// below 10 %) a difference is indistinguishable from the centring noise (tolerance 0.010 mm).
pub(crate) const MIN_GAIN_MM: f64 = 0.002;

/// The mean validation error (mm) before and after of a campaign result.
fn validation_means(result: &Value) -> Option<(f64, f64)> {
    let v = result.get("validation")?;
    Some((
        v.get("before")?.get("mean")?.as_f64()?,
        v.get("after")?.get("mean")?.as_f64()?,
    ))
}

/// After a successful campaign: accept its calibrated model as the cell's current model if
/// validation improved, else record it as a rejected candidate with the reason.
pub(super) async fn after_success(svc: &Service, id: i64, kind: &str, result: &Value) {
    if kind != "cell.trical_campaign" {
        return;
    }
    let Some(cell_name) = result
        .get("cell")
        .and_then(Value::as_str)
        .map(str::to_string)
    else {
        return;
    };
    let model = result
        .get("calibrated_model")
        .cloned()
        .unwrap_or(Value::Null);
    let validation = result.get("validation").cloned().unwrap_or(Value::Null);
    let (accepted, reason) = match validation_means(result) {
        Some((before, after)) if before - after > (0.1 * before).max(MIN_GAIN_MM) => (
            true,
            format!(
                "validation mean error improved from {before:.4} mm (starting model) to {after:.4} mm"
            ),
        ),
        Some((before, after)) => (
            false,
            format!(
                "validation did not improve enough: mean error {after:.4} mm against {before:.4} mm for the starting model (a candidate must gain more than 10 % and {MIN_GAIN_MM} mm)"
            ),
        ),
        None => (
            false,
            "the campaign had no validation pass: nothing shows the model is better".into(),
        ),
    };
    let parsed = serde_json::from_value::<DhFile>(model.clone());
    let (accepted, reason) = match (&parsed, accepted) {
        (Err(e), true) => (
            false,
            format!("the calibrated model could not be read back: {e}"),
        ),
        _ => (accepted, reason),
    };
    let st = svc.shared.store.clone();
    let (c, r, v, m) = (
        cell_name.clone(),
        reason.clone(),
        validation.clone(),
        model.clone(),
    );
    let stored = tokio::task::spawn_blocking(move || {
        st.record_cell_model(&c, Some(id), accepted, &r, &v, &m)?;
        st.log(
            Some(id),
            "info",
            &format!(
                "cell {c}: model {}: {r}",
                if accepted { "accepted" } else { "rejected" }
            ),
        )
    })
    .await;
    if !matches!(stored, Ok(Ok(()))) {
        tracing::error!(job = id, "recording the cell model failed");
        return;
    }
    tracing::info!(job = id, cell = %cell_name, accepted, reason = %reason, "campaign model decision");
    if accepted {
        if let (Ok(f), Some(cell)) = (
            parsed,
            svc.shared.lab.as_ref().and_then(|l| l.trical.as_ref()),
        ) {
            if cell.name == cell_name {
                cell.set_model(f);
            }
        }
    }
}

impl Service {
    /// The lab, if the daemon drives one.
    pub fn lab(&self) -> Option<&crate::lab::Lab> {
        self.shared.lab.as_deref()
    }

    /// Resume a paused or interrupted campaign: it is queued again and continues from the
    /// first configuration its journal does not hold.
    pub async fn resume(&self, id: i64) -> Result<JobState, ServiceError> {
        let rec = self.job(id).await?;
        if !matches!(rec.state, JobState::Paused | JobState::Interrupted) {
            return Err(ServiceError::Conflict(format!(
                "job {id} is {}: only a paused or interrupted campaign can be resumed",
                rec.state.as_str()
            )));
        }
        if !resumable(&self.shared.store, id).await {
            return Err(ServiceError::Conflict(format!(
                "job {id} (`{}`) is not a campaign with a measurement journal; re-run it instead",
                rec.kind
            )));
        }
        let st = self.shared.store.clone();
        let ok = blocking(move || Ok(st.resume_job(id, "resumed by the operator")?)).await?;
        if !ok {
            return Err(ServiceError::Conflict(format!(
                "job {id} changed state; try again"
            )));
        }
        lock(&self.shared.queue).push(Entry {
            id,
            priority: rec.priority,
            devices: rec.devices.clone(),
            job: None,
        });
        self.update_gauges();
        self.publish(Event::State {
            id,
            kind: rec.kind,
            state: JobState::Queued,
            error: None,
        });
        self.shared.wake.notify_one();
        Ok(JobState::Queued)
    }

    /// The measurement journal of a job (empty for jobs that measure nothing).
    pub async fn measurements(&self, id: i64) -> Result<Value, ServiceError> {
        self.job(id).await?;
        let st = self.shared.store.clone();
        let entries = blocking(move || Ok(st.measurements(id)?)).await?;
        Ok(json!({"job": id, "count": entries.len(), "entries": entries}))
    }

    /// The lab's cells: devices, current model and model history.
    pub async fn cells(&self) -> Result<Vec<Value>, ServiceError> {
        let Some(cell) = self.shared.lab.as_ref().and_then(|l| l.trical.as_ref()) else {
            return Ok(Vec::new());
        };
        let st = self.shared.store.clone();
        let name = cell.name.clone();
        let history: Vec<CellModel> = blocking(move || Ok(st.cell_models(&name)?)).await?;
        let current = history.iter().find(|m| m.state == "current").map(|m| m.id);
        Ok(vec![json!({
            "name": cell.name,
            "kind": "ball_centring",
            "devices": cell.devices,
            "current_model": current,
            "current_model_is_nominal": current.is_none(),
            "models": history,
        })])
    }
}
