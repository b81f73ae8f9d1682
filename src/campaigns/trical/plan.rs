//! `cell.trical_campaign`: configurations per ball (given, or a DETMAX selection from a pool
//! reaching the balls on the current model), each centred and journalled before the next
//! move; then `serial.identify` on what was recorded and, optionally, a validation pass:
//! held-out configurations centred the same way, whose ball centres the calibrated model
//! must hit. Resumable: what the journal holds is never measured again.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::Value;

use crate::campaigns::instruments::check_tolerance;
use crate::campaigns::preflight::{self, check, travel};
use crate::campaigns::spec::{CentringSpec, RetrySpec, default_cell, trical_devices};
use crate::campaigns::trical::{Planned, Recorded};
use crate::design::balls::ball_pool;
use crate::jobs::serial::SerialModel;
use crate::jobs::serial::design::{DesignOptions, select};
use crate::jobs::serial::identify::{IdentifyJob, IdentifyOptions, SerialCalibration};
use crate::lab::{Lab, TricalCell};
use crate::measure::BallPlate;
use crate::measure::point::{PointMeasurement, Target};
use crate::model::Chain;
use crate::model::dh::DhFile;
use crate::procedures::Envelope;
use crate::run::Run;
use crate::run::{Cx, Inputs, JobError, Kind, Preflight, RunFuture, parse_spec};
use crate::util::Monitor;

#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct DesignSpec {
    /// Candidate configurations per ball.
    #[serde(default = "pool_default")]
    pool_per_ball: usize,
    /// Configurations selected per ball (n = per_ball x balls in total).
    per_ball: usize,
    #[serde(default)]
    seed: u64,
}

fn pool_default() -> usize {
    60
}

#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct ValidationSpec {
    per_ball: usize,
    #[serde(default = "validation_seed")]
    seed: u64,
}

fn validation_seed() -> u64 {
    1_000_003
}

#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct Options {
    pub(crate) centring: CentringSpec,
    pub(crate) retry: RetrySpec,
    identify: IdentifyOptions,
    /// The largest held-out position error the calibrated model may leave (mm): the
    /// result's and the report's pass/fail (none declared: no pass/fail).
    pub(crate) tolerance_mm: Option<f64>,
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
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::table_opt")]
    configurations: Option<Value>,
    #[serde(default)]
    design: Option<DesignSpec>,
    #[serde(default)]
    validation: Option<ValidationSpec>,
    #[serde(default)]
    options: Options,
}

/// A validated `cell.trical_campaign` job.
#[derive(Debug)]
pub struct CampaignJob {
    pub(crate) cell: String,
    pub(crate) model: Option<DhFile>,
    /// Given configurations: joints (deg) and 0-based ball.
    configurations: Option<Vec<(Vec<f64>, usize)>>,
    design: Option<DesignSpec>,
    validation: Option<ValidationSpec>,
    pub(crate) options: Options,
}

/// Validate a `cell.trical_campaign` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<CampaignJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let model = match &s.model {
        Some(v) => {
            let j = inputs.json("model", v)?;
            let text = serde_json::to_string(&j).unwrap_or_default();
            let f = DhFile::parse(&text)?;
            f.to_chain()?;
            Some(f)
        }
        None => None,
    };
    let configurations = match &s.configurations {
        Some(v) => {
            let t = inputs.table("configurations", v)?;
            let cols: Vec<String> = (1..=6).map(|k| format!("q{k}")).collect();
            let mut all = cols.clone();
            all.push("ball".into());
            let idx = t.cols("configurations", &all)?;
            let mut out = Vec::new();
            for (i, r) in t.rows.iter().enumerate() {
                let b = r[idx[6]];
                if !(b.fract() == 0.0 && (1.0..=3.0).contains(&b)) {
                    return Err(JobError::row(
                        "configurations",
                        i + 1,
                        format!("ball = {b}: expected 1, 2 or 3"),
                    ));
                }
                out.push((idx[..6].iter().map(|&c| r[c]).collect(), b as usize - 1));
            }
            if out.is_empty() {
                return Err(JobError::invalid("configurations", "no configuration"));
            }
            Some(out)
        }
        None => None,
    };
    match (&configurations, &s.design) {
        (Some(_), Some(_)) => {
            return Err(JobError::invalid(
                "design",
                "give `configurations` or `design`, not both",
            ));
        }
        (None, None) => {
            return Err(JobError::invalid(
                "configurations",
                "give `configurations` (q1..q6 in deg, ball) or `design` ({\"per_ball\": n})",
            ));
        }
        (None, Some(d)) if d.per_ball == 0 || d.pool_per_ball < d.per_ball => {
            return Err(JobError::invalid(
                "design",
                format!(
                    "per_ball = {} must be at least 1 and at most pool_per_ball = {}",
                    d.per_ball, d.pool_per_ball
                ),
            ));
        }
        _ => {}
    }
    if let Some(v) = &s.validation
        && v.per_ball == 0
    {
        return Err(JobError::invalid(
            "validation.per_ball",
            "must be at least 1",
        ));
    }
    s.options.centring.validate("options.centring")?;
    check_tolerance("options.tolerance_mm", s.options.tolerance_mm, "mm")?;
    if s.options.retry.attempts == 0 {
        return Err(JobError::invalid(
            "options.retry.attempts",
            "must be at least 1",
        ));
    }
    Ok(CampaignJob {
        cell: s.cell,
        model,
        configurations,
        design: s.design,
        validation: s.validation,
        options: s.options,
    })
}

