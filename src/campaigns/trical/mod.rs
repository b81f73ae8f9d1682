//! The TriCal campaign: centre the device on a ball in each planned configuration and
//! journal the joints before the next move (the [`Centring`] step over the engine); then
//! identify on what was recorded and, with a validation pass, propose the calibrated model
//! to the cell.

pub mod plan;

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::engine::{self, CampaignError, Retry, Step, StepError, Summary};
use super::instruments::{ToleranceCheck, identify as identify_instruments};
use super::results::{TricalCampaign, TricalStats};
use crate::campaigns::trical::plan::CampaignJob;
use crate::lab::{Candidate, CellModel, Evidence};
use crate::procedures::centring::{CentringError, CentringOptions, centre};
use crate::procedures::{DeviceError, Indicators, Journal, Robot};
use crate::run::{Cx, JobError, Produced, Table};
use crate::util::Monitor;

/// One planned configuration: where to start and which ball (0-based) it aims at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Planned {
    /// Start joint values (rad).
    pub q: Vec<f64>,
    /// Ball index (0-based).
    pub ball: usize,
}

/// One recorded measurement (the journal's format).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Recorded {
    /// Index in the journal.
    pub index: usize,
    /// Ball (0-based).
    pub ball: usize,
    /// Joint values at the end of centring (rad).
    pub q: Vec<f64>,
    /// Final |r| (mm).
    pub residual_mm: f64,
    /// Corrective moves.
    pub iterations: usize,
}

impl std::fmt::Debug for Centring<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Centring").finish_non_exhaustive()
    }
}

/// The centring loop as a campaign step.
pub struct Centring<'a> {
    /// The arm.
    pub robot: &'a dyn Robot,
    /// The centring device.
    pub indicators: &'a dyn Indicators,
    /// Loop bounds.
    pub options: &'a CentringOptions,
}

/// Whether a centring error is a device fault (retried, then a pause) rather than a
/// property of the configuration (skipped).
pub(crate) fn is_device_fault(e: &CentringError) -> bool {
    matches!(
        e,
        CentringError::Device(
            DeviceError::Timeout { .. }
                | DeviceError::Disconnected { .. }
                | DeviceError::Protocol { .. }
                | DeviceError::Fault { .. }
        ) | CentringError::ReadingTimeout { .. }
            | CentringError::NotSettled { .. }
    )
}

impl Step for Centring<'_> {
    type Plan = Planned;
    type Sample = Recorded;
    const STAGE: &'static str = "centring";

    fn describe(&self, k: usize, n: usize, p: &Planned) -> String {
        format!("configuration {k}/{n} (ball {})", p.ball + 1)
    }

    async fn measure(
        &self,
        index: usize,
        p: &Planned,
        monitor: &dyn Monitor,
    ) -> Result<Recorded, StepError> {
        match centre(self.robot, self.indicators, &p.q, self.options, monitor).await {
            Ok(c) => Ok(Recorded {
                index,
                ball: p.ball,
                q: c.q,
                residual_mm: c.residual_mm,
                iterations: c.iterations,
            }),
            Err(CentringError::Cancelled) => Err(StepError::Cancelled),
            Err(e) if is_device_fault(&e) => Err(StepError::Fault(e.to_string())),
            Err(e) => Err(StepError::Skip(e.to_string())),
        }
    }
}

/// Centre every configuration of `plan` not yet in the journal (plan entry `k` is journal
/// index `offset + k`).
#[allow(clippy::too_many_arguments)]
pub async fn run(
    robot: &dyn Robot,
    indicators: &dyn Indicators,
    plan: &[Planned],
    offset: usize,
    journal: &dyn Journal,
    options: &CentringOptions,
    retry: &Retry,
    monitor: &dyn Monitor,
) -> Result<Summary, CampaignError> {
    let step = Centring {
        robot,
        indicators,
        options,
    };
    engine::run(&step, plan, offset, journal, retry, monitor).await
}

fn recorded_table(rec: &[Recorded]) -> Table {
    let mut t = Table::new(&[
        "index",
        "ball",
        "q1",
        "q2",
        "q3",
        "q4",
        "q5",
        "q6",
        "residual_mm",
        "moves",
    ]);
    for r in rec {
        let mut row = vec![r.index as f64, (r.ball + 1) as f64];
        row.extend(r.q.iter().map(|v| v.to_degrees()));
        row.extend([r.residual_mm, r.iterations as f64]);
        t.push(row);
    }
    t
}

