//! `calibd bench humanoid`: identification on the real F1 set, the base-parameter QR of the
//! paper's three cluster layouts at 1000 random feasible configurations (the counts are in
//! the figure names), and NOCP / COCP / DETMAX for the TALOS left arm with 6 clusters.

use std::time::Duration;

use super::{Figure, time};
use crate::design::humanoid::{ConstraintOptions, HumanoidPostures};
use crate::design::ocp::{NocpOptions, OptimOptions, cocp, nocp, o1_of_postures};
use crate::design::postures::PostureSet;
use crate::design::{DetmaxOptions, Pool, PostureModel, detmax};
use crate::jobs::{NoReferences, prepare};
use crate::measure::marker_fit::Groups;
use crate::model::humanoid::{BaseMode, Elasticity, HParam, Humanoid};
use crate::model::srdf::disabled_collisions;
use crate::model::urdf::UrdfModel;
use crate::twin::humanoid::{TALOS_URDF, clusters};
use crate::util::{NoMonitor, Rng};

const F1: &str =
    include_str!("../../tests/data/real/talos_arm_mocap/talos_left_arm_02_10_contact.csv");
const SRDF: &str = include_str!("../../tests/data/robots/talos/talos.srdf");

fn arm_joints(torso: bool) -> Vec<String> {
    let mut v: Vec<String> = if torso {
        vec!["torso_1_joint".into(), "torso_2_joint".into()]
    } else {
        Vec::new()
    };
    v.extend((1..=7).map(|k| format!("arm_left_{k}_joint")));
    v
}

/// The six arm clusters of the Fig. 6 layout.
pub const ARM_CLUSTERS: [(&str, [f64; 3]); 6] = [
    ("arm_left_2_link", [0.05, 0.02, -0.15]),
    ("arm_left_3_link", [0.05, 0.0, -0.10]),
    ("arm_left_4_link", [0.05, 0.0, -0.12]),
    ("arm_left_5_link", [0.05, 0.0, -0.10]),
    ("arm_left_6_link", [0.04, 0.0, -0.03]),
    ("arm_left_7_link", [0.04, 0.0, -0.10]),
];

/// A posture model for a layout (cluster base mode: the waist or torso cluster measures the
/// root), constraints with the SRDF's disabled pairs.
fn layout(root: &str, joints: Vec<String>, links: &[(&str, [f64; 3])]) -> HumanoidPostures {
    let urdf = UrdfModel::parse(TALOS_URDF).expect("embedded URDF");
    let markers = clusters(links, 0.04);
    let model = Humanoid::new(
        &urdf,
        root,
        &joints,
        &markers,
        BaseMode::Cluster,
        &Elasticity::default(),
    )
    .expect("layout builds");
    let opts = ConstraintOptions {
        disabled: disabled_collisions(SRDF).expect("embedded SRDF"),
        ..Default::default()
    };
    HumanoidPostures::new(
        &urdf,
        model.clone(),
        Groups::GEOMETRIC.select(&model),
        &opts,
    )
    .expect("constraints build")
}

/// Base-parameter count (and its split) of a layout at `n` random feasible configurations.
fn base_count(pm: &mut HumanoidPostures, n: usize, seed: u64) -> (usize, usize, usize, usize) {
    let mut rng = Rng::new(seed);
    let qs = pm
        .random_postures(n, &mut rng, 100_000)
        .expect("feasible postures exist");
    pm.select_base(&qs, 1e-8, &NoMonitor)
        .expect("not cancelled");
    let count =
        |f: &dyn Fn(&HParam) -> bool| pm.cols.iter().filter(|&&g| f(&pm.model.params[g])).count();
    (
        pm.cols.len(),
        count(&|p| matches!(p, HParam::Joint(..))),
        count(&|p| matches!(p, HParam::Base(_))),
        count(&|p| matches!(p, HParam::Marker(..))),
    )
}

