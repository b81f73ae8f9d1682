//! Rigid transforms in 3-D and 2-D with the elementary motions the models are built from,
//! exact point derivatives of the parameterised transforms, and the Kabsch rigid fit.
//! Pure maths, no I/O.

mod derivatives;
mod frame;
mod planar;

pub use derivatives::{kabsch, urdf_errors_point_derivatives, xyzabc_point_derivatives};
pub use frame::{Frame, Motion};
pub use planar::{Pose2, wrap_angle};
