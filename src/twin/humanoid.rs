//! Twin of TALOS in a motion-capture room: a "true" robot (the URDF with placement errors and
//! joint offsets, marker positions off their guesses, optional joint and base compliance),
//! gravity torques measured by the joint torque sensors, a waist cluster, and mocap noise.
//!
//! True error sizes (the paper's Table 1 is not available to us; these are typical TALOS
//! magnitudes, documented here): joint offsets and placement angles N(0, 0.005 rad),
//! placement translations N(0, 2 mm), marker positions uniform +-5 mm around their guesses;
//! joint compliances 1e-4..2e-4 rad/(N*m) (stiffness 5,000..10,000 N*m/rad) and a floating
//! base compliance of 5e-6 m/N and 5e-5 rad/(N*m) (2e5 N/m, 2e4 N*m/rad: TALOS's flexible
//! hips) when elastic.

use nalgebra::Vector3;

use crate::geometry::Frame;
use crate::measure::markers::{MarkerSample, fit_cluster};
use crate::model::humanoid::{BaseMode, Elasticity, HParam, Humanoid, MarkerDef, MassTree, State};
use crate::model::urdf::UrdfModel;
use crate::model::{JointField, ModelError};
use crate::util::Rng;

/// The TALOS URDF shipped with calibd (copied from `../shared/data/robots/talos`).
pub const TALOS_URDF: &str = include_str!("../../tests/data/robots/talos/talos_reduced.urdf");

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

/// The twin.
#[derive(Debug, Clone)]
pub struct HumanoidTwin {
    /// The URDF.
    pub urdf: UrdfModel,
    /// The model an identification starts from (nominal, marker guesses).
    pub nominal: Humanoid,
    /// The true robot.
    pub truth: Humanoid,
    /// Whole-tree gravity torques.
    pub tree: MassTree,
    /// What was simulated.
    pub spec: TwinSpec,
}

impl HumanoidTwin {
    /// A twin from a spec with true errors drawn from `seed`.
    pub fn new(spec: TwinSpec, seed: u64) -> Result<Self, ModelError> {
        let urdf = UrdfModel::parse(TALOS_URDF)?;
        let nominal = Humanoid::new(
            &urdf,
            &spec.root,
            &spec.joints,
            &spec.markers,
            spec.base.clone(),
            &spec.elasticity,
        )?;
        let tree = MassTree::new(&urdf, &spec.root, &spec.joints)?;
        let mut rng = Rng::new(seed);
        let mut truth = nominal.clone();
        let vals: Vec<f64> = truth
            .params
            .iter()
            .zip(truth.values())
            .map(|(p, v)| match p {
                HParam::Joint(_, JointField::Err(k)) if *k < 3 => v + 2e-3 * rng.normal(),
                HParam::Joint(_, JointField::Compliance) if spec.elastic_truth => {
                    1e-4 * (1.0 + rng.uniform())
                }
                HParam::Joint(_, JointField::Compliance) => 0.0,
                HParam::Joint(..) => v + 0.005 * rng.normal(),
                HParam::BaseCompliance(k) if spec.elastic_truth => {
                    if *k < 3 {
                        5e-6
                    } else {
                        5e-5
                    }
                }
                HParam::BaseCompliance(_) => 0.0,
                HParam::Marker(..) => v + rng.range(-5e-3, 5e-3),
                HParam::Base(_) => v,
            })
            .collect();
        truth.set_all(&vals);
        // Cluster frame -> root, or the support foot in the room.
        truth.base = match truth.base_mode {
            BaseMode::Cluster => {
                // The cluster frame is the principal-axes frame of the waist markers.
                let local: Vec<Vector3<f64>> =
                    WAIST_CLUSTER.iter().map(|p| Vector3::from(*p)).collect();
                let pts: Vec<Vec<Option<Vector3<f64>>>> =
                    vec![local.iter().map(|p| Some(*p)).collect()];
                let fit = fit_cluster(&pts).ok_or_else(|| {
                    ModelError::Parse("waist cluster markers are collinear".into())
                })?;
                // fit.poses[0] maps the cluster frame to the root frame: base = its inverse.
                fit.poses[0]
                    .map(|f| f.inverse().to_xyzabc())
                    .unwrap_or([0.0; 6])
            }
            _ => [1.0, 0.5, 0.0, 0.3, 0.0, 0.0],
        };
        Ok(Self {
            urdf,
            nominal,
            truth,
            tree,
            spec,
        })
    }

    /// Uniformly random joint values within the limits (or the spec's ranges).
    pub fn random_q(&self, rng: &mut Rng) -> Vec<f64> {
        self.nominal
            .limits()
            .iter()
            .zip(&self.nominal.variables)
            .map(|(l, v)| {
                let r = self
                    .spec
                    .ranges
                    .iter()
                    .find(|r| &r.0 == v)
                    .map(|r| r.1)
                    .or(*l);
                r.map_or(rng.range(-1.0, 1.0), |[a, b]| rng.range(a, b))
            })
            .collect()
    }

