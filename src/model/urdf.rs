//! URDF models: parsed with `urdf-rs`, chains from a root link to a tip link with six
//! placement errors per joint origin plus a joint offset (`../shared/spec/humanoid.md`),
//! and the calibrated URDF written back by editing only the `<origin>` of changed joints,
//! so meshes, transmissions and comments survive.

use std::collections::{HashMap, HashSet};

use nalgebra::Vector3;

use super::ModelError;
use super::chain::{Chain, Geometry, Joint, PointMass, Units};
use super::joint::{JointKind, Mimic};
use crate::geometry::Frame;

/// Standard gravity (m/s^2).
pub const G: f64 = 9.80665;

/// A parsed URDF with its original text.
#[derive(Debug, Clone)]
pub struct UrdfModel {
    /// The text as given, used as the template of the calibrated file.
    pub text: String,
    /// The parsed robot.
    pub robot: urdf_rs::Robot,
    /// Index of the joint whose child is each link.
    parent_joint: HashMap<String, usize>,
}

fn pose_frame(p: &urdf_rs::Pose) -> Frame {
    Frame::from_xyzabc(&[p.xyz[0], p.xyz[1], p.xyz[2], p.rpy[2], p.rpy[1], p.rpy[0]])
}

impl UrdfModel {
    /// Parse URDF text.
    pub fn parse(text: &str) -> Result<Self, ModelError> {
        let robot =
            urdf_rs::read_from_string(text).map_err(|e| ModelError::Parse(format!("URDF: {e}")))?;
        let parent_joint = check_graph(&robot)?;
        Ok(Self {
            text: text.to_string(),
            robot,
            parent_joint,
        })
    }

    /// Whether a link of that name exists.
    pub fn has_link(&self, name: &str) -> bool {
        self.robot.links.iter().any(|l| l.name == name)
    }

    /// Indices (in `robot.joints`) of the joints from `root` to `tip`, root first.
    pub fn path(&self, root: &str, tip: &str) -> Result<Vec<usize>, ModelError> {
        for l in [root, tip] {
            if !self.has_link(l) {
                return Err(ModelError::Chain(format!(
                    "no link named `{l}` in the URDF"
                )));
            }
        }
        let mut path = Vec::new();
        let mut link = tip.to_string();
        while link != root {
            let Some(&j) = self.parent_joint.get(&link) else {
                return Err(ModelError::Chain(format!(
                    "`{tip}` does not descend from `{root}`"
                )));
            };
            path.push(j);
            link = self.robot.joints[j].parent.link.clone();
        }
        path.reverse();
        Ok(path)
    }

    /// The chain from `root` to `tip` (metres, radians), base and tool at identity, gravity
    /// along -z of the root frame. Masses: each chain link's, plus every link hanging off the
    /// chain through other joints, placed at their zero joint values.
    pub fn chain(&self, root: &str, tip: &str) -> Result<Chain, ModelError> {
        let path = self.path(root, tip)?;
        let mut joints = Vec::with_capacity(path.len());
        for &ji in &path {
            let j = &self.robot.joints[ji];
            let kind = match j.joint_type {
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {
                    JointKind::Revolute
                }
                urdf_rs::JointType::Prismatic => JointKind::Prismatic,
                urdf_rs::JointType::Fixed => JointKind::Fixed,
                ref other => {
                    return Err(ModelError::Chain(format!(
                        "joint `{}` is {other:?}: only revolute, continuous, prismatic and fixed joints are supported",
                        j.name
                    )));
                }
            };
            let moves = kind != JointKind::Fixed;
            let axis = Vector3::from(*j.axis.xyz);
            if moves && !(axis.norm() > 0.0 && axis.iter().all(|v| v.is_finite())) {
                return Err(ModelError::Field {
                    field: format!("joint `{}` axis", j.name),
                    reason: "zero axis".into(),
                });
            }
            let limits = (matches!(
                j.joint_type,
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Prismatic
            ) && j.limit.lower.is_finite()
                && j.limit.upper.is_finite()
                && j.limit.lower < j.limit.upper)
                .then_some([j.limit.lower, j.limit.upper]);
            joints.push(Joint {
                name: j.name.clone(),
                geometry: Geometry::Urdf {
                    origin: pose_frame(&j.origin),
                    errors: [0.0; 6],
                    axis: axis.normalize(),
                },
                kind,
                mimic: None,
                offset: 0.0,
                compliance: 0.0,
                limits,
                effort: (moves && j.limit.effort > 0.0).then_some(j.limit.effort),
            });
        }
        self.resolve_mimics(&path, &mut joints)?;
        let masses = self.masses_along(&path);
        Ok(Chain::new(
            joints,
            [0.0; 6],
            [0.0; 6],
            Vector3::new(0.0, 0.0, -G),
            masses,
            Units {
                mm: false,
                deg: false,
            },
        ))
    }

