//! The numerics of commissioning: the TCP as the point whose positions coincide best over
//! flange poses on one ball (linear least squares over `R_i t + p_i = c`), with its standard
//! deviation and the refusal of poses too alike to determine it; ball positions with their
//! uncertainty; the base frame from a rigid fit of the balls onto the plate.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use crate::geometry::Frame;
use crate::geometry::kabsch;

/// Why a commissioning computation refused its data.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CommissionError {
    /// Not enough configurations.
    #[error("{got} centred configurations; at least {need} are needed")]
    TooFew {
        /// Configurations given.
        got: usize,
        /// Configurations needed.
        need: usize,
    },
    /// The orientations are too alike for the TCP to be determined.
    #[error(
        "configurations {configurations} are too similar in orientation to determine the TCP: {why} (pairwise rotation angles: {angles}); jog to orientations further apart and run again"
    )]
    TooSimilar {
        /// The configurations (1-based).
        configurations: String,
        /// Which test refused them, with the figures.
        why: String,
        /// Every pairwise rotation angle, `i-j: deg`.
        angles: String,
    },
    /// The ball positions do not determine a rigid transform (fewer than three, collinear).
    #[error("the measured balls do not determine the base frame (fewer than three or collinear)")]
    Degenerate,
}

/// The identified TCP.
#[derive(Debug, Clone, PartialEq)]
pub struct TcpFit {
    /// TCP in the flange frame (model length unit).
    pub t: Vector3<f64>,
    /// The ball centre in {0}.
    pub c: Vector3<f64>,
    /// Standard deviation of each component of `t` (from the residual variance and
    /// `(A^T A)^-1`; zero with exact data).
    pub t_std: [f64; 3],
    /// Distance of each `R_i t + p_i` to `c`.
    pub spread: Vec<f64>,
    /// Largest pairwise rotation angle between the poses (deg).
    pub max_rotation_deg: f64,
    /// Smallest singular value of `A`.
    pub min_singular_value: f64,
}

/// Pairwise rotation angles (deg) between flange poses, `(i, j, angle)` with 0-based i < j.
pub fn pairwise_angles(poses: &[Frame]) -> Vec<(usize, usize, f64)> {
    let mut out = Vec::new();
    for i in 0..poses.len() {
        for j in i + 1..poses.len() {
            out.push((i, j, poses[i].angle_to(&poses[j]).to_degrees()));
        }
    }
    out
}

