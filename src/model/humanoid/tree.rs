//! The whole subtree below a root link as serial [`Chain`]s to its leaves: the pose of every
//! link and the static gravity torque of every measured joint with all the masses it carries
//! (arms, head and legs at their actual joint values, unmeasured joints at zero). Used for
//! the torque feasibility check of posture design and for the torques of the digital twin.
//! Geometry is the URDF's nominal one; the root is held upright (gravity along -z).

use nalgebra::Vector3;

use crate::geometry::Frame;
use crate::model::urdf::{G, UrdfModel};
use crate::model::{Chain, ModelError};

/// A link of the subtree: where its frame comes from and what it weighs.
#[derive(Debug, Clone)]
struct TreeLink {
    name: String,
    /// (leaf chain, joint index) whose output frame is this link; `None` for the root.
    at: Option<(usize, usize)>,
    mass: f64,
    com: Vector3<f64>,
    /// URDF joint indices from the root to this link.
    path: Vec<usize>,
}

/// Link frames and gravity torques of the subtree below a root.
#[derive(Debug, Clone)]
pub struct MassTree {
    chains: Vec<(Chain, Vec<Option<usize>>)>,
    links: Vec<TreeLink>,
    /// For each variable: (chain, joint index) of its joint, the links it carries, and its
    /// URDF joint index.
    joints: Vec<Option<(usize, usize, Vec<usize>, usize)>>,
}

impl MassTree {
    /// The tree below `root`, with joint variables named by `variables` (others held at 0).
    pub fn new(urdf: &UrdfModel, root: &str, variables: &[String]) -> Result<Self, ModelError> {
        if !urdf.has_link(root) {
            return Err(ModelError::Chain(format!(
                "no link named `{root}` in the URDF"
            )));
        }
        let robot = &urdf.robot;
        // Links below the root, depth first.
        let mut names = vec![root.to_string()];
        let mut k = 0;
        while k < names.len() {
            let here = names[k].clone();
            names.extend(
                robot
                    .joints
                    .iter()
                    .filter(|j| j.parent.link == here)
                    .map(|j| j.child.link.clone()),
            );
            k += 1;
        }
        let leaves: Vec<&String> = names
            .iter()
            .filter(|n| !robot.joints.iter().any(|j| &j.parent.link == *n))
            .filter(|n| n.as_str() != root)
            .collect();
        let mut chains = Vec::new();
        let mut leaf_paths = Vec::new();
        for leaf in leaves {
            let chain = urdf.chain(root, leaf)?;
            let vars = chain
                .actuated()
                .iter()
                .map(|&j| variables.iter().position(|v| v == &chain.joints[j].name))
                .collect();
            leaf_paths.push(urdf.path(root, leaf)?);
            chains.push((chain, vars));
        }
        let mut links = Vec::with_capacity(names.len());
        for name in &names {
            let path = if name == root {
                Vec::new()
            } else {
                urdf.path(root, name)?
            };
            let at = if path.is_empty() {
                None
            } else {
                leaf_paths
                    .iter()
                    .position(|p| p.starts_with(&path))
                    .map(|c| (c, path.len() - 1))
            };
            let (mass, com) =
                robot
                    .links
                    .iter()
                    .find(|l| &l.name == name)
                    .map_or((0.0, Vector3::zeros()), |l| {
                        (
                            l.inertial.mass.value.max(0.0),
                            Vector3::from(*l.inertial.origin.xyz),
                        )
                    });
            links.push(TreeLink {
                name: name.clone(),
                at,
                mass,
                com,
                path,
            });
        }
        let joints = variables
            .iter()
            .map(|v| {
                let ji = robot.joints.iter().position(|j| &j.name == v)?;
                let (c, k) = links
                    .iter()
                    .find(|l| l.path.last() == Some(&ji))
                    .and_then(|l| l.at)?;
                let carried = (0..links.len())
                    .filter(|&l| links[l].path.contains(&ji) && links[l].mass > 0.0)
                    .collect();
                Some((c, k, carried, ji))
            })
            .collect();
        Ok(Self {
            chains,
            links,
            joints,
        })
    }

