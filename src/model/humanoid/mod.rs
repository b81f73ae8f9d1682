//! Humanoid model for whole-body calibration (`../shared/spec/humanoid.md`): a URDF tree seen
//! as several serial [`Chain`]s sharing a root link, one per leaf link that carries markers;
//! markers fixed on links at unknown local positions; the root pose from six unknowns, from a
//! marker cluster on the root link, or from a support foot (exact elimination of the
//! support-foot constraint); joint compliance from measured torques; a Cartesian compliance of
//! the floating base loaded through the support leg.
//!
//! Parameters are shared by name across chains: a torso joint on the way to the head and to
//! an arm is one set of unknowns. Evaluation (positions and exact Jacobians) is in [`eval`];
//! whole-tree gravity torques in [`tree`].

pub mod eval;
mod params;
pub mod tree;

use nalgebra::Vector3;

use super::urdf::UrdfModel;
use super::{Chain, JointField, ModelError, ParamId};

pub use eval::State;
pub use tree::MassTree;

/// A marker: a point fixed on a link at an unknown local position.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerDef {
    /// Name (measurement columns `<name>_x`, `<name>_y`, `<name>_z`).
    pub name: String,
    /// URDF link carrying it.
    pub link: String,
    /// Initial guess of its position in the link frame (m).
    pub initial: Vector3<f64>,
}

/// How the pose of the root link in the measurement frame is obtained.
#[derive(Debug, Clone, PartialEq)]
pub enum BaseMode {
    /// Six constant unknowns: the root link in the measurement frame.
    Identify,
    /// Measured per sample by a rigid fit of a marker cluster on the root link, composed with
    /// six constant unknowns (root link in the cluster frame).
    Cluster,
    /// The support foot `link` stays still: the root pose is `F * G(q)^-1` with `F` the
    /// support foot pose in the measurement frame (six constant unknowns) and `G` the
    /// root-to-foot forward kinematics (exact elimination of the support-foot constraint).
    SupportFoot {
        /// The support foot (sole) link.
        link: String,
    },
}

/// One parameter of the humanoid model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HParam {
    /// A field of tree joint `joint` (index into [`Humanoid::joints`]).
    Joint(usize, JointField),
    /// Root pose component x, y, z, a, b, c (or support foot pose in that mode).
    Base(u8),
    /// Base Cartesian compliance along/about the root axes x, y, z, rx, ry, rz.
    BaseCompliance(u8),
    /// Local coordinate 0..3 of marker `m`.
    Marker(usize, u8),
}

/// Priority class of a parameter in rank detection (spec order: joint offsets, translations,
/// angles, then base, then markers; compliances come after the geometry of the joints).
impl HParam {
    /// Smaller is kept first by the pivoted QR.
    pub fn priority(&self) -> u8 {
        match self {
            HParam::Joint(_, JointField::Offset) => 0,
            HParam::Joint(_, JointField::Err(k)) if *k < 3 => 1,
            HParam::Joint(_, JointField::Err(_)) => 2,
            HParam::Joint(_, _) => 3,
            HParam::BaseCompliance(_) => 4,
            HParam::Base(_) => 5,
            HParam::Marker(..) => 6,
        }
    }
}

/// A joint of the tree (a joint on the path from the root to some marker link).
#[derive(Debug, Clone, PartialEq)]
pub struct TreeJoint {
    /// URDF joint name.
    pub name: String,
    /// Revolute (else fixed).
    pub revolute: bool,
    /// Index of its measured variable in [`Humanoid::variables`] (revolute joints).
    pub var: Option<usize>,
    /// Whether its compliance is a parameter.
    pub elastic: bool,
}

/// A chain from the root to a leaf link, with its joints' tree indices and variables.
#[derive(Debug, Clone)]
pub(crate) struct TreeChain {
    pub(crate) chain: Chain,
    /// Tree joint index of each chain joint.
    pub(crate) joints: Vec<usize>,
    /// Measured variable of each actuated chain joint (in `chain.actuated()` order).
    pub(crate) vars: Vec<usize>,
    /// (global parameter index, chain parameter column) of the joint parameters.
    pub(crate) cols: Vec<(usize, usize)>,
    /// Number of chain parameter columns (`chain.param_ids().len()`).
    pub(crate) params: usize,
}

/// Where the non-joint parameters start in [`Humanoid::params`].
#[derive(Debug, Clone, Default)]
pub(crate) struct Layout {
    /// First of the six base (or foot) pose parameters.
    pub(crate) base: usize,
    /// First of the six base compliances, if identified.
    pub(crate) compliance: Option<usize>,
    /// First of the three coordinates of each marker.
    pub(crate) markers: Vec<usize>,
}

