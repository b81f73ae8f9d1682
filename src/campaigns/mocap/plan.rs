//! `cell.mocap_campaign`: play calibration postures (a NOCP design of the cell's marker
//! layout through `humanoid.design`, or a given table) on a motion-capture cell, record and
//! pre-process the marker stream per posture, journal each posture before the next move,
//! then `humanoid.identify` on what was recorded. Resumable: what the journal holds is
//! never measured again.

use std::sync::Arc;
use std::time::Duration;

use serde::Deserialize;
use serde_json::Value;

use crate::campaigns::engine::Retry;
use crate::campaigns::instruments::check_tolerance;
use crate::campaigns::mocap::{PostureSample, RecordOptions};
use crate::campaigns::preflight;
use crate::jobs::humanoid::design::{ConstraintSpec, DesignJob, DesignOptions};
use crate::jobs::humanoid::identify::{HumanoidCalibration, IdentifyJob};
use crate::jobs::humanoid::{BaseSpec, ColumnMap, FitSpec, MarkerSpec, PreprocessSpec};
use crate::lab::{Lab, MocapCell};
use crate::model::humanoid::MarkerDef;
use crate::procedures::Envelope;
use crate::run::Run;
use crate::run::{
    Cx, Inputs, JobError, Kind, NoReferences, Preflight, RunFuture, Table, parse_spec,
};
use crate::util::Monitor;

/// `postures.nocp`: the `humanoid.design` fields that are not the cell's own.
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct NocpSpec {
    #[serde(default)]
    constraints: ConstraintSpec,
    #[serde(default)]
    seed: u64,
    #[serde(default)]
    n: Option<usize>,
    #[serde(default)]
    options: DesignOptions,
}

#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
struct Options {
    settle_s: f64,
    record_s: f64,
    preprocess: Option<PreprocessSpec>,
    retry_attempts: usize,
    retry_backoff_ms: u64,
    identify: FitSpec,
    /// The largest cross-validated held-out marker RMSE the calibrated model may leave
    /// (mm; needs `identify.cross_validation`): the result's and the report's pass/fail.
    pub(crate) tolerance_mm: Option<f64>,
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
            identify: FitSpec::default(),
            tolerance_mm: None,
        }
    }
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    #[schemars(schema_with = "postures_schema")]
    postures: Value,
    #[serde(default)]
    options: Options,
}

/// Schema of `postures`: `{"nocp": {...}}` (designed on the cell's model) or a table.
fn postures_schema(g: &mut schemars::SchemaGenerator) -> schemars::Schema {
    let mut nocp = g.subschema_for::<NocpSpec>();
    if let Some(srdf) = nocp.pointer_mut("/properties/constraints/properties/srdf") {
        *srdf = crate::jobs::humanoid::design::inline_srdf_schema();
    }
    schemars::json_schema!({"anyOf": [
        {"type": "object", "required": ["nocp"], "properties": {"nocp": nocp}},
        crate::run::schema::table(g),
    ]})
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
    pub(crate) cell: String,
    postures: Postures,
    options: Options,
}

/// Validate a `cell.mocap_campaign` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<MocapCampaignJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let postures = match s.postures.get("nocp") {
        Some(v) => {
            let n = serde_path_to_error::deserialize::<_, NocpSpec>(v).map_err(|e| {
                JobError::invalid(
                    format!("postures.nocp.{}", e.path()),
                    e.into_inner().to_string(),
                )
            })?;
            n.constraints
                .check_srdf_inline("postures.nocp.constraints.srdf")?;
            Postures::Nocp(n)
        }
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
        if !(v.is_finite() && (0.0..=60.0).contains(&v)) {
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
    check_tolerance("options.tolerance_mm", o.tolerance_mm, "mm")?;
    Ok(MocapCampaignJob {
        cell: s.cell,
        postures,
        options: s.options,
    })
}

/// What a motion-capture campaign uses of its cell: a snapshot, so that the numerical
/// steps can run on the blocking pool.
#[derive(Debug, Clone)]
pub struct MocapSetup {
    /// The cell's current model (URDF text).
    pub urdf: String,
    /// Root link of the measured chain.
    pub root_link: String,
    /// Measured joints, in the robot interface's order.
    pub joints: Vec<String>,
    /// Joint limits (rad).
    pub limits: Vec<[f64; 2]>,
    /// Markers with their guessed positions.
    pub markers: Vec<MarkerDef>,
}

impl MocapSetup {
    /// The markers as `humanoid.*` jobs take them.
    fn marker_specs(&self) -> Vec<MarkerSpec> {
        self.markers
            .iter()
            .map(|m| MarkerSpec {
                name: m.name.clone(),
                link: m.link.clone(),
                initial: [m.initial.x, m.initial.y, m.initial.z],
            })
            .collect()
    }
}

impl MocapCampaignJob {
    /// The snapshot of `cell` the campaign works with.
    pub(crate) fn setup(&self, cell: &MocapCell) -> MocapSetup {
        MocapSetup {
            urdf: cell.current_model(),
            root_link: cell.root_link.clone(),
            joints: cell.joints.clone(),
            limits: cell.limits.clone(),
            markers: cell.markers.clone(),
        }
    }

