//! An elastic upper-body twin: a torso (yaw, pitch and a coupled passive pitch) carrying two
//! 4-joint arms with one marker each, a "true" robot with geometric errors and lumped joint
//! and lateral elasticity from known compliances and mass moments, and noisy marker
//! measurements. Seeded, no I/O.

use nalgebra::Vector3;

use crate::geometry::Frame;
use crate::measure::tree_markers::TreeObservation;
use crate::model::elastic::gravity::{STANDARD_GRAVITY_M_S2, lumped};
use crate::model::elastic::{
    Drive, ElasticOptions, ElasticTree, Lumping, RowKind, TParam, TreeMarker, TreeRow,
};
use crate::util::Rng;

/// Number of joint variables of the twin (2 torso, 4 per arm).
pub const VARIABLES: usize = 10;

/// Names of the twin's revolute rows.
pub fn revolute_rows() -> Vec<String> {
    [
        "t0", "t1", "t2", "r0", "r1", "r2", "r3", "l0", "l1", "l2", "l3",
    ]
    .map(String::from)
    .to_vec()
}

/// The nominal twin tree (MDH rows in m and rad), elasticity on the rows `elastic` names.
pub fn nominal(elastic: &ElasticOptions) -> ElasticTree {
    let h = std::f64::consts::FRAC_PI_2;
    let rev = |name: &str, parent: usize, g: [f64; 5], drive: Drive| TreeRow {
        name: name.into(),
        parent: Some(parent),
        kind: RowKind::Revolute { geometry: g, drive },
    };
    let fixed = |name: &str, parent: Option<usize>, frame: Frame| TreeRow {
        name: name.into(),
        parent,
        kind: RowKind::Fixed {
            frame,
            errors: [0.0; 6],
        },
    };
    let mut rows = vec![
        fixed("pedestal", None, Frame::trans(0.0, 0.0, 0.5)),
        rev("t0", 0, [0.0, 0.0, 0.0, 0.0, 0.1], Drive::Variable(0)),
        rev("t1", 1, [-h, 0.0, 0.0, -h, 0.0], Drive::Variable(1)),
        rev(
            "t2",
            2,
            [0.0, 0.35, 0.0, 0.0, 0.0],
            Drive::Coupled(vec![(1, -1.0)]),
        ),
    ];
    let mut markers = Vec::new();
    for (side, sign, var) in [("r", -1.0, 2), ("l", 1.0, 6)] {
        let mount = Frame::trans(0.05, 0.0, sign * 0.2).mul(&Frame::rot_x(-sign * h));
        rows.push(fixed(&format!("{side}_mount"), Some(3), mount));
        let geo = [
            [0.0, 0.0, 0.0, 0.0, 0.0],
            [h, 0.0, 0.0, 0.0, 0.0],
            [-h, 0.0, 0.0, 0.0, 0.35],
            [h, 0.0, 0.0, 0.0, 0.0],
        ];
        for (k, g) in geo.iter().enumerate() {
            let parent = rows.len() - 1;
            rows.push(rev(
                &format!("{side}{k}"),
                parent,
                *g,
                Drive::Variable(var + k),
            ));
        }
        let parent = rows.len() - 1;
        rows.push(fixed(
            &format!("{side}_hand"),
            Some(parent),
            Frame::trans(0.0, -0.3, 0.0),
        ));
        markers.push(TreeMarker {
            name: side.into(),
            row: rows.len() - 1,
            local: Vector3::new(0.03, -0.02, 0.05),
        });
    }
    let mut tree = match ElasticTree::new(rows, markers, VARIABLES, elastic) {
        Ok(t) => t,
        // The rows above are well formed by construction.
        Err(e) => unreachable!("twin tree: {e}"),
    };
    tree.base = [1.0, -0.5, 0.1, 0.3, 0.0, 0.0];
    tree
}

/// The compliances `[c_z, c_x, c_y]` (rad/(N*m)) and carried first mass moment (kg*m,
/// joint frame, constant) of every revolute row of the twin's truth.
pub fn physical(rng: &mut Rng) -> Vec<(String, [f64; 3], Vector3<f64>)> {
    revolute_rows()
        .into_iter()
        .map(|n| {
            let c = [
                rng.range(1e-4, 4e-4),
                rng.range(3e-5, 1.5e-4),
                rng.range(3e-5, 1.5e-4),
            ];
            let m = Vector3::new(
                rng.range(-2.0, 2.0),
                rng.range(-2.0, 2.0),
                rng.range(-2.0, 2.0),
            );
            (n, c, m)
        })
        .collect()
}

