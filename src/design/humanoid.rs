//! Posture design for a humanoid marker layout: the [`PostureModel`] of a [`Humanoid`] with
//! its base parameters (found by pivoted QR over random feasible postures) and a fixed column
//! scaling, its feasibility (joint limits, whole-tree gravity torques under the URDF efforts,
//! an end-effector box, link spheres), and the comparison of a design with DETMAX and with
//! COCP from random starts (the paper's Fig. 6).

use nalgebra::{DMatrix, Vector3};

use serde::Serialize;

use super::detmax::{DetmaxOptions, Pool, detmax};
use super::feasibility::{Constraints, PointBox, Sphere, Violation, spheres_along};
use super::ocp::{OptimOptions, cocp, o1_of_postures, random_feasible};
use super::postures::{PostureModel, PostureSet};
use crate::identify::{IdentifyError, RankReport};
use crate::measure::marker_fit::base_parameters;
use crate::model::ModelError;
use crate::model::humanoid::{Humanoid, MassTree, State};
use crate::model::urdf::UrdfModel;
use crate::util::{Monitor, Rng};

/// What to check besides joint limits.
#[derive(Debug, Clone)]
pub struct ConstraintOptions {
    /// Radius of the automatic link spheres (m).
    pub sphere_radius: f64,
    /// Spheres given explicitly for some links (link, centre in the link frame, radius);
    /// they replace that link's automatic spheres.
    pub spheres: Vec<(String, Vector3<f64>, f64)>,
    /// Link pairs never checked (e.g. an SRDF's disabled collisions).
    pub disabled: Vec<(String, String)>,
    /// A point of a link that must stay in a box of the root frame (link, point, min, max).
    pub ee_box: Option<(String, Vector3<f64>, Vector3<f64>, Vector3<f64>)>,
    /// Check static torques against the URDF efforts.
    pub torque: bool,
    /// Check self-collision.
    pub collision: bool,
}

impl Default for ConstraintOptions {
    fn default() -> Self {
        Self {
            sphere_radius: 0.05,
            spheres: Vec::new(),
            disabled: Vec::new(),
            ee_box: None,
            torque: true,
            collision: true,
        }
    }
}

/// A humanoid marker layout as a posture model.
#[derive(Debug, Clone)]
pub struct HumanoidPostures {
    /// The model (marker positions = the layout).
    pub model: Humanoid,
    /// Base parameters: indices into `model.params` (all free parameters until
    /// [`HumanoidPostures::select_base`]).
    pub cols: Vec<usize>,
    /// Fixed column scale of each base parameter (RMS column norm per posture).
    pub scale: Vec<f64>,
    /// Whole-tree frames and torques.
    pub tree: MassTree,
    /// Feasibility.
    pub constraints: Constraints,
    elastic: bool,
}