    /// Couple the chain's `<mimic>` joints to their leaders, which must be moving joints of
    /// the same chain with their own variable (a mimic of a mimic is refused).
    fn resolve_mimics(&self, path: &[usize], joints: &mut [Joint]) -> Result<(), ModelError> {
        let vars: Vec<&str> = path
            .iter()
            .map(|&ji| &self.robot.joints[ji])
            .filter(|j| j.mimic.is_none() && j.joint_type != urdf_rs::JointType::Fixed)
            .map(|j| j.name.as_str())
            .collect();
        for (joint, &ji) in joints.iter_mut().zip(path) {
            let Some(m) = &self.robot.joints[ji].mimic else {
                continue;
            };
            if joint.kind == JointKind::Fixed {
                continue;
            }
            let leader = vars.iter().position(|v| *v == m.joint).ok_or_else(|| {
                let why = if self.robot.joints.iter().any(|j| j.name == m.joint) {
                    "is not a moving joint with its own variable on the same chain"
                } else {
                    "is not a joint of the URDF"
                };
                ModelError::Field {
                    field: format!("joint `{}` mimic", joint.name),
                    reason: format!("leader `{}` {why}", m.joint),
                }
            })?;
            let multiplier = m.multiplier.unwrap_or(1.0);
            let offset = m.offset.unwrap_or(0.0);
            if !multiplier.is_finite() || !offset.is_finite() {
                return Err(ModelError::Field {
                    field: format!("joint `{}` mimic", joint.name),
                    reason: "multiplier and offset must be finite".into(),
                });
            }
            joint.mimic = Some(Mimic {
                leader,
                leader_name: m.joint.clone(),
                multiplier,
                offset,
            });
        }
        Ok(())
    }

    /// Point masses of the chain's links and of everything hanging off them.
    fn masses_along(&self, path: &[usize]) -> Vec<PointMass> {
        let on_chain: Vec<&str> = path
            .iter()
            .map(|&j| self.robot.joints[j].child.link.as_str())
            .collect();
        let mut out = Vec::new();
        for (body, &ji) in path.iter().enumerate() {
            let link = &self.robot.joints[ji].child.link;
            // Depth-first over the subtree not on the chain, with the pose of each link in the
            // chain link's frame (other joints at zero).
            let mut stack = vec![(link.clone(), Frame::identity())];
            while let Some((name, pose)) = stack.pop() {
                if let Some(l) = self.robot.links.iter().find(|l| l.name == name) {
                    let m = l.inertial.mass.value;
                    if m > 0.0 {
                        let c = pose.apply(&Vector3::from(*l.inertial.origin.xyz));
                        out.push(PointMass {
                            name: name.clone(),
                            body,
                            mass: m,
                            com: c,
                        });
                    }
                }
                for j in self.robot.joints.iter().filter(|j| j.parent.link == name) {
                    if !on_chain.contains(&j.child.link.as_str()) {
                        stack.push((j.child.link.clone(), pose.mul(&pose_frame(&j.origin))));
                    }
                }
            }
        }
        out
    }

    /// The URDF text with the placement errors and offsets of `chain` folded into the
    /// `<origin>` of each of its joints: `origin' = origin * E(errors) * Rot(axis, offset)`,
    /// which reproduces the chain's forward kinematics exactly.
    pub fn write_calibrated(&self, chain: &Chain) -> Result<String, ModelError> {
        self.write_calibrated_chains([chain])
    }

