//! Joint kinds of a chain: revolute, prismatic, fixed, and the coupling of a mimic joint to
//! another joint's variable. Kept apart from `chain.rs` so joint-type logic stays in one
//! small place.

/// How a joint moves with its variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// Rotation about the joint axis; the variable is an angle (rad).
    Revolute,
    /// Translation along the joint axis; the variable is a length (model length unit).
    Prismatic,
    /// No motion (URDF `fixed`, or a constant DH row).
    Fixed,
}

/// A joint whose variable is derived from another joint's: `value = multiplier * q[leader] +
/// offset` (URDF `<mimic>`, DH coupling row). It has no column in measurement tables.
#[derive(Debug, Clone, PartialEq)]
pub struct Mimic {
    /// Index of the leader's variable in the chain's joint-variable order.
    pub leader: usize,
    /// Name of the leader joint (for reports and write-back).
    pub leader_name: String,
    /// Multiplier (leader unit to follower unit; 1 between two joints of the same kind).
    pub multiplier: f64,
    /// Constant of the coupling, in the follower's variable unit (rad or length). Fixed
    /// value from the file: its error is the follower joint's own offset parameter.
    pub offset: f64,
}

/// Where one joint's value comes from, resolved for a joint vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Motion {
    /// Rotation about the joint axis (rad): theta for revolute joints and MDH rows.
    pub theta: f64,
    /// Translation along the joint axis (length), added to MDH `d`.
    pub shift: f64,
}

impl super::chain::Joint {
    /// True when the joint moves (revolute or prismatic), mimic joints included.
    pub fn moves(&self) -> bool {
        self.kind != JointKind::Fixed
    }

    /// True when the joint has its own variable: it moves and is not a mimic joint.
    pub fn has_variable(&self) -> bool {
        self.moves() && self.mimic.is_none()
    }
}

/// Resolve each mimic's `leader_name` among `joints` to the leader's variable index, and
/// divide its multiplier (given per leader file unit) by the leader's internal-per-file
/// factor: `k` (rad per file angle unit) for a revolute leader, 1 for a prismatic one.
/// Errors give the index of the offending joint and the reason.
pub(crate) fn link_mimics(
    joints: &mut [super::chain::Joint],
    k: f64,
) -> Result<(), (usize, String)> {
    let vars: Vec<(String, JointKind)> = joints
        .iter()
        .filter(|j| j.has_variable())
        .map(|j| (j.name.clone(), j.kind))
        .collect();
    let names: Vec<String> = joints.iter().map(|j| j.name.clone()).collect();
    for (i, j) in joints.iter_mut().enumerate() {
        let Some(m) = j.mimic.as_mut() else {
            continue;
        };
        let Some(pos) = vars.iter().position(|v| v.0 == m.leader_name) else {
            let why = if names.contains(&m.leader_name) {
                "has no variable of its own (fixed or itself a mimic)"
            } else {
                "is not a row of this chain"
            };
            return Err((i, format!("leader `{}` {why}", m.leader_name)));
        };
        m.leader = pos;
        if vars[pos].1 != JointKind::Prismatic {
            m.multiplier /= k;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
