//! `cell.mocap_campaign`: play calibration postures (a NOCP design of the cell's marker
//! layout through `humanoid.design`, or a given table) on a motion-capture cell, record and
//! pre-process the marker stream per posture, journal each posture before the next move,
//! then `humanoid.identify` on what was recorded. Resumable: what the journal holds is
//! never measured again.

use std::time::{Duration, Instant};

use serde::Deserialize;
use serde_json::{Map, Value, json};

use crate::jobs::humanoid::PreprocessSpec;
use crate::jobs::{
    Artefact, Inputs, JobError, NoReferences, Output, Prepared, RunContext, Table, parse_spec,
};
use crate::lab::MocapCell;
use crate::procedures::mocap::{self, PostureSample, RecordOptions};
use crate::procedures::trical::{CampaignError, Retry};
use crate::procedures::{Journal, MemoryJournal};
use crate::util::{Monitor, SubMonitor};

const KIND: &str = "cell.mocap_campaign";

/// `postures.nocp`: the `humanoid.design` fields that are not the cell's own.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct NocpSpec {
    #[serde(default)]
    constraints: Option<Value>,
    #[serde(default)]
    seed: u64,
    #[serde(default)]
    n: Option<usize>,
    #[serde(default)]
    options: Option<Value>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct Options {
    settle_s: f64,
    record_s: f64,
    preprocess: Option<PreprocessSpec>,
    retry_attempts: usize,
    retry_backoff_ms: u64,
    identify: Option<Value>,
}

impl Default for Options {
    fn default() -> Self {
        let r = Retry::default();
        Self {
            settle_s: 0.2,
            record_s: 1.0,
            preprocess: None,
            retry_attempts: r.attempts,
            retry_backoff_ms: r.backoff.as_millis() as u64,
            identify: None,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    postures: Value,
    #[serde(default)]
    options: Options,
}

fn default_cell() -> String {
    "talos".into()
}

/// Where the postures come from.
#[derive(Debug)]
enum Postures {
    Nocp(NocpSpec),
    Table(Table),
}

/// A validated `cell.mocap_campaign` job.
#[derive(Debug)]
pub struct MocapCampaignJob {
    cell: String,
    postures: Postures,
    options: Options,
}

/// Validate a `cell.mocap_campaign` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<MocapCampaignJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let postures = match s.postures.get("nocp") {
        Some(v) => Postures::Nocp(serde_path_to_error::deserialize::<_, NocpSpec>(v).map_err(
            |e| {
                JobError::invalid(
                    format!("postures.nocp.{}", e.path()),
                    e.into_inner().to_string(),
                )
            },
        )?),
        None => {
            let t = inputs.table("postures", &s.postures)?;
            if t.rows.is_empty() {
                return Err(JobError::invalid("postures", "no posture"));
            }
            Postures::Table(t)
        }
    };
    let o = &s.options;
    for (k, v) in [("settle_s", o.settle_s), ("record_s", o.record_s)] {
        if !(v.is_finite() && v >= 0.0 && v <= 60.0) {
            return Err(JobError::invalid(
                format!("options.{k}"),
                format!("{v} s must be in [0, 60]"),
            ));
        }
    }
    if o.record_s <= 0.0 {
        return Err(JobError::invalid("options.record_s", "must be positive"));
    }
    if o.retry_attempts == 0 {
        return Err(JobError::invalid(
            "options.retry_attempts",
            "must be at least 1",
        ));
    }
    Ok(MocapCampaignJob {
        cell: s.cell,
        postures,
        options: s.options,
    })
}

/// The motion-capture cell `name` of the context's lab.
fn mocap_cell<'a>(
    ctx: &RunContext<'a>,
    name: &str,
) -> Result<(&'a MocapCell, &'a tokio::runtime::Handle), JobError> {
    let (Some(lab), Some(rt)) = (ctx.lab, ctx.runtime) else {
        return Err(JobError::NeedsLab { kind: KIND.into() });
    };
    match &lab.mocap {
        Some(c) if c.name == name => Ok((c, rt)),
        _ => Err(JobError::invalid(
            "cell",
            format!("this lab has no motion-capture cell `{name}`"),
        )),
    }
}

