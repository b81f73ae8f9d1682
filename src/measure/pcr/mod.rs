//! The 3-PF robot's measurement model (`../shared/spec/pcr.md`): a microscope reads the pose
//! Z of the pattern frame {M} in the sensor frame {Se}; with the extrinsic transforms
//! W_T_Se = (sx, sy, stheta) and M_T_P = (mx, my, mtheta) the measured platform pose is
//! `W_T_P = W_T_Se * Z * M_T_P`. Residuals are `[w (theta_model - theta_meas), x_model -
//! x_meas, y_model - y_meas]` with `w` = position / orientation repeatability.
//!
//! - [`problem`]: the least-squares [`crate::identify::Problem`] over robot parameters and
//!   extrinsics, with warm-started forward kinematics.
//! - [`steps`]: the bounded three-step identification and its gauge handling.
//! - [`prior`]: the Gaussian prior of a MAP identification and its weight by K-fold.
//! - [`report`]: model errors, the paper's Table 3, step reports.
//! - [`accuracy`]: ISO 9283 pose accuracy and repeatability (the paper's Table 4).

pub mod accuracy;
pub mod prior;
pub mod problem;
pub mod report;
pub mod steps;

pub use problem::PcrProblem;
pub use report::{ErrorStats, StepReport, Table3};
pub use steps::{Calibration, CalibrationOptions, Step, identify_steps};

use crate::geometry::{Pose2, wrap_angle};
use crate::model::pcr::file::Extrinsics;
use crate::model::pcr::{ROBOT_PARAMS, param_name, param_unit};

/// Names of the six extrinsic parameters, in the order of [`Extrinsics::to_array`].
pub const EXTRINSIC_NAMES: [&str; 6] = ["sx", "sy", "stheta", "mx", "my", "mtheta"];
/// Number of unknowns of a 3-PF identification: 28 robot parameters, then 6 extrinsics.
pub const UNKNOWNS: usize = ROBOT_PARAMS + 6;

/// Name of unknown `k` (robot parameters first, then extrinsics).
pub fn unknown_name(k: usize) -> String {
    if k < ROBOT_PARAMS {
        param_name(k)
    } else {
        EXTRINSIC_NAMES[k - ROBOT_PARAMS].to_string()
    }
}

/// SI unit of unknown `k`.
pub fn unknown_unit(k: usize) -> &'static str {
    match k {
        _ if k < ROBOT_PARAMS => param_unit(k),
        _ if (k - ROBOT_PARAMS) % 3 == 2 => "rad",
        _ => "m",
    }
}

/// One measurement: joint values and the sensor reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PcrMeasurement {
    /// Joint values q1, q2, q3 (m).
    pub q: [f64; 3],
    /// Sensor reading Z: pose of {M} in {Se}.
    pub z: Pose2,
}

/// The platform pose a reading stands for: `W_T_Se * Z * M_T_P`.
pub fn measured_pose(ext: &Extrinsics, z: &Pose2) -> Pose2 {
    let s = Pose2::new(ext.sx, ext.sy, ext.stheta);
    let m = Pose2::new(ext.mx, ext.my, ext.mtheta);
    s.compose(&z.compose(&m))
}

/// The reading a platform pose produces: `Z = W_T_Se^-1 * W_T_P * M_T_P^-1`.
pub fn reading(ext: &Extrinsics, platform: &Pose2) -> Pose2 {
    let s = Pose2::new(ext.sx, ext.sy, ext.stheta);
    let m = Pose2::new(ext.mx, ext.my, ext.mtheta);
    s.inverse().compose(&platform.compose(&m.inverse()))
}

/// Derivatives of the measured pose (x, y, theta) with respect to the six extrinsics.
pub fn measured_pose_jacobian(ext: &Extrinsics, z: &Pose2) -> [[f64; 6]; 3] {
    let m = Pose2::new(ext.mx, ext.my, ext.mtheta);
    let zm = z.compose(&m);
    let (ss, cs) = ext.stheta.sin_cos();
    // The lever of {P}'s origin about {Se}'s origin, in {W}.
    let v = [cs * zm.x - ss * zm.y, ss * zm.x + cs * zm.y];
    let (sa, ca) = (ext.stheta + z.theta).sin_cos();
    [
        [1.0, 0.0, -v[1], ca, -sa, 0.0],
        [0.0, 1.0, v[0], sa, ca, 0.0],
        [0.0, 0.0, 1.0, 0.0, 0.0, 1.0],
    ]
}

/// Model error of one measurement: position distance (m) and |angle difference| (rad)
/// between the model's platform pose and the measured one.
pub fn pose_error(model: &Pose2, measured: &Pose2) -> (f64, f64) {
    (
        (model.x - measured.x).hypot(model.y - measured.y),
        wrap_angle(model.theta - measured.theta).abs(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reading_inverts_measured_pose_and_jacobian_matches_differences() {
        let ext = Extrinsics {
            sx: 1e-3,
            sy: -2e-3,
            stheta: 0.03,
            mx: 5e-4,
            my: 2e-4,
            mtheta: -0.02,
        };
        let p = Pose2::new(1.2e-3, -0.4e-3, 0.07);
        let z = reading(&ext, &p);
        let back = measured_pose(&ext, &z);
        assert!((back.x - p.x).abs() < 1e-18 && (back.y - p.y).abs() < 1e-18);
        assert!((back.theta - p.theta).abs() < 1e-15);
        let jac = measured_pose_jacobian(&ext, &z);
        let h = 1e-7;
        for k in 0..6 {
            let shifted = |d: f64| {
                let mut a = ext.to_array();
                a[k] += d;
                measured_pose(&Extrinsics::from_array(&a), &z)
            };
            let (a, b) = (shifted(h), shifted(-h));
            let fd = [
                (a.x - b.x) / (2.0 * h),
                (a.y - b.y) / (2.0 * h),
                (a.theta - b.theta) / (2.0 * h),
            ];
            for c in 0..3 {
                assert!(
                    (fd[c] - jac[c][k]).abs() < 1e-9,
                    "{} row {c}: {} vs {}",
                    EXTRINSIC_NAMES[k],
                    fd[c],
                    jac[c][k]
                );
            }
        }
        assert_eq!(unknown_name(30), "stheta");
        assert_eq!(unknown_unit(33), "rad");
        assert_eq!(unknown_unit(31), "m");
    }
}
