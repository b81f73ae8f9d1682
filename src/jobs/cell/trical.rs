//! `cell.trical_campaign`: configurations per ball (given, or a DETMAX selection from a pool
//! reaching the balls on the current model), each centred and journalled before the next
//! move; then `serial.identify` on what was recorded and, optionally, a validation pass:
//! held-out configurations centred the same way, whose ball centres the calibrated model
//! must hit. Resumable: what the journal holds is never measured again.

use std::time::Instant;

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::{CentringSpec, RetrySpec, default_cell, trical_cell, trical_devices};
use crate::design::balls::ball_pool;
use crate::jobs::serial::identify::IdentifyOptions;
use crate::jobs::{
    Artefact, Inputs, JobError, NoReferences, Output, Prepared, RunContext, Table, parse_spec,
};
use crate::lab::TricalCell;
use crate::measure::BallPlate;
use crate::model::Chain;
use crate::model::dh::DhFile;
use crate::procedures::trical::{self, CampaignError, Planned, Recorded, Retry};
use crate::procedures::{Journal, MemoryJournal};
use crate::util::{Monitor, SubMonitor};

#[derive(Debug, Clone, Deserialize)]
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

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ValidationSpec {
    per_ball: usize,
    #[serde(default = "validation_seed")]
    seed: u64,
}

