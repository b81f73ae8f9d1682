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
use crate::model::humanoid::{BaseMode, HParam, Humanoid, MassTree, State};
use crate::model::urdf::UrdfModel;
use crate::model::{JointField, ModelError};
use crate::util::Rng;

mod layouts;

pub use layouts::{
    TwinSpec, WAIST_CLUSTER, clusters, left_arm_spec, left_leg_support_spec, samples_table,
};

/// The TALOS URDF shipped with calibd (copied from `../shared/data/robots/talos`).
pub const TALOS_URDF: &str = include_str!("../../../tests/data/robots/talos/talos_reduced.urdf");

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
        Self::with_urdf(TALOS_URDF, spec, seed)
    }

    /// A twin of the robot described by `urdf` (a lab's model) with true errors drawn from
    /// `seed` around it.
    pub fn with_urdf(urdf: &str, spec: TwinSpec, seed: u64) -> Result<Self, ModelError> {
        let urdf = UrdfModel::parse(urdf)?;
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
                    qs.push(crate::design::playback::quintic(p, next, move_s, i as f64 * dt).0);
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
            // About 5 cm and 0.05 rad (3 degrees) per component.
            for v in t.truth.base.iter_mut() {
                *v += 0.05 * rng.normal();
            }
        }
        t
    }
}
