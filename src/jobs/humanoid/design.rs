//! `humanoid.design`: optimal calibration postures for a marker layout. The base parameters
//! come from a pivoted QR over a pool of random feasible postures; then NOCP (plateau rule)
//! or, with `n`, COCP from `n` random feasible postures. The postures are ordered to keep
//! joint travel short and joined by quintic segments. Optionally compared with DETMAX over a
//! random feasible pool and with COCP from random starts (the paper's Fig. 6).

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{BaseSpec, ElasticSpec, LoadedModel, MarkerSpec, load_model_text};
use crate::design::humanoid::{Comparison, ConstraintOptions, HumanoidPostures, compare_baselines};
use crate::design::ocp::{NocpOptions, OptimOptions, cocp, nocp};
use crate::design::playback::{order_postures, sample_trajectory, travel};
use crate::design::postures::PostureSet;
use crate::measure::marker_fit::Groups;
use crate::model::srdf::disabled_collisions;
use crate::run::Run;
use crate::run::{Artefact, Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::{Monitor, Rng, SubMonitor};

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::urdf")]
    urdf: Value,
    root_link: String,
    joints: Vec<String>,
    #[serde(default)]
    markers: Vec<MarkerSpec>,
    #[serde(default)]
    clusters: Vec<ClusterSpec>,
    #[serde(default)]
    base: BaseSpec,
    #[serde(default)]
    constraints: ConstraintSpec,
    #[serde(default)]
    seed: u64,
    #[serde(default)]
    n: Option<usize>,
    #[serde(default)]
    options: DesignOptions,
}

/// `clusters`: three markers on a triangle of `radius_m` around `centre` (link frame, m),
/// named `<link>_1`, `<link>_2`, `<link>_3`.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct ClusterSpec {
    link: String,
    centre: [f64; 3],
    #[serde(default = "default_radius")]
    radius_m: f64,
}

fn default_radius() -> f64 {
    0.04
}

/// `constraints` of `humanoid.design` (end-effector box, collision spheres, SRDF,
/// torque and collision checks).
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ConstraintSpec {
    #[serde(default)]
    ee_box: Option<BoxSpec>,
    #[serde(default)]
    sphere_radius_m: Option<f64>,
    /// link -> [[x, y, z, r], ...] (m).
    #[serde(default)]
    spheres: std::collections::BTreeMap<String, Vec<[f64; 4]>>,
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::urdf_opt")]
    srdf: Option<Value>,
    #[serde(default)]
    torque: Option<bool>,
    #[serde(default)]
    collision: Option<bool>,
}

#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct BoxSpec {
    link: String,
    #[serde(default)]
    point: [f64; 3],
    min: [f64; 3],
    max: [f64; 3],
}

/// `options` of `humanoid.design`.
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DesignOptions {
    #[serde(default)]
    block: Option<usize>,
    #[serde(default)]
    epsilon: Option<f64>,
    #[serde(default)]
    max_postures: Option<usize>,
    #[serde(default)]
    base_pool: Option<usize>,
    #[serde(default)]
    rank_tolerance: Option<f64>,
    #[serde(default)]
    optim_iterations: Option<usize>,
    #[serde(default)]
    segment_s: Option<f64>,
    #[serde(default)]
    sample_rate_hz: Option<f64>,
    #[serde(default)]
    elastic: ElasticSpec,
    #[serde(default)]
    compare: Option<CompareSpec>,
}

#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct CompareSpec {
    #[serde(default)]
    detmax_pool: Option<usize>,
    #[serde(default)]
    random_starts: Option<usize>,
}

/// A validated `humanoid.design` job.
#[derive(Debug)]
pub struct DesignJob {
    loaded: LoadedModel,
    postures: HumanoidPostures,
    seed: u64,
    n: Option<usize>,
    nocp: NocpOptions,
    base_pool: usize,
    rank_tolerance: f64,
    segment_s: f64,
    rate_hz: f64,
    compare: Option<(usize, usize)>,
}

fn positive(field: &str, v: Option<f64>, default: f64) -> Result<f64, JobError> {
    match v {
        Some(x) if !(x > 0.0 && x.is_finite()) => {
            Err(JobError::invalid(field, format!("{x} must be positive")))
        }
        Some(x) => Ok(x),
        None => Ok(default),
    }
}

/// Validate a `humanoid.design` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<DesignJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let mut markers = s.markers.clone();
    for c in &s.clusters {
        for m in crate::twin::humanoid::clusters(&[(c.link.as_str(), c.centre)], c.radius_m) {
            markers.push(MarkerSpec {
                name: m.name,
                link: m.link,
                initial: [m.initial.x, m.initial.y, m.initial.z],
            });
        }
    }
    check_markers(&markers)?;
    let urdf = inputs.text("urdf", &s.urdf)?;
    DesignJob::new(
        inputs,
        &urdf,
        &s.root_link,
        &s.joints,
        markers,
        &s.base,
        &s.constraints,
        s.seed,
        s.n,
        &s.options,
    )
}

