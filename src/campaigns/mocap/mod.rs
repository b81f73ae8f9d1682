//! The motion-capture posture campaign: move the robot to each planned posture, wait, record
//! the marker stream for a window, pre-process it (zero-phase low-pass, stable samples:
//! [`crate::measure::mocap::preprocess`]) and journal the posture's averaged marker positions
//! before the next move. Resume skips journalled postures; device faults are retried with
//! doubling back-off, then the campaign pauses with the reason.

pub mod plan;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::engine::{self, CampaignError, Retry, Step, StepError, Summary};
use super::instruments::{ToleranceCheck, identify as identify_instruments};
use super::results::{MeanErrors, MocapCampaign, MocapStats};
use crate::campaigns::mocap::plan::{MocapCampaignJob, samples_table};
use crate::lab::{Candidate, CellModel, Evidence};
use crate::measure::mocap::{MocapOptions, average_stable};
use crate::procedures::{DeviceError, JointRobot, Journal, MarkerFrames, MarkerStream};
use crate::run::{Cx, JobError, Produced};
use crate::util::Monitor;

/// How each posture is measured.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordOptions {
    /// Wait after the move before recording.
    pub settle: Duration,
    /// Length of the recording window.
    pub window: Duration,
    /// Pre-processing of the window (filter, stable samples).
    pub preprocess: MocapOptions,
}

/// One journalled posture: the joints read after the move and each marker's position
/// averaged over the window's stable samples.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PostureSample {
    /// Index in the plan.
    pub index: usize,
    /// Joint values read from the robot (rad), in the plan's joint order.
    pub q: Vec<f64>,
    /// Averaged position per marker label (m); `null` when it had no stable sample.
    pub markers: BTreeMap<String, Option<[f64; 3]>>,
    /// Frames recorded in the window.
    pub frames: usize,
    /// Stable samples averaged (per marker, at most).
    pub stable: usize,
}

/// Why a window gave no measurement.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PostureError {
    /// A device call failed.
    #[error(transparent)]
    Device(#[from] DeviceError),
    /// The window had no stable posture (the robot still moving, or too short a window).
    #[error("no stable samples in the recording window: {0}")]
    Unstable(String),
}

/// Average the stable samples of one recording window (see
/// [`crate::measure::mocap::average_stable`]).
pub fn reduce(
    rec: &MarkerFrames,
    opts: &MocapOptions,
) -> Result<(BTreeMap<String, Option<[f64; 3]>>, usize), PostureError> {
    average_stable(&rec.labels, &rec.t_s, &rec.frames, opts).map_err(PostureError::Unstable)
}

async fn measure(
    robot: &dyn JointRobot,
    stream: &dyn MarkerStream,
    index: usize,
    posture: &[(String, f64)],
    opts: &RecordOptions,
) -> Result<PostureSample, PostureError> {
    robot.move_to(posture).await?;
    tokio::time::sleep(opts.settle).await;
    let names = robot.joint_names();
    let all = robot.joints().await?;
    let q = posture
        .iter()
        .map(|(n, _)| {
            names
                .iter()
                .position(|x| x == n)
                .and_then(|k| all.get(k).copied())
                .ok_or_else(|| {
                    PostureError::Device(DeviceError::Protocol {
                        device: "robot".into(),
                        message: format!("no reading of joint `{n}`"),
                    })
                })
        })
        .collect::<Result<Vec<f64>, _>>()?;
    let rec = stream.record(opts.window).await?;
    let (markers, stable) = reduce(&rec, &opts.preprocess)?;
    Ok(PostureSample {
        index,
        q,
        markers,
        frames: rec.t_s.len(),
        stable,
    })
}

impl std::fmt::Debug for Posture<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Posture").finish_non_exhaustive()
    }
}

/// One posture as a campaign step: refused postures are skipped, other failures retried.
pub struct Posture<'a> {
    /// The robot.
    pub robot: &'a dyn JointRobot,
    /// The capture system.
    pub stream: &'a dyn MarkerStream,
    /// Settling, window, pre-processing.
    pub options: &'a RecordOptions,
}

impl Step for Posture<'_> {
    type Plan = Vec<(String, f64)>;
    type Sample = PostureSample;
    const STAGE: &'static str = "postures";

    fn describe(&self, k: usize, n: usize, _: &Vec<(String, f64)>) -> String {
        format!("posture {k}/{n}")
    }

    async fn measure(
        &self,
        index: usize,
        posture: &Vec<(String, f64)>,
        _monitor: &dyn Monitor,
    ) -> Result<PostureSample, StepError> {
        match measure(self.robot, self.stream, index, posture, self.options).await {
            Ok(s) => Ok(s),
            Err(PostureError::Device(DeviceError::Refused { reason, .. })) => {
                Err(StepError::Skip(reason))
            }
            Err(e) => Err(StepError::Fault(e.to_string())),
        }
    }
}

