//! Robot models: pure, `Send + Sync`, no I/O beyond parsing text handed to them.

pub mod base_duplicates;
pub mod chain;
pub mod compensate;
pub mod dh;
pub mod dh_tree;
pub mod elastic;
pub mod humanoid;
pub mod ik;
pub mod joint;
pub mod opw;
pub mod params;
pub mod pcr;
pub mod rapid;
pub mod srdf;
pub mod trig;
pub mod urdf;
pub mod urdf_export;

pub use chain::{Chain, Geometry, Joint, PointMass};
pub use joint::{JointKind, Mimic};
pub use params::{JointField, ParamId, Quantity};

/// Errors in a model file or model parameters.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    /// The file text is not valid for its format.
    #[error("model file: {0}")]
    Parse(String),
    /// A field has a value that cannot be used.
    #[error("model field `{field}`: {reason}")]
    Field {
        /// Path of the field.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// A parameter name that the model does not have.
    #[error("unknown parameter name `{0}` (see the model's parameter list)")]
    UnknownParameter(String),
    /// A link named for a chain is not in the URDF, or no path joins root and tip.
    #[error("URDF chain: {0}")]
    Chain(String),
}
