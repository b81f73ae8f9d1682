//! `cell.verify`: the job document and the plan of an ISO 9283 verification on a
//! ball-centring cell: ball-centre poses from configurations not used for calibration, the
//! joints commanding them through the compensated model (`serial.compensate`) and through
//! the nominal one (closed-form OPW inverse kinematics), each with its pre-pose.

use std::sync::Arc;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::campaigns::spec::{CentringSpec, RetrySpec, default_cell, trical_devices};
use crate::campaigns::trical::plan::{pool, short_tour};
use crate::campaigns::verify::drift::DriftPolicy;
use crate::geometry::Frame;
use crate::jobs::serial::SerialModel;
use crate::jobs::serial::compensate::CompensateJob;
use crate::measure::BallPlate;
use crate::model::Chain;
use crate::model::compensate::Status;
use crate::model::dh::DhFile;
use crate::model::opw::{Opw, nearest_turn};
use crate::procedures::Envelope;
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, parse_spec};
use crate::twin::cell::INDICATOR_HALF_RANGE_MM;
use crate::util::Monitor;

/// Cycles the standard asks for (ISO 9283, 7.2.1).
pub const ISO_CYCLES: usize = 30;

/// Where the verification poses come from.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct PosesSpec {
    /// Poses per ball.
    per_ball: usize,
    /// Seed of the configurations (distinct from the calibration's design and validation
    /// seeds, so the poses are not those of the calibration).
    #[serde(default = "poses_seed")]
    seed: u64,
}

fn poses_seed() -> u64 {
    2_000_029
}

fn default_cycles() -> usize {
    5
}

fn default_approach() -> f64 {
    5.0
}

fn default_range() -> f64 {
    INDICATOR_HALF_RANGE_MM
}

/// `options` of `cell.verify`.
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct Options {
    /// Settling and reading bounds (the loop itself is not run: readings are not centred).
    pub(crate) centring: CentringSpec,
    pub(crate) retry: RetrySpec,
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    /// The compensated model (DH file); default the cell's current model.
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::json_file_opt")]
    model: Option<Value>,
    /// The nominal model the controller plans with; default the lab file's model.
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::json_file_opt")]
    nominal: Option<Value>,
    poses: PosesSpec,
    /// Cycles per pose (ISO 9283 asks for 30; default 5 keeps the simulated lab fast).
    #[serde(default = "default_cycles")]
    cycles: usize,
    /// Pre-pose offset (mm) along the tool -z axis: every pose is approached from there.
    #[serde(default = "default_approach")]
    approach_mm: f64,
    /// Half-travel of the indicators around their zero (mm): a reading at the end of
    /// travel is out of range, not an error of that size.
    #[serde(default = "default_range")]
    indicator_range_mm: f64,
    /// After the verification: submit a recalibration on drift, else record "within
    /// tolerance" (applied by the service).
    #[serde(default)]
    drift: Option<DriftPolicy>,
    #[serde(default)]
    options: Options,
}

/// A validated `cell.verify` job.
#[derive(Debug)]
pub struct VerifyJob {
    pub(crate) cell: String,
    pub(crate) model: Option<DhFile>,
    pub(crate) nominal: Option<DhFile>,
    poses: PosesSpec,
    pub(crate) cycles: usize,
    pub(crate) approach_mm: f64,
    pub(crate) indicator_range_mm: f64,
    pub(crate) options: Options,
}

fn dh(inputs: &Inputs<'_>, field: &str, v: &Option<Value>) -> Result<Option<DhFile>, JobError> {
    let Some(v) = v else { return Ok(None) };
    let j = inputs.json(field, v)?;
    let text = serde_json::to_string(&j).unwrap_or_default();
    let f = DhFile::parse(&text)?;
    f.to_chain()?;
    Ok(Some(f))
}

/// Validate a `cell.verify` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<VerifyJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    if s.poses.per_ball == 0 {
        return Err(JobError::invalid("poses.per_ball", "must be at least 1"));
    }
    if s.cycles == 0 {
        return Err(JobError::invalid("cycles", "must be at least 1"));
    }
    if !s.approach_mm.is_finite() || s.approach_mm.abs() > 50.0 {
        return Err(JobError::invalid(
            "approach_mm",
            format!(
                "{} mm: expected a finite offset within 50 mm",
                s.approach_mm
            ),
        ));
    }
    if !(s.indicator_range_mm.is_finite() && s.indicator_range_mm > 0.0) {
        return Err(JobError::invalid(
            "indicator_range_mm",
            format!("{} must be a positive number", s.indicator_range_mm),
        ));
    }
    if let Some(d) = &s.drift {
        d.validate()?;
    }
    s.options.centring.validate("options.centring")?;
    if s.options.retry.attempts == 0 {
        return Err(JobError::invalid(
            "options.retry.attempts",
            "must be at least 1",
        ));
    }
    Ok(VerifyJob {
        cell: s.cell,
        model: dh(inputs, "model", &s.model)?,
        nominal: dh(inputs, "nominal", &s.nominal)?,
        poses: s.poses,
        cycles: s.cycles,
        approach_mm: s.approach_mm,
        indicator_range_mm: s.indicator_range_mm,
        options: s.options,
    })
}

/// Which model commands a visit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Commanded {
    /// The nominal model's inverse kinematics (what the controller does alone).
    Nominal,
    /// The calibrated model's compensation.
    Compensated,
}