/// The humanoid calibration model.
#[derive(Debug, Clone)]
pub struct Humanoid {
    /// Root link name.
    pub root: String,
    /// Measured joint variables, in sample order (revolute URDF joint names).
    pub variables: Vec<String>,
    /// Joints of the tree, root outwards chain by chain.
    pub joints: Vec<TreeJoint>,
    /// Markers.
    pub markers: Vec<MarkerDef>,
    /// Base mode.
    pub base_mode: BaseMode,
    /// Every parameter, in a fixed order.
    pub params: Vec<HParam>,
    /// Current local marker positions (m).
    pub marker_pos: Vec<Vector3<f64>>,
    /// Current root pose (or cluster-to-root, or support foot pose): x, y, z, a, b, c.
    pub base: [f64; 6],
    /// Current base compliance (m/N for x, y, z; rad/(N*m) for rx, ry, rz).
    pub base_compliance: [f64; 6],
    pub(crate) chains: Vec<TreeChain>,
    /// (chain, body) of each marker; `None` for markers on the root link.
    pub(crate) marker_at: Vec<Option<(usize, usize)>>,
    /// Chain from the root to the support foot, when a support leg carries the base.
    pub(crate) support: Option<TreeChain>,
    /// Whether the base compliance is a parameter.
    pub base_elastic: bool,
    pub(crate) layout: Layout,
}

/// Options of [`Humanoid::new`] besides the geometry.
#[derive(Debug, Clone, Default)]
pub struct Elasticity {
    /// Joints whose compliance is identified (theta = q + offset + c * tau).
    pub joints: Vec<String>,
    /// Identify the base Cartesian compliance (needs a support leg).
    pub base: bool,
    /// The support foot link for the base compliance (default: the support-foot base mode's).
    pub support_link: Option<String>,
}

fn chain_err(m: String) -> ModelError {
    ModelError::Chain(m)
}

impl Humanoid {
    /// Build the model: chains from `root` to the links carrying `markers` (and to the
    /// support foot), checking that every revolute joint on them is in `variables`.
    pub fn new(
        urdf: &UrdfModel,
        root: &str,
        variables: &[String],
        markers: &[MarkerDef],
        base_mode: BaseMode,
        elastic: &Elasticity,
    ) -> Result<Self, ModelError> {
        if !urdf.has_link(root) {
            return Err(chain_err(format!("root link `{root}` is not in the URDF")));
        }
        for (i, v) in variables.iter().enumerate() {
            if variables[..i].contains(v) {
                return Err(chain_err(format!("joint `{v}` is listed twice")));
            }
        }
        let mut names: Vec<&str> = Vec::new();
        for m in markers {
            if names.contains(&m.name.as_str()) {
                return Err(chain_err(format!("marker `{}` is defined twice", m.name)));
            }
            names.push(&m.name);
            if !urdf.has_link(&m.link) {
                return Err(chain_err(format!(
                    "marker `{}`: no link `{}` in the URDF",
                    m.name, m.link
                )));
            }
        }
        // Links to reach: marker links, then the support foot.
        let support_link = match (&base_mode, &elastic.support_link) {
            (_, Some(l)) => Some(l.clone()),
            (BaseMode::SupportFoot { link }, None) => Some(link.clone()),
            _ => None,
        };
        if elastic.base && support_link.is_none() {
            return Err(chain_err(
                "base elasticity needs a support leg: a `support_foot` base mode or a support link"
                    .into(),
            ));
        }
        let mut paths: Vec<(String, Vec<usize>)> = Vec::new();
        for m in markers {
            if m.link != root && !paths.iter().any(|p| p.0 == m.link) {
                paths.push((m.link.clone(), urdf.path(root, &m.link)?));
            }
        }
        // A link whose path is a prefix of another's is reached by that longer chain.
        let leaves: Vec<usize> = (0..paths.len())
            .filter(|&i| {
                !paths.iter().enumerate().any(|(j, p)| {
                    j != i && p.1.len() > paths[i].1.len() && p.1.starts_with(&paths[i].1)
                })
            })
            .collect();
        let mut model = Self {
            root: root.to_string(),
            variables: variables.to_vec(),
            joints: Vec::new(),
            markers: markers.to_vec(),
            base_mode,
            params: Vec::new(),
            marker_pos: markers.iter().map(|m| m.initial).collect(),
            base: [0.0; 6],
            base_compliance: [0.0; 6],
            chains: Vec::new(),
            marker_at: Vec::new(),
            support: None,
            base_elastic: elastic.base,
            layout: Layout::default(),
        };
        let mut chain_paths = Vec::new();
        for &i in &leaves {
            let (link, path) = &paths[i];
            let tc = model.tree_chain(urdf, link, path, elastic)?;
            model.chains.push(tc);
            chain_paths.push(path.clone());
        }
        if let Some(l) = &support_link {
            let path = urdf.path(root, l)?;
            let tc = model.tree_chain(urdf, l, &path, elastic)?;
            if tc.chain.dof() != 6 && elastic.base {
                return Err(chain_err(format!(
                    "support leg `{root}` -> `{l}` has {} revolute joints: base elasticity needs 6",
                    tc.chain.dof()
                )));
            }
            model.support = Some(tc);
        }
        for e in &elastic.joints {
            if !model.joints.iter().any(|j| &j.name == e && j.revolute) {
                return Err(chain_err(format!(
                    "elastic joint `{e}` is not a revolute joint of any chain"
                )));
            }
        }
        for v in variables {
            if !model.joints.iter().any(|j| &j.name == v) {
                return Err(chain_err(format!(
                    "joint `{v}` is on no chain from `{root}` to a marker link or the support foot"
                )));
            }
        }
        // Where each marker sits: (chain, body) with the longest chain through its link.
        for m in markers {
            if m.link == root {
                model.marker_at.push(None);
                continue;
            }
            let path = urdf.path(root, &m.link)?;
            let c = chain_paths
                .iter()
                .position(|p| p.starts_with(&path))
                .ok_or_else(|| chain_err(format!("no chain reaches `{}`", m.link)))?;
            model.marker_at.push(Some((c, path.len() - 1)));
        }
        model.build_params();
        Ok(model)
    }

