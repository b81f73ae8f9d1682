//! The predicted covariance of held-out errors *after* a refit of nuisance parameters (a
//! session's base frame and marker positions) on the held-out set itself, the held
//! parameters fixed. With `J` (held) and `F` (refitted) stacked over the held-out points and
//! `P = I - F (F^T F)^-1 F^T`, the refit's residual is `P (J dp + noise)` to first order, so
//! its covariance is `P (J Sigma_p J^T + sigma^2 I) P`: the parameter directions the refit
//! absorbs (a joint offset that turns like the base) predict no error.

use nalgebra::{DMatrix, Matrix3, Vector3};

use super::{Coverage, of_covariances};

/// Singular values of the stacked refit Jacobian below this fraction of the largest are
/// directions the refit does not move (rank-deficient frames).
const RANK_TOLERANCE: f64 = 1e-10;

/// Per held-out point, the predicted covariance after the refit: of the model's part,
/// `(P J Sigma_p J^T P)_ii`, and of the whole residual, that plus `sigma^2 (P)_ii`.
/// `jacobians` are 3 x held unknowns (the columns of `sigma_p`), `refit` 3 x refitted
/// unknowns, one per point.
pub fn covariances_after_refit(
    jacobians: &[DMatrix<f64>],
    refit: &[DMatrix<f64>],
    sigma_p: &DMatrix<f64>,
    noise_std: f64,
) -> Vec<(Matrix3<f64>, Matrix3<f64>)> {
    let n = jacobians.len();
    let k = refit.first().map_or(0, DMatrix::ncols);
    // An orthonormal basis of the refit's column space over all points.
    let mut f = DMatrix::zeros(3 * n, k);
    for (i, b) in refit.iter().enumerate() {
        f.view_mut((3 * i, 0), (3, k)).copy_from(b);
    }
    let q = if k == 0 || n == 0 {
        DMatrix::zeros(3 * n, 0)
    } else {
        let svd = f.svd(true, false);
        let top = svd.singular_values.max();
        let u = svd.u.expect("U was asked for");
        let keep: Vec<usize> = (0..svd.singular_values.len())
            .filter(|&c| svd.singular_values[c] > RANK_TOLERANCE * top)
            .collect();
        DMatrix::from_fn(3 * n, keep.len(), |r, c| u[(r, keep[c])])
    };
    // Q^T J over all points, then per point P J = J_i - Q_i (Q^T J).
    let held = sigma_p.nrows();
    let mut qtj = DMatrix::zeros(q.ncols(), held);
    for (i, j) in jacobians.iter().enumerate() {
        qtj += q.rows(3 * i, 3).transpose() * j;
    }
    let noise2 = noise_std * noise_std;
    jacobians
        .iter()
        .enumerate()
        .map(|(i, j)| {
            let qi = q.rows(3 * i, 3);
            let pj = j - &qi * &qtj;
            let m = &pj * sigma_p * pj.transpose();
            let model = Matrix3::from_fn(|r, c| m[(r, c)]);
            let qq = &qi * qi.transpose();
            let p = Matrix3::from_fn(|r, c| f64::from(u8::from(r == c)) - qq[(r, c)]);
            (model, model + p * noise2)
        })
        .collect()
}

/// The coverage of held-out `errors` measured after the refit (see the module
/// documentation); `None` when a predicted covariance is not positive semi-definite.
pub fn coverage_after_refit(
    errors: &[Vector3<f64>],
    jacobians: &[DMatrix<f64>],
    refit: &[DMatrix<f64>],
    sigma_p: &DMatrix<f64>,
    noise_std: f64,
    noise_from: &str,
    unit: &str,
) -> Option<Coverage> {
    let covariances = covariances_after_refit(jacobians, refit, sigma_p, noise_std);
    of_covariances(errors, covariances, noise_std, noise_from, unit)
}