    /// As [`UrdfModel::write_calibrated`] for several chains of one tree (a joint shared by
    /// chains carries the same values in each, so writing it twice is harmless).
    pub fn write_calibrated_chains<'c>(
        &self,
        chains: impl IntoIterator<Item = &'c Chain>,
    ) -> Result<String, ModelError> {
        let mut text = self.text.clone();
        for joint in chains.into_iter().flat_map(|c| c.joints.iter()) {
            let Geometry::Urdf {
                origin,
                errors,
                axis,
            } = &joint.geometry
            else {
                continue;
            };
            let mut o = origin.mul(&Frame::from_urdf_errors(errors));
            match joint.kind {
                JointKind::Revolute => o = o.mul(&Frame::rot_axis(axis, joint.offset)),
                JointKind::Prismatic => {
                    let t = axis * joint.offset;
                    o = o.mul(&Frame::trans(t.x, t.y, t.z));
                }
                JointKind::Fixed => {}
            }
            let v = o.to_xyzabc();
            let tag = format!(
                "<origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/>",
                v[0], v[1], v[2], v[5], v[4], v[3]
            );
            text = replace_origin(&text, &joint.name, &tag).ok_or_else(|| {
                ModelError::Chain(format!("joint `{}` not found in the URDF text", joint.name))
            })?;
            if let Some(m) = &joint.mimic {
                // The identified offset is in the origin; the multiplier goes to `<mimic>`.
                let tag = format!(
                    "<mimic joint=\"{}\" multiplier=\"{}\" offset=\"{}\"/>",
                    m.leader_name, m.multiplier, m.offset
                );
                text = replace_child(&text, &joint.name, "mimic", &tag).ok_or_else(|| {
                    ModelError::Chain(format!(
                        "the <mimic> of joint `{}` not found in the URDF text",
                        joint.name
                    ))
                })?;
            }
        }
        Ok(text)
    }
}

/// The kinematic graph of a URDF must be a tree: unique link and joint names, every joint
/// between two existing, different links, no link with two parent joints, no cycle. Checked
/// before any walk over the graph, so a hostile file cannot make one run forever. Returns
/// the index of the joint whose child is each link.
fn check_graph(robot: &urdf_rs::Robot) -> Result<HashMap<String, usize>, ModelError> {
    let bad = |msg: String| Err(ModelError::Parse(format!("URDF: {msg}")));
    let mut links = HashSet::with_capacity(robot.links.len());
    for l in &robot.links {
        if !links.insert(l.name.as_str()) {
            return bad(format!("link `{}` is declared twice", l.name));
        }
    }
    let mut joint_names = HashSet::with_capacity(robot.joints.len());
    let mut parent_joint: HashMap<String, usize> = HashMap::with_capacity(robot.joints.len());
    for (i, j) in robot.joints.iter().enumerate() {
        if !joint_names.insert(j.name.as_str()) {
            return bad(format!("joint `{}` is declared twice", j.name));
        }
        for (role, link) in [("parent", &j.parent.link), ("child", &j.child.link)] {
            if !links.contains(link.as_str()) {
                return bad(format!(
                    "joint `{}` is dangling: its {role} link `{link}` is not declared",
                    j.name
                ));
            }
        }
        if j.parent.link == j.child.link {
            return bad(format!(
                "joint `{}` joins link `{}` to itself (a cycle)",
                j.name, j.child.link
            ));
        }
        if let Some(&other) = parent_joint.get(&j.child.link) {
            return bad(format!(
                "link `{}` has two parents: it is the child of joints `{}` and `{}`",
                j.child.link, robot.joints[other].name, j.name
            ));
        }
        parent_joint.insert(j.child.link.clone(), i);
    }
    // With one parent per link, a cycle is a walk up the parents that comes back. Each link
    // is walked once: `state` marks links known to reach a root (2) or on the current walk (1).
    let mut state: HashMap<&str, u8> = HashMap::with_capacity(links.len());
    for start in robot.links.iter().map(|l| l.name.as_str()) {
        let mut walk: Vec<&str> = Vec::new();
        let mut link = start;
        loop {
            match state.get(link) {
                Some(2) => break,
                Some(_) => {
                    // `link` is on this walk: the joints from it back to itself form the cycle.
                    let from = walk.iter().position(|l| *l == link).unwrap_or(0);
                    let joints: Vec<&str> = walk[from..]
                        .iter()
                        .filter_map(|l| parent_joint.get(*l))
                        .map(|&ji| robot.joints[ji].name.as_str())
                        .collect();
                    return bad(format!(
                        "joints form a cycle: {} (link `{link}` is its own ancestor)",
                        joints
                            .iter()
                            .map(|n| format!("`{n}`"))
                            .collect::<Vec<_>>()
                            .join(" <- ")
                    ));
                }
                None => {}
            }
            state.insert(link, 1);
            walk.push(link);
            match parent_joint.get(link) {
                Some(&ji) => link = robot.joints[ji].parent.link.as_str(),
                None => break,
            }
        }
        for l in walk {
            state.insert(l, 2);
        }
    }
    Ok(parent_joint)
}

