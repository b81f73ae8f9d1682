//! Checks of the humanoid model against independent computations: central differences for
//! every parameter column in each base mode, the potential-energy derivative for the tree
//! torques, and a URDF round trip of calibrated values.

use nalgebra::Vector3;

use super::*;
use crate::geometry::Frame;
use crate::model::urdf::UrdfModel;
use crate::util::Rng;

pub(crate) const TALOS: &str = include_str!("../../../tests/data/robots/talos/talos_reduced.urdf");

fn names(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

fn arm_joints() -> Vec<String> {
    let mut v = names(&["torso_1_joint", "torso_2_joint"]);
    v.extend((1..=7).map(|k| format!("arm_left_{k}_joint")));
    v
}

fn marker(name: &str, link: &str, p: [f64; 3]) -> MarkerDef {
    MarkerDef {
        name: name.into(),
        link: link.into(),
        initial: Vector3::from(p),
    }
}

/// Random values for every parameter so that every column is exercised.
fn perturb(h: &mut Humanoid, rng: &mut Rng) {
    let vals: Vec<f64> = h
        .params
        .iter()
        .zip(h.values())
        .map(|(p, v)| match p {
            HParam::Joint(_, JointField::Compliance) => 1e-3 * rng.uniform(),
            HParam::BaseCompliance(k) if *k < 3 => 1e-5 * rng.uniform(),
            HParam::BaseCompliance(_) => 1e-4 * rng.uniform(),
            HParam::Base(k) if *k >= 3 => v + rng.range(-1.0, 1.0),
            _ => v + 0.01 * rng.range(-1.0, 1.0),
        })
        .collect();
    h.set_all(&vals);
}

fn random_state(h: &Humanoid, rng: &mut Rng, cluster: bool) -> State {
    let q = h
        .limits()
        .iter()
        .map(|l| l.map_or(0.0, |[a, b]| rng.range(a, b)))
        .collect();
    let tau = (0..h.variables.len())
        .map(|_| rng.range(-20.0, 20.0))
        .collect();
    let mut s = State {
        q,
        tau,
        cluster: cluster.then(|| Frame::from_xyzabc(&[0.1, 0.2, 0.9, 0.3, -0.2, 0.1])),
        wrench: [0.0; 6],
    };
    h.fill_wrench(&mut s);
    assert_eq!(s.wrench == [0.0; 6], !h.base_elastic);
    s
}

fn check_columns(h: &Humanoid, s: &State) {
    let mut jac = vec![Vector3::zeros(); h.params.len()];
    let x = h.values();
    for m in 0..h.markers.len() {
        let p = h.marker_jacobian(m, s, &mut jac);
        assert!((p - h.marker_positions(s)[m]).norm() < 1e-12);
        for g in 0..h.params.len() {
            let step = match h.params[g] {
                HParam::Joint(_, JointField::Compliance) | HParam::BaseCompliance(_) => 1e-7,
                _ => 1e-6,
            };
            let mut a = h.clone();
            let mut xa = x.clone();
            xa[g] += step;
            a.set_all(&xa);
            let pa = a.marker_positions(s)[m];
            xa[g] -= 2.0 * step;
            a.set_all(&xa);
            let pb = a.marker_positions(s)[m];
            let fd = (pa - pb) / (2.0 * step);
            let tol = 1e-6 * (1.0 + fd.norm());
            assert!(
                (fd - jac[g]).norm() < tol,
                "marker {m} column {} ({}): fd {fd:?} vs {:?}",
                g,
                h.param_name(h.params[g]),
                jac[g]
            );
        }
    }
}

#[test]
fn jacobian_matches_differences_in_cluster_mode_with_joint_elasticity() {
    let urdf = UrdfModel::parse(TALOS).unwrap();
    let markers = vec![
        marker("a", "arm_left_4_link", [0.02, 0.03, -0.1]),
        marker("b", "arm_left_7_link", [0.0, 0.05, -0.08]),
        marker("h", "head_2_link", [0.05, 0.0, 0.1]),
        marker("w", "base_link", [0.1, 0.0, 0.05]),
    ];
    let mut vars = arm_joints();
    vars.extend(names(&["head_1_joint", "head_2_joint"]));
    let el = Elasticity {
        joints: names(&["torso_2_joint", "arm_left_2_joint"]),
        ..Default::default()
    };
    let mut h = Humanoid::new(&urdf, "base_link", &vars, &markers, BaseMode::Cluster, &el).unwrap();
    // Two leaf chains (arm and head) share the torso joints.
    assert_eq!(h.chains.len(), 2);
    assert_eq!(h.joints.len(), 11);
    let mut rng = Rng::new(1);
    perturb(&mut h, &mut rng);
    let s = random_state(&h, &mut rng, true);
    check_columns(&h, &s);
}

#[test]
fn jacobian_matches_differences_with_support_foot_and_base_elasticity() {
    let urdf = UrdfModel::parse(TALOS).unwrap();
    let mut vars: Vec<String> = (1..=6).map(|k| format!("leg_left_{k}_joint")).collect();
    vars.extend((1..=6).map(|k| format!("leg_right_{k}_joint")));
    let markers = vec![
        marker("t", "leg_left_3_link", [0.05, 0.0, -0.2]),
        marker("f", "leg_left_6_link", [0.05, 0.02, -0.05]),
        marker("w", "base_link", [0.1, 0.05, 0.0]),
        marker("s", "leg_right_4_link", [0.05, 0.0, -0.1]),
    ];
    let el = Elasticity {
        base: true,
        ..Default::default()
    };
    let mode = BaseMode::SupportFoot {
        link: "right_sole_link".into(),
    };
    let mut h = Humanoid::new(&urdf, "base_link", &vars, &markers, mode, &el).unwrap();
    assert!(
        h.params
            .iter()
            .any(|p| matches!(p, HParam::BaseCompliance(5)))
    );
    assert_eq!(
        h.param_name(h.params[h.params.len() - 3 * 4 - 12]),
        "foot.x"
    );
    let mut rng = Rng::new(2);
    perturb(&mut h, &mut rng);
    let s = random_state(&h, &mut rng, false);
    check_columns(&h, &s);
}

#[test]
fn missing_joints_and_links_are_named() {
    let urdf = UrdfModel::parse(TALOS).unwrap();
    let m = vec![marker("b", "arm_left_7_link", [0.0; 3])];
    let e = Humanoid::new(
        &urdf,
        "base_link",
        &arm_joints()[1..],
        &m,
        BaseMode::Identify,
        &Elasticity::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("torso_1_joint"), "{e}");
    let m = vec![marker("b", "no_link", [0.0; 3])];
    let e = Humanoid::new(
        &urdf,
        "base_link",
        &arm_joints(),
        &m,
        BaseMode::Identify,
        &Elasticity::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("no_link"), "{e}");
}

/// Motor torques holding the tree = dV/dq with V = sum m g z (potential energy).
#[test]
fn tree_torques_are_the_potential_energy_gradient() {
    let urdf = UrdfModel::parse(TALOS).unwrap();
    let mut vars = arm_joints();
    vars.extend(names(&[
        "head_1_joint",
        "arm_right_2_joint",
        "arm_right_4_joint",
    ]));
    let tree = MassTree::new(&urdf, "base_link", &vars).unwrap();
    let masses: Vec<(f64, Vector3<f64>)> = tree
        .link_names()
        .iter()
        .map(|n| {
            let l = urdf.robot.links.iter().find(|l| &l.name == n).unwrap();
            (l.inertial.mass.value, Vector3::from(*l.inertial.origin.xyz))
        })
        .collect();
    let energy = |q: &[f64]| -> f64 {
        tree.link_frames(q)
            .iter()
            .zip(&masses)
            .map(|(f, (m, c))| m * crate::model::urdf::G * f.apply(c).z)
            .sum()
    };
    let q = vec![
        0.3, 0.2, -0.5, 0.8, 0.4, -1.2, 0.3, 0.2, 0.1, 0.3, -0.6, -0.9,
    ];
    let tau = tree.static_torques(&q);
    for k in 0..q.len() {
        let (mut a, mut b) = (q.clone(), q.clone());
        a[k] += 1e-6;
        b[k] -= 1e-6;
        let d = (energy(&a) - energy(&b)) / 2e-6;
        assert!(
            (d - tau[k]).abs() < 1e-5 * (1.0 + d.abs()),
            "{k}: {d} vs {}",
            tau[k]
        );
    }
    // The torso pitch carries most of the upper body: tens of N*m when leaning.
    assert!(tau[1].abs() > 10.0, "{}", tau[1]);
}

#[test]
fn calibrated_urdf_reproduces_the_model() {
    let urdf = UrdfModel::parse(TALOS).unwrap();
    let markers = vec![
        marker("a", "arm_left_4_link", [0.02, 0.03, -0.1]),
        marker("b", "arm_left_7_link", [0.0, 0.05, -0.08]),
    ];
    let mut h = Humanoid::new(
        &urdf,
        "base_link",
        &arm_joints(),
        &markers,
        BaseMode::Identify,
        &Elasticity::default(),
    )
    .unwrap();
    let mut rng = Rng::new(3);
    perturb(&mut h, &mut rng);
    let text = urdf.write_calibrated_chains(h.chains()).unwrap();
    let back = UrdfModel::parse(&text).unwrap();
    let mut h2 = Humanoid::new(
        &back,
        "base_link",
        &arm_joints(),
        &markers,
        BaseMode::Identify,
        &Elasticity::default(),
    )
    .unwrap();
    // Only the frames and markers carry over; the joint geometry is now in the URDF.
    let keep: Vec<usize> = (0..h.params.len())
        .filter(|&g| !matches!(h.params[g], HParam::Joint(..)))
        .collect();
    let vals: Vec<f64> = keep.iter().map(|&g| h.value(h.params[g])).collect();
    h2.set_values(&keep, &vals);
    for _ in 0..20 {
        let s = random_state(&h, &mut rng, false);
        let s = State {
            tau: vec![0.0; s.q.len()],
            ..s
        };
        for (a, b) in h.marker_positions(&s).iter().zip(h2.marker_positions(&s)) {
            assert!((a - b).norm() < 1e-9, "{}", (a - b).norm());
        }
    }
}

/// Standing on the right foot: every motor torque (support leg, swing leg, arm) is the
/// derivative of the potential energy with the foot fixed in the world.
#[test]
fn support_torques_are_the_potential_energy_gradient_with_the_foot_fixed() {
    let urdf = UrdfModel::parse(TALOS).unwrap();
    let mut vars: Vec<String> = (1..=6).map(|k| format!("leg_right_{k}_joint")).collect();
    vars.extend(names(&[
        "leg_left_3_joint",
        "leg_left_4_joint",
        "arm_left_2_joint",
        "torso_2_joint",
    ]));
    let tree = MassTree::new(&urdf, "base_link", &vars).unwrap();
    let foot = tree.link_index("right_sole_link").unwrap();
    let masses: Vec<(f64, Vector3<f64>)> = (0..tree.link_names().len())
        .map(|i| tree.link_mass(i))
        .collect();
    let g = crate::model::urdf::G;
    let energy = |q: &[f64]| -> f64 {
        let frames = tree.link_frames(q);
        let root_in_world = frames[foot].inverse();
        frames
            .iter()
            .zip(&masses)
            .map(|(f, (m, c))| m * g * root_in_world.apply(&f.apply(c)).z)
            .sum()
    };
    let q = vec![0.1, -0.1, -0.4, 0.6, -0.3, 0.05, -0.5, 0.9, 0.4, 0.3];
    let frames = tree.link_frames(&q);
    let g_root = frames[foot].r * Vector3::new(0.0, 0.0, -g);
    let (_, tau) = tree.frames_and_torques_with(&q, &g_root, Some(foot));
    for k in 0..q.len() {
        let (mut a, mut b) = (q.clone(), q.clone());
        a[k] += 1e-6;
        b[k] -= 1e-6;
        let d = (energy(&a) - energy(&b)) / 2e-6;
        assert!(
            (d - tau[k]).abs() < 1e-4 * (1.0 + d.abs()),
            "{}: {d} vs {}",
            vars[k],
            tau[k]
        );
    }
    // The support knee carries the body: tens of N*m when bent.
    assert!(tau[3].abs() > 20.0, "{}", tau[3]);
}
