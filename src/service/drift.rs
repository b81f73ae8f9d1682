//! Drift watch: each cell's history of verifications (`cell.verify`: AP and RP through the
//! compensated and the nominal model) against its last calibration; and, after a
//! verification with a `drift` policy, the policy applied: the recalibration submitted or
//! "within tolerance" recorded (in the schedule's runs when a schedule submitted it), a
//! `drift` event published and counted in `calibd_drift_decisions_total`.

use serde::Serialize;
use serde_json::Value;

use super::{DriftEvent, Event, Origin, Service, ServiceError, Submitter, blocking};
use crate::campaigns::verify::drift::DriftPolicy;
use crate::report::drift::{DriftSample, drift_chart};
use crate::store::{JobFilter, JobState};

/// Most verifications a history reads.
const MAX_POINTS: usize = 1000;

/// One verification of a cell.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriftPoint {
    /// The `cell.verify` job.
    pub job: i64,
    /// When it finished (RFC 3339).
    pub at: String,
    /// Mean AP through the compensated model (mm).
    pub ap_mm: Option<f64>,
    /// Largest RP through the compensated model (mm).
    pub rp_mm: Option<f64>,
    /// Mean AP through the nominal model (mm).
    pub nominal_ap_mm: Option<f64>,
}

/// A cell's verifications, oldest first, and its last calibration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriftHistory {
    /// The cell.
    pub cell: String,
    /// When the current model was adopted (absent: the nominal model is current).
    pub last_calibration: Option<String>,
    /// The campaign that produced it.
    pub last_calibration_job: Option<i64>,
    /// The AP threshold of the latest verification's drift policy (mm).
    pub threshold_mm: Option<f64>,
    /// Verifications, oldest first.
    pub points: Vec<DriftPoint>,
}

impl DriftHistory {
    /// The chart: AP and RP per verification, the threshold, the last calibration.
    pub fn chart(&self) -> String {
        let since = self.last_calibration.as_deref();
        let mut marked = false;
        let samples: Vec<DriftSample> = self
            .points
            .iter()
            .map(|p| {
                let after = !marked && since.is_some_and(|c| p.at.as_str() > c);
                marked |= after;
                DriftSample {
                    label: p.at.get(5..10).unwrap_or(&p.at).to_string(),
                    ap_mm: p.ap_mm,
                    rp_mm: p.rp_mm,
                    after_calibration: after,
                }
            })
            .collect();
        drift_chart(&self.cell, &samples, self.threshold_mm)
    }

    /// The baseline for job `id`: the first verification since the last calibration that
    /// precedes it.
    pub fn baseline(&self, id: i64) -> Option<f64> {
        let since = self.last_calibration.as_deref().unwrap_or("");
        self.points
            .iter()
            .find(|p| p.job < id && p.at.as_str() > since && p.ap_mm.is_some())
            .and_then(|p| p.ap_mm)
    }
}

fn num(v: &Value, a: &str, b: &str) -> Option<f64> {
    v.get(a).and_then(|x| x.get(b)).and_then(Value::as_f64)
}

impl Service {
    /// The verifications of `cell` (succeeded `cell.verify` jobs), oldest first.
    pub async fn drift_history(&self, cell: &str) -> Result<DriftHistory, ServiceError> {
        let st = self.shared.store.clone();
        let cell = cell.to_string();
        blocking(move || {
            let jobs = st.jobs(&JobFilter {
                state: Some(JobState::Succeeded),
                kind: Some("cell.verify".into()),
                before: None,
                limit: MAX_POINTS,
            })?;
            let mut points = Vec::new();
            for j in jobs {
                let Some(r) = st.result(j.id)? else { continue };
                if r.get("cell").and_then(Value::as_str) != Some(cell.as_str()) {
                    continue;
                }
                points.push(DriftPoint {
                    job: j.id,
                    at: j.finished_at.unwrap_or(j.submitted_at),
                    ap_mm: num(&r, "compensated", "ap_mean_mm"),
                    rp_mm: num(&r, "compensated", "rp_max_mm"),
                    nominal_ap_mm: num(&r, "nominal", "ap_mean_mm"),
                });
            }
            points.sort_by_key(|p| p.job);
            let threshold_mm = match points.last() {
                Some(p) => st
                    .job_doc(p.job)?
                    .and_then(|d| num(&d, "drift", "ap_threshold_mm")),
                None => None,
            };
            let models = st.cell_models(&cell)?;
            let current = models.iter().find(|m| m.state == "current");
            Ok(DriftHistory {
                last_calibration: current.map(|m| m.at.clone()),
                last_calibration_job: current.and_then(|m| m.job_id),
                cell,
                threshold_mm,
                points,
            })
        })
        .await
    }
}