/// One verification pose: the commanded TCP frame on a ball centre and the joints (rad)
/// of the pose and its pre-pose under each model.
#[derive(Debug, Clone, PartialEq)]
pub struct VerifyPose {
    /// Ball (0-based).
    pub ball: usize,
    /// Commanded TCP frame in {W} (position: the ball centre, mm).
    pub target: Frame,
    /// Joints of the pose and pre-pose through the nominal model.
    pub nominal: [Vec<f64>; 2],
    /// Joints of the pose and pre-pose through the compensated model.
    pub compensated: [Vec<f64>; 2],
}

/// The plan: poses, and those dropped because a model cannot command them (why).
#[derive(Debug, Clone, Default)]
pub struct VerifyPlan {
    /// Poses both models command.
    pub poses: Vec<VerifyPose>,
    /// Poses dropped, with the reason.
    pub dropped: Vec<String>,
}

/// The nominal joints of `target` (rad): the OPW branch nearest `reference` inside the
/// limits, as the controller would pick it.
fn nominal_ik(chain: &Chain, opw: &Opw, target: &Frame, reference: &[f64]) -> Option<Vec<f64>> {
    let lim: Vec<_> = chain.joints.iter().map(|j| j.limits).collect();
    opw.solve(target, reference[3])
        .into_iter()
        .map(|q| {
            (0..6)
                .map(|k| nearest_turn(q[k], reference[k], lim[k]))
                .collect::<Vec<f64>>()
        })
        .filter(|q| chain.limit_violation(q).is_none())
        .min_by(|a, b| {
            let d = |q: &Vec<f64>| {
                q.iter()
                    .zip(reference)
                    .map(|(x, y)| (x - y).powi(2))
                    .sum::<f64>()
            };
            d(a).total_cmp(&d(b))
        })
}

/// `target` moved by `offset` (mm) along its own z axis.
fn pre_pose(target: &Frame, offset_mm: f64) -> Frame {
    Frame {
        r: target.r,
        p: target.apply(&Vector3::new(0.0, 0.0, -offset_mm)),
    }
}

impl VerifyJob {
    /// The poses: configurations reaching each ball on the compensated model inside the
    /// cell's envelope (a pool seeded apart from the calibration's), their TCP frames as targets, commanded through
    /// both models; ordered for short joint travel.
    pub(crate) fn plan(
        &self,
        compensated: &DhFile,
        nominal: &DhFile,
        ballbar: [f64; 3],
        envelope: &Envelope,
        monitor: &dyn Monitor,
    ) -> Result<VerifyPlan, JobError> {
        let plate = BallPlate::from_ballbar(ballbar[0], ballbar[1], ballbar[2])?;
        let comp = SerialModel::from_dh(compensated.clone())?;
        let nom = nominal.to_chain()?;
        let opw = Opw::of(&nom, 1e-6)
            .map_err(|e| JobError::invalid("nominal", format!("not an OPW arm: {e}")))?;
        let found = short_tour(pool(
            &comp.chain,
            &plate,
            envelope,
            self.poses.per_ball,
            self.poses.seed,
        ));
        let mut targets = Vec::new();
        let mut refs = Vec::new();
        for p in &found {
            let Some(centre) = plate.centres.get(p.ball).copied().flatten() else {
                continue;
            };
            let tau = comp.chain.static_torques(&p.q);
            let r = comp.chain.tcp(&p.q, Some(&tau)).r;
            let t = Frame { r, p: centre };
            let q: [f64; 6] = std::array::from_fn(|k| p.q.get(k).copied().unwrap_or(0.0));
            targets.push((t, q));
            targets.push((pre_pose(&t, self.approach_mm), q));
            refs.push((p.ball, t, p.q.clone()));
        }
        let to_rad = 1.0 / comp.chain.units.to_file(crate::model::Quantity::Angle);
        let run = CompensateJob::for_targets(comp, targets)?.compensate(monitor)?;
        let joints = &run.result.joints;
        let mut out = VerifyPlan::default();
        for (i, (ball, t, q0)) in refs.into_iter().enumerate() {
            let rows = [2 * i, 2 * i + 1];
            let bad = rows
                .iter()
                .find_map(|&k| (run.result.rows[k].status != Status::Reached).then_some(k));
            if let Some(k) = bad {
                out.dropped.push(format!(
                    "pose {} (ball {}): compensated model: {}",
                    i + 1,
                    ball + 1,
                    run.result.rows[k].reason
                ));
                continue;
            }
            let comp_q = rows.map(|k| joints.rows[k][..6].iter().map(|v| v * to_rad).collect());
            let nom_q =
                [t, pre_pose(&t, self.approach_mm)].map(|f| nominal_ik(&nom, &opw, &f, &q0));
            let [Some(a), Some(b)] = nom_q else {
                out.dropped.push(format!(
                    "pose {} (ball {}): the nominal model has no solution inside the joint limits",
                    i + 1,
                    ball + 1
                ));
                continue;
            };
            out.poses.push(VerifyPose {
                ball,
                target: t,
                nominal: [a, b],
                compensated: comp_q,
            });
        }
        if out.poses.is_empty() {
            return Err(JobError::Failed(format!(
                "no verification pose can be commanded: {}",
                out.dropped.join("; ")
            )));
        }
        Ok(out)
    }
}

impl Kind for VerifyJob {
    fn resumable(&self) -> bool {
        true
    }

    fn devices(&self) -> Vec<String> {
        trical_devices(&self.cell)
    }

    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        Box::pin(crate::campaigns::verify::campaign(self, cx))
    }
}