    /// The chain from the root to `link` along `path`, registering its joints in the tree.
    fn tree_chain(
        &mut self,
        urdf: &UrdfModel,
        link: &str,
        path: &[usize],
        elastic: &Elasticity,
    ) -> Result<TreeChain, ModelError> {
        let chain = urdf.chain(&self.root, link)?;
        let mut joints = Vec::with_capacity(path.len());
        let mut vars = Vec::new();
        for cj in &chain.joints {
            if cj.kind == super::JointKind::Prismatic || cj.mimic.is_some() {
                return Err(chain_err(format!(
                    "joint `{}` is prismatic or a mimic joint: the humanoid model supports revolute and fixed joints only (use a serial chain)",
                    cj.name
                )));
            }
            let revolute = cj.has_variable();
            let idx = match self.joints.iter().position(|j| j.name == cj.name) {
                Some(i) => i,
                None => {
                    let var = if revolute {
                        Some(self.variables.iter().position(|v| v == &cj.name).ok_or_else(
                            || {
                                chain_err(format!(
                                    "joint `{}` on the way from `{}` to `{link}` is not among the measured joints",
                                    cj.name, self.root
                                ))
                            },
                        )?)
                    } else {
                        None
                    };
                    self.joints.push(TreeJoint {
                        name: cj.name.clone(),
                        revolute,
                        var,
                        elastic: revolute && elastic.joints.contains(&cj.name),
                    });
                    self.joints.len() - 1
                }
            };
            if let Some(v) = self.joints[idx].var {
                vars.push(v);
            }
            joints.push(idx);
        }
        let params = chain.param_ids().len();
        Ok(TreeChain {
            chain,
            joints,
            vars,
            cols: Vec::new(),
            params,
        })
    }

    /// The parameter list and each chain's column map.
    fn build_params(&mut self) {
        let mut params = Vec::new();
        for (j, tj) in self.joints.iter().enumerate() {
            params.extend((0..6).map(|k| HParam::Joint(j, JointField::Err(k))));
            if tj.revolute {
                params.push(HParam::Joint(j, JointField::Offset));
                if tj.elastic {
                    params.push(HParam::Joint(j, JointField::Compliance));
                }
            }
        }
        params.extend((0..6).map(HParam::Base));
        if self.base_elastic {
            params.extend((0..6).map(HParam::BaseCompliance));
        }
        for m in 0..self.markers.len() {
            params.extend((0..3).map(|a| HParam::Marker(m, a)));
        }
        let map = |tc: &mut TreeChain| {
            tc.cols = params
                .iter()
                .enumerate()
                .filter_map(|(g, p)| match p {
                    HParam::Joint(j, f) => {
                        let k = tc.joints.iter().position(|x| x == j)?;
                        Some((g, tc.chain.param_index(ParamId::Joint(k, *f))?))
                    }
                    _ => None,
                })
                .collect();
        };
        for tc in &mut self.chains {
            map(tc);
        }
        if let Some(tc) = &mut self.support {
            map(tc);
        }
        let find = |want: HParam| params.iter().position(|p| *p == want);
        self.layout = Layout {
            base: find(HParam::Base(0)).unwrap_or(0),
            compliance: find(HParam::BaseCompliance(0)),
            markers: (0..self.markers.len())
                .map(|m| find(HParam::Marker(m, 0)).unwrap_or(0))
                .collect(),
        };
        self.params = params;
    }
}

#[cfg(test)]
mod tests;