impl HumanoidPostures {
    /// The layout of `model` with constraints from `urdf` and `opts`; `free` are the
    /// parameters an identification would estimate.
    pub fn new(
        urdf: &UrdfModel,
        model: Humanoid,
        free: Vec<usize>,
        opts: &ConstraintOptions,
    ) -> Result<Self, ModelError> {
        let tree = MassTree::new(urdf, &model.root, &model.variables)?;
        let names = tree
            .link_names()
            .iter()
            .map(|s| s.to_string())
            .collect::<Vec<_>>();
        let mut spheres = Vec::new();
        for (i, name) in names.iter().enumerate() {
            let given: Vec<&(String, Vector3<f64>, f64)> =
                opts.spheres.iter().filter(|s| &s.0 == name).collect();
            if !given.is_empty() {
                spheres.extend(given.iter().map(|s| Sphere {
                    body: i,
                    centre: s.1,
                    radius: s.2,
                }));
                continue;
            }
            let (mass, com) = tree.link_mass(i);
            if mass < 0.05 {
                continue;
            }
            let children: Vec<Vector3<f64>> = urdf
                .robot
                .joints
                .iter()
                .filter(|j| &j.parent.link == name)
                .map(|j| Vector3::from(*j.origin.xyz))
                .filter(|p| p.norm() > 1e-6)
                .collect();
            let r = opts.sphere_radius;
            if children.is_empty() {
                spheres.extend(spheres_along(i, Vector3::zeros(), 2.0 * com, r));
            }
            for c in children {
                spheres.extend(spheres_along(i, Vector3::zeros(), c, r));
            }
        }
        for (a, b) in &opts.disabled {
            for l in [a, b] {
                if !urdf.has_link(l) {
                    return Err(ModelError::Chain(format!("disabled pair: no link `{l}`")));
                }
            }
        }
        let var_joints: Vec<usize> = model
            .variables
            .iter()
            .filter_map(|v| urdf.robot.joints.iter().position(|j| &j.name == v))
            .collect();
        let efforts = if opts.torque {
            model.efforts()
        } else {
            vec![None; model.variables.len()]
        };
        let limits = model
            .limits()
            .iter()
            .map(|l| l.unwrap_or([-std::f64::consts::PI, std::f64::consts::PI]))
            .collect();
        let ee_box = match &opts.ee_box {
            Some((link, point, min, max)) => Some(PointBox {
                body: tree.link_index(link).ok_or_else(|| {
                    ModelError::Chain(format!("end-effector box: no link `{link}` below the root"))
                })?,
                point: *point,
                min: *min,
                max: *max,
            }),
            None => None,
        };
        let mut constraints = Constraints {
            limits,
            efforts,
            ee_box,
            spheres: if opts.collision { spheres } else { Vec::new() },
            pairs: Vec::new(),
        };
        constraints.set_pairs(|a, b| {
            let (pa, pb) = (tree.link_path(a), tree.link_path(b));
            let diff: Vec<usize> = pa
                .iter()
                .filter(|j| !pb.contains(j))
                .chain(pb.iter().filter(|j| !pa.contains(j)))
                .copied()
                .collect();
            let disabled = opts.disabled.iter().any(|(x, y)| {
                (x == &names[a] && y == &names[b]) || (x == &names[b] && y == &names[a])
            });
            // Links one long joint apart (through any number of joints shorter than a sphere
            // diameter, e.g. a hip or a wrist) touch at that joint by construction.
            let apart = diff
                .iter()
                .filter(|&&j| {
                    Vector3::from(*urdf.robot.joints[j].origin.xyz).norm()
                        > 2.0 * opts.sphere_radius
                })
                .count();
            apart > 1 && !disabled && diff.iter().any(|j| var_joints.contains(j))
        });
        let n = free.len();
        let elastic = model.joints.iter().any(|j| j.elastic);
        Ok(Self {
            model,
            cols: free,
            scale: vec![1.0; n],
            tree,
            constraints,
            elastic,
        })
    }

    /// The first violated constraint at `q`, if any.
    pub fn violation(&self, q: &[f64]) -> Option<Violation> {
        if let Some(v) = self.constraints.limit_violation(q) {
            return Some(v);
        }
        let (frames, torques) = self.tree.frames_and_torques(q);
        self.constraints.check(q, &frames, &torques)
    }

    /// The state the Jacobian is evaluated at (gravity torques when joints are elastic).
    fn state(&self, q: &[f64]) -> State {
        let mut s = State::from_q(q.to_vec());
        if self.elastic || self.model.base_elastic {
            s.tau = self.tree.static_torques(q);
        }
        self.model.fill_wrench(&mut s);
        s
    }

    /// Unscaled Jacobian block of the markers at `q` for parameters `cols`.
    pub fn raw_block(&self, q: &[f64], cols: &[usize]) -> DMatrix<f64> {
        let s = self.state(q);
        let nm = self.model.markers.len();
        let mut b = DMatrix::zeros(3 * nm, cols.len());
        let all: Vec<usize> = (0..nm).collect();
        self.model.marker_jacobians(&s, &all, |m, _, buf| {
            for (c, &g) in cols.iter().enumerate() {
                for k in 0..3 {
                    b[(3 * m + k, c)] = buf[g][k];
                }
            }
        });
        b
    }

    /// Random feasible postures (`None` if the constraints leave no room in `tries` draws).
    pub fn random_postures(&self, n: usize, rng: &mut Rng, tries: usize) -> Option<Vec<Vec<f64>>> {
        (0..n).map(|_| random_feasible(self, rng, tries)).collect()
    }

