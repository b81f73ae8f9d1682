//! Parameters of a URDF chain that duplicate its base frame: `base * (placements up to the
//! first moving joint) * Rot(axis, offset)` is one rigid transform, so with the base frame's
//! six parameters identified, those placements and that offset add no direction the data
//! could determine (a gauge of the parameterisation that a plate's gauge row can unmask).

use super::{Chain, Geometry, JointField, JointKind, ParamId};

/// Why [`base_duplicates`] parameters are held (the result's `dependencies[].reason`).
pub const DUPLICATES_BASE: &str = "not identifiable: duplicates the base frame (base * this \
     placement up to joint 1's motion is one rigid transform; the base frame carries it)";

/// Indices into `ids` of the parameters that duplicate the base frame when all six base
/// parameters are among `ids`: the URDF placement errors of every joint up to and including
/// the first moving one, and that joint's offset. Empty without the whole base, or when a
/// joint before the first moving one is not a URDF joint.
pub fn base_duplicates(chain: &Chain, ids: &[ParamId]) -> Vec<usize> {
    let whole_base = (0..6u8).all(|c| ids.contains(&ParamId::Base(c)));
    let Some(first) = chain.joints.iter().position(|j| j.kind != JointKind::Fixed) else {
        return Vec::new();
    };
    if !whole_base
        || chain.joints[..=first]
            .iter()
            .any(|j| !matches!(j.geometry, Geometry::Urdf { .. }))
    {
        return Vec::new();
    }
    ids.iter()
        .enumerate()
        .filter(|(_, id)| match id {
            ParamId::Joint(j, JointField::Err(_)) => *j <= first,
            ParamId::Joint(j, JointField::Offset | JointField::LinearOffset) => *j == first,
            _ => false,
        })
        .map(|(k, _)| k)
        .collect()
}

#[cfg(test)]
mod tests;