/// Configurations reaching each ball centre on `chain`, drawn from the middle 70 % of each
/// joint range of the cell's envelope (its narrowed limits), kept away from the wrist
/// singularity (|q5| > 10 deg) and inside the envelope (the TCP in its workspace box).
pub(crate) fn pool(
    chain: &Chain,
    plate: &BallPlate,
    envelope: &Envelope,
    per_ball: usize,
    seed: u64,
) -> Vec<Planned> {
    let lim = &envelope.limits;
    let centres: Vec<_> = plate.centres.iter().flatten().copied().collect();
    ball_pool(
        chain,
        &centres,
        per_ball,
        seed,
        |rng| {
            lim.iter()
                .map(|l| {
                    let (c, h) = ((l[0] + l[1]) / 2.0, 0.35 * (l[1] - l[0]));
                    rng.range(c - h, c + h)
                })
                .collect()
        },
        |q| q.get(4).is_some_and(|v| v.abs() > 10f64.to_radians()) && envelope.outside(q).is_none(),
    )
    .into_iter()
    .map(|(q, ball)| Planned { q, ball })
    .collect()
}

/// Order configurations to keep joint travel short (greedy nearest neighbour in the largest
/// joint change, from the first), deterministic.
pub(crate) fn short_tour(mut rest: Vec<Planned>) -> Vec<Planned> {
    let mut out = Vec::with_capacity(rest.len());
    if rest.is_empty() {
        return out;
    }
    out.push(rest.remove(0));
    while !rest.is_empty() {
        let last = &out[out.len() - 1].q;
        let d = |p: &Planned| {
            p.q.iter()
                .zip(last)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        };
        let (k, _) = rest
            .iter()
            .enumerate()
            .min_by(|a, b| d(a.1).total_cmp(&d(b.1)))
            .unwrap_or((0, &out[0]));
        out.push(rest.remove(k));
    }
    out
}

impl CampaignJob {
    /// The measurement plan (given configurations, or DETMAX on a pool) and the held-out
    /// validation configurations, each ordered for short joint travel.
    pub(crate) fn plan(
        &self,
        file: &DhFile,
        ballbar: [f64; 3],
        envelope: &Envelope,
        monitor: &dyn Monitor,
    ) -> Result<(Vec<Planned>, Vec<Planned>), JobError> {
        let plate = &BallPlate::from_ballbar(ballbar[0], ballbar[1], ballbar[2])?;
        let chain = file.to_chain()?;
        let vplan = match &self.validation {
            Some(v) => short_tour(pool(&chain, plate, envelope, v.per_ball, v.seed)),
            None => Vec::new(),
        };
        if let Some(c) = &self.configurations {
            // Checked against the cell's envelope with the whole plan (`Kind::preflight`).
            let out = c
                .iter()
                .map(|(q, ball)| Planned {
                    q: q.iter().map(|v| v.to_radians()).collect(),
                    ball: *ball,
                })
                .collect();
            return Ok((out, vplan));
        }
        let Some(d) = &self.design else {
            return Err(JobError::invalid("design", "missing"));
        };
        let candidates = pool(&chain, plate, envelope, d.pool_per_ball, d.seed);
        let n = d.per_ball * plate.len();
        if candidates.len() < n {
            return Err(JobError::CellMismatch {
                what: "model",
                message: format!(
                    "only {} configurations of the pool reach the balls inside the cell's envelope on the model; {n} are needed",
                    candidates.len()
                ),
            });
        }
        let pool = candidates
            .iter()
            .map(|p| ball_point(&p.q, p.ball))
            .collect();
        let options = DesignOptions {
            seed: d.seed,
            ..DesignOptions::default()
        };
        let model = SerialModel::from_dh(file.clone())?;
        let selected = select(model, pool, Some(plate.clone()), n, &options, monitor)?;
        Ok((
            short_tour(
                selected
                    .into_iter()
                    .filter_map(|i| candidates.get(i).cloned())
                    .collect(),
            ),
            vplan,
        ))
    }

