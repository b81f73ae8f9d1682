//! Names and units of the parameters of a serial chain.
//!
//! A parameter is addressed by a [`ParamId`]; its public name follows
//! `../shared/spec/serial-robot.md` for DH models (`alpha2` lives in joint entry 3) and
//! `<joint>.dx` ... `<joint>.offset` for URDF joints.

use serde::Serialize;

/// Physical kind of a parameter, which fixes its unit in files and reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Quantity {
    /// A length (mm in DH files, m in URDF).
    Length,
    /// An angle (deg in DH files, rad in URDF); radians internally.
    Angle,
    /// A joint compliance (deg/(N*m) in DH files, rad/(N*m) in URDF); rad/(N*m) internally.
    Compliance,
    /// A dimensionless number.
    Scalar,
}

/// Which parameter of a joint: the MDH fields, the URDF placement errors, or the shared ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum JointField {
    /// MDH alpha[i-1] (rotation about x before the joint).
    Alpha,
    /// MDH a[i-1] (translation along x before the joint).
    A,
    /// Hayati beta[i-1] (rotation about y before the joint).
    Beta,
    /// MDH d[i] (translation along z after the joint).
    D,
    /// URDF placement error: 0..3 translations dx, dy, dz, 3..6 rotations rx, ry, rz.
    Err(u8),
    /// Joint offset (theta_offset for MDH).
    Offset,
    /// Joint compliance c (rad/(N*m) internally).
    Compliance,
    /// Offset of a prismatic URDF joint's variable (a length, not an angle).
    LinearOffset,
    /// Multiplier of a mimic joint's coupling (dimensionless).
    Multiplier,
}

/// Address of one parameter of a chain model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ParamId {
    /// A field of joint `j` (0-based index in the chain).
    Joint(usize, JointField),
    /// Base frame component 0..6: x, y, z, a, b, c.
    Base(u8),
    /// Tool frame component 0..6: x, y, z, a, b, c.
    Tool(u8),
}

/// Names of the six xyzabc components.
pub const XYZABC: [&str; 6] = ["x", "y", "z", "a", "b", "c"];
/// Names of the six URDF placement errors.
pub const URDF_ERRORS: [&str; 6] = ["dx", "dy", "dz", "rx", "ry", "rz"];

impl ParamId {
    /// The physical quantity of the parameter.
    pub fn quantity(&self) -> Quantity {
        match self {
            ParamId::Base(k) | ParamId::Tool(k) => {
                if *k < 3 {
                    Quantity::Length
                } else {
                    Quantity::Angle
                }
            }
            ParamId::Joint(_, f) => match f {
                JointField::A | JointField::D | JointField::LinearOffset => Quantity::Length,
                JointField::Multiplier => Quantity::Scalar,
                JointField::Err(k) if *k < 3 => Quantity::Length,
                JointField::Compliance => Quantity::Compliance,
                _ => Quantity::Angle,
            },
        }
    }
}

impl ParamId {
    /// Priority class in rank detection for URDF-style chains (`../shared/spec/humanoid.md`):
    /// joint offsets, then translations, then angles, then compliances, then base and tool.
    /// Smaller is kept first; a dependent column later in the order is the one dropped.
    pub fn priority(&self) -> u8 {
        match self {
            ParamId::Joint(_, JointField::Offset | JointField::LinearOffset) => 0,
            ParamId::Joint(_, JointField::A | JointField::D) => 1,
            ParamId::Joint(_, JointField::Err(k)) if *k < 3 => 1,
            ParamId::Joint(_, JointField::Compliance) => 3,
            ParamId::Joint(_, _) => 2,
            ParamId::Base(_) | ParamId::Tool(_) => 4,
        }
    }
}
