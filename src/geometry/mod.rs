//! Rigid transforms in 3-D and 2-D with the elementary motions the models are built from.
//! Pure maths, no I/O.

mod frame;
mod planar;

pub use frame::{Frame, Motion};
pub use planar::{Pose2, wrap_angle};
