//! ISO 9283 pose accuracy of a planar robot: for each commanded pose reached `R` times,
//! AP_P is the distance from the commanded position to the barycentre of the reached
//! positions and AP_theta the mean reached angle minus the commanded one; RP (position
//! repeatability) is the mean distance of the reached positions from their barycentre plus
//! three standard deviations. Table 4 of the paper reports max, mean and min of AP_P and
//! |AP_theta| over a trajectory.

use serde::Serialize;

use crate::geometry::{Pose2, wrap_angle};
use crate::measure::iso9283::position_accuracy;
use crate::util::stats::mean;

/// Accuracy and repeatability at one commanded pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PoseAccuracy {
    /// Position accuracy AP_P (m).
    pub ap_p: f64,
    /// Orientation accuracy AP_theta (rad), signed.
    pub ap_theta: f64,
    /// Position repeatability RP (m).
    pub rp: f64,
    /// Barycentre of the reached positions (m).
    pub barycentre: [f64; 2],
}

/// ISO 9283 accuracy of one commanded pose from the poses reached (at least one); the
/// position part is [`crate::measure::iso9283::position_accuracy`].
pub fn pose_accuracy(commanded: &Pose2, reached: &[Pose2]) -> PoseAccuracy {
    let xy: Vec<Vec<f64>> = reached.iter().map(|p| vec![p.x, p.y]).collect();
    let a = position_accuracy(&[commanded.x, commanded.y], &xy);
    let dth: Vec<f64> = reached
        .iter()
        .map(|p| wrap_angle(p.theta - commanded.theta))
        .collect();
    PoseAccuracy {
        ap_p: a.ap,
        ap_theta: mean(&dth),
        rp: a.rp,
        barycentre: [a.barycentre[0], a.barycentre[1]],
    }
}

/// Max, mean and min of a trajectory's AP_P (um) and |AP_theta| (mrad): one row of the
/// paper's Table 4.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AccuracySummary {
    /// Commanded poses.
    pub poses: usize,
    /// AP_P over the poses, um.
    pub ap_p_um: super::report::ErrorStats,
    /// |AP_theta| over the poses, mrad.
    pub ap_theta_mrad: super::report::ErrorStats,
    /// Largest RP, um.
    pub rp_max_um: f64,
}

/// The summary of per-pose accuracies.
pub fn summarise(acc: &[PoseAccuracy]) -> AccuracySummary {
    let p: Vec<f64> = acc.iter().map(|a| a.ap_p).collect();
    let t: Vec<f64> = acc.iter().map(|a| a.ap_theta.abs()).collect();
    AccuracySummary {
        poses: acc.len(),
        ap_p_um: super::report::ErrorStats::of(&p, 1e6),
        ap_theta_mrad: super::report::ErrorStats::of(&t, 1e3),
        rp_max_um: acc.iter().map(|a| a.rp).fold(0.0, f64::max) * 1e6,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accuracy_is_the_barycentre_offset_and_repeatability_the_spread() {
        let c = Pose2::new(1e-3, 2e-3, 0.01);
        // Four reached poses on a 1 um square around (c + (3, 4) um), angles +/- 1 urad
        // around c + 5 urad.
        let off = (3e-6, 4e-6);
        let reached: Vec<Pose2> = [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
            .iter()
            .enumerate()
            .map(|(k, (a, b))| {
                let s = if k % 2 == 0 { 1.0 } else { -1.0 };
                Pose2::new(
                    c.x + off.0 + 0.5e-6 * a,
                    c.y + off.1 + 0.5e-6 * b,
                    c.theta + 5e-6 + s * 1e-6,
                )
            })
            .collect();
        let a = pose_accuracy(&c, &reached);
        assert!((a.ap_p - 5e-6).abs() < 1e-15, "{a:?}");
        assert!((a.ap_theta - 5e-6).abs() < 1e-15);
        // All four points are 0.5 * sqrt(2) um from the barycentre: no spread.
        assert!((a.rp - 0.5e-6 * 2f64.sqrt()).abs() < 1e-15);
        let s = summarise(&[
            a,
            PoseAccuracy {
                ap_p: 1e-6,
                ap_theta: -2e-6,
                rp: 0.0,
                barycentre: [0.0; 2],
            },
        ]);
        assert!((s.ap_p_um.max - 5.0).abs() < 1e-9 && (s.ap_p_um.min - 1.0).abs() < 1e-9);
        assert!((s.ap_theta_mrad.mean - 0.0035).abs() < 1e-12);
    }
}
