//! The service's side of the lab: which stored jobs are resumable campaigns, resuming a
//! paused or interrupted campaign, and each cell's model history: a campaign's calibrated
//! model becomes its cell's current model only if the cell's acceptance rule says its
//! validation improved on the starting model; otherwise it is kept as a rejected candidate.
//! The decision is stored in the transaction that stores the result.

use serde_json::{Value, json};

use super::{Entry, Event, Service, ServiceError, StoreResolver, blocking, lock};
use crate::lab::{Decision, ModelSource};
use crate::store::{CellModel, JobState, Store};

/// Whether stored job `id` is a campaign that can continue from its journal.
pub(super) async fn resumable(store: &Store, id: i64) -> bool {
    super::storage::call(store, move |st| {
        Ok(st
            .job_doc(id)
            .ok()
            .flatten()
            .and_then(|d| crate::jobs::prepare(&d, &StoreResolver(st.clone())).ok())
            .is_some_and(|j| j.resumable()))
    })
    .await
    .unwrap_or(false)
}

/// Give each cell of the lab its current model from the store.
pub(super) async fn load_current_models(svc: &Service) {
    for cell in svc.shared.lab.cells() {
        let name = cell.name().to_string();
        let history =
            super::storage::call(&svc.shared.store, move |st| st.cell_models(&name)).await;
        let Ok(history) = history else {
            continue;
        };
        let Some(m) = history.iter().find(|m| m.state == "current") else {
            continue;
        };
        match cell.parse_model(&m.model).and_then(|f| cell.set_model(f)) {
            Ok(()) => {
                svc.shared
                    .lab
                    .set_model_source(cell.name(), source_of(&history));
                tracing::info!(cell = cell.name(), model = m.id, "current model loaded")
            }
            Err(e) => {
                tracing::error!(cell = cell.name(), error = %e, "stored current model unreadable; using the nominal model")
            }
        }
    }
}

/// Where the current model of a cell with model history `history` (newest first) comes
/// from: the accepted calibration marked current, numbered among the accepted ones.
pub(super) fn source_of(history: &[CellModel]) -> ModelSource {
    let accepted = |m: &&CellModel| matches!(m.state.as_str(), "current" | "superseded");
    match history.iter().find(|m| m.state == "current") {
        Some(c) => ModelSource::Calibration {
            number: history
                .iter()
                .filter(accepted)
                .filter(|m| m.id <= c.id)
                .count(),
            job_id: c.job_id,
            at: c.at.clone(),
        },
        None => ModelSource::Nominal,
    }
}

/// Before a campaign's decision is stored with its result: an accepted model becomes the
/// cell's current model in memory; the model it replaced, to restore if the store fails.
pub(super) fn apply(svc: &Service, id: i64, d: &Decision) -> Option<crate::lab::CellModel> {
    if !d.accepted {
        return None;
    }
    let cell = svc.shared.lab.cell(&d.cell)?;
    let previous = cell.current_model();
    match cell.parse_model(&d.model).and_then(|m| cell.set_model(m)) {
        Ok(()) => Some(previous),
        Err(e) => {
            tracing::error!(job = id, cell = %d.cell, error = %e, "the accepted model could not be applied");
            None
        }
    }
}

/// The store did not take the result: the cell goes back to the model it had.
pub(super) fn restore(svc: &Service, cell: &str, previous: crate::lab::CellModel) {
    if let Some(c) = svc.shared.lab.cell(cell)
        && let Err(e) = c.set_model(previous)
    {
        tracing::error!(cell, error = %e, "the previous model could not be restored");
    }
}

/// After a campaign's decision is stored with its result: log it, and an accepted model's
/// source becomes the stored calibration (its number in the cell's history).
pub(super) async fn adopt(svc: &Service, id: i64, d: &Decision) {
    tracing::info!(job = id, cell = %d.cell, accepted = d.accepted, reason = %d.reason, "campaign model decision");
    if !d.accepted || svc.shared.lab.cell(&d.cell).is_none() {
        return;
    }
    let name = d.cell.clone();
    match super::storage::call(&svc.shared.store, move |st| st.cell_models(&name)).await {
        Ok(history) => svc
            .shared
            .lab
            .set_model_source(&d.cell, source_of(&history)),
        Err(e) => {
            tracing::error!(job = id, cell = %d.cell, error = %e, "the cell's model history could not be read")
        }
    }
}

impl Service {
    /// The lab (empty if the daemon drives none).
    pub fn lab(&self) -> &crate::lab::Lab {
        &self.shared.lab
    }

    /// Resume a paused or interrupted campaign: it is queued again and continues from the
    /// first configuration its journal does not hold.
    pub async fn resume(&self, id: i64) -> Result<JobState, ServiceError> {
        self.resume_as(id, "resumed by the operator").await
    }

    /// [`Service::resume`], logging `why` (who resumed it and on what grounds).
    pub(super) async fn resume_as(&self, id: i64, why: &str) -> Result<JobState, ServiceError> {
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
        let why = why.to_string();
        let ok = blocking(move || Ok(st.resume_job(id, &why)?)).await?;
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

    /// The lab's cells: kind, devices, current model and model history.
    pub async fn cells(&self) -> Result<Vec<Value>, ServiceError> {
        let mut out = Vec::new();
        for cell in self.shared.lab.cells() {
            let st = self.shared.store.clone();
            let name = cell.name().to_string();
            let history: Vec<CellModel> = blocking(move || Ok(st.cell_models(&name)?)).await?;
            let current = history.iter().find(|m| m.state == "current").map(|m| m.id);
            let rule = crate::lab::acceptance(cell);
            out.push(json!({
                "name": cell.name(),
                "kind": cell.kind(),
                "devices": cell.devices(),
                "current_model": current,
                "current_model_is_nominal": current.is_none(),
                "acceptance": {
                    "min_relative_gain": rule.min_relative_gain,
                    "min_gain": rule.min_gain,
                    "unit": rule.unit,
                },
                "models": history,
            }));
        }
        Ok(out)
    }
}
