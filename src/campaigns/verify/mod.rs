//! The verification campaign (`cell.verify`, ISO 9283): each cycle visits every pose
//! through the nominal and the compensated joints, each from its pre-pose, and reads the
//! indicators without centring (the reading is the position error); each reading is
//! journalled before the next move. The figures are in [`figures`].

pub mod drift;
pub mod figures;
pub mod plan;

use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::engine::{self, Step, StepError};
use crate::campaigns::trical::is_device_fault;
use crate::procedures::centring::{CentringError, CentringOptions, approach, read};
use crate::procedures::{Indicators, Robot};
use crate::report::plots::{self, Series};
use crate::report::svg_artefact;
use crate::run::{Artefact, Cx, JobError, Output, Produced, Table};
use crate::util::Monitor;
use figures::{DistanceFigures, PoseFigures, Reading, Totals, evaluate};
use plan::{Commanded, ISO_CYCLES, VerifyJob, VerifyPose};

/// One visit: a pose in a cycle, commanded through one model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Visit {
    /// Cycle (0-based).
    pub cycle: usize,
    /// Pose (0-based).
    pub pose: usize,
    /// Ball (0-based).
    pub ball: usize,
    /// Which model commands it.
    pub commanded: Commanded,
    /// Joints of the pre-pose, then of the pose (rad).
    pub pre: Vec<f64>,
    /// Joints of the pose (rad).
    pub q: Vec<f64>,
}

/// The visits of `cycles` cycles over `poses`: in each cycle every pose in order, first
/// through the nominal then the compensated model.
pub fn visits(poses: &[VerifyPose], cycles: usize) -> Vec<Visit> {
    let mut out = Vec::with_capacity(2 * cycles * poses.len());
    for cycle in 0..cycles {
        for (k, p) in poses.iter().enumerate() {
            for (commanded, j) in [
                (Commanded::Nominal, &p.nominal),
                (Commanded::Compensated, &p.compensated),
            ] {
                out.push(Visit {
                    cycle,
                    pose: k,
                    ball: p.ball,
                    commanded,
                    pre: j[1].clone(),
                    q: j[0].clone(),
                });
            }
        }
    }
    out
}

/// Reading the indicators at commanded poses, as a campaign step.
pub struct Reader<'a> {
    /// The arm.
    pub robot: &'a dyn Robot,
    /// The indicators.
    pub indicators: &'a dyn Indicators,
    /// Settling and reading bounds, and the approach step.
    pub options: &'a CentringOptions,
    /// Half-travel of the indicators (mm).
    pub range_mm: f64,
}

impl std::fmt::Debug for Reader<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reader")
            .field("range_mm", &self.range_mm)
            .finish_non_exhaustive()
    }
}

impl Reader<'_> {
    async fn visit(&self, v: &Visit, monitor: &dyn Monitor) -> Result<[f64; 3], CentringError> {
        approach(self.robot, &v.pre, self.options.approach_step, monitor).await?;
        approach(self.robot, &v.q, self.options.approach_step, monitor).await?;
        tokio::time::sleep(self.options.settle).await;
        read(self.indicators, self.options).await
    }
}

impl Step for Reader<'_> {
    type Plan = Visit;
    type Sample = Reading;
    const STAGE: &'static str = "verifying";

    fn describe(&self, k: usize, n: usize, v: &Visit) -> String {
        let m = match v.commanded {
            Commanded::Nominal => "nominal",
            Commanded::Compensated => "compensated",
        };
        format!(
            "visit {k}/{n}: cycle {}, pose {} (ball {}), {m}",
            v.cycle + 1,
            v.pose + 1,
            v.ball + 1
        )
    }

    async fn measure(
        &self,
        index: usize,
        v: &Visit,
        monitor: &dyn Monitor,
    ) -> Result<Reading, StepError> {
        match self.visit(v, monitor).await {
            Ok(r) => Ok(Reading {
                index,
                cycle: v.cycle,
                pose: v.pose,
                commanded: v.commanded,
                r_mm: r,
                // A saturated plunger reads its end of travel (within its 0.001 mm step).
                out_of_range: r.iter().any(|x| x.abs() >= self.range_mm - 0.0015),
            }),
            Err(CentringError::Cancelled) => Err(StepError::Cancelled),
            Err(e) if is_device_fault(&e) => Err(StepError::Fault(e.to_string())),
            Err(e) => Err(StepError::Skip(e.to_string())),
        }
    }
}