fn markers_json(cell: &MocapCell) -> Value {
    Value::Array(
        cell.markers
            .iter()
            .map(|m| json!({"name": m.name, "link": m.link, "initial": [m.initial.x, m.initial.y, m.initial.z]}))
            .collect(),
    )
}

impl MocapCampaignJob {
    /// The postures (named joint values, rad): the NOCP design of the cell, or the table.
    fn plan(
        &self,
        cell: &MocapCell,
        monitor: &dyn Monitor,
    ) -> Result<Vec<Vec<(String, f64)>>, JobError> {
        let (table, field) = match &self.postures {
            Postures::Table(t) => (t.clone(), "postures"),
            Postures::Nocp(n) => {
                let mut doc = json!({
                    "kind": "humanoid.design",
                    "urdf": cell.urdf,
                    "root_link": cell.root_link,
                    "joints": cell.joints,
                    "markers": markers_json(cell),
                    "base": {"mode": "identify"},
                    "seed": n.seed,
                });
                if let Some(c) = &n.constraints {
                    doc["constraints"] = c.clone();
                }
                if let Some(k) = n.n {
                    doc["n"] = json!(k);
                }
                if let Some(o) = &n.options {
                    doc["options"] = o.clone();
                }
                let job =
                    crate::jobs::humanoid::design::prepare(&doc, &Inputs::new(&NoReferences))?;
                let out = job.execute(monitor)?;
                let t = out.main_table.ok_or_else(|| {
                    JobError::Failed("the NOCP design returned no postures".into())
                })?;
                (t, "postures.nocp")
            }
        };
        let idx = table.cols(field, &cell.joints)?;
        let mut plan = Vec::with_capacity(table.rows.len());
        for (i, r) in table.rows.iter().enumerate() {
            let mut p = Vec::with_capacity(idx.len());
            for (k, &c) in idx.iter().enumerate() {
                let v = r[c];
                let [lo, hi] = cell.limits[k];
                if !(v.is_finite() && v >= lo && v <= hi) {
                    return Err(JobError::row(
                        field,
                        i + 1,
                        format!(
                            "{} = {v} rad is outside the limits [{lo}, {hi}]",
                            cell.joints[k]
                        ),
                    ));
                }
                p.push((cell.joints[k].clone(), v));
            }
            plan.push(p);
        }
        Ok(plan)
    }

    fn record_options(&self) -> RecordOptions {
        RecordOptions {
            settle: Duration::from_secs_f64(self.options.settle_s),
            window: Duration::from_secs_f64(self.options.record_s),
            preprocess: self
                .options
                .preprocess
                .as_ref()
                .map(PreprocessSpec::options)
                .unwrap_or_default(),
        }
    }
}