    /// Device-fault retries.
    /// The declared tolerance (mm), if any.
    pub(crate) fn tolerance_mm(&self) -> Option<f64> {
        self.options.tolerance_mm
    }

    pub(crate) fn retry(&self) -> Retry {
        Retry {
            attempts: self.options.retry_attempts,
            backoff: Duration::from_millis(self.options.retry_backoff_ms),
        }
    }

    /// `humanoid.identify` on the averaged postures.
    pub(crate) fn identify(
        &self,
        cell: &MocapSetup,
        samples: &Table,
        monitor: &dyn Monitor,
    ) -> Result<Run<HumanoidCalibration>, JobError> {
        let samples = samples.without("posture");
        let job = IdentifyJob::new(
            &cell.urdf,
            &cell.root_link,
            &cell.joints,
            &cell.marker_specs(),
            &BaseSpec::Identify {},
            samples,
            &ColumnMap::new(),
            self.options.identify.clone(),
        )?;
        job.calibrate(monitor)
    }

    /// The postures table (the NOCP design of the cell, or the job's) and its field name.
    fn posture_table(
        &self,
        cell: &MocapSetup,
        monitor: &dyn Monitor,
    ) -> Result<(Table, &'static str), JobError> {
        Ok(match &self.postures {
            Postures::Table(t) => (t.clone(), "postures"),
            Postures::Nocp(n) => {
                let mut job = DesignJob::new(
                    &Inputs::new(&NoReferences),
                    &cell.urdf,
                    &cell.root_link,
                    &cell.joints,
                    cell.marker_specs(),
                    &BaseSpec::Identify {},
                    &n.constraints,
                    n.seed,
                    n.n,
                    &n.options,
                )?;
                // Postures only inside the cell's envelope (its limits narrow the URDF's).
                job.narrow_limits(&cell.limits)?;
                (job.design(monitor)?.result.postures, "postures.nocp")
            }
        })
    }

    /// The postures' joint values (rad, the cell's joint order), unchecked.
    fn posture_rows(
        &self,
        cell: &MocapSetup,
        monitor: &dyn Monitor,
    ) -> Result<(Vec<Vec<f64>>, &'static str), JobError> {
        let (table, field) = self.posture_table(cell, monitor)?;
        let idx = table.cols(field, &cell.joints)?;
        let rows = table
            .rows
            .iter()
            .map(|r| idx.iter().map(|&c| r[c]).collect())
            .collect();
        Ok((rows, field))
    }

    /// The postures (named joint values, rad): the NOCP design of the cell, or the table.
    pub(crate) fn plan(
        &self,
        cell: &MocapSetup,
        monitor: &dyn Monitor,
    ) -> Result<Vec<Vec<(String, f64)>>, JobError> {
        let (rows, field) = self.posture_rows(cell, monitor)?;
        let mut plan = Vec::with_capacity(rows.len());
        for (i, r) in rows.iter().enumerate() {
            let mut p = Vec::with_capacity(r.len());
            for (k, &v) in r.iter().enumerate() {
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

    /// The plan on `cell` before anything moves: every posture and the joint path to it
    /// against the cell's limits, each move split within its joint step, and the estimated
    /// duration (joint travel at the interface's speed, plus settling and recording).
    pub(crate) fn preflight_on(
        &self,
        cell: &MocapCell,
        monitor: &dyn Monitor,
    ) -> Result<Preflight, JobError> {
        let setup = self.setup(cell);
        let (rows, _) = self.posture_rows(&setup, monitor)?;
        let targets: Vec<preflight::Target> = rows
            .into_iter()
            .enumerate()
            .map(|(i, q)| preflight::Target {
                stage: "measurement",
                what: format!("posture {}", i + 1),
                q,
            })
            .collect();
        let envelope = Envelope {
            limits: setup.limits.clone(),
            max_joint_step: cell.max_step_rad,
            max_tool_step_mm: f64::INFINITY,
            workspace_mm: None,
        };
        let (plan, check) = preflight::check(&targets, None, &envelope);
        let travel_rad = preflight::travel(&targets, None);
        let per_posture_s = self.options.settle_s + self.options.record_s;
        Ok(Preflight {
            cell: self.cell.clone(),
            joints: setup.joints,
            plan,
            envelope: check,
            estimated_duration_s: travel_rad / cell.speed_rad_s
                + targets.len() as f64 * per_posture_s,
        })
    }

    pub(crate) fn record_options(&self) -> RecordOptions {
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
pub fn samples_table(cell: &MocapSetup, rec: &[PostureSample]) -> Table {
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

impl Kind for MocapCampaignJob {
    fn resumable(&self) -> bool {
        true
    }

    fn preflight(&self, lab: &Lab, monitor: &dyn Monitor) -> Option<Result<Preflight, JobError>> {
        // A cell of another daemon (a fleet) is checked there, before its first move.
        lab.cell(&self.cell)?;
        Some(
            lab.mocap(&self.cell)
                .map_err(JobError::from)
                .and_then(|cell| self.preflight_on(cell, monitor)),
        )
    }

    fn devices(&self) -> Vec<String> {
        vec![
            format!("{}.joints", self.cell),
            format!("{}.qtm", self.cell),
        ]
    }

    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        Box::pin(crate::campaigns::mocap::campaign(self, cx))
    }
}
