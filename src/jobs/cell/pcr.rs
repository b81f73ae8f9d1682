//! `cell.pcr_campaign`: a seeded Poisson-disc set of joint sets of the 3-PF robot, each
//! driven on the stages, settled, read by the microscope and journalled before the next
//! move; then `pcr.identify` on what was recorded (a share held out for validation) and,
//! optionally, `pcr.accuracy` on a trajectory commanded by inverse kinematics of the
//! identified model and executed on the robot. Resumable: what the journal holds is never
//! measured again.

use std::time::{Duration, Instant};

use serde::Deserialize;
use serde_json::{Value, json};

use super::RetrySpec;
use super::RunContext;
use crate::jobs::pcr::accuracy::trajectory;
use crate::jobs::pcr::identify::IdentifyOptions;
use crate::jobs::pcr::ik::solve_rows;
use crate::jobs::pcr::{PcrModel, load_model};
use crate::jobs::{Artefact, Inputs, JobError, NoReferences, Output, Prepared, Table, parse_spec};
use crate::lab::PcrCell;
use crate::model::pcr::PcrFile;
use crate::procedures::pcr::{self, PcrOptions, PcrRecorded};
use crate::procedures::trical::{CampaignError, Retry};
use crate::procedures::{Journal, MemoryJournal};
use crate::util::{Monitor, SubMonitor};

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct Options {
    /// Wait after the stages settle, before the image (ms).
    settle_ms: u64,
    retry: RetrySpec,
    identify: Option<Value>,
}

/// `accuracy`: the `pcr.accuracy` trajectory and repetitions.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct AccuracySpec {
    trajectory: Value,
    #[serde(default = "default_repetitions")]
    repetitions: usize,
}

fn default_repetitions() -> usize {
    5
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    #[serde(default)]
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
    cell: String,
    model: Option<PcrModel>,
    poses: usize,
    seed: u64,
    validation_fraction: f64,
    accuracy: Option<AccuracySpec>,
    options: Options,
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
    if let Some(a) = &s.accuracy {
        let (_, c) = trajectory(inputs, &a.trajectory)
            .map_err(|e| JobError::invalid("accuracy.trajectory", e.to_string()))?;
        if c.is_empty() || a.repetitions == 0 {
            return Err(JobError::invalid(
                "accuracy",
                "the trajectory needs a pose and repetitions at least 1",
            ));
        }
    }
    if s.options.retry.attempts == 0 {
        return Err(JobError::invalid(
            "options.retry.attempts",
            "must be at least 1",
        ));
    }
    if let Some(o) = &s.options.identify {
        let io: IdentifyOptions = serde_path_to_error::deserialize(o).map_err(|e| {
            JobError::invalid(
                format!("options.identify.{}", e.path()),
                e.into_inner().to_string(),
            )
        })?;
        crate::jobs::pcr::identify::calibration_options(&io)?;
    }
    Ok(PcrCampaignJob {
        cell: s.cell,
        model,
        poses: s.poses,
        seed: s.seed,
        validation_fraction: s.validation_fraction,
        accuracy: s.accuracy,
        options: s.options,
    })
}

fn calibration_count(n: usize, fraction: f64) -> usize {
    n - (n as f64 * fraction).round() as usize
}

/// The 3-PF cell `name` of the context's lab.
fn pcr_cell<'a>(
    ctx: &RunContext<'a>,
    name: &str,
) -> Result<(&'a PcrCell, &'a tokio::runtime::Handle), JobError> {
    let (Some(lab), Some(rt)) = (ctx.lab, ctx.runtime) else {
        return Err(JobError::NeedsLab {
            kind: "cell.pcr_campaign".into(),
        });
    };
    match &lab.pcr {
        Some(c) if c.name == name => Ok((c, rt)),
        Some(c) => Err(JobError::invalid(
            "cell",
            format!("no 3-PF cell `{name}` in this lab (it has `{}`)", c.name),
        )),
        None => Err(JobError::invalid(
            "cell",
            format!("this lab has no 3-PF cell (asked for `{name}`)"),
        )),
    }
}

