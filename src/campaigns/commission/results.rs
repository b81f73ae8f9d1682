//! The typed results of the commissioning kinds (units in the field names).

use serde::Serialize;

/// One indicator outside the zero tolerance.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IndicatorOff {
    /// Indicator (1-based, as the device labels them).
    pub indicator: usize,
    /// The reading furthest from zero (mm).
    pub worst_reading_mm: f64,
    /// By how much it exceeds the tolerance (mm).
    pub excess_mm: f64,
}

/// The result of `cell.zero_check`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ZeroCheck {
    /// The cell.
    pub cell: String,
    /// Whether every reading of every indicator is within the tolerance of 0.000 mm.
    pub passed: bool,
    /// The tolerance (mm).
    pub tolerance_mm: f64,
    /// Readings taken (of all three indicators).
    pub readings: usize,
    /// Mean reading of each indicator (mm).
    pub mean_mm: [f64; 3],
    /// Largest |reading| of each indicator (mm).
    pub max_abs_mm: [f64; 3],
    /// The indicators out of tolerance, and by how much.
    pub out_of_tolerance: Vec<IndicatorOff>,
    /// One line for the operator.
    pub message: String,
}

/// One centred configuration of the TCP identification.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TcpPoint {
    /// Configuration (1-based).
    pub configuration: usize,
    /// Centred joints (deg).
    pub q_deg: Vec<f64>,
    /// Distance of its TCP point to the ball centre with the new TCP (mm).
    pub distance_mm: f64,
    /// Distance of its TCP point to the centroid with the previous TCP (mm).
    pub previous_distance_mm: f64,
    /// Final |r| of the centring (mm).
    pub centring_residual_mm: f64,
}

/// The result of `cell.identify_tcp`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TcpIdentification {
    /// The cell.
    pub cell: String,
    /// The ball used (1-based).
    pub ball: usize,
    /// The TCP in the flange frame (mm).
    pub tcp_mm: [f64; 3],
    /// Its standard deviation per component (mm).
    pub tcp_std_mm: [f64; 3],
    /// The model's TCP before (mm).
    pub previous_tcp_mm: [f64; 3],
    /// The ball centre in the robot frame {0} (mm).
    pub ball_in_robot_mm: [f64; 3],
    /// RMS distance of the centred TCP points to the ball centre, new TCP (mm).
    pub spread_rms_mm: f64,
    /// The same with the previous TCP, to the points' centroid (mm).
    pub previous_spread_rms_mm: f64,
    /// Largest pairwise rotation between the configurations (deg).
    pub max_rotation_deg: f64,
    /// Smallest singular value of the least-squares matrix (1).
    pub min_singular_value: f64,
    /// Each configuration.
    pub points: Vec<TcpPoint>,
}

/// One located ball.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LocatedBall {
    /// Ball (1-based).
    pub ball: usize,
    /// Centre in the robot frame {0} (mm).
    pub in_robot_mm: [f64; 3],
    /// Standard deviation per coordinate (mm).
    pub std_mm: [f64; 3],
    /// Centre in {W} with the fitted base (mm).
    pub in_world_mm: [f64; 3],
    /// Distance to the plate's ball after the base fit (mm).
    pub fit_residual_mm: f64,
    /// Centred joints (deg).
    pub q_deg: Vec<f64>,
}

/// One ball-to-ball distance beside the ballbar's.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BallDistance {
    /// The pair, e.g. `1-2`.
    pub pair: String,
    /// Measured (mm).
    pub measured_mm: f64,
    /// Its standard deviation (mm).
    pub std_mm: f64,
    /// The ballbar's (mm).
    pub ballbar_mm: f64,
    /// measured - ballbar (mm).
    pub difference_mm: f64,
}

/// A base frame {0} in {W} (x, y, z in mm; a, b, c in deg).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BaseFrame {
    /// x (mm).
    pub x_mm: f64,
    /// y (mm).
    pub y_mm: f64,
    /// z (mm).
    pub z_mm: f64,
    /// Rotation about z (deg).
    pub a_deg: f64,
    /// Rotation about y (deg).
    pub b_deg: f64,
    /// Rotation about x (deg).
    pub c_deg: f64,
}

impl BaseFrame {
    /// From internal xyzabc (mm, rad).
    pub fn from_internal(v: &[f64; 6]) -> Self {
        Self {
            x_mm: v[0],
            y_mm: v[1],
            z_mm: v[2],
            a_deg: v[3].to_degrees(),
            b_deg: v[4].to_degrees(),
            c_deg: v[5].to_degrees(),
        }
    }
}

/// The result of `cell.locate_balls`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BallLocation {
    /// The cell.
    pub cell: String,
    /// The TCP used (mm, flange frame).
    pub tcp_mm: [f64; 3],
    /// Its standard deviation as propagated (mm).
    pub tcp_std_mm: [f64; 3],
    /// Centring noise propagated (mm, per coordinate).
    pub centring_noise_mm: f64,
    /// Each ball.
    pub balls: Vec<LocatedBall>,
    /// Distances between the balls beside the ballbar's.
    pub distances: Vec<BallDistance>,
    /// The base frame from the rigid fit of the balls onto the plate.
    pub base: BaseFrame,
    /// The model's base before.
    pub previous_base: BaseFrame,
    /// RMS distance of the balls to the plate's after the fit (mm).
    pub fit_residual_rms_mm: f64,
    /// The same with the previous base (mm).
    pub previous_residual_rms_mm: f64,
}

/// The result of `cell.jog`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Jogged {
    /// The cell.
    pub cell: String,
    /// Joints the robot reports after the move (deg).
    pub q_deg: Vec<f64>,
    /// Largest joint change of the jog (deg).
    pub moved_deg: f64,
}