/// A seeded twin: the truth (nominal + geometric errors of 1 mm / 0.2 deg + elasticity from
/// [`physical`]: lumped coefficients of the carried mass moments, or, for
/// [`Lumping::Bodies`], the compliances and a random 1-4 kg link on every revolute row) and
/// `n` observations with Gaussian noise `noise_m` per coordinate.
#[derive(Debug, Clone)]
pub struct ElasticTwin {
    /// The true robot.
    pub truth: ElasticTree,
    /// The nominal model (what an identification starts from).
    pub nominal: ElasticTree,
    /// Observations (gravity features from the truth's geometry: the physics).
    pub observations: Vec<TreeObservation>,
}

impl ElasticTwin {
    /// Build the twin; `elastic` chooses which coefficients the truth and models carry.
    pub fn new(elastic: &ElasticOptions, n: usize, noise_m: f64, seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        let nominal = nominal(elastic);
        let mut truth = nominal.clone();
        for p in truth.params.clone() {
            let e = match p {
                TParam::Geometry(..) | TParam::Placement(..) if p.is_length() => {
                    rng.normal() * 1e-3
                }
                TParam::Geometry(..) | TParam::Placement(..) => rng.normal() * 0.2f64.to_radians(),
                _ => 0.0,
            };
            truth.set(p, truth.value(p) + e);
        }
        for (name, c, m) in physical(&mut rng) {
            let Some(i) = truth.row(&name) else {
                continue;
            };
            if truth.lumping == Lumping::Bodies {
                // A link of 1-4 kg with its centre within 0.15 m of its frame origin.
                let kg = rng.range(1.0, 4.0);
                let w = kg * STANDARD_GRAVITY_M_S2;
                let com = Vector3::new(
                    rng.range(-0.15, 0.15),
                    rng.range(-0.15, 0.15),
                    rng.range(-0.15, 0.15),
                );
                truth.weights[i] = [w * com.x, w * com.y, w * com.z, w];
                let (j, l) = (
                    truth.has_joint_elasticity(i),
                    truth.has_lateral_elasticity(i),
                );
                truth.compliance[i] = [
                    if j { c[0] } else { 0.0 },
                    if l { c[1] } else { 0.0 },
                    if l { c[2] } else { 0.0 },
                ];
                continue;
            }
            {
                let k = lumped(c, &m);
                for (j, v) in k.iter().enumerate() {
                    let lateral = j >= 2;
                    let on = if lateral {
                        truth.has_lateral_elasticity(i)
                    } else {
                        truth.has_joint_elasticity(i)
                    };
                    truth.elastic[i][j] = if on { *v } else { 0.0 };
                }
            }
        }
        let observations = (0..n)
            .map(|_| {
                let mut q: Vec<f64> = (0..VARIABLES).map(|_| rng.range(-2.0, 2.0)).collect();
                q[1] = rng.range(-0.6, 0.6);
                let sample = truth.sample(q);
                let points = truth
                    .marker_positions(&sample)
                    .into_iter()
                    .map(|p| {
                        Some(p + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * noise_m)
                    })
                    .collect();
                TreeObservation { sample, points }
            })
            .collect();
        Self {
            truth,
            nominal,
            observations,
        }
    }

    /// Noise-free positions of the truth for fresh seeded configurations (a validation set).
    pub fn validation(&self, n: usize, seed: u64) -> Vec<TreeObservation> {
        let mut rng = Rng::new(seed);
        (0..n)
            .map(|_| {
                let mut q: Vec<f64> = (0..VARIABLES).map(|_| rng.range(-2.0, 2.0)).collect();
                q[1] = rng.range(-0.6, 0.6);
                let sample = self.truth.sample(q);
                let points = self
                    .truth
                    .marker_positions(&sample)
                    .into_iter()
                    .map(Some)
                    .collect();
                TreeObservation { sample, points }
            })
            .collect()
    }
}