fn campaign_error(e: CampaignError) -> JobError {
    match e {
        CampaignError::Paused { index, reason } => JobError::Paused { index, reason },
        CampaignError::Cancelled => JobError::Cancelled,
        other => JobError::Failed(format!("{other}; nothing more is measured")),
    }
}

/// Measurement rows (q1, q2, q3 settled, x, y, theta) for `pcr.identify`/`pcr.accuracy`.
fn rows(rec: &[PcrRecorded]) -> Value {
    Value::Array(
        rec.iter()
            .map(|r| {
                json!({"q1": r.q[0], "q2": r.q[1], "q3": r.q[2],
                       "x": r.z[0], "y": r.z[1], "theta": r.z[2]})
            })
            .collect(),
    )
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

fn journal_err(m: String) -> JobError {
    JobError::Failed(format!("journal: {m}"))
}

impl PcrCampaignJob {
    /// The Poisson-disc joint sets of the model's joint box.
    fn plan(&self, file: &PcrFile) -> Result<Vec<[f64; 3]>, JobError> {
        let l = file.limits();
        let (lo, hi) = ([l[0][0], l[1][0], l[2][0]], [l[0][1], l[1][1], l[2][1]]);
        crate::design::poisson_disc_n(lo, hi, self.poses, self.seed)
            .map(|(q, _)| q)
            .map_err(|e| JobError::invalid("poses", e.to_string()))
    }

    /// Execute the accuracy trajectory on the robot with the identified model; returns the
    /// `pcr.accuracy` output and the measurements.
    #[allow(clippy::too_many_arguments)]
    fn accuracy(
        &self,
        a: &AccuracySpec,
        calibrated: &Value,
        cell: &PcrCell,
        rt: &tokio::runtime::Handle,
        journal: &dyn Journal,
        offset: usize,
        opts: &PcrOptions,
        monitor: &dyn Monitor,
    ) -> Result<(Output, Vec<PcrRecorded>), JobError> {
        let inputs = Inputs::new(&NoReferences);
        let model = load_model(&inputs, calibrated)?;
        let (_, commanded) = trajectory(&inputs, &a.trajectory)?;
        let control = solve_rows(&model.robot, &commanded, "accuracy.trajectory", monitor)?;
        let n = control.len();
        // ISO 9283: the poses are visited in cycles, `repetitions` times.
        let plan: Vec<[f64; 3]> = (0..a.repetitions)
            .flat_map(|_| control.iter().map(|e| e.q))
            .collect();
        rt.block_on(pcr::run(
            &*cell.stages,
            &*cell.microscope,
            &plan,
            offset,
            journal,
            opts,
            monitor,
        ))
        .map_err(campaign_error)?;
        let rec = pcr::recorded(journal, offset, plan.len()).map_err(journal_err)?;
        if rec.len() != plan.len() {
            return Err(JobError::Failed(format!(
                "{} of {} accuracy poses were measured (see the journal)",
                rec.len(),
                plan.len()
            )));
        }
        // Grouped by pose for pcr.accuracy: pose k, repetition c is plan entry c n + k.
        let grouped: Vec<PcrRecorded> = (0..n)
            .flat_map(|k| (0..a.repetitions).map(move |c| c * n + k))
            .filter_map(|i| rec.get(i).cloned())
            .collect();
        let doc = json!({
            "kind": "pcr.accuracy",
            "model": calibrated,
            "trajectory": a.trajectory,
            "repetitions": a.repetitions,
            "reached": rows(&grouped),
        });
        let job = crate::jobs::pcr::accuracy::prepare(&doc, &inputs)?;
        Ok((job.execute(monitor)?, rec))
    }
}

impl Prepared for PcrCampaignJob {
    fn execute(&self, _monitor: &dyn Monitor) -> Result<Output, JobError> {
        Err(JobError::NeedsLab {
            kind: "cell.pcr_campaign".into(),
        })
    }

    fn resumable(&self) -> bool {
        true
    }

    fn devices(&self) -> Vec<String> {
        vec![
            format!("{}.mcs2", self.cell),
            format!("{}.microscope", self.cell),
        ]
    }

    fn execute_in(&self, ctx: &RunContext<'_>, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let t0 = Instant::now();
        let (cell, rt) = pcr_cell(ctx, &self.cell)?;
        let file = match &self.model {
            Some(m) => m.file.clone(),
            None => cell.current_model(),
        };
        let plan = self.plan(&file)?;
        let n_cal = calibration_count(plan.len(), self.validation_fraction);
        let opts = PcrOptions {
            limits: file.limits(),
            settle: Duration::from_millis(self.options.settle_ms),
            retry: Retry {
                attempts: self.options.retry.attempts,
                backoff: Duration::from_millis(self.options.retry.backoff_ms),
            },
        };
        let local = MemoryJournal::default();
        let journal: &dyn Journal = ctx.journal.unwrap_or(&local);
        let has_acc = self.accuracy.is_some();
        let meas_end = if has_acc { 0.6 } else { 0.85 };
        let t_meas = Instant::now();
        let s = rt
            .block_on(pcr::run(
                &*cell.stages,
                &*cell.microscope,
                &plan,
                0,
                journal,
                &opts,
                &SubMonitor::new(monitor, 0.0, meas_end),
            ))
            .map_err(campaign_error)?;
        let measuring_s = t_meas.elapsed().as_secs_f64();
        let cal = pcr::recorded(journal, 0, n_cal).map_err(journal_err)?;
        let val = pcr::recorded(journal, n_cal, plan.len() - n_cal).map_err(journal_err)?;
        if cal.len() < 12 {
            return Err(JobError::Failed(format!(
                "only {} of {n_cal} calibration joint sets were measured: too few to identify",
                cal.len()
            )));
        }
        let mut doc = json!({
            "kind": "pcr.identify",
            "model": serde_json::to_value(&file).map_err(|e| JobError::Failed(e.to_string()))?,
            "measurements": rows(&cal),
        });
        if !val.is_empty() {
            doc["validation"] = rows(&val);
        }
        if let Some(o) = &self.options.identify {
            doc["options"] = o.clone();
        }
        let t_id = Instant::now();
        let id = crate::jobs::pcr::identify::prepare(&doc, &Inputs::new(&NoReferences))?;
        let id_end = if has_acc { 0.7 } else { 1.0 };
        let mut out = id.execute(&SubMonitor::new(monitor, meas_end, id_end))?;
        let identify_s = t_id.elapsed().as_secs_f64();
        let mut acc_rec = Vec::new();
        if let Some(a) = &self.accuracy {
            let calibrated = out
                .fields
                .get("calibrated_model")
                .cloned()
                .ok_or_else(|| JobError::Failed("pcr.identify returned no model".into()))?;
            let (acc, rec) = self.accuracy(
                a,
                &calibrated,
                cell,
                rt,
                journal,
                plan.len(),
                &opts,
                &SubMonitor::new(monitor, id_end, 1.0),
            )?;
            out.fields
                .insert("accuracy".into(), Value::Object(acc.fields));
            acc_rec = rec;
        }
        let all: Vec<PcrRecorded> = cal.iter().chain(&val).cloned().collect();
        let measurements = table(&all);
        out.fields.insert("cell".into(), json!(self.cell));
        out.fields.insert(
            "campaign".into(),
            json!({
                "planned": plan.len(),
                "calibration": cal.len(),
                "validation": val.len(),
                "recorded": s.recorded,
                "skipped": s.skipped,
                "accuracy_measurements": acc_rec.len(),
                "seed": self.seed,
                "measuring_s": measuring_s,
                "identify_s": identify_s,
                "wall_time_s": t0.elapsed().as_secs_f64(),
                "journal_entries": journal.entries().map(|e| e.len()).unwrap_or(0),
            }),
        );
        out.fields
            .insert("measurements".into(), measurements.to_json_rows());
        out.artefacts.push(Artefact {
            name: "measurements.csv".into(),
            media_type: "text/csv".into(),
            content: measurements.to_csv().into_bytes(),
        });
        if !acc_rec.is_empty() {
            out.artefacts.push(Artefact {
                name: "accuracy_measurements.csv".into(),
                media_type: "text/csv".into(),
                content: table(&acc_rec).to_csv().into_bytes(),
            });
        }
        out.main_table = Some(measurements);
        Ok(out)
    }
}