    /// Measured torques at `q`: whole-tree gravity torques plus sensor noise. Standing on a
    /// support foot, gravity is taken in the true root frame and the support leg carries the
    /// rest of the robot.
    pub fn torques(&self, q: &[f64], rng: &mut Rng) -> Vec<f64> {
        let exact = match &self.truth.base_mode {
            BaseMode::SupportFoot { link } => {
                let foot = self.tree.link_index(link);
                let frames = self.tree.link_frames(q);
                let f = Frame::from_xyzabc(&self.truth.base);
                let g_foot = f.r.transpose() * Vector3::new(0.0, 0.0, -crate::model::urdf::G);
                let g_root = foot.map_or(g_foot, |i| frames[i].r * g_foot);
                self.tree.frames_and_torques_with(q, &g_root, foot).1
            }
            _ => self.tree.static_torques(q),
        };
        exact
            .into_iter()
            .map(|t| t + self.spec.torque_noise * rng.normal())
            .collect()
    }

    /// Noisy samples at `qs`: the waist sways (a few cm, a few degrees) in cluster mode; the
    /// cluster pose is fitted from its noisy markers; each model marker is measured with
    /// noise. Rows whose waist cluster cannot be fitted do not occur (no occlusions here).
    pub fn samples(&self, qs: &[Vec<f64>], seed: u64) -> Vec<MarkerSample> {
        let mut rng = Rng::new(seed);
        let noise = self.spec.noise;
        let local: Vec<Vector3<f64>> = WAIST_CLUSTER.iter().map(|p| Vector3::from(*p)).collect();
        let shape = fit_cluster(&[local.iter().map(|p| Some(*p)).collect()]);
        qs.iter()
            .map(|q| {
                let tau = self.torques(q, &mut rng);
                let mut state = State {
                    q: q.clone(),
                    tau,
                    cluster: None,
                    wrench: [0.0; 6],
                };
                self.truth.fill_wrench(&mut state);
                if matches!(self.truth.base_mode, BaseMode::Cluster) {
                    // True waist pose in the room, and its cluster as the mocap sees it.
                    let sway = [
                        0.5 + 0.02 * rng.normal(),
                        0.2 + 0.02 * rng.normal(),
                        1.0 + 0.01 * rng.normal(),
                        0.3 + 0.03 * rng.normal(),
                        0.03 * rng.normal(),
                        0.03 * rng.normal(),
                    ];
                    let waist = Frame::from_xyzabc(&sway);
                    let seen: Vec<Option<Vector3<f64>>> = local
                        .iter()
                        .map(|p| Some(waist.apply(p) + self.noise_vec(&mut rng)))
                        .collect();
                    let cluster_local = shape.as_ref().map(|s| s.local.clone()).unwrap_or_default();
                    let fitted = crate::geometry::kabsch(
                        &cluster_local,
                        &seen.iter().flatten().copied().collect::<Vec<_>>(),
                    );
                    // Truth: the waist = C_true * X_true; the model sees C_fitted.
                    let x_true = Frame::from_xyzabc(&self.truth.base);
                    let c_true = waist.mul(&x_true.inverse());
                    let mut st_true = state.clone();
                    st_true.cluster = Some(c_true);
                    let pts = self
                        .truth
                        .marker_positions(&st_true)
                        .into_iter()
                        .map(|p| Some(p + self.noise_vec(&mut rng)))
                        .collect();
                    state.cluster = fitted;
                    return MarkerSample { state, points: pts };
                }
                let points = self
                    .truth
                    .marker_positions(&state)
                    .into_iter()
                    .map(|p| {
                        Some(p + noise * Vector3::new(rng.normal(), rng.normal(), rng.normal()))
                    })
                    .collect();
                MarkerSample { state, points }
            })
            .collect()
    }

    fn noise_vec(&self, rng: &mut Rng) -> Vector3<f64> {
        self.spec.noise * Vector3::new(rng.normal(), rng.normal(), rng.normal())
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

impl HumanoidTwin {
    /// A continuous recording at `rate_hz` (identify base mode: the waist stands still):
    /// each posture held `hold_s`, quintic moves of `move_s` between them, every sample with
    /// mocap noise and its true joint values and torques. Returns time stamps and samples.
    pub fn recording(
        &self,
        postures: &[Vec<f64>],
        hold_s: f64,
        move_s: f64,
        rate_hz: f64,
        seed: u64,
    ) -> (Vec<f64>, Vec<MarkerSample>) {
        let mut qs = Vec::new();
        let dt = 1.0 / rate_hz;
        for (k, p) in postures.iter().enumerate() {
            for _ in 0..(hold_s * rate_hz).round() as usize {
                qs.push(p.clone());
            }
            if let Some(next) = postures.get(k + 1) {
                for i in 0..(move_s * rate_hz).round() as usize {
                    qs.push(crate::design::trajectory::quintic(p, next, move_s, i as f64 * dt).0);
                }
            }
        }
        let t = (0..qs.len()).map(|i| i as f64 * dt).collect();
        (t, self.samples(&qs, seed))
    }
}

impl HumanoidTwin {
    /// The same robot in a new session: markers re-mounted (each moved by up to +-5 mm) and
    /// the measurement frame moved; the joints keep their true errors and compliances.
    pub fn remounted(&self, seed: u64) -> HumanoidTwin {
        let mut rng = Rng::new(seed);
        let mut t = self.clone();
        for p in &mut t.truth.marker_pos {
            *p += Vector3::new(
                rng.range(-5e-3, 5e-3),
                rng.range(-5e-3, 5e-3),
                rng.range(-5e-3, 5e-3),
            );
        }
        if !matches!(t.truth.base_mode, BaseMode::Cluster) {
            for (k, v) in t.truth.base.iter_mut().enumerate() {
                *v += if k < 3 {
                    0.05 * rng.normal()
                } else {
                    0.05 * rng.normal()
                };
            }
        }
        t
    }
}
