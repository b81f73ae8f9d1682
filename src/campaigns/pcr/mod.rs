//! The 3-PF campaign: drive the three stages to each planned joint set, wait for them to
//! settle and read the microscope (the [`StagesAndScope`] step over the engine); then
//! identify, optionally execute an accuracy trajectory, and propose the calibrated model.

pub mod plan;

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::campaigns::pcr::plan::PcrCampaignJob;
use crate::lab::{Candidate, CellModel, Evidence};
use crate::run::{Cx, JobError, Produced, Table};

use super::engine::{self, Retry, Step, StepError};
use super::instruments::{ToleranceCheck, identify as identify_instruments};
use super::results::{PcrCampaign, PcrStats};
use crate::procedures::{DeviceError, LinearStages, PoseSensor};
use crate::util::Monitor;

/// One recorded measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PcrRecorded {
    /// Index in the journal.
    pub index: usize,
    /// Commanded joints (m).
    pub q_cmd: [f64; 3],
    /// Joints the stages settled at (m): what the identification uses.
    pub q: [f64; 3],
    /// Microscope reading x (m), y (m), theta (rad).
    pub z: [f64; 3],
}

/// How the campaign moves and waits.
#[derive(Debug, Clone, PartialEq)]
pub struct PcrOptions {
    /// Joint limits the plan must respect (m): the cell's motion envelope.
    pub limits: [[f64; 2]; 3],
    /// Wait after the stages report settled, before the image (vibrations die out).
    pub settle: Duration,
    /// Device-fault retries.
    pub retry: Retry,
}

impl std::fmt::Debug for StagesAndScope<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StagesAndScope").finish_non_exhaustive()
    }
}

/// One joint set as a campaign step: refused outside the envelope (never sent), else
/// move, settle, image.
pub struct StagesAndScope<'a> {
    /// The stages.
    pub stages: &'a dyn LinearStages,
    /// The microscope.
    pub scope: &'a dyn PoseSensor,
    /// Envelope and settling.
    pub options: &'a PcrOptions,
}

impl Step for StagesAndScope<'_> {
    type Plan = [f64; 3];
    type Sample = PcrRecorded;
    const STAGE: &'static str = "measuring";

    fn describe(&self, k: usize, n: usize, _: &[f64; 3]) -> String {
        format!("joint set {k}/{n}")
    }

    async fn measure(
        &self,
        index: usize,
        q: &[f64; 3],
        _monitor: &dyn Monitor,
    ) -> Result<PcrRecorded, StepError> {
        let lim = &self.options.limits;
        if let Some(j) = (0..3).find(|&j| !(q[j] >= lim[j][0] && q[j] <= lim[j][1])) {
            return Err(StepError::Skip(format!(
                "q{} = {} m is outside the envelope [{}, {}] m",
                j + 1,
                q[j],
                lim[j][0],
                lim[j][1]
            )));
        }
        let fault = |e: DeviceError| StepError::Fault(e.to_string());
        let at = self.stages.move_to(q).await.map_err(fault)?;
        if !self.options.settle.is_zero() {
            tokio::time::sleep(self.options.settle).await;
        }
        let z = self.scope.read_pose().await.map_err(fault)?;
        Ok(PcrRecorded {
            index,
            q_cmd: *q,
            q: at,
            z,
        })
    }
}

fn table(rec: &[PcrRecorded]) -> Table {
    let mut t = Table::new(&[
        "index", "q1_cmd", "q2_cmd", "q3_cmd", "q1", "q2", "q3", "x", "y", "theta",
    ]);
    for r in rec {
        let mut row = vec![r.index as f64];
        row.extend(r.q_cmd);
        row.extend(r.q);
        row.extend(r.z);
        t.push(row);
    }
    t
}

