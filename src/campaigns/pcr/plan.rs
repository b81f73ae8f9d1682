//! `cell.pcr_campaign`: a seeded Poisson-disc set of joint sets of the 3-PF robot, each
//! driven on the stages, settled, read by the microscope and journalled before the next
//! move; then `pcr.identify` on what was recorded (a share held out for validation) and,
//! optionally, `pcr.accuracy` on a trajectory commanded by inverse kinematics of the
//! identified model and executed on the robot. Resumable: what the journal holds is never
//! measured again.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::Value;

use crate::campaigns::instruments::check_tolerance;
use crate::campaigns::pcr::PcrRecorded;
use crate::campaigns::spec::RetrySpec;
use crate::geometry::Pose2;
use crate::jobs::pcr::accuracy::{AccuracyJob, PcrAccuracy, trajectory};
use crate::jobs::pcr::identify::{IdentifyJob, IdentifyOptions, PcrCalibration};
use crate::jobs::pcr::ik::solve_rows;
use crate::jobs::pcr::{PcrModel, load_model};
use crate::measure::pcr::PcrMeasurement;
use crate::model::pcr::PcrFile;
use crate::run::Run;
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, parse_spec};
use crate::util::Monitor;

#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct Options {
    /// Wait after the stages settle, before the image (ms).
    pub(crate) settle_ms: u64,
    pub(crate) retry: RetrySpec,
    identify: IdentifyOptions,
    /// The largest held-out position error the calibrated model may leave (um): the
    /// result's and the report's pass/fail (none declared: no pass/fail).
    pub(crate) tolerance_um: Option<f64>,
}

/// `accuracy` as given: the `pcr.accuracy` trajectory and repetitions.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct AccuracySpec {
    #[schemars(schema_with = "crate::jobs::pcr::accuracy::trajectory_schema")]
    trajectory: Value,
    #[serde(default = "default_repetitions")]
    repetitions: usize,
}

/// The accuracy pass: the trajectory's name and commanded poses (m, rad), and the cycles.
#[derive(Debug, Clone)]
pub(crate) struct Accuracy {
    name: String,
    commanded: Vec<Pose2>,
    repetitions: usize,
}

fn default_repetitions() -> usize {
    5
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::json_file_opt")]
    model: Option<Value>,
    poses: usize,
    #[serde(default)]
    seed: u64,
    #[serde(default = "default_fraction")]
    validation_fraction: f64,
    #[serde(default)]
    accuracy: Option<AccuracySpec>,
    #[serde(default)]
    options: Options,
}

fn default_cell() -> String {
    "pcr3pf".into()
}

fn default_fraction() -> f64 {
    0.25
}

/// A validated `cell.pcr_campaign` job.
#[derive(Debug)]
pub struct PcrCampaignJob {
    pub(crate) cell: String,
    model: Option<PcrModel>,
    poses: usize,
    pub(crate) seed: u64,
    validation_fraction: f64,
    pub(crate) accuracy: Option<Accuracy>,
    pub(crate) options: Options,
}

/// Validate a `cell.pcr_campaign` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<PcrCampaignJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let model = match &s.model {
        Some(v) => Some(load_model(inputs, v)?),
        None => None,
    };
    if !(0.0..0.9).contains(&s.validation_fraction) {
        return Err(JobError::invalid(
            "validation_fraction",
            format!("{} must be in [0, 0.9)", s.validation_fraction),
        ));
    }
    let n_cal = calibration_count(s.poses, s.validation_fraction);
    if n_cal < 12 {
        return Err(JobError::invalid(
            "poses",
            format!(
                "{} poses leave {n_cal} for calibration: pcr.identify needs at least 12",
                s.poses
            ),
        ));
    }
    let accuracy = match &s.accuracy {
        Some(a) => {
            let (name, commanded) = trajectory(inputs, &a.trajectory)
                .map_err(|e| JobError::invalid("accuracy.trajectory", e.to_string()))?;
            if commanded.is_empty() || a.repetitions == 0 {
                return Err(JobError::invalid(
                    "accuracy",
                    "the trajectory needs a pose and repetitions at least 1",
                ));
            }
            Some(Accuracy {
                name,
                commanded,
                repetitions: a.repetitions,
            })
        }
        None => None,
    };
    if s.options.retry.attempts == 0 {
        return Err(JobError::invalid(
            "options.retry.attempts",
            "must be at least 1",
        ));
    }
    check_tolerance("options.tolerance_um", s.options.tolerance_um, "um")?;
    crate::jobs::pcr::identify::calibration_options(&s.options.identify)?;
    Ok(PcrCampaignJob {
        cell: s.cell,
        model,
        poses: s.poses,
        seed: s.seed,
        validation_fraction: s.validation_fraction,
        accuracy,
        options: s.options,
    })
}