/// Solve `R_i t + p_i = c` for the TCP `t` (flange frame) and the ball centre `c` ({0}) over
/// flange poses `(R_i, p_i)` centred on one ball. Refused when the largest pairwise rotation
/// is below `min_rotation_deg` or the smallest singular value of `A = [R_i, -I]` is below
/// `min_singular_value` (rotations about nearly one axis leave `t` along it undetermined).
pub fn solve_tcp(
    poses: &[Frame],
    min_rotation_deg: f64,
    min_singular_value: f64,
) -> Result<TcpFit, CommissionError> {
    let n = poses.len();
    if n < 3 {
        return Err(CommissionError::TooFew { got: n, need: 3 });
    }
    let angles = pairwise_angles(poses);
    let max_rotation_deg = angles.iter().map(|a| a.2).fold(0.0, f64::max);
    let (mut a, mut b) = (DMatrix::zeros(3 * n, 6), DVector::zeros(3 * n));
    for (i, f) in poses.iter().enumerate() {
        a.view_mut((3 * i, 0), (3, 3)).copy_from(&f.r);
        a.view_mut((3 * i, 3), (3, 3))
            .copy_from(&(-Matrix3::<f64>::identity()));
        b.rows_mut(3 * i, 3).copy_from(&(-f.p));
    }
    let s_min = a
        .singular_values()
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let refuse = |why: String| CommissionError::TooSimilar {
        configurations: (1..=n)
            .map(|k| k.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        why,
        angles: angles
            .iter()
            .map(|(i, j, d)| format!("{}-{}: {d:.1} deg", i + 1, j + 1))
            .collect::<Vec<_>>()
            .join(", "),
    };
    if max_rotation_deg < min_rotation_deg {
        return Err(refuse(format!(
            "the largest pairwise rotation is {max_rotation_deg:.1} deg, below {min_rotation_deg} deg"
        )));
    }
    if s_min.is_nan() || s_min < min_singular_value {
        return Err(refuse(format!(
            "the smallest singular value of A is {s_min:.4}, below {min_singular_value} (the rotations turn about nearly one axis)"
        )));
    }
    let ata = a.transpose() * &a;
    let inv = ata
        .clone()
        .try_inverse()
        .ok_or_else(|| refuse("A^T A is singular".into()))?;
    let x = &inv * (a.transpose() * &b);
    let t = Vector3::new(x[0], x[1], x[2]);
    let c = Vector3::new(x[3], x[4], x[5]);
    let r = &a * &x - &b;
    let dof = (3 * n - 6) as f64;
    let s2 = r.norm_squared() / dof;
    let t_std = [0, 1, 2].map(|k| (s2 * inv[(k, k)]).max(0.0).sqrt());
    let spread = poses.iter().map(|f| (f.apply(&t) - c).norm()).collect();
    Ok(TcpFit {
        t,
        c,
        t_std,
        spread,
        max_rotation_deg,
        min_singular_value: s_min,
    })
}

/// RMS distance of the points `R_i t + p_i` to their centroid (the spread of a TCP guess).
pub fn spread_rms(poses: &[Frame], t: &Vector3<f64>) -> f64 {
    if poses.is_empty() {
        return 0.0;
    }
    let pts: Vec<Vector3<f64>> = poses.iter().map(|f| f.apply(t)).collect();
    let m = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
    (pts.iter().map(|p| (p - m).norm_squared()).sum::<f64>() / pts.len() as f64).sqrt()
}

/// A ball centre in {0} from a centred flange pose and the TCP, with its covariance: the
/// TCP's (independent components of std `t_std`) carried by the pose's rotation plus an
/// isotropic centring noise of std `noise`.
pub fn ball_position(
    flange: &Frame,
    t: &Vector3<f64>,
    t_std: &[f64; 3],
    noise: f64,
) -> (Vector3<f64>, Matrix3<f64>) {
    let st = Matrix3::from_diagonal(&Vector3::from(t_std.map(|s| s * s)));
    let cov = flange.r * st * flange.r.transpose() + Matrix3::identity() * noise * noise;
    (flange.apply(t), cov)
}

/// Distance between two uncertain points and its standard deviation (first order, the
/// two covariances taken as independent).
pub fn distance(a: &(Vector3<f64>, Matrix3<f64>), b: &(Vector3<f64>, Matrix3<f64>)) -> (f64, f64) {
    let d = b.0 - a.0;
    let n = d.norm();
    let u = if n > 0.0 { d / n } else { Vector3::x() };
    (n, (u.transpose() * (a.1 + b.1) * u)[0].max(0.0).sqrt())
}

/// The base frame ({0} in {W}) carrying the measured balls (in {0}) onto the plate's ball
/// centres (in {W}), and the residual distance of each ball after the fit.
pub fn fit_base(
    in_robot: &[Vector3<f64>],
    in_world: &[Vector3<f64>],
) -> Result<(Frame, Vec<f64>), CommissionError> {
    let f = kabsch(in_robot, in_world).ok_or(CommissionError::Degenerate)?;
    let res = residuals(&f, in_robot, in_world);
    Ok((f, res))
}

/// Distance of each `base * in_robot[k]` to `in_world[k]`.
pub fn residuals(base: &Frame, in_robot: &[Vector3<f64>], in_world: &[Vector3<f64>]) -> Vec<f64> {
    in_robot
        .iter()
        .zip(in_world)
        .map(|(p, w)| (base.apply(p) - w).norm())
        .collect()
}

/// Root mean square of `v`.
pub fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

#[cfg(test)]
mod tests;