/// Run the humanoid benchmarks.
pub fn run() -> Vec<Figure> {
    let mut figs = Vec::new();
    let mut sink = 0.0;
    // 1. Identification on F1 (frames-only + full fit), through the job.
    let job = serde_json::json!({
        "kind": "humanoid.identify",
        "urdf": TALOS_URDF,
        "samples": crate::jobs::Table::from_csv("samples", F1).map(|t| t.to_json_rows()).unwrap_or_default(),
        "column_map": {"x1": "hand_x", "y1": "hand_y", "z1": "hand_z"},
        "root_link": "base_link",
        "joints": arm_joints(true),
        "markers": [{"name": "hand", "link": "gripper_left_base_link", "initial": [0, 0, 0]}],
    });
    let prepared = prepare(&job, &NoReferences).expect("F1 job is valid");
    let mut summary = String::new();
    let mut f = time("", 5, 1, Some(Duration::from_secs(1)), || {
        let r = prepared.run(&NoMonitor).expect("F1 calibrates");
        summary = format!(
            "{:.2} -> {:.2} mm, {} parameters",
            r.result["rmse_before_mm"].as_f64().unwrap_or(f64::NAN),
            r.result["rmse_after_mm"].as_f64().unwrap_or(f64::NAN),
            r.result["base_parameter_count"]
        );
    });
    f.name = format!("F1 identification, 61 samples ({summary})");
    figs.push(f);
    // 2. Base parameters at 1000 configurations (structural tolerance 1e-8).
    let legs: Vec<String> = (1..=6).map(|k| format!("leg_left_{k}_joint")).collect();
    let ht: Vec<String> = [
        "torso_1_joint",
        "torso_2_joint",
        "head_1_joint",
        "head_2_joint",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let cases: Vec<(&str, &str, Vec<String>, Vec<(&str, [f64; 3])>, u64)> = vec![
        (
            "leg, 3 clusters (paper 44)",
            "base_link",
            legs,
            vec![
                ("leg_left_3_link", [0.05, 0.0, -0.2]),
                ("leg_left_4_link", [0.05, 0.0, -0.15]),
                ("leg_left_6_link", [0.05, 0.0, -0.05]),
            ],
            1,
        ),
        (
            "head-trunk, 2 clusters (paper 30)",
            "base_link",
            ht,
            vec![
                ("torso_2_link", [0.1, 0.0, 0.2]),
                ("head_2_link", [0.05, 0.0, 0.1]),
            ],
            2,
        ),
        (
            "arm from torso, 6 clusters (paper 74)",
            "torso_2_link",
            arm_joints(false),
            ARM_CLUSTERS.to_vec(),
            3,
        ),
        (
            "arm + torso from waist, 6 clusters",
            "base_link",
            arm_joints(true),
            ARM_CLUSTERS.to_vec(),
            4,
        ),
    ];
    for (name, root, joints, links, seed) in cases {
        let pm = layout(root, joints, &links);
        let mut c = (0, 0, 0, 0);
        let mut f = time("", 1, 1, Some(Duration::from_secs(5)), || {
            c = base_count(&mut pm.clone(), 1000, seed);
        });
        f.name = format!(
            "base-parameter QR, 1000 configs, {name}: {} (joints {}, base {}, markers {})",
            c.0, c.1, c.2, c.3
        );
        figs.push(f);
    }
    // 3. NOCP for the left arm with 6 clusters, and the Fig. 6 baselines.
    let mut pm = layout("torso_2_link", arm_joints(false), &ARM_CLUSTERS);
    base_count(&mut pm, 1000, 5);
    let mut result = None;
    let mut f = time("", 1, 1, Some(Duration::from_secs(60)), || {
        let o = NocpOptions {
            seed: 1,
            ..Default::default()
        };
        result = Some(nocp(&pm, &o, &NoMonitor).expect("not cancelled"));
    });
    let Some(r) = result else { return figs };
    let n = r.set.len();
    let history: Vec<String> = r
        .history
        .iter()
        .map(|s| format!("{}:{:.3}", s.postures, s.o1))
        .collect();
    f.name = format!(
        "NOCP left arm, 6 clusters: {n} postures, O1 {:.4} [{}]",
        r.set.o1(),
        history.join(" ")
    );
    figs.push(f);
    let pool = detmax_pool(&pm);
    let (f, d) = detmax_figure(&pm, &pool, n);
    figs.push(f);
    let mut starts = Vec::new();
    let mut f = time("", 1, 1, Some(Duration::from_secs(60)), || {
        for s in 0..5 {
            let mut rng = Rng::new(200 + s);
            let q = pm
                .random_postures(n, &mut rng, 100_000)
                .expect("feasible postures exist");
            let mut set = PostureSet::from_postures(&pm, q);
            let rep = cocp(&pm, &mut set, &OptimOptions::default(), 4 * n, &NoMonitor)
                .expect("not cancelled");
            starts.push(format!("{:.3}->{:.3}", rep.o1_start, rep.o1));
        }
    });
    f.name = format!("COCP from 5 random starts of {n}: O1 {}", starts.join(" "));
    figs.push(f);
    sink += d;
    std::hint::black_box(sink);
    figs
}

/// The 1,000 random feasible postures DETMAX chooses from (seeded).
fn detmax_pool(pm: &HumanoidPostures) -> Vec<Vec<f64>> {
    let mut rng = Rng::new(99);
    pm.random_postures(1000, &mut rng, 100_000)
        .expect("feasible postures exist")
}

/// DETMAX `n` of the pool for the left arm with 6 clusters: the figure (the pool's
/// Jacobians are part of it) and the O1 of the selection.
fn detmax_figure(pm: &HumanoidPostures, pool: &[Vec<f64>], n: usize) -> (Figure, f64) {
    let mut d = 0.0;
    // The pool takes the blocks as `compare_baselines` gives them.
    let mut f = time("", 3, 1, Some(Duration::from_millis(300)), || {
        let sel = detmax(
            &Pool::from_block_fn(pool.len(), |i| pm.block(&pool[i])),
            &DetmaxOptions {
                n,
                seed: 1,
                max_excursion: 6,
                path: true,
            },
            &NoMonitor,
        )
        .expect("not cancelled");
        let chosen: Vec<Vec<f64>> = sel.selected.iter().map(|&i| pool[i].clone()).collect();
        d = o1_of_postures(pm, &chosen);
    });
    f.name = format!(
        "DETMAX {n} of {} random feasible postures: O1 {d:.4}",
        pool.len()
    );
    (f, d)
}

/// `calibd bench humanoid.detmax`: only the DETMAX figure, 12 of 1,000 postures (the size
/// NOCP reaches on this layout in `calibd bench humanoid`).
pub fn detmax_only() -> Vec<Figure> {
    let mut pm = layout("torso_2_link", arm_joints(false), &ARM_CLUSTERS);
    base_count(&mut pm, 1000, 5);
    let pool = detmax_pool(&pm);
    vec![detmax_figure(&pm, &pool, 12).0]
}
