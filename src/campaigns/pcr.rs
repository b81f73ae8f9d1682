//! The 3-PF campaign: drive the three stages to each planned joint set, wait for them to
//! settle and read the microscope (the [`StagesAndScope`] step over the engine); then
//! identify, optionally execute an accuracy trajectory, and propose the calibrated model.

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::jobs::cell::pcr::PcrCampaignJob;
use crate::jobs::{Artefact, Cx, JobError, Output, Produced, Table};
use crate::lab::{Candidate, CellModel, Evidence};

use super::engine::{self, CampaignError, Retry, Step, StepError, Summary};
use crate::procedures::{DeviceError, Journal, LinearStages, PoseSensor};
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

/// Measure every joint set of `plan` not yet in the journal; plan entry `k` is journal
/// index `offset + k`.
pub async fn run(
    stages: &dyn LinearStages,
    scope: &dyn PoseSensor,
    plan: &[[f64; 3]],
    offset: usize,
    journal: &dyn Journal,
    opts: &PcrOptions,
    monitor: &dyn Monitor,
) -> Result<Summary, CampaignError> {
    let step = StagesAndScope {
        stages,
        scope,
        options: opts,
    };
    engine::run(&step, plan, offset, journal, &opts.retry, monitor).await
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

/// Figures of a 3-PF campaign's measuring.
#[derive(Debug, Clone, Serialize)]
pub struct CampaignStats {
    /// Joint sets planned (calibration + validation).
    pub planned: usize,
    /// Calibration joint sets measured.
    pub calibration: usize,
    /// Validation joint sets measured.
    pub validation: usize,
    /// Measured (including earlier runs).
    pub recorded: usize,
    /// Skipped (outside the envelope).
    pub skipped: usize,
    /// Accuracy poses measured.
    pub accuracy_measurements: usize,
    /// Seed of the Poisson-disc plan.
    pub seed: u64,
    /// Time measuring (s).
    pub measuring_s: f64,
    /// Time identifying (s).
    pub identify_s: f64,
    /// Whole campaign (s).
    pub wall_time_s: f64,
    /// Journal entries.
    pub journal_entries: usize,
}

/// The result of a `cell.pcr_campaign`.
#[derive(Debug, Clone, Serialize)]
pub struct PcrCampaign {
    /// The `pcr.identify` result.
    #[serde(flatten)]
    pub calibration: serde_json::Map<String, serde_json::Value>,
    /// The `pcr.accuracy` result of the identified model, if asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accuracy: Option<serde_json::Map<String, serde_json::Value>>,
    /// The cell.
    pub cell: String,
    /// Measuring figures.
    pub campaign: CampaignStats,
    /// The calibration and validation joint sets (rows of the main table).
    pub measurements: serde_json::Value,
}

/// Run a `cell.pcr_campaign`: Poisson-disc joint sets, identify, optional accuracy,
/// propose.
pub async fn campaign(job: Arc<PcrCampaignJob>, cx: Cx) -> Result<Produced, JobError> {
    let t0 = Instant::now();
    let cell = cx.lab().pcr(&job.cell)?;
    let file = job.start_model().unwrap_or_else(|| cell.current_model());
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
    let (meas_end, id_end) = if job.accuracy.is_some() { (0.6, 0.7) } else { (0.85, 1.0) };
    let t_meas = Instant::now();
    let s = engine::run(&step, &plan, 0, journal, &opts.retry, &cx.phase(0.0, meas_end)).await?;
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
            let (job, model) = (job.clone(), identified.model.clone());
            cx.compute(move |m| job.accuracy_plan(&model, m)).await?
        };
        let offset = plan.len();
        engine::run(&step, &control, offset, journal, &opts.retry, &cx.phase(id_end, 0.95))
            .await?;
        acc_rec = engine::recorded(journal, offset, control.len())?;
        if acc_rec.len() != control.len() {
            return Err(JobError::Failed(format!(
                "{} of {} accuracy poses were measured (see the journal)",
                acc_rec.len(),
                control.len()
            )));
        }
        let (job, model, rec) = (job.clone(), identified.model.clone(), acc_rec.clone());
        accuracy = Some(
            cx.phase(0.95, 1.0)
                .compute(move |m| job.accuracy(&model, &rec, n, m))
                .await?,
        );
    }
    let all: Vec<PcrRecorded> = cal.iter().chain(&val).cloned().collect();
    let measurements = table(&all);
    let candidate = Candidate {
        cell: job.cell.clone(),
        model: CellModel::Pcr(identified.model.clone()),
        evidence: identified.validation.as_ref().map(|v| Evidence {
            what: "validation mean position error".into(),
            before: v.before.mean,
            after: v.after.mean,
            unit: "m",
        }),
        validation: serde_json::to_value(&identified.validation).unwrap_or_default(),
    };
    let result = PcrCampaign {
        calibration: identified.fields,
        accuracy,
        cell: job.cell.clone(),
        campaign: CampaignStats {
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
        measurements: measurements.to_json_rows(),
    };
    let mut out = Output::typed(&result)?;
    out.artefacts = identified.artefacts;
    out.artefacts.push(Artefact::csv("measurements.csv", &measurements));
    if !acc_rec.is_empty() {
        out.artefacts
            .push(Artefact::csv("accuracy_measurements.csv", &table(&acc_rec)));
    }
    out.main_table = Some(measurements);
    Ok(Produced {
        output: out,
        candidate: Some(candidate),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedures::{EntryStatus, MemoryJournal};
    use crate::util::NoMonitor;
    use std::sync::Mutex;

    /// Stages that settle 1 nm past the target; the first `faults` moves time out.
    struct FakeStages {
        faults: Mutex<usize>,
        moves: Mutex<Vec<[f64; 3]>>,
    }
    impl LinearStages for FakeStages {
        fn move_to<'a>(&'a self, q: &'a [f64; 3]) -> DeviceFuture<'a, [f64; 3]> {
            Box::pin(async move {
                let mut f = self.faults.lock().expect("lock");
                if *f > 0 {
                    *f -= 1;
                    return Err(DeviceError::Timeout {
                        device: "stages".into(),
                        timeout_ms: 1,
                    });
                }
                self.moves.lock().expect("lock").push(*q);
                Ok(q.map(|v| v + 1e-9))
            })
        }
        fn positions(&self) -> DeviceFuture<'_, [f64; 3]> {
            Box::pin(async { Ok([0.0; 3]) })
        }
    }
    /// A microscope that sees the last joint set scaled (a known linear map).
    struct FakeScope<'a>(&'a FakeStages);
    impl PoseSensor for FakeScope<'_> {
        fn read_pose(&self) -> DeviceFuture<'_, [f64; 3]> {
            Box::pin(async move {
                let q = self
                    .0
                    .moves
                    .lock()
                    .expect("lock")
                    .last()
                    .copied()
                    .unwrap_or_default();
                Ok([2.0 * q[0], 3.0 * q[1], q[2]])
            })
        }
    }
    use crate::procedures::DeviceFuture;

    fn opts(attempts: usize) -> PcrOptions {
        PcrOptions {
            limits: [[-1e-3, 1e-3]; 3],
            settle: Duration::ZERO,
            retry: Retry {
                attempts,
                backoff: Duration::from_millis(1),
            },
        }
    }

    #[tokio::test]
    async fn faults_are_retried_then_pause_and_the_envelope_skips() {
        let plan = [[1e-4, 2e-4, 3e-4], [5e-3, 0.0, 0.0], [-1e-4, 0.0, 1e-4]];
        let st = FakeStages {
            faults: Mutex::new(2),
            moves: Mutex::default(),
        };
        let j = MemoryJournal::default();
        // Two timeouts, three attempts: the first joint set is measured on the third.
        let s = run(&st, &FakeScope(&st), &plan, 10, &j, &opts(3), &NoMonitor)
            .await
            .expect("campaign");
        assert_eq!((s.recorded, s.skipped, s.planned), (2, 1, 3));
        let rec: Vec<PcrRecorded> = engine::recorded(&j, 10, 3).expect("journal");
        assert_eq!(rec[0].index, 10);
        assert_eq!(rec[0].q, [1e-4 + 1e-9, 2e-4 + 1e-9, 3e-4 + 1e-9]);
        assert_eq!(rec[0].z, [2.0 * 1e-4, 3.0 * 2e-4, 3e-4]);
        let e = j.entries().expect("entries");
        assert_eq!(e[1].status, EntryStatus::Skipped);
        assert!(e[1].data["reason"].as_str().unwrap_or("").contains("q1"));
        // The out-of-envelope joint set never reached the stages.
        assert_eq!(st.moves.lock().expect("lock").len(), 2);
        // Resume: nothing left, nothing measured again.
        run(&st, &FakeScope(&st), &plan, 10, &j, &opts(3), &NoMonitor)
            .await
            .expect("resume");
        assert_eq!(st.moves.lock().expect("lock").len(), 2);
        // Persistent faults pause at the first unmeasured index.
        *st.faults.lock().expect("lock") = 5;
        let j2 = MemoryJournal::default();
        let e = run(&st, &FakeScope(&st), &plan, 0, &j2, &opts(2), &NoMonitor)
            .await
            .expect_err("paused");
        assert!(matches!(e, CampaignError::Paused { index: 0, .. }), "{e}");
        assert!(j2.entries().expect("entries").is_empty());
    }
}