/// Run a `cell.trical_campaign`: plan, centre, identify, propose.
pub async fn campaign(job: Arc<CampaignJob>, cx: Cx) -> Result<Produced, JobError> {
    let t0 = Instant::now();
    let cell = cx.lab().trical(&job.cell)?;
    let file = job.model.clone().unwrap_or_else(|| cell.current_model());
    let started_from = match &job.model {
        Some(_) => "the model named in the job document".to_string(),
        None => cx.lab().model_source(&job.cell).label(),
    };
    let copts = job.options.centring.options("options.centring", cell)?;
    let retry = job.options.retry.retry();
    let (plan, vplan) = {
        let (job, file, ballbar) = (job.clone(), file.clone(), cell.ballbar);
        let envelope = cell.envelope.clone();
        cx.phase(0.0, 0.02)
            .compute(move |m| job.plan(&file, ballbar, &envelope, m))
            .await?
    };
    // The whole plan against the envelope before the first move (from where the robot
    // stands on a fresh start; a resumed campaign continues from a measured configuration).
    let fresh = cx
        .journal()
        .entries()
        .map(|e| e.is_empty())
        .unwrap_or(false);
    let start = if fresh {
        cell.robot.joints().await.ok()
    } else {
        None
    };
    if let Some(refused) = job
        .preflight_on(cell, &plan, &vplan, start.as_deref())?
        .refusal()
    {
        return Err(refused);
    }
    let instruments = identify_instruments(&cell.links, Duration::from_secs(2)).await;
    let total = (plan.len() + vplan.len()).max(1) as f64;
    let split = 0.02 + 0.9 * plan.len() as f64 / total;
    let journal = cx.journal();
    let t_meas = Instant::now();
    let step = Centring {
        robot: &*cell.robot,
        indicators: &*cell.indicators,
        options: &copts,
    };
    let s1 = engine::run(&step, &plan, 0, journal, &retry, &cx.phase(0.02, split)).await?;
    let s2 = engine::run(
        &step,
        &vplan,
        plan.len(),
        journal,
        &retry,
        &cx.phase(split, 0.92),
    )
    .await?;
    let measuring_s = t_meas.elapsed().as_secs_f64();
    let rec: Vec<Recorded> = engine::recorded(journal, 0, plan.len())?;
    let vrec: Vec<Recorded> = engine::recorded(journal, plan.len(), vplan.len())?;
    if rec.len() < 10 {
        return Err(JobError::Failed(format!(
            "only {} of {} configurations were centred: too few to identify ({} skipped; see the journal)",
            rec.len(),
            plan.len(),
            s1.skipped
        )));
    }
    let t_id = Instant::now();
    let run = {
        let (job, file, ballbar) = (job.clone(), file.clone(), cell.ballbar);
        let (rec, vrec) = (rec.clone(), vrec.clone());
        cx.phase(0.92, 1.0)
            .compute(move |m| job.identify(&file, ballbar, &rec, &vrec, m))
            .await?
    };
    let identify_s = t_id.elapsed().as_secs_f64();
    let measurements = recorded_table(&rec);
    let stats = TricalStats {
        planned: plan.len(),
        recorded: s1.recorded,
        skipped: s1.skipped,
        validation_planned: vplan.len(),
        validation_recorded: s2.recorded,
        validation_skipped: s2.skipped,
        mean_moves: rec.iter().map(|r| r.iterations as f64).sum::<f64>() / rec.len() as f64,
        max_residual_mm: rec.iter().map(|r| r.residual_mm).fold(0.0, f64::max),
        measuring_s,
        identify_s,
        wall_time_s: t0.elapsed().as_secs_f64(),
        journal_entries: journal.entries().map(|e| e.len()).unwrap_or(0),
    };
    let model = run.result.calibrated_model.dh().cloned().ok_or_else(|| {
        JobError::internal(
            "the identification of a DH cell",
            "it returned a URDF model",
        )
    })?;
    let candidate = Candidate {
        cell: job.cell.clone(),
        model: CellModel::Serial(model),
        evidence: run.result.validation.as_ref().map(|v| Evidence {
            what: "validation mean error".into(),
            before: v.before.mean,
            after: v.after.mean,
            unit: "mm",
        }),
        validation: serde_json::to_value(&run.result.validation).unwrap_or_default(),
        assessment: Some(run.result.assessment.clone()),
    };
    let tolerance = job.options.tolerance_mm.map(|t| {
        let max = run.result.validation.as_ref().map(|v| v.after.max);
        ToleranceCheck::new(t, max, "mm")
    });
    let result = TricalCampaign {
        calibration: run.result,
        cell: job.cell.clone(),
        started_from,
        campaign: stats,
        tolerance,
        instruments,
        start_model: file,
        measurements: measurements.clone(),
    };
    engine::conclude(
        &result,
        run.artefacts,
        measurements,
        (!vrec.is_empty()).then(|| ("validation_measurements.csv", recorded_table(&vrec))),
        candidate,
    )
}

#[cfg(test)]
mod tests;