fn check_markers(markers: &[MarkerSpec]) -> Result<(), JobError> {
    if markers.is_empty() {
        return Err(JobError::invalid("markers", "give `markers` or `clusters`"));
    }
    Ok(())
}

/// Parse a JSON field into a typed spec, naming the offending path under `field`.
fn parse_field<T: serde::de::DeserializeOwned>(field: &str, v: &Value) -> Result<T, JobError> {
    serde_path_to_error::deserialize(v)
        .map_err(|e| JobError::invalid(format!("{field}.{}", e.path()), e.into_inner().to_string()))
}

impl ConstraintSpec {
    /// Parse `constraints` given as JSON (a campaign's), naming the offending field.
    pub fn from_value(v: &Value) -> Result<ConstraintSpec, JobError> {
        parse_field("constraints", v)
    }

    /// Check `srdf` as a campaign takes it: inline SRDF text (the campaign designs its
    /// postures when it runs, where no reference is read), refused when submitted otherwise.
    pub(crate) fn check_srdf_inline(&self, field: &str) -> Result<(), JobError> {
        if let Some(v) = &self.srdf {
            let text = Inputs::new(&crate::run::NoReferences).text(field, v)?;
            disabled_collisions(&text)?;
        }
        Ok(())
    }
}

/// Schema of a campaign's `constraints.srdf`: inline SRDF text only (see
/// [`ConstraintSpec::check_srdf_inline`]).
pub(crate) fn inline_srdf_schema() -> Value {
    serde_json::json!({"anyOf": [
        {"type": "string", "pattern": "^\\s*<", "description": "SRDF text inline"},
        {"type": "null"},
    ]})
}

impl DesignOptions {
    /// Parse `options` given as JSON (a campaign's), naming the offending field.
    pub fn from_value(v: &Value) -> Result<DesignOptions, JobError> {
        parse_field("options", v)
    }
}

impl DesignJob {
    /// A `humanoid.design` job from typed inputs (the mocap campaign's entry point; the
    /// JSON path calls it too): URDF text, root link, joints, markers, base mode,
    /// constraints, seed, `n` (COCP) or none (NOCP), options. `inputs` resolves a file
    /// reference in `constraints.srdf` (`Inputs::new(&NoReferences)` for inline SRDF).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        inputs: &Inputs<'_>,
        urdf: &str,
        root_link: &str,
        joints: &[String],
        markers: Vec<MarkerSpec>,
        base: &BaseSpec,
        constraints: &ConstraintSpec,
        seed: u64,
        n: Option<usize>,
        options: &DesignOptions,
    ) -> Result<DesignJob, JobError> {
        check_markers(&markers)?;
        let loaded = load_model_text(urdf, root_link, joints, &markers, base, &options.elastic)?;
        let c = constraints;
        let mut opts = ConstraintOptions {
            sphere_radius: positive("constraints.sphere_radius_m", c.sphere_radius_m, 0.05)?,
            torque: c.torque.unwrap_or(true),
            collision: c.collision.unwrap_or(true),
            ..Default::default()
        };
        for (link, list) in &c.spheres {
            for (i, v) in list.iter().enumerate() {
                if !(v[3] > 0.0) || v.iter().any(|x| !x.is_finite()) {
                    return Err(JobError::invalid(
                        format!("constraints.spheres.{link}[{i}]"),
                        "needs [x, y, z, r] with r > 0 (m)",
                    ));
                }
                opts.spheres
                    .push((link.clone(), [v[0], v[1], v[2]].into(), v[3]));
            }
        }
        if let Some(srdf) = &c.srdf {
            let text = inputs.text("constraints.srdf", srdf)?;
            opts.disabled = disabled_collisions(&text)?;
        }
        if let Some(b) = &c.ee_box {
            if (0..3).any(|k| !(b.min[k] < b.max[k])) {
                return Err(JobError::invalid(
                    "constraints.ee_box",
                    "needs min < max on every axis (m)",
                ));
            }
            opts.ee_box = Some((b.link.clone(), b.point.into(), b.min.into(), b.max.into()));
        }
        let free = Groups::ALL.select(&loaded.model);
        let postures = HumanoidPostures::new(&loaded.urdf, loaded.model.clone(), free, &opts)?;
        let o = options;
        let d = NocpOptions::default();
        let nocp = NocpOptions {
            block: o.block.unwrap_or(d.block).max(1),
            epsilon: positive("options.epsilon", o.epsilon, d.epsilon)?,
            max_postures: o.max_postures.unwrap_or(d.max_postures),
            seed,
            optim: OptimOptions {
                iterations: o
                    .optim_iterations
                    .unwrap_or(OptimOptions::default().iterations),
                ..Default::default()
            },
            tries: d.tries,
        };
        if let Some(n) = n
            && n == 0
        {
            return Err(JobError::invalid("n", "must be at least 1"));
        }
        Ok(DesignJob {
            loaded,
            postures,
            seed,
            n,
            nocp,
            base_pool: o.base_pool.unwrap_or(1000).max(1),
            rank_tolerance: positive("options.rank_tolerance", o.rank_tolerance, 1e-8)?,
            segment_s: positive("options.segment_s", o.segment_s, 5.0)?,
            rate_hz: positive("options.sample_rate_hz", o.sample_rate_hz, 10.0)?,
            compare: o
                .compare
                .as_ref()
                .map(|c| (c.detmax_pool.unwrap_or(500), c.random_starts.unwrap_or(3))),
        })
    }
}