    /// `serial.identify` on the centred configurations, validated on the held-out ones.
    pub(crate) fn identify(
        &self,
        file: &DhFile,
        ballbar: [f64; 3],
        rec: &[Recorded],
        vrec: &[Recorded],
        monitor: &dyn Monitor,
    ) -> Result<Run<SerialCalibration>, JobError> {
        let plate = BallPlate::from_ballbar(ballbar[0], ballbar[1], ballbar[2])?;
        let meas = rec.iter().map(|r| ball_point(&r.q, r.ball)).collect();
        let validation: Vec<PointMeasurement> = vrec
            .iter()
            .filter_map(|r| {
                Some(PointMeasurement {
                    q: r.q.clone(),
                    target: Target::Point(plate.centres.get(r.ball).copied().flatten()?),
                })
            })
            .collect();
        let validation = (!validation.is_empty()).then_some(validation);
        let options = self.options.identify.clone();
        IdentifyJob::from_dh(file.clone(), meas, ballbar, validation, options)?.calibrate(monitor)
    }
}

/// A measurement of the centre of ball `ball` (0-based) at joints `q` (rad).
fn ball_point(q: &[f64], ball: usize) -> PointMeasurement {
    PointMeasurement {
        q: q.to_vec(),
        target: Target::Ball(ball),
    }
}

/// Assumed corrective moves of the centring loop per configuration, for the estimate (the
/// simulated cell averages about 3).
const CENTRING_MOVES: f64 = 4.0;

impl CampaignJob {
    /// The plan as targets for the envelope check.
    pub(crate) fn targets(plan: &[Planned], vplan: &[Planned]) -> Vec<preflight::Target> {
        let t = |stage, p: &Planned| preflight::Target {
            stage,
            what: format!("ball {}", p.ball + 1),
            q: p.q.clone(),
        };
        plan.iter()
            .map(|p| t("measurement", p))
            .chain(vplan.iter().map(|p| t("validation", p)))
            .collect()
    }

    /// The plan on `cell`, checked against its envelope from `start` (the robot's joints,
    /// when known), with the estimated duration: the joint travel at the cell's joint speed
    /// plus [`CENTRING_MOVES`] settled corrective moves per configuration.
    pub(crate) fn preflight_on(
        &self,
        cell: &TricalCell,
        plan: &[Planned],
        vplan: &[Planned],
        start: Option<&[f64]>,
    ) -> Result<Preflight, JobError> {
        let copts = self.options.centring.options("options.centring", cell)?;
        let targets = Self::targets(plan, vplan);
        let (steps, envelope) = check(&targets, start, &cell.envelope);
        let travel_deg = travel(&targets, start).to_degrees();
        let centring_s = targets.len() as f64 * CENTRING_MOVES * copts.settle.as_secs_f64();
        Ok(Preflight {
            cell: self.cell.clone(),
            joints: (1..=6).map(|k| format!("q{k}")).collect(),
            plan: steps,
            envelope,
            estimated_duration_s: travel_deg / cell.joint_speed_deg_s + centring_s,
        })
    }

    fn preflight_in(&self, lab: &Lab, monitor: &dyn Monitor) -> Result<Preflight, JobError> {
        let cell = lab.trical(&self.cell)?;
        let file = self.model.clone().unwrap_or_else(|| cell.current_model());
        let (plan, vplan) = self.plan(&file, cell.ballbar, &cell.envelope, monitor)?;
        self.preflight_on(cell, &plan, &vplan, None)
    }
}

impl Kind for CampaignJob {
    fn resumable(&self) -> bool {
        true
    }

    fn preflight(&self, lab: &Lab, monitor: &dyn Monitor) -> Option<Result<Preflight, JobError>> {
        // A cell of another daemon (a fleet) is checked there, before its first move.
        lab.cell(&self.cell)?;
        Some(self.preflight_in(lab, monitor))
    }

    fn devices(&self) -> Vec<String> {
        trical_devices(&self.cell)
    }

    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        Box::pin(crate::campaigns::trical::campaign(self, cx))
    }
}
