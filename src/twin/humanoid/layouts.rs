//! Twin layouts: which joints move, where the marker clusters sit, how the base is known,
//! and the samples table of the `humanoid.*` jobs written from twin samples.

use nalgebra::Vector3;

use crate::measure::markers::MarkerSample;
use crate::model::humanoid::{BaseMode, Elasticity, Humanoid, MarkerDef};

/// The waist cluster markers in the root (`base_link`) frame (m).
pub const WAIST_CLUSTER: [[f64; 3]; 3] =
    [[0.12, 0.06, 0.05], [0.12, -0.07, 0.06], [0.02, 0.0, 0.16]];

/// What to simulate.
#[derive(Debug, Clone)]
pub struct TwinSpec {
    /// Root link.
    pub root: String,
    /// Measured joints.
    pub joints: Vec<String>,
    /// Markers with their guessed positions.
    pub markers: Vec<MarkerDef>,
    /// Base mode of the model (cluster: the waist cluster is simulated).
    pub base: BaseMode,
    /// Elasticity of the model to identify (and the true robot's when `elastic_truth`).
    pub elasticity: Elasticity,
    /// Give the true robot its compliances (joint list and base of `elasticity`).
    pub elastic_truth: bool,
    /// Mocap noise, standard deviation per coordinate (m).
    pub noise: f64,
    /// Torque sensor noise, standard deviation (N*m).
    pub torque_noise: f64,
    /// Joint ranges (rad) drawn by [`HumanoidTwin::random_q`] instead of the URDF limits.
    pub ranges: Vec<(String, [f64; 2])>,
}

/// Marker clusters: three markers per link, on a triangle of `radius` around `centre`.
pub fn clusters(links: &[(&str, [f64; 3])], radius: f64) -> Vec<MarkerDef> {
    let mut out = Vec::new();
    for (link, c) in links {
        for k in 0..3 {
            let a = 2.0 * std::f64::consts::PI * k as f64 / 3.0;
            out.push(MarkerDef {
                name: format!("{link}_{}", k + 1),
                link: link.to_string(),
                initial: Vector3::new(c[0] + radius * a.cos(), c[1] + radius * a.sin(), c[2]),
            });
        }
    }
    out
}

/// The torso + left-arm layout used by the twin tests: waist cluster, clusters on the upper
/// arm, forearm and hand.
pub fn left_arm_spec(elastic: bool) -> TwinSpec {
    let mut joints = vec!["torso_1_joint".to_string(), "torso_2_joint".to_string()];
    joints.extend((1..=7).map(|k| format!("arm_left_{k}_joint")));
    let el_joints: Vec<String> = if elastic {
        // Joints whose axes carry gravity load (torso_1 and arm_left_1 turn about near-vertical
        // axes: their gravity torque is close to zero and their compliance unobservable).
        let mut v = vec!["torso_2_joint".to_string()];
        v.extend((2..=4).map(|k| format!("arm_left_{k}_joint")));
        v
    } else {
        Vec::new()
    };
    TwinSpec {
        root: "base_link".into(),
        joints,
        markers: clusters(
            &[
                ("arm_left_2_link", [0.05, 0.02, -0.15]),
                ("arm_left_4_link", [0.05, 0.0, -0.12]),
                ("arm_left_7_link", [0.04, 0.0, -0.10]),
            ],
            0.04,
        ),
        base: BaseMode::Cluster,
        elasticity: Elasticity {
            joints: el_joints,
            ..Default::default()
        },
        elastic_truth: elastic,
        noise: 0.5e-3,
        torque_noise: 0.2,
        ranges: Vec::new(),
    }
}

/// A leg problem: TALOS stands on its right foot (support-foot base mode) and moves its left
/// leg; clusters on the left thigh, shank and foot and on the waist. With `elastic`, the true
/// floating base deflects under the wrench the support leg carries (the paper's TALOS hip
/// flexibility) and the model identifies the base compliance.
pub fn left_leg_support_spec(elastic: bool) -> TwinSpec {
    let mut joints: Vec<String> = (1..=6).map(|k| format!("leg_right_{k}_joint")).collect();
    joints.extend((1..=6).map(|k| format!("leg_left_{k}_joint")));
    let mut markers = clusters(
        &[
            ("leg_left_3_link", [0.06, 0.0, -0.2]),
            ("leg_left_4_link", [0.06, 0.0, -0.15]),
            ("leg_left_6_link", [0.08, 0.0, -0.06]),
        ],
        0.04,
    );
    markers.extend(WAIST_CLUSTER.iter().enumerate().map(|(k, p)| MarkerDef {
        name: format!("waist_{}", k + 1),
        link: "base_link".into(),
        initial: Vector3::from(*p),
    }));
    // Standing: the support leg stays near a flexed stance (the knee never straight, where
    // the leg Jacobian is singular and the torques do not determine the wrench).
    let stance = [
        [-0.2, 0.2],
        [-0.15, 0.15],
        [-0.6, 0.0],
        [0.3, 0.9],
        [-0.5, 0.1],
        [-0.1, 0.1],
    ];
    TwinSpec {
        root: "base_link".into(),
        joints,
        markers,
        base: BaseMode::SupportFoot {
            link: "right_sole_link".into(),
        },
        elasticity: Elasticity {
            base: elastic,
            ..Default::default()
        },
        elastic_truth: elastic,
        noise: 0.5e-3,
        torque_noise: 0.2,
        ranges: (1..=6)
            .map(|k| (format!("leg_right_{k}_joint"), stance[k - 1]))
            .collect(),
    }
}

/// A samples table as column names and rows, in the `humanoid.*` job layout: `t`, the joint
/// columns, `tau_<joint>` for the elastic joints, then `<marker>_x/_y/_z` (NaN = occluded).
pub fn samples_table(
    nominal: &Humanoid,
    t: Option<&[f64]>,
    samples: &[MarkerSample],
) -> (Vec<String>, Vec<Vec<f64>>) {
    let mut cols = Vec::new();
    if t.is_some() {
        cols.push("t".to_string());
    }
    cols.extend(nominal.variables.iter().cloned());
    let taus: Vec<usize> = (0..nominal.variables.len())
        .filter(|&v| {
            nominal
                .joints
                .iter()
                .any(|j| j.elastic && j.name == nominal.variables[v])
                || nominal.support_variables().contains(&nominal.variables[v])
        })
        .collect();
    cols.extend(
        taus.iter()
            .map(|&v| format!("tau_{}", nominal.variables[v])),
    );
    for m in &nominal.markers {
        for a in ["x", "y", "z"] {
            cols.push(format!("{}_{a}", m.name));
        }
    }
    let rows = samples
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let mut r = Vec::with_capacity(cols.len());
            if let Some(t) = t {
                r.push(t[i]);
            }
            r.extend(&s.state.q);
            r.extend(taus.iter().map(|&v| s.state.tau[v]));
            for p in &s.points {
                match p {
                    Some(p) => r.extend([p.x, p.y, p.z]),
                    None => r.extend([f64::NAN; 3]),
                }
            }
            r
        })
        .collect();
    (cols, rows)
}