/// One step of the O1 history (`o1_start` only for COCP).
#[derive(Debug, Clone, Serialize)]
pub struct O1Step {
    /// Postures in the set.
    pub postures: usize,
    /// O1 of the set.
    pub o1: f64,
    /// O1 of the random start (COCP).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub o1_start: Option<f64>,
}

/// `trajectory` of `humanoid.design`: the quintic playback of the ordered postures.
#[derive(Debug, Clone, Serialize)]
pub struct PostureTrajectory {
    /// Duration of one segment (s).
    pub segment_s: f64,
    /// Total duration (s).
    pub duration_s: f64,
    /// Joint travel in the chosen order (rad).
    pub travel_rad: f64,
    /// Joint travel in the design's order (rad).
    pub travel_unordered_rad: f64,
    /// Sampling rate of `trajectory.csv` (Hz).
    pub sample_rate_hz: f64,
}

/// The result of `humanoid.design`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct HumanoidDesign {
    /// The ordered postures (`posture` 1-based, then the joints in rad; the main table).
    #[serde(serialize_with = "crate::report::json_rows")]
    pub postures: Table,
    /// Number of postures.
    pub posture_count: usize,
    /// O1 of the set.
    pub o1: f64,
    /// O1 per step: per NOCP block of postures, or (COCP) one step for the whole set.
    pub o1_history: Vec<O1Step>,
    /// COCP only: O1 at the random start and after each re-optimised posture (the last
    /// is `o1`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cocp_o1_history: Option<Vec<f64>>,
    /// Whether NOCP stopped on the plateau rule.
    pub plateau: bool,
    /// `nocp plateau` or `cocp with n postures`.
    pub rule: &'static str,
    /// Base parameters.
    pub base_parameter_count: usize,
    /// Their names.
    pub base_parameters: Vec<String>,
    /// Parameters no posture set can identify.
    pub unidentifiable: Vec<String>,
    /// Size of the base-parameter pool.
    pub base_pool: usize,
    /// Playback.
    pub trajectory: PostureTrajectory,
    /// Collision sphere pairs checked.
    pub collision_sphere_pairs: usize,
    /// DETMAX and random-start baselines (when asked).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub comparison: Option<Comparison>,
}

fn no_room(what: &str) -> JobError {
    JobError::Failed(format!(
        "no feasible posture found for {what}: the constraints (limits, torques, box, collisions) leave no room"
    ))
}

impl DesignJob {
    /// Draw the postures only within `limits` (rad, one per measured joint, in their order):
    /// a cell's envelope narrowing the URDF's limits. The intersection is used; a joint whose
    /// envelope does not overlap the URDF's range is refused, named.
    pub fn narrow_limits(&mut self, limits: &[[f64; 2]]) -> Result<(), JobError> {
        let names = self.loaded.model.variables.clone();
        let own = &mut self.postures.constraints.limits;
        if limits.len() != own.len() {
            return Err(JobError::invalid(
                "cell",
                format!(
                    "{} joint limits for {} measured joints",
                    limits.len(),
                    own.len()
                ),
            ));
        }
        for (k, (l, n)) in own.iter_mut().zip(limits).enumerate() {
            let (lo, hi) = (l[0].max(n[0]), l[1].min(n[1]));
            if !(lo <= hi) {
                return Err(JobError::invalid(
                    "cell",
                    format!(
                        "joint `{}`: the cell's limits [{:.3}, {:.3}] rad leave nothing of the model's [{:.3}, {:.3}] rad",
                        names.get(k).map_or("?", String::as_str),
                        n[0],
                        n[1],
                        l[0],
                        l[1]
                    ),
                ));
            }
            *l = [lo, hi];
        }
        Ok(())
    }