/// Run a `cell.pcr_campaign`: Poisson-disc joint sets, identify, optional accuracy,
/// propose.
pub async fn campaign(job: Arc<PcrCampaignJob>, cx: Cx) -> Result<Produced, JobError> {
    let t0 = Instant::now();
    let cell = cx.lab().pcr(&job.cell)?;
    let started_from = match job.start_model() {
        Some(_) => "the model named in the job document".to_string(),
        None => cx.lab().model_source(&job.cell).label(),
    };
    let file = job.start_model().unwrap_or_else(|| cell.current_model());
    let instruments = identify_instruments(&cell.links, Duration::from_secs(2)).await;
    let plan = job.plan(&file)?;
    let n_cal = job.calibration_count(plan.len());
    let opts = PcrOptions {
        limits: file.limits(),
        settle: Duration::from_millis(job.options.settle_ms),
        retry: job.options.retry.retry(),
    };
    let step = StagesAndScope {
        stages: &*cell.stages,
        scope: &*cell.microscope,
        options: &opts,
    };
    let journal = cx.journal();
    let (meas_end, id_end) = if job.accuracy.is_some() {
        (0.6, 0.7)
    } else {
        (0.85, 1.0)
    };
    let t_meas = Instant::now();
    let s = engine::run(
        &step,
        &plan,
        0,
        journal,
        &opts.retry,
        &cx.phase(0.0, meas_end),
    )
    .await?;
    let measuring_s = t_meas.elapsed().as_secs_f64();
    let cal: Vec<PcrRecorded> = engine::recorded(journal, 0, n_cal)?;
    let val: Vec<PcrRecorded> = engine::recorded(journal, n_cal, plan.len() - n_cal)?;
    if cal.len() < 12 {
        return Err(JobError::Failed(format!(
            "only {} of {n_cal} calibration joint sets were measured: too few to identify",
            cal.len()
        )));
    }
    let t_id = Instant::now();
    let identified = {
        let (job, file, cal, val) = (job.clone(), file.clone(), cal.clone(), val.clone());
        cx.phase(meas_end, id_end)
            .compute(move |m| job.identify(&file, &cal, &val, m))
            .await?
    };
    let identify_s = t_id.elapsed().as_secs_f64();
    let mut accuracy = None;
    let mut acc_rec = Vec::new();
    if job.accuracy.is_some() {
        let (control, n) = {
            let (job, model) = (job.clone(), identified.result.calibrated_model.clone());
            cx.compute(move |m| job.accuracy_plan(&model, m)).await?
        };
        let offset = plan.len();
        engine::run(
            &step,
            &control,
            offset,
            journal,
            &opts.retry,
            &cx.phase(id_end, 0.95),
        )
        .await?;
        acc_rec = engine::recorded(journal, offset, control.len())?;
        if acc_rec.len() != control.len() {
            return Err(JobError::Failed(format!(
                "{} of {} accuracy poses were measured (see the journal)",
                acc_rec.len(),
                control.len()
            )));
        }
        let model = identified.result.calibrated_model.clone();
        let (job, rec) = (job.clone(), acc_rec.clone());
        accuracy = cx
            .phase(0.95, 1.0)
            .compute(move |m| job.accuracy(&model, &rec, n, m))
            .await?
            .map(|run| run.result);
    }
    let all: Vec<PcrRecorded> = cal.iter().chain(&val).cloned().collect();
    let measurements = table(&all);
    let candidate = Candidate {
        cell: job.cell.clone(),
        model: CellModel::Pcr(identified.result.calibrated_model.clone()),
        evidence: identified.result.validation.as_ref().map(|v| Evidence {
            what: "validation mean position error".into(),
            before: v.before.mean,
            after: v.after.mean,
            unit: "m",
        }),
        validation: serde_json::to_value(&identified.result.validation).unwrap_or_default(),
        assessment: Some(identified.result.assessment.clone()),
    };
    let tolerance = job.options.tolerance_um.map(|t| {
        let max_um = identified
            .result
            .validation
            .as_ref()
            .map(|v| v.after.max * 1e6);
        ToleranceCheck::of(
            t,
            max_um,
            "um",
            "largest held-out position error after calibration",
        )
    });
    let result = PcrCampaign {
        instruments,
        tolerance,
        calibration: identified.result,
        accuracy,
        cell: job.cell.clone(),
        started_from,
        campaign: PcrStats {
            planned: plan.len(),
            calibration: cal.len(),
            validation: val.len(),
            recorded: s.recorded,
            skipped: s.skipped,
            accuracy_measurements: acc_rec.len(),
            seed: job.seed,
            measuring_s,
            identify_s,
            wall_time_s: t0.elapsed().as_secs_f64(),
            journal_entries: journal.entries().map(|e| e.len()).unwrap_or(0),
        },
        measurements: measurements.clone(),
    };
    engine::conclude(
        &result,
        identified.artefacts,
        measurements,
        (!acc_rec.is_empty()).then(|| ("accuracy_measurements.csv", table(&acc_rec))),
        candidate,
    )
}

#[cfg(test)]
mod tests;