/// Apply the drift policy of succeeded `cell.verify` job `id`, if it has one.
pub(super) async fn after_verify(svc: &Service, id: i64) {
    if let Err(e) = apply(svc, id).await {
        tracing::error!(job = id, error = %e, "the drift policy could not be applied");
    }
}

async fn apply(svc: &Service, id: i64) -> Result<(), ServiceError> {
    let st = svc.shared.store.clone();
    let (doc, result) = blocking(move || Ok((st.job_doc(id)?, st.result(id)?))).await?;
    let Some(policy) = doc.as_ref().and_then(|d| d.get("drift")) else {
        tracing::info!(job = id, "verification without a drift policy");
        return Ok(());
    };
    let policy: DriftPolicy = serde_json::from_value(policy.clone())
        .map_err(|e| ServiceError::Internal(format!("drift policy: {e}")))?;
    let result = result.unwrap_or_default();
    let cell = result
        .get("cell")
        .and_then(Value::as_str)
        .unwrap_or_default()
        .to_string();
    let Some(ap) = num(&result, "compensated", "ap_mean_mm") else {
        return Err(ServiceError::Internal(
            "the verification has no compensated AP (every reading out of range?)".into(),
        ));
    };
    let baseline = svc.drift_history(&cell).await?.baseline(id);
    let d = policy.decide(ap, baseline);
    metrics::gauge!("calibd_cell_ap_mm", "cell" => cell.clone()).set(ap);
    metrics::counter!("calibd_drift_decisions_total", "cell" => cell.clone(), "action" => d.action)
        .increment(1);
    let rec = svc.job(id).await?;
    let mut recalibration = None;
    let mut message = d.reason.clone();
    if d.action == "recalibrate" {
        let who = Submitter {
            name: Some(format!("drift:{cell}")),
            // The verification drove the cell's devices: its submitter may.
            may_drive_devices: true,
        };
        match svc
            .submit(
                policy.recalibrate.clone(),
                rec.priority,
                who,
                Origin::default(),
            )
            .await
        {
            Ok(j) => {
                recalibration = Some(j);
                message = format!("{message}; recalibration job {j} submitted");
            }
            Err(e) => message = format!("{message}; the recalibration was refused: {e}"),
        }
    }
    tracing::info!(job = id, cell = %cell, action = d.action, ?recalibration, "{message}");
    svc.publish(Event::Drift(DriftEvent {
        id,
        cell,
        action: d.action.into(),
        ap_mm: ap,
        recalibration,
        reason: message.clone(),
    }));
    if let Some(s) = rec.schedule_id {
        let outcome = match (d.action, recalibration) {
            ("recalibrate", Some(_)) => "recalibration_submitted",
            ("recalibrate", None) => "recalibration_refused",
            _ => "within_tolerance",
        };
        // The occurrence that submitted this verification.
        let due = svc
            .schedule_runs(s, 50)
            .await?
            .into_iter()
            .find(|r| r.job_id == Some(id))
            .map_or(rec.submitted_at.clone(), |r| r.due_at);
        svc.record_schedule_run(s, due, outcome, Some(message))
            .await?;
    }
    Ok(())
}