    /// Design the postures: the typed result (the postures are also the main table) and
    /// `trajectory.csv`.
    pub fn design(&self, monitor: &dyn Monitor) -> Result<Run<HumanoidDesign>, JobError> {
        let mut pm = self.postures.clone();
        let mut rng = Rng::new(self.seed);
        monitor.progress(0.0, "feasible pool");
        let pool = pm
            .random_postures(self.base_pool, &mut rng, 20_000)
            .ok_or_else(|| no_room("the base-parameter pool"))?;
        let rank = pm.select_base(
            &pool,
            self.rank_tolerance,
            &SubMonitor::new(monitor, 0.05, 0.1),
        )?;
        let names = |cols: &[usize]| -> Vec<String> {
            cols.iter()
                .map(|&g| pm.model.param_name(pm.model.params[g]))
                .collect()
        };
        let all_free = Groups::ALL.select(&pm.model);
        let unidentifiable: Vec<String> = names(
            &rank
                .dropped
                .iter()
                .map(|&k| all_free[k])
                .collect::<Vec<_>>(),
        );
        let main = SubMonitor::new(
            monitor,
            0.1,
            if self.compare.is_some() { 0.6 } else { 0.95 },
        );
        let mut cocp_history = None;
        let (set, history, plateau) = match self.n {
            Some(n) => {
                let start = pm
                    .random_postures(n, &mut rng, 20_000)
                    .ok_or_else(|| no_room("the start"))?;
                let mut set = PostureSet::from_postures(&pm, start);
                let rep = cocp(&pm, &mut set, &self.nocp.optim, 4 * n, &main)?;
                cocp_history = Some(rep.history.clone());
                (
                    set,
                    vec![O1Step {
                        postures: n,
                        o1: rep.o1,
                        o1_start: Some(rep.o1_start),
                    }],
                    false,
                )
            }
            None => {
                let r = nocp(&pm, &self.nocp, &main)?;
                let h = r
                    .history
                    .iter()
                    .map(|s| O1Step {
                        postures: s.postures,
                        o1: s.o1,
                        o1_start: None,
                    })
                    .collect();
                (r.set, h, r.plateau)
            }
        };
        let count = set.len();
        let order = order_postures(&set.postures, None);
        let identity: Vec<usize> = (0..count).collect();
        let ordered: Vec<Vec<f64>> = order.iter().map(|&i| set.postures[i].clone()).collect();
        let mut cols: Vec<&str> = vec!["posture"];
        cols.extend(self.loaded.model.variables.iter().map(String::as_str));
        let mut table = Table::new(&cols);
        for (k, q) in ordered.iter().enumerate() {
            let mut row = vec![(k + 1) as f64];
            row.extend(q);
            table.push(row);
        }
        let mut tcols: Vec<&str> = vec!["t"];
        tcols.extend(self.loaded.model.variables.iter().map(String::as_str));
        let mut traj = Table::new(&tcols);
        for (t, q) in sample_trajectory(&ordered, self.segment_s, 1.0 / self.rate_hz) {
            let mut row = vec![t];
            row.extend(q);
            traj.push(row);
        }
        let comparison = match self.compare {
            Some((pool_n, starts)) => {
                let sub = SubMonitor::new(monitor, 0.6, 0.95);
                Some(
                    compare_baselines(
                        &pm,
                        &set,
                        pool_n,
                        starts,
                        self.seed,
                        &self.nocp.optim,
                        &sub,
                    )?
                    .ok_or_else(|| no_room("the comparison pools"))?,
                )
            }
            None => None,
        };
        let result = HumanoidDesign {
            postures: table.clone(),
            posture_count: count,
            o1: set.o1(),
            o1_history: history,
            cocp_o1_history: cocp_history,
            plateau,
            rule: match self.n {
                Some(_) => "cocp with n postures",
                None => "nocp plateau",
            },
            base_parameter_count: pm.cols.len(),
            base_parameters: names(&pm.cols),
            unidentifiable,
            base_pool: self.base_pool,
            trajectory: PostureTrajectory {
                segment_s: self.segment_s,
                duration_s: self.segment_s * count.saturating_sub(1) as f64,
                travel_rad: travel(&set.postures, &order, None),
                travel_unordered_rad: travel(&set.postures, &identity, None),
                sample_rate_hz: self.rate_hz,
            },
            collision_sphere_pairs: pm.constraints.pairs.len(),
            comparison,
        };
        let plot = super::plots::design_history(&result);
        Ok(Run {
            result,
            main_table: Some(table),
            artefacts: vec![
                Artefact {
                    name: "trajectory.csv".into(),
                    media_type: "text/csv".into(),
                    content: traj.to_csv().into_bytes(),
                },
                plot,
            ],
        })
    }
}

impl Kind for DesignJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::design)
    }
}
