//! Measurement models: how a measurement constrains a model (ball plates and points for
//! serial arms, the microscope of the 3-PF robot in [`pcr`]). Each turns data into an
//! [`crate::identify::Problem`]; none does I/O.

pub mod ballplate;
pub mod distance;
pub mod fiducial;
pub mod iso9283;
pub mod justin;
pub mod marker_fit;
pub mod markers;
pub mod mocap;
pub mod pattern;
pub mod pcr;
pub mod point;
pub mod tree_markers;
pub mod tree_prior;
pub mod tree_robust;

pub use ballplate::BallPlate;
pub use distance::{DistanceMeasurement, DistanceProblem};
pub use markers::{MarkerProblem, MarkerSample};
pub use point::{PointMeasurement, PointProblem, PointStart, Target};

/// Errors in measurement data.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeasureError {
    /// A ball plate definition cannot place the balls.
    #[error("ball plate: {0}")]
    Plate(String),
    /// A measurement refers to something that does not exist or is out of range.
    #[error("measurement row {row}: {reason}")]
    Row {
        /// 1-based data row.
        row: usize,
        /// What is wrong.
        reason: String,
    },
}