fn calibration_count(n: usize, fraction: f64) -> usize {
    n - (n as f64 * fraction).round() as usize
}

impl PcrCampaignJob {
    /// The model given in the job, if any (else the cell's current model is used).
    pub(crate) fn start_model(&self) -> Option<PcrFile> {
        self.model.as_ref().map(|m| m.file.clone())
    }

    /// Joint sets used for the identification (the rest validate).
    pub(crate) fn calibration_count(&self, n: usize) -> usize {
        calibration_count(n, self.validation_fraction)
    }

    /// The Poisson-disc joint sets of the model's joint box.
    pub(crate) fn plan(&self, file: &PcrFile) -> Result<Vec<[f64; 3]>, JobError> {
        let l = file.limits();
        let (lo, hi) = ([l[0][0], l[1][0], l[2][0]], [l[0][1], l[1][1], l[2][1]]);
        crate::design::poisson_disc_n(lo, hi, self.poses, self.seed)
            .map(|(q, _)| q)
            .map_err(|e| JobError::invalid("poses", e.to_string()))
    }

    /// `pcr.identify` on the calibration joint sets, validated on the others.
    pub(crate) fn identify(
        &self,
        file: &PcrFile,
        cal: &[PcrRecorded],
        val: &[PcrRecorded],
        monitor: &dyn Monitor,
    ) -> Result<Run<PcrCalibration>, JobError> {
        let validation = (!val.is_empty()).then(|| measurements(val));
        let options = &self.options.identify;
        IdentifyJob::from_file(file.clone(), measurements(cal), validation, options)?
            .calibrate(monitor)
    }

    /// The accuracy trajectory's joint sets by inverse kinematics of `model`, visited in
    /// `repetitions` cycles (ISO 9283), and the number of poses per cycle.
    pub(crate) fn accuracy_plan(
        &self,
        model: &PcrFile,
        monitor: &dyn Monitor,
    ) -> Result<(Vec<[f64; 3]>, usize), JobError> {
        let Some(a) = &self.accuracy else {
            return Ok((Vec::new(), 0));
        };
        let robot = model
            .robot()
            .map_err(|e| JobError::Failed(format!("the identified model: {e}")))?;
        let control = solve_rows(&robot, &a.commanded, "accuracy.trajectory", monitor)?;
        let n = control.len();
        Ok((
            (0..a.repetitions)
                .flat_map(|_| control.iter().map(|e| e.q))
                .collect(),
            n,
        ))
    }

    /// `pcr.accuracy` of `model` on what the robot reached (cycle `c`, pose `k` is
    /// `rec[c n + k]`); `None` when the job asks for no accuracy pass.
    pub(crate) fn accuracy(
        &self,
        model: &PcrFile,
        rec: &[PcrRecorded],
        n: usize,
        monitor: &dyn Monitor,
    ) -> Result<Option<Run<PcrAccuracy>>, JobError> {
        let Some(a) = &self.accuracy else {
            return Ok(None);
        };
        let grouped: Vec<PcrRecorded> = (0..n)
            .flat_map(|k| (0..a.repetitions).map(move |c| c * n + k))
            .filter_map(|i| rec.get(i).cloned())
            .collect();
        let robot = model
            .robot()
            .map_err(|e| JobError::Failed(format!("the identified model: {e}")))?;
        let model = PcrModel {
            file: model.clone(),
            robot,
        };
        let job = AccuracyJob::reached(
            model,
            a.name.clone(),
            a.commanded.clone(),
            a.repetitions,
            measurements(&grouped),
        )?;
        job.evaluate(monitor).map(Some)
    }
}

/// The journalled joint sets (m) and microscope poses (m, rad) as measurements.
fn measurements(rec: &[PcrRecorded]) -> Vec<PcrMeasurement> {
    rec.iter()
        .map(|r| PcrMeasurement {
            q: r.q,
            z: Pose2::new(r.z[0], r.z[1], r.z[2]),
        })
        .collect()
}

impl Kind for PcrCampaignJob {
    fn resumable(&self) -> bool {
        true
    }

    fn devices(&self) -> Vec<String> {
        vec![
            format!("{}.stages", self.cell),
            format!("{}.microscope", self.cell),
        ]
    }

    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        Box::pin(crate::campaigns::pcr::campaign(self, cx))
    }
}