fn validation_seed() -> u64 {
    1_000_003
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct Options {
    centring: CentringSpec,
    retry: RetrySpec,
    identify: Option<Value>,
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
    #[serde(default)]
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
    cell: String,
    model: Option<DhFile>,
    /// Given configurations: joints (deg) and 0-based ball.
    configurations: Option<Vec<(Vec<f64>, usize)>>,
    design: Option<DesignSpec>,
    validation: Option<ValidationSpec>,
    options: Options,
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
    if let Some(v) = &s.validation {
        if v.per_ball == 0 {
            return Err(JobError::invalid(
                "validation.per_ball",
                "must be at least 1",
            ));
        }
    }
    s.options.centring.validate("options.centring")?;
    if s.options.retry.attempts == 0 {
        return Err(JobError::invalid(
            "options.retry.attempts",
            "must be at least 1",
        ));
    }
    if let Some(o) = &s.options.identify {
        serde_path_to_error::deserialize::<_, IdentifyOptions>(o).map_err(|e| {
            JobError::invalid(
                format!("options.identify.{}", e.path()),
                e.into_inner().to_string(),
            )
        })?;
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

/// The chain's joint limits (rad).
fn limits(chain: &Chain) -> Vec<[f64; 2]> {
    chain
        .actuated()
        .iter()
        .map(|&j| {
            chain.joints[j]
                .limits
                .unwrap_or([-std::f64::consts::PI, std::f64::consts::PI])
        })
        .collect()
}

/// Configurations reaching each ball centre on `chain`, drawn from the middle 70 % of each
/// joint range and kept away from the wrist singularity (|q5| > 10 deg).
fn pool(chain: &Chain, plate: &BallPlate, per_ball: usize, seed: u64) -> Vec<Planned> {
    let lim = limits(chain);
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
        |q| q.get(4).is_some_and(|v| v.abs() > 10f64.to_radians()),
    )
    .into_iter()
    .map(|(q, ball)| Planned { q, ball })
    .collect()
}

/// Order configurations to keep joint travel short (greedy nearest neighbour in the largest
/// joint change, from the first), deterministic.
fn short_tour(mut rest: Vec<Planned>) -> Vec<Planned> {
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

fn rows(plan: &[Planned]) -> Value {
    Value::Array(
        plan.iter()
            .map(|p| {
                let mut m = Map::new();
                for (k, v) in p.q.iter().enumerate() {
                    m.insert(format!("q{}", k + 1), json!(v.to_degrees()));
                }
                m.insert("ball".into(), json!(p.ball + 1));
                Value::Object(m)
            })
            .collect(),
    )
}

fn ballbar_spec(cell: &TricalCell) -> Value {
    json!({"d12": cell.ballbar[0], "d13": cell.ballbar[1], "d23": cell.ballbar[2]})
}

impl CampaignJob {
    /// The measurement plan: given configurations, or DETMAX on a pool.
    fn plan(
        &self,
        file: &DhFile,
        chain: &Chain,
        cell: &TricalCell,
        plate: &BallPlate,
        monitor: &dyn Monitor,
    ) -> Result<Vec<Planned>, JobError> {
        if let Some(c) = &self.configurations {
            let mut out = Vec::new();
            for (i, (q, ball)) in c.iter().enumerate() {
                let q: Vec<f64> = q.iter().map(|v| v.to_radians()).collect();
                if let Some((j, v, l)) = chain.limit_violation(&q) {
                    return Err(JobError::row(
                        "configurations",
                        i + 1,
                        format!(
                            "q{} = {:.3} deg is outside the joint limits [{:.3}, {:.3}] deg",
                            j + 1,
                            v.to_degrees(),
                            l[0].to_degrees(),
                            l[1].to_degrees()
                        ),
                    ));
                }
                out.push(Planned { q, ball: *ball });
            }
            return Ok(out);
        }
        let Some(d) = &self.design else {
            return Err(JobError::invalid("design", "missing"));
        };
        let candidates = pool(chain, plate, d.pool_per_ball, d.seed);
        let n = d.per_ball * plate.len();
        if candidates.len() < n {
            return Err(JobError::Failed(format!(
                "only {} configurations of the pool reach the balls on the model; {n} are needed",
                candidates.len()
            )));
        }
        let doc = json!({
            "kind": "serial.design",
            "model": serde_json::to_value(file).unwrap_or(Value::Null),
            "pool": rows(&candidates),
            "n": n,
            "ball_plate": ballbar_spec(cell),
            "options": {"seed": d.seed},
        });
        let job = crate::jobs::serial::design::prepare(&doc, &Inputs::new(&NoReferences))?;
        let out = job.execute(monitor)?;
        let selected: Vec<usize> = out
            .fields
            .get("selected")
            .and_then(|v| serde_json::from_value(v.clone()).ok())
            .ok_or_else(|| JobError::Failed("the DETMAX selection returned no indices".into()))?;
        Ok(short_tour(
            selected
                .into_iter()
                .filter_map(|i| candidates.get(i).cloned())
                .collect(),
        ))
    }
}

fn campaign_error(e: CampaignError) -> JobError {
    match e {
        CampaignError::Paused { index, reason } => JobError::Paused { index, reason },
        CampaignError::Cancelled => JobError::Cancelled,
        CampaignError::Journal(m) => JobError::Failed(format!(
            "the measurement journal failed: {m}; nothing more is measured"
        )),
    }
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

impl Prepared for CampaignJob {
    fn execute(&self, _monitor: &dyn Monitor) -> Result<Output, JobError> {
        Err(JobError::NeedsLab {
            kind: "cell.trical_campaign".into(),
        })
    }

    fn resumable(&self) -> bool {
        true
    }

    fn devices(&self) -> Vec<String> {
        trical_devices(&self.cell)
    }

    fn execute_in(&self, ctx: &RunContext<'_>, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let t0 = Instant::now();
        let (cell, rt) = trical_cell(ctx, "cell.trical_campaign", &self.cell)?;
        let file = self.model.clone().unwrap_or_else(|| cell.current_model());
        let chain = file.to_chain()?;
        let plate = BallPlate::from_ballbar(cell.ballbar[0], cell.ballbar[1], cell.ballbar[2])?;
        let copts = self.options.centring.options("options.centring", cell)?;
        let retry = Retry {
            attempts: self.options.retry.attempts,
            backoff: std::time::Duration::from_millis(self.options.retry.backoff_ms),
        };
        let plan = self.plan(
            &file,
            &chain,
            cell,
            &plate,
            &SubMonitor::new(monitor, 0.0, 0.02),
        )?;
        let vplan = match &self.validation {
            Some(v) => short_tour(pool(&chain, &plate, v.per_ball, v.seed)),
            None => Vec::new(),
        };
        let local = MemoryJournal::default();
        let journal: &dyn Journal = ctx.journal.unwrap_or(&local);
        let total = (plan.len() + vplan.len()).max(1) as f64;
        let t_meas = Instant::now();
        let m1 = SubMonitor::new(monitor, 0.02, 0.02 + 0.9 * plan.len() as f64 / total);
        let s1 = rt
            .block_on(trical::run(
                &*cell.robot,
                &*cell.indicators,
                &plan,
                0,
                journal,
                &copts,
                &retry,
                &m1,
            ))
            .map_err(campaign_error)?;
        let m2 = SubMonitor::new(monitor, 0.02 + 0.9 * plan.len() as f64 / total, 0.92);
        let s2 = rt
            .block_on(trical::run(
                &*cell.robot,
                &*cell.indicators,
                &vplan,
                plan.len(),
                journal,
                &copts,
                &retry,
                &m2,
            ))
            .map_err(campaign_error)?;
        let measuring_s = t_meas.elapsed().as_secs_f64();
        let rec = trical::recorded(journal, 0, plan.len())
            .map_err(|m| JobError::Failed(format!("journal: {m}")))?;
        let vrec = trical::recorded(journal, plan.len(), vplan.len())
            .map_err(|m| JobError::Failed(format!("journal: {m}")))?;
        if rec.len() < 10 {
            return Err(JobError::Failed(format!(
                "only {} of {} configurations were centred: too few to identify ({} skipped; see the journal)",
                rec.len(),
                plan.len(),
                s1.skipped
            )));
        }
        let meas: Vec<Planned> = rec
            .iter()
            .map(|r| Planned {
                q: r.q.clone(),
                ball: r.ball,
            })
            .collect();
        let mut doc = json!({
            "kind": "serial.identify",
            "model": serde_json::to_value(&file).unwrap_or(Value::Null),
            "measurements": rows(&meas),
            "ball_plate": ballbar_spec(cell),
        });
        if let Some(o) = &self.options.identify {
            doc["options"] = o.clone();
        }
        if !vrec.is_empty() {
            let v: Vec<Value> = vrec
                .iter()
                .filter_map(|r| {
                    let c = plate.centres.get(r.ball).copied().flatten()?;
                    let mut m = Map::new();
                    for (k, x) in r.q.iter().enumerate() {
                        m.insert(format!("q{}", k + 1), json!(x.to_degrees()));
                    }
                    m.insert("x".into(), json!(c.x));
                    m.insert("y".into(), json!(c.y));
                    m.insert("z".into(), json!(c.z));
                    Some(Value::Object(m))
                })
                .collect();
            doc["validation"] = Value::Array(v);
        }
        let t_id = Instant::now();
        let id = crate::jobs::serial::identify::prepare(&doc, &Inputs::new(&NoReferences))?;
        let mut out = id.execute(&SubMonitor::new(monitor, 0.92, 1.0))?;
        let identify_s = t_id.elapsed().as_secs_f64();
        let measurements = recorded_table(&rec);
        let validation = recorded_table(&vrec);
        out.fields.insert("cell".into(), json!(self.cell));
        out.fields.insert("campaign".into(), json!({
            "planned": plan.len(),
            "recorded": s1.recorded,
            "skipped": s1.skipped,
            "validation_planned": vplan.len(),
            "validation_recorded": s2.recorded,
            "validation_skipped": s2.skipped,
            "mean_moves": rec.iter().map(|r| r.iterations as f64).sum::<f64>() / rec.len() as f64,
            "max_residual_mm": rec.iter().map(|r| r.residual_mm).fold(0.0, f64::max),
            "measuring_s": measuring_s,
            "identify_s": identify_s,
            "wall_time_s": t0.elapsed().as_secs_f64(),
            "journal_entries": journal.entries().map(|e| e.len()).unwrap_or(0),
        }));
        out.fields.insert(
            "start_model".into(),
            serde_json::to_value(&file).unwrap_or(Value::Null),
        );
        out.fields
            .insert("measurements".into(), measurements.to_json_rows());
        out.artefacts.push(Artefact {
            name: "measurements.csv".into(),
            media_type: "text/csv".into(),
            content: measurements.to_csv().into_bytes(),
        });
        if !vrec.is_empty() {
            out.artefacts.push(Artefact {
                name: "validation_measurements.csv".into(),
                media_type: "text/csv".into(),
                content: validation.to_csv().into_bytes(),
            });
        }
        out.main_table = Some(measurements);
        Ok(out)
    }
}
