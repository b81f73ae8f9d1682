//! Structural identifiability of marker layouts on TALOS: the pivoted QR over random feasible
//! configurations finds 4 parameters per revolute joint (its axis line, the offset included)
//! plus 9 per 3-marker cluster (every marker coordinate; the cluster link's placement and the
//! last offset merge into them), with the measurement-frame transform merged into the first
//! joint's placement errors. `calibd bench humanoid` runs the same at 1000 configurations.

use calibd::design::humanoid::{ConstraintOptions, HumanoidPostures};
use calibd::measure::marker_fit::Groups;
use calibd::model::humanoid::{BaseMode, Elasticity, HParam, Humanoid};
use calibd::model::urdf::UrdfModel;
use calibd::twin::humanoid::{TALOS_URDF, clusters};
use calibd::util::{NoMonitor, Rng};

fn count(root: &str, joints: &[&str], links: &[(&str, [f64; 3])], n: usize) -> (usize, usize) {
    let urdf = UrdfModel::parse(TALOS_URDF).unwrap();
    let joints: Vec<String> = joints.iter().map(|s| s.to_string()).collect();
    let markers = clusters(links, 0.04);
    let model = Humanoid::new(
        &urdf,
        root,
        &joints,
        &markers,
        BaseMode::Cluster,
        &Elasticity::default(),
    )
    .unwrap();
    let free = Groups::GEOMETRIC.select(&model);
    let mut pm =
        HumanoidPostures::new(&urdf, model.clone(), free, &ConstraintOptions::default()).unwrap();
    let qs = pm.random_postures(n, &mut Rng::new(1), 100_000).unwrap();
    pm.select_base(&qs, 1e-8, &NoMonitor).unwrap();
    let base = pm
        .cols
        .iter()
        .filter(|&&g| matches!(model.params[g], HParam::Base(_)))
        .count();
    (pm.cols.len(), base)
}

#[test]
fn base_parameters_are_four_per_joint_and_nine_per_cluster() {
    let (ht, base) = count(
        "base_link",
        &[
            "torso_1_joint",
            "torso_2_joint",
            "head_1_joint",
            "head_2_joint",
        ],
        &[
            ("torso_2_link", [0.1, 0.0, 0.2]),
            ("head_2_link", [0.05, 0.0, 0.1]),
        ],
        60,
    );
    assert_eq!((ht, base), (4 * 4 + 9 * 2, 0));
    let arm: Vec<String> = (1..=7).map(|k| format!("arm_left_{k}_joint")).collect();
    let arm: Vec<&str> = arm.iter().map(String::as_str).collect();
    let (n, _) = count(
        "torso_2_link",
        &arm,
        &[
            ("arm_left_2_link", [0.05, 0.02, -0.15]),
            ("arm_left_3_link", [0.05, 0.0, -0.10]),
            ("arm_left_4_link", [0.05, 0.0, -0.12]),
            ("arm_left_5_link", [0.05, 0.0, -0.10]),
            ("arm_left_6_link", [0.04, 0.0, -0.03]),
            ("arm_left_7_link", [0.04, 0.0, -0.10]),
        ],
        40,
    );
    assert_eq!(n, 4 * 7 + 9 * 6);
}