/// Replace (or insert) the `<origin .../>` of the `<joint name=.. type=..>` element.
fn replace_origin(text: &str, name: &str, new_tag: &str) -> Option<String> {
    replace_child(text, name, "origin", new_tag)
}

/// Replace (or insert) the `<element .../>` child of the `<joint name=.. type=..>` element.
fn replace_child(text: &str, name: &str, element: &str, new_tag: &str) -> Option<String> {
    let open = format!("<{element}");
    let close_tag = format!("</{element}>");
    let mut from = 0;
    while let Some(rel) = text[from..].find("<joint") {
        let start = from + rel;
        let head_end = start + text[start..].find('>')?;
        let head = &text[start..=head_end];
        from = head_end;
        let has_name =
            head.contains(&format!("name=\"{name}\"")) || head.contains(&format!("name='{name}'"));
        // Joints inside <transmission> have a name but no type.
        if !has_name || !head.contains("type=") {
            continue;
        }
        if head.ends_with("/>") {
            return None;
        }
        let end = head_end + text[head_end..].find("</joint>")?;
        let body = &text[head_end + 1..end];
        let mut out = String::with_capacity(text.len() + new_tag.len());
        out.push_str(&text[..=head_end]);
        if let Some(o) = body.find(open.as_str()) {
            let o_abs = head_end + 1 + o;
            let close = o_abs + text[o_abs..].find('>')?;
            // `<origin ... />` or `<origin ...></origin>`.
            let after = if text[o_abs..=close].ends_with("/>") {
                close + 1
            } else {
                close + 1 + text[close + 1..].find(close_tag.as_str())? + close_tag.len()
            };
            out.push_str(&text[head_end + 1..o_abs]);
            out.push_str(new_tag);
            out.push_str(&text[after..]);
        } else {
            out.push_str("\n    ");
            out.push_str(new_tag);
            out.push_str(&text[head_end + 1..]);
        }
        return Some(out);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{JointField, ParamId};

    const PANDA: &str = include_str!("../../tests/data/mukca/panda_nominal.urdf");

    #[test]
    fn panda_chain_and_write_back_reproduce_fk() {
        let m = UrdfModel::parse(PANDA).unwrap();
        let mut c = m.chain("panda_link0", "ball_link").unwrap();
        assert_eq!(c.dof(), 7);
        // Perturb every error and offset, fold them into the text, reload: same FK.
        let ids: Vec<ParamId> = c
            .param_ids()
            .into_iter()
            .filter(|id| {
                matches!(
                    id,
                    ParamId::Joint(_, JointField::Err(_) | JointField::Offset)
                )
            })
            .collect();
        for (k, id) in ids.iter().enumerate() {
            c.set_param(*id, 1e-3 * ((k as f64 * 1.7).sin()));
        }
        let text = m.write_calibrated(&c).unwrap();
        let back = UrdfModel::parse(&text)
            .unwrap()
            .chain("panda_link0", "ball_link")
            .unwrap();
        let q = [0.3, -0.5, 0.2, -2.0, 0.4, 1.7, 0.8];
        let (a, b) = (c.tcp(&q, None), back.tcp(&q, None));
        assert!((a.p - b.p).norm() < 1e-12, "{}", (a.p - b.p).norm());
        assert!(a.angle_to(&b) < 1e-12);
        // Meshes and the rest of the text are untouched.
        assert!(text.contains("<mesh") == PANDA.contains("<mesh"));
    }

    /// A URDF of `n` links and the joints `(parent, child)` between them.
    fn graph_urdf(n: usize, joints: &[(usize, usize)]) -> String {
        let mut t = String::from("<robot name=\"g\">\n");
        for l in 0..n {
            t.push_str(&format!("<link name=\"l{l}\"/>\n"));
        }
        for (k, (p, c)) in joints.iter().enumerate() {
            t.push_str(&format!(
                "<joint name=\"j{k}\" type=\"revolute\"><parent link=\"l{p}\"/><child link=\"l{c}\"/>\
                 <axis xyz=\"0 0 1\"/><limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/></joint>\n"
            ));
        }
        t.push_str("</robot>\n");
        t
    }

    /// Whether the joints (at most one parent per child) contain a cycle: a second,
    /// independent method (repeated removal of links with no parent, Kahn's algorithm).
    fn has_cycle(n: usize, joints: &[(usize, usize)]) -> bool {
        let mut indegree = vec![0usize; n];
        for &(_, c) in joints {
            indegree[c] += 1;
        }
        let mut ready: Vec<usize> = (0..n).filter(|&l| indegree[l] == 0).collect();
        let mut seen = 0;
        while let Some(l) = ready.pop() {
            seen += 1;
            for &(p, c) in joints {
                if p == l {
                    indegree[c] -= 1;
                    if indegree[c] == 0 {
                        ready.push(c);
                    }
                }
            }
        }
        seen < n
    }

    #[test]
    fn random_link_graphs_are_accepted_exactly_when_they_are_trees() {
        let mut rng = crate::util::Rng::new(28);
        let (mut trees, mut cycles) = (0, 0);
        for _ in 0..3000 {
            let n = 1 + rng.below(9);
            // A random forest (each link but the first picks an earlier parent, or none)...
            let mut joints: Vec<(usize, usize)> = Vec::new();
            for c in 1..n {
                if rng.below(5) > 0 {
                    joints.push((rng.below(c), c));
                }
            }
            // ...then, half of the time, one joint re-aimed at a random parent, which may
            // close a loop (a -> b -> a, a self-joint, a longer cycle) or stay a tree.
            if !joints.is_empty() && rng.below(2) == 0 {
                let k = rng.below(joints.len());
                joints[k].0 = rng.below(n);
            }
            let text = graph_urdf(n, &joints);
            let parsed = UrdfModel::parse(&text);
            if has_cycle(n, &joints) {
                cycles += 1;
                let e = parsed.expect_err(&text).to_string();
                assert!(e.contains("cycle"), "{e}\n{text}");
                assert!(e.contains("`j"), "the joints are named: {e}");
            } else {
                trees += 1;
                let m = parsed.unwrap_or_else(|e| panic!("{e}\n{text}"));
                // Every joint's child descends from link 0's tree root along a finite path.
                for (k, &(_, c)) in joints.iter().enumerate() {
                    let mut root = c;
                    while let Some(&(p, _)) = joints.iter().find(|(_, cc)| *cc == root) {
                        root = p;
                    }
                    let path = m.path(&format!("l{root}"), &format!("l{c}")).unwrap();
                    assert!(path.contains(&k), "{path:?} {k}");
                }
            }
        }
        assert!(
            trees > 500 && cycles > 200,
            "{trees} trees, {cycles} cycles"
        );
    }

    #[test]
    fn bad_graphs_name_the_joints() {
        let two_cycle = graph_urdf(4, &[(0, 3), (1, 2), (2, 1)]);
        let e = UrdfModel::parse(&two_cycle).unwrap_err().to_string();
        assert!(
            e.contains("cycle") && e.contains("`j1`") && e.contains("`j2`"),
            "{e}"
        );
        assert!(!e.contains("`j0`"), "j0 is not on the cycle: {e}");
        // Closing a loop onto a link that has a parent gives it two parents.
        let closed = graph_urdf(3, &[(0, 1), (1, 2), (2, 1)]);
        let e = UrdfModel::parse(&closed).unwrap_err().to_string();
        assert!(
            e.contains("two parents") && e.contains("`j0`") && e.contains("`j2`"),
            "{e}"
        );
        let selfie = graph_urdf(2, &[(0, 1), (1, 1)]);
        let e = UrdfModel::parse(&selfie).unwrap_err().to_string();
        assert!(e.contains("`j1`") && e.contains("to itself"), "{e}");
        let two_parents = graph_urdf(3, &[(0, 2), (1, 2)]);
        let e = UrdfModel::parse(&two_parents).unwrap_err().to_string();
        assert!(
            e.contains("two parents") && e.contains("`j0`") && e.contains("`j1`"),
            "{e}"
        );
        let dangling = graph_urdf(2, &[(0, 1)]).replace("l1\"/></joint>", "l7\"/></joint>");
        let dangling = dangling.replace("<child link=\"l1\"/>", "<child link=\"l7\"/>");
        let e = UrdfModel::parse(&dangling).unwrap_err().to_string();
        assert!(
            e.contains("dangling") && e.contains("`j0`") && e.contains("`l7`"),
            "{e}"
        );
        // A tip that is not below the root.
        let m = UrdfModel::parse(&graph_urdf(3, &[(0, 1), (0, 2)])).unwrap();
        let e = m.path("l1", "l2").unwrap_err().to_string();
        assert!(e.contains("does not descend"), "{e}");
    }

    #[test]
    fn missing_links_are_named() {
        let m = UrdfModel::parse(PANDA).unwrap();
        let e = m
            .chain("panda_link0", "no_such_link")
            .unwrap_err()
            .to_string();
        assert!(e.contains("no_such_link"), "{e}");
    }
}