/// The journalled samples as a `humanoid.identify` samples table (joints, then markers;
/// NaN where a marker had no stable sample).
fn samples_table(cell: &MocapCell, rec: &[PostureSample]) -> Table {
    let mut cols: Vec<String> = vec!["posture".into()];
    cols.extend(cell.joints.iter().cloned());
    for m in &cell.markers {
        cols.extend(["x", "y", "z"].map(|a| format!("{}_{a}", m.name)));
    }
    let refs: Vec<&str> = cols.iter().map(String::as_str).collect();
    let mut t = Table::new(&refs);
    for s in rec {
        let mut row = vec![s.index as f64 + 1.0];
        row.extend(&s.q);
        for m in &cell.markers {
            row.extend(
                s.markers
                    .get(&m.name)
                    .copied()
                    .flatten()
                    .unwrap_or([f64::NAN; 3]),
            );
        }
        t.push(row);
    }
    t
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

impl Prepared for MocapCampaignJob {
    fn execute(&self, _monitor: &dyn Monitor) -> Result<Output, JobError> {
        Err(JobError::NeedsLab { kind: KIND.into() })
    }

    fn resumable(&self) -> bool {
        true
    }

    fn devices(&self) -> Vec<String> {
        vec![
            format!("{}.joints", self.cell),
            format!("{}.qtm", self.cell),
        ]
    }

    fn execute_in(&self, ctx: &RunContext<'_>, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let t0 = Instant::now();
        let (cell, rt) = mocap_cell(ctx, &self.cell)?;
        let plan = self.plan(cell, &SubMonitor::new(monitor, 0.0, 0.05))?;
        let design_s = t0.elapsed().as_secs_f64();
        let local = MemoryJournal::default();
        let journal: &dyn Journal = ctx.journal.unwrap_or(&local);
        let retry = Retry {
            attempts: self.options.retry_attempts,
            backoff: Duration::from_millis(self.options.retry_backoff_ms),
        };
        let t_meas = Instant::now();
        let sum = rt
            .block_on(mocap::run(
                &*cell.robot,
                &*cell.stream,
                &plan,
                journal,
                &self.record_options(),
                &retry,
                &SubMonitor::new(monitor, 0.05, 0.9),
            ))
            .map_err(campaign_error)?;
        let measuring_s = t_meas.elapsed().as_secs_f64();
        let rec = mocap::recorded(journal, plan.len())
            .map_err(|m| JobError::Failed(format!("journal: {m}")))?;
        if rec.len() < 3 {
            return Err(JobError::Failed(format!(
                "only {} of {} postures were recorded: too few to identify ({} skipped; see the journal)",
                rec.len(),
                plan.len(),
                sum.skipped
            )));
        }
        let table = samples_table(cell, &rec);
        let mut samples = table.to_json_rows();
        if let Some(rows) = samples.as_array_mut() {
            for r in rows.iter_mut().filter_map(Value::as_object_mut) {
                r.remove("posture");
            }
        }
        let mut doc = json!({
            "kind": "humanoid.identify",
            "urdf": cell.urdf,
            "samples": samples,
            "root_link": cell.root_link,
            "joints": cell.joints,
            "markers": markers_json(cell),
            "base": {"mode": "identify"},
        });
        if let Some(o) = &self.options.identify {
            doc["options"] = o.clone();
        }
        let t_id = Instant::now();
        let id = crate::jobs::humanoid::identify::prepare(&doc, &Inputs::new(&NoReferences))?;
        let mut out = id.execute(&SubMonitor::new(monitor, 0.9, 1.0))?;
        let identify_s = t_id.elapsed().as_secs_f64();
        let mean = |f: fn(&PostureSample) -> usize| {
            rec.iter().map(|s| f(s) as f64).sum::<f64>() / rec.len() as f64
        };
        out.fields.insert("cell".into(), json!(self.cell));
        let mut c = Map::new();
        for (k, v) in [
            ("planned", json!(plan.len())),
            ("recorded", json!(sum.recorded)),
            ("skipped", json!(sum.skipped)),
            ("mean_frames_per_posture", json!(mean(|s| s.frames))),
            ("mean_stable_samples", json!(mean(|s| s.stable))),
            ("design_s", json!(design_s)),
            ("measuring_s", json!(measuring_s)),
            ("identify_s", json!(identify_s)),
            ("wall_time_s", json!(t0.elapsed().as_secs_f64())),
            (
                "journal_entries",
                json!(journal.entries().map(|e| e.len()).unwrap_or(0)),
            ),
        ] {
            c.insert(k.into(), v);
        }
        out.fields.insert("campaign".into(), Value::Object(c));
        out.fields
            .insert("measurements".into(), table.to_json_rows());
        out.artefacts.push(Artefact {
            name: "measurements.csv".into(),
            media_type: "text/csv".into(),
            content: table.to_csv().into_bytes(),
        });
        out.main_table = Some(table);
        Ok(out)
    }
}