/// Measure every posture of `plan` (named joint values, rad) not yet in the journal.
pub async fn run(
    robot: &dyn JointRobot,
    stream: &dyn MarkerStream,
    plan: &[Vec<(String, f64)>],
    journal: &dyn Journal,
    opts: &RecordOptions,
    retry: &Retry,
    monitor: &dyn Monitor,
) -> Result<Summary, CampaignError> {
    let step = Posture {
        robot,
        stream,
        options: opts,
    };
    engine::run(&step, plan, 0, journal, retry, monitor).await
}

/// Run a `cell.mocap_campaign`: postures, record, identify, propose.
pub async fn campaign(job: Arc<MocapCampaignJob>, cx: Cx) -> Result<Produced, JobError> {
    let t0 = Instant::now();
    let cell = cx.lab().mocap(&job.cell)?;
    let started_from = cx.lab().model_source(&job.cell).label();
    let setup = Arc::new(job.setup(cell));
    let instruments = identify_instruments(&cell.links, Duration::from_secs(2)).await;
    let plan = {
        let (job, setup) = (job.clone(), setup.clone());
        cx.phase(0.0, 0.05)
            .compute(move |m| job.plan(&setup, m))
            .await?
    };
    let design_s = t0.elapsed().as_secs_f64();
    let journal = cx.journal();
    let options = job.record_options();
    let step = Posture {
        robot: &*cell.robot,
        stream: &*cell.stream,
        options: &options,
    };
    let t_meas = Instant::now();
    let sum = engine::run(&step, &plan, 0, journal, &job.retry(), &cx.phase(0.05, 0.9)).await?;
    let measuring_s = t_meas.elapsed().as_secs_f64();
    let rec: Vec<PostureSample> = engine::recorded(journal, 0, plan.len())?;
    if rec.len() < 3 {
        return Err(JobError::Failed(format!(
            "only {} of {} postures were recorded: too few to identify ({} skipped; see the journal)",
            rec.len(),
            plan.len(),
            sum.skipped
        )));
    }
    let table = samples_table(&setup, &rec);
    let t_id = Instant::now();
    let identified = {
        let (job, setup, table) = (job.clone(), setup.clone(), table.clone());
        cx.phase(0.9, 1.0)
            .compute(move |m| job.identify(&setup, &table, m))
            .await?
    };
    let identify_s = t_id.elapsed().as_secs_f64();
    let mean = |f: fn(&PostureSample) -> usize| {
        rec.iter().map(|s| f(s) as f64).sum::<f64>() / rec.len() as f64
    };
    let fit = &identified.result;
    let means = MeanErrors::new(fit.rmse_before_mm, fit.rmse_after_mm);
    let candidate = Candidate {
        cell: job.cell.clone(),
        model: CellModel::Humanoid(fit.calibrated_model.clone()),
        evidence: Some(Evidence {
            what: "marker RMSE on the campaign's postures".into(),
            before: fit.rmse_before_mm,
            after: fit.rmse_after_mm,
            unit: "mm",
        }),
        validation: serde_json::to_value(&means).unwrap_or_default(),
        assessment: Some(fit.assessment.clone()),
    };
    let tolerance = job.tolerance_mm().map(|t| match &fit.cross_validation {
        Some(cv) => ToleranceCheck::of(
            t,
            Some(cv.rmse_calibrated_mm),
            "mm",
            &format!(
                "held-out marker RMSE after calibration ({}-fold cross-validation)",
                cv.folds
            ),
        ),
        None => ToleranceCheck::of(
            t,
            None,
            "mm",
            "held-out marker RMSE after calibration (set options.identify.cross_validation to check it)",
        ),
    });
    let result = MocapCampaign {
        instruments,
        tolerance,
        calibration: identified.result,
        cell: job.cell.clone(),
        started_from,
        campaign: MocapStats {
            planned: plan.len(),
            recorded: sum.recorded,
            skipped: sum.skipped,
            mean_frames_per_posture: mean(|s| s.frames),
            mean_stable_samples: mean(|s| s.stable),
            design_s,
            measuring_s,
            identify_s,
            wall_time_s: t0.elapsed().as_secs_f64(),
            journal_entries: journal.entries().map(|e| e.len()).unwrap_or(0),
        },
        measurements: table.clone(),
    };
    engine::conclude(&result, identified.artefacts, table, None, candidate)
}

#[cfg(test)]
mod tests;