    /// Names of the links, in [`MassTree::link_frames`] order (the root first).
    pub fn link_names(&self) -> Vec<&str> {
        self.links.iter().map(|l| l.name.as_str()).collect()
    }

    /// Index of a link in [`MassTree::link_names`].
    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| l.name == name)
    }

    /// URDF joint indices from the root to link `i`.
    pub fn link_path(&self, i: usize) -> &[usize] {
        &self.links[i].path
    }

    /// Mass (kg) and centre of mass (link frame, m) of link `i`.
    pub fn link_mass(&self, i: usize) -> (f64, Vector3<f64>) {
        (self.links[i].mass, self.links[i].com)
    }

    /// Joint frames of every leaf chain at `q` (variables in the constructor's order).
    fn chain_frames(&self, q: &[f64]) -> Vec<Vec<Frame>> {
        self.chains
            .iter()
            .map(|(c, vars)| {
                let qc: Vec<f64> = vars.iter().map(|v| v.map_or(0.0, |i| q[i])).collect();
                let mut f = Vec::new();
                c.joint_frames(&qc, None, &mut f);
                f
            })
            .collect()
    }

    /// Pose of every link in the root frame at `q`.
    pub fn link_frames(&self, q: &[f64]) -> Vec<Frame> {
        self.frames_of(&self.chain_frames(q))
    }

    fn frames_of(&self, cf: &[Vec<Frame>]) -> Vec<Frame> {
        self.links
            .iter()
            .map(|l| l.at.map_or_else(Frame::identity, |(c, k)| cf[c][k]))
            .collect()
    }

    /// Static motor torques (N*m) holding every variable's joint against gravity at `q`,
    /// with the masses of the whole subtree it carries (0 for a variable not in the tree).
    pub fn static_torques(&self, q: &[f64]) -> Vec<f64> {
        self.frames_and_torques(q).1
    }

    /// [`MassTree::link_frames`] and [`MassTree::static_torques`] from one forward pass.
    pub fn frames_and_torques(&self, q: &[f64]) -> (Vec<Frame>, Vec<f64>) {
        self.frames_and_torques_with(q, &Vector3::new(0.0, 0.0, -G), None)
    }

    /// Frames and static torques with gravity `g_root` (m/s^2, in the root frame) and,
    /// optionally, a support foot link that stands on the ground: a joint on the way from the
    /// root to that foot then holds everything except what lies beyond it towards the foot
    /// (the rest of the robot rests on it), instead of its own subtree.
    pub fn frames_and_torques_with(
        &self,
        q: &[f64],
        g_root: &Vector3<f64>,
        support: Option<usize>,
    ) -> (Vec<Frame>, Vec<f64>) {
        let cf = self.chain_frames(q);
        let frames = self.frames_of(&cf);
        let support_path: &[usize] = support.map_or(&[], |l| &self.links[l].path);
        let torques = self
            .joints
            .iter()
            .map(|j| {
                let Some((c, k, carried, ji)) = j else {
                    return 0.0;
                };
                let f = &cf[*c][*k];
                let axis = f.r * crate::model::chain::joint_axis(&self.chains[*c].0.joints[*k]);
                let moment_of = |l: usize| {
                    let link = &self.links[l];
                    (frames[l].apply(&link.com) - f.p).cross(&(g_root * link.mass))
                };
                let on_support = support_path.contains(ji);
                let moment: Vector3<f64> = if on_support {
                    // Motor torque on the foot side = gravity moment of the body side.
                    (0..self.links.len())
                        .filter(|l| !carried.contains(l) && self.links[*l].mass > 0.0)
                        .map(moment_of)
                        .sum()
                } else {
                    // Motor torque holding the subtree = minus its gravity moment.
                    -carried.iter().map(|&l| moment_of(l)).sum::<Vector3<f64>>()
                };
                axis.dot(&moment)
            })
            .collect();
        (frames, torques)
    }
}