    /// Find the base parameters among the free ones by pivoted QR in priority order over
    /// `postures`, and fix the column scaling to their RMS column norm per posture.
    pub fn select_base(
        &mut self,
        postures: &[Vec<f64>],
        tolerance: f64,
        monitor: &dyn Monitor,
    ) -> Result<RankReport, IdentifyError> {
        let states: Vec<State> = postures.iter().map(|q| self.state(q)).collect();
        let (rank, kept) = base_parameters(&self.model, &self.cols, &states, tolerance, monitor)?;
        let mut sq = vec![0.0; kept.len()];
        for q in postures {
            let b = self.raw_block(q, &kept);
            for (c, v) in sq.iter_mut().enumerate() {
                *v += b.column(c).norm_squared();
            }
        }
        self.scale = sq
            .iter()
            .map(|v| {
                (v / postures.len().max(1) as f64)
                    .sqrt()
                    .max(f64::MIN_POSITIVE)
            })
            .collect();
        self.cols = kept;
        Ok(rank)
    }
}

impl PostureModel for HumanoidPostures {
    fn dof(&self) -> usize {
        self.model.variables.len()
    }
    fn limits(&self) -> Vec<[f64; 2]> {
        self.constraints.limits.clone()
    }
    fn block(&self, q: &[f64]) -> DMatrix<f64> {
        let mut b = self.raw_block(q, &self.cols);
        for (c, s) in self.scale.iter().enumerate() {
            b.column_mut(c).unscale_mut(*s);
        }
        b
    }
    fn feasible(&self, q: &[f64]) -> bool {
        self.violation(q).is_none()
    }
}

/// One COCP run from a random start.
#[derive(Debug, Clone, Serialize)]
pub struct RandomStart {
    /// Index of the start.
    pub start: usize,
    /// O1 of the random feasible postures.
    pub o1_random_start: f64,
    /// O1 after COCP.
    pub o1: f64,
    /// Postures COCP re-optimised.
    pub iterations: usize,
}

/// DETMAX's part of a [`Comparison`].
#[derive(Debug, Clone, Serialize)]
pub struct DetmaxResult {
    /// O1 of the selection.
    pub o1: f64,
    /// Random feasible postures it chose from.
    pub pool: usize,
    /// log det of the selection's information matrix.
    pub log_det: f64,
}

/// The paper's Fig. 6 comparison for a posture set.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// Number of postures compared.
    pub postures: usize,
    /// O1 of the set being compared (NOCP's).
    pub nocp_o1: f64,
    /// DETMAX over a random feasible pool.
    pub detmax: DetmaxResult,
    /// COCP from random feasible starts.
    pub cocp_random_starts: Vec<RandomStart>,
}

/// Compare `set` with DETMAX over `pool_n` random feasible postures and with COCP from
/// `starts` random feasible starts, all of the same size (`None` when no feasible posture
/// can be drawn).
pub fn compare_baselines(
    pm: &HumanoidPostures,
    set: &PostureSet,
    pool_n: usize,
    starts: usize,
    seed: u64,
    optim: &OptimOptions,
    monitor: &dyn Monitor,
) -> Result<Option<Comparison>, IdentifyError> {
    let n = set.len();
    let mut rng = Rng::new(seed ^ 0x5eed);
    let Some(pool) = pm.random_postures(pool_n, &mut rng, 20_000) else {
        return Ok(None);
    };
    let opts = DetmaxOptions {
        n,
        seed,
        max_excursion: 6,
        path: true,
    };
    // The blocks are made on every core in batches (a 1000-posture pool of 54-row blocks
    // would hold 35 MB of them).
    let blocks = Pool::from_block_fn(pool.len(), |i| pm.block(&pool[i]));
    let sel = detmax(&blocks, &opts, monitor)?;
    let chosen: Vec<Vec<f64>> = sel.selected.iter().map(|&i| pool[i].clone()).collect();
    let mut runs = Vec::new();
    for k in 0..starts {
        let Some(start) = pm.random_postures(n, &mut rng, 20_000) else {
            return Ok(None);
        };
        let mut s = PostureSet::from_postures(pm, start);
        let rep = cocp(pm, &mut s, optim, 4 * n, monitor)?;
        runs.push(RandomStart {
            start: k,
            o1_random_start: rep.o1_start,
            o1: rep.o1,
            iterations: rep.iterations,
        });
    }
    Ok(Some(Comparison {
        postures: n,
        nocp_o1: set.o1(),
        detmax: DetmaxResult {
            o1: o1_of_postures(pm, &chosen),
            pool: pool_n,
            log_det: sel.log_det,
        },
        cocp_random_starts: runs,
    }))
}
