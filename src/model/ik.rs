//! Inverse kinematics of a serial chain by damped least squares, used by twins, simulated
//! controllers and configuration planners (compliance off: this is what a controller does).

use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};

use super::Chain;
use crate::geometry::Frame;

/// Joint values near `q0` that put the point `tcp(q)` at `target` (position only, the
/// redundancy resolved towards `q0`), or `None` if it does not converge to 1e-9.
pub fn reach_point(
    q0: &[f64],
    target: &Vector3<f64>,
    tcp: impl Fn(&[f64]) -> Vector3<f64>,
) -> Option<Vec<f64>> {
    let mut q = q0.to_vec();
    let n = q.len();
    for _ in 0..100 {
        let e = target - tcp(&q);
        if e.norm() < 1e-9 {
            return Some(q);
        }
        let mut jac = nalgebra::DMatrix::zeros(3, n);
        for k in 0..n {
            let h = 1e-7;
            let mut qp = q.clone();
            qp[k] += h;
            let mut qm = q.clone();
            qm[k] -= h;
            jac.set_column(k, &((tcp(&qp) - tcp(&qm)) / (2.0 * h)));
        }
        let a: Matrix3<f64> = Matrix3::from_iterator((&jac * jac.transpose()).iter().copied())
            + Matrix3::identity() * 1e-2;
        let dq = jac.transpose() * (a.try_inverse()? * e);
        let step = dq.amax();
        let scale = if step > 0.2 { 0.2 / step } else { 1.0 };
        for k in 0..n {
            q[k] += dq[k] * scale;
        }
    }
    None
}

/// Joint values near `q0` that put the TCP frame of `chain` (compliance off) at `target`
/// (position and orientation), by damped least squares; `None` if it does not converge.
pub fn reach_pose(chain: &Chain, q0: &[f64], target: &Frame) -> Option<Vec<f64>> {
    let mut q = q0.to_vec();
    let err = |q: &[f64]| -> Vector6<f64> {
        let f = chain.tcp(q, None);
        let dp = target.p - f.p;
        // Rotation error: the axis-angle vector of target * f^-1 (small angles), in {W},
        // weighted so 0.01 rad counts like 1 length unit.
        let rel = target.r * f.r.transpose();
        let w = Vector3::new(
            rel[(2, 1)] - rel[(1, 2)],
            rel[(0, 2)] - rel[(2, 0)],
            rel[(1, 0)] - rel[(0, 1)],
        ) * 0.5;
        Vector6::new(dp.x, dp.y, dp.z, w.x * 100.0, w.y * 100.0, w.z * 100.0)
    };
    if q.len() != 6 {
        return None;
    }
    for _ in 0..50 {
        let e = err(&q);
        if e.norm() < 1e-9 {
            return Some(q);
        }
        let mut j = Matrix6::zeros();
        for k in 0..6 {
            let h = 1e-7;
            let mut qp = q.clone();
            qp[k] += h;
            let mut qm = q.clone();
            qm[k] -= h;
            j.set_column(k, &(-(err(&qp) - err(&qm)) / (2.0 * h)));
        }
        let a = j.transpose() * j + Matrix6::identity() * 1e-9;
        let dq = a.cholesky()?.solve(&(j.transpose() * e));
        for k in 0..6 {
            q[k] += dq[k];
        }
    }
    None
}