/// The result of `cell.verify`: both models' ISO 9283 figures side by side.
#[derive(Debug, Clone, Serialize)]
pub struct Verification {
    /// The cell.
    pub cell: String,
    /// Cycles per pose run (the standard asks for `iso_cycles`).
    pub cycles: usize,
    /// Cycles ISO 9283 asks for.
    pub iso_cycles: usize,
    /// Pre-pose offset along the tool -z axis (mm).
    pub approach_mm: f64,
    /// Half-travel of the indicators (mm).
    pub indicator_range_mm: f64,
    /// Summary through the nominal model.
    pub nominal: Totals,
    /// Summary through the compensated model.
    pub compensated: Totals,
    /// AP and RP per pose.
    pub poses: Vec<PoseFigures>,
    /// AD per pair of poses on different balls.
    pub distances: Vec<DistanceFigures>,
    /// Poses not commanded, with the reason.
    pub dropped: Vec<String>,
    /// Visits planned, read, skipped.
    pub visits: [usize; 3],
    /// Whole campaign (s).
    pub wall_time_s: f64,
}

fn readings_table(rec: &[Reading], poses: &[VerifyPose]) -> Table {
    let mut t = Table::new(&[
        "index",
        "cycle",
        "pose",
        "ball",
        "compensated",
        "rx_mm",
        "ry_mm",
        "rz_mm",
        "error_mm",
        "out_of_range",
    ]);
    for r in rec {
        let n = r.r_mm.iter().map(|v| v * v).sum::<f64>().sqrt();
        t.push(vec![
            r.index as f64,
            (r.cycle + 1) as f64,
            (r.pose + 1) as f64,
            poses.get(r.pose).map_or(0.0, |p| (p.ball + 1) as f64),
            f64::from(u8::from(r.commanded == Commanded::Compensated)),
            r.r_mm[0],
            r.r_mm[1],
            r.r_mm[2],
            n,
            f64::from(u8::from(r.out_of_range)),
        ]);
    }
    t
}

/// AP per pose through both models, side by side (`verification_ap.svg`).
fn ap_plot(v: &Verification) -> Artefact {
    let cats: Vec<String> = v
        .poses
        .iter()
        .map(|p| format!("pose {} (ball {})", p.pose, p.ball))
        .collect();
    let nom: Vec<Option<f64>> = v.poses.iter().map(|p| p.nominal.ap_mm).collect();
    let comp: Vec<Option<f64>> = v.poses.iter().map(|p| p.compensated.ap_mm).collect();
    let svg = plots::category_bars(
        "Pose accuracy AP (ISO 9283): nominal vs compensated",
        &v.cell,
        "AP (mm)",
        &cats,
        &[
            Series {
                name: "nominal",
                legend: "nominal model",
                values: &nom,
            },
            Series {
                name: "compensated",
                legend: "compensated",
                values: &comp,
            },
        ],
    );
    svg_artefact("verification_ap.svg", svg)
}

/// Run a `cell.verify`: plan, visit every pose in every cycle through both models, figures.
pub async fn campaign(job: Arc<VerifyJob>, cx: Cx) -> Result<Produced, JobError> {
    let t0 = Instant::now();
    let cell = cx.lab().trical(&job.cell)?;
    let comp = job.model.clone().unwrap_or_else(|| cell.current_model());
    let nom = job.nominal.clone().unwrap_or_else(|| cell.nominal.clone());
    let copts = job.options.centring.options("options.centring", cell)?;
    let retry = job.options.retry.retry();
    let plan = {
        let (job, ballbar, envelope) = (job.clone(), cell.ballbar, cell.envelope.clone());
        cx.phase(0.0, 0.05)
            .compute(move |m| job.plan(&comp, &nom, ballbar, &envelope, m))
            .await?
    };
    let v = visits(&plan.poses, job.cycles);
    let step = Reader {
        robot: &*cell.robot,
        indicators: &*cell.indicators,
        options: &copts,
        range_mm: job.indicator_range_mm,
    };
    let journal = cx.journal();
    let s = engine::run(&step, &v, 0, journal, &retry, &cx.phase(0.05, 1.0)).await?;
    let rec: Vec<Reading> = engine::recorded(journal, 0, v.len())?;
    let (poses, distances, [nominal, compensated]) = evaluate(&plan.poses, &rec, job.cycles);
    let result = Verification {
        cell: job.cell.clone(),
        cycles: job.cycles,
        iso_cycles: ISO_CYCLES,
        approach_mm: job.approach_mm,
        indicator_range_mm: job.indicator_range_mm,
        nominal,
        compensated,
        poses,
        distances,
        dropped: plan.dropped,
        visits: [v.len(), s.recorded, s.skipped],
        wall_time_s: t0.elapsed().as_secs_f64(),
    };
    let table = readings_table(&rec, &plan.poses);
    let mut output = Output::typed(&result)?;
    output.artefacts.push(ap_plot(&result));
    output.artefacts.push(Artefact::csv("readings.csv", &table));
    output.main_table = Some(table);
    Ok(Produced {
        output,
        candidate: None,
    })
}

#[cfg(test)]
mod tests;
