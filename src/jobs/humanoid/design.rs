//! `humanoid.design`: optimal calibration postures for a marker layout. The base parameters
//! come from a pivoted QR over a pool of random feasible postures; then NOCP (plateau rule)
//! or, with `n`, COCP from `n` random feasible postures. The postures are ordered to keep
//! joint travel short and joined by quintic segments. Optionally compared with DETMAX over a
//! random feasible pool and with COCP from random starts (the paper's Fig. 6).

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::{BaseSpec, ElasticSpec, LoadedModel, MarkerSpec, load_model};
use crate::design::humanoid::{ConstraintOptions, HumanoidPostures, compare_baselines};
use crate::design::ocp::{NocpOptions, OptimOptions, cocp, nocp};
use crate::design::playback::{order_postures, sample_trajectory, travel};
use crate::design::postures::PostureSet;
use crate::jobs::{
    Artefact, Cx, Inputs, JobError, Kind, Output, RunFuture, Table, computed, parse_spec,
};
use crate::measure::marker_fit::Groups;
use crate::model::srdf::disabled_collisions;
use crate::util::{Monitor, Rng, SubMonitor};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
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
#[derive(Debug, Deserialize)]
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

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ConstraintSpec {
    #[serde(default)]
    ee_box: Option<BoxSpec>,
    #[serde(default)]
    sphere_radius_m: Option<f64>,
    /// link -> [[x, y, z, r], ...] (m).
    #[serde(default)]
    spheres: std::collections::BTreeMap<String, Vec<[f64; 4]>>,
    #[serde(default)]
    srdf: Option<Value>,
    #[serde(default)]
    torque: Option<bool>,
    #[serde(default)]
    collision: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoxSpec {
    link: String,
    #[serde(default)]
    point: [f64; 3],
    min: [f64; 3],
    max: [f64; 3],
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct DesignOptions {
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

#[derive(Debug, Deserialize)]
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
    if markers.is_empty() {
        return Err(JobError::invalid("markers", "give `markers` or `clusters`"));
    }
    let loaded = load_model(
        inputs,
        &s.urdf,
        &s.root_link,
        &s.joints,
        &markers,
        &s.base,
        &s.options.elastic,
    )?;
    let c = &s.constraints;
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
    let o = &s.options;
    let d = NocpOptions::default();
    let nocp = NocpOptions {
        block: o.block.unwrap_or(d.block).max(1),
        epsilon: positive("options.epsilon", o.epsilon, d.epsilon)?,
        max_postures: o.max_postures.unwrap_or(d.max_postures),
        seed: s.seed,
        optim: OptimOptions {
            iterations: o
                .optim_iterations
                .unwrap_or(OptimOptions::default().iterations),
            ..Default::default()
        },
        tries: d.tries,
    };
    if let Some(n) = s.n {
        if n == 0 {
            return Err(JobError::invalid("n", "must be at least 1"));
        }
    }
    Ok(DesignJob {
        loaded,
        postures,
        seed: s.seed,
        n: s.n,
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

fn no_room(what: &str) -> JobError {
    JobError::Failed(format!(
        "no feasible posture found for {what}: the constraints (limits, torques, box, collisions) leave no room"
    ))
}

impl Kind for DesignJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::execute)
    }
}

impl DesignJob {
    /// Compute the job's output (on the blocking pool, see [`Kind::run`]).
    pub fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
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
        let (set, history, plateau) = match self.n {
            Some(n) => {
                let start = pm
                    .random_postures(n, &mut rng, 20_000)
                    .ok_or_else(|| no_room("the start"))?;
                let mut set = PostureSet::from_postures(&pm, start);
                let rep = cocp(&pm, &mut set, &self.nocp.optim, 4 * n, &main)?;
                (
                    set,
                    vec![json!({"postures": n, "o1": rep.o1, "o1_start": rep.o1_start})],
                    false,
                )
            }
            None => {
                let r = nocp(&pm, &self.nocp, &main)?;
                let h = r
                    .history
                    .iter()
                    .map(|s| json!({"postures": s.postures, "o1": s.o1}))
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
        let mut f = Map::new();
        f.insert("postures".into(), table.to_json_rows());
        f.insert("posture_count".into(), json!(count));
        f.insert("o1".into(), json!(set.o1()));
        f.insert("o1_history".into(), json!(history));
        f.insert("plateau".into(), json!(plateau));
        f.insert(
            "rule".into(),
            json!(match self.n {
                Some(_) => "cocp with n postures",
                None => "nocp plateau",
            }),
        );
        f.insert("base_parameter_count".into(), json!(pm.cols.len()));
        f.insert("base_parameters".into(), json!(names(&pm.cols)));
        f.insert("unidentifiable".into(), json!(unidentifiable));
        f.insert("base_pool".into(), json!(self.base_pool));
        f.insert(
            "trajectory".into(),
            json!({
                "segment_s": self.segment_s, "duration_s": self.segment_s * count.saturating_sub(1) as f64,
                "travel_rad": travel(&set.postures, &order, None),
                "travel_unordered_rad": travel(&set.postures, &identity, None),
                "sample_rate_hz": self.rate_hz,
            }),
        );
        f.insert(
            "collision_sphere_pairs".into(),
            json!(pm.constraints.pairs.len()),
        );
        if let Some((pool_n, starts)) = self.compare {
            let sub = SubMonitor::new(monitor, 0.6, 0.95);
            let c =
                compare_baselines(&pm, &set, pool_n, starts, self.seed, &self.nocp.optim, &sub)?
                    .ok_or_else(|| no_room("the comparison pools"))?;
            f.insert(
                "comparison".into(),
                serde_json::to_value(&c).unwrap_or(Value::Null),
            );
        }
        Ok(Output {
            fields: f,
            main_table: Some(table),
            artefacts: vec![Artefact {
                name: "trajectory.csv".into(),
                media_type: "text/csv".into(),
                content: traj.to_csv().into_bytes(),
            }],
        })
    }
}
