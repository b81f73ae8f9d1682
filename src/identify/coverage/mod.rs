//! Output-space uncertainty: the predicted covariance of the 3-D error at a held-out point,
//! `J Sigma_p J^T + sigma_noise^2 I`, and the coverage of the held-out errors by their
//! predicted 2-sigma region (chi-square with 3 degrees of freedom, see [`CHI2_3_AT_2SIGMA`]).

use nalgebra::{DMatrix, Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Probability of a 1-D normal within 2 sigma, erf(sqrt 2): the coverage a correct noise
/// model gives in expectation.
pub const TWO_SIGMA_PROBABILITY: f64 = 0.954_499_736_103_641_6;

/// The chi-square (3 degrees of freedom) quantile at [`TWO_SIGMA_PROBABILITY`]: a 3-D error
/// `e` with predicted covariance `C` is within 2 sigma when `e^T C^-1 e` is at most this
/// (the 3-D region with the 1-D 2-sigma probability; radius 2.833 in Mahalanobis units).
pub const CHI2_3_AT_2SIGMA: f64 = 8.024_881_760_266_245;

/// Below this fraction of held-out errors within 2 predicted sigma the noise model is too
/// optimistic (the verdict's `noise_model_optimistic`).
pub const MIN_COVERAGE: f64 = 0.90;

/// One held-out point: its error and the predicted spread.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PredictedPoint {
    /// Length of the held-out error (length unit).
    pub error: f64,
    /// Predicted RMS length of the error, sqrt(trace C), model and noise (length unit).
    pub predicted_rms: f64,
    /// Predicted RMS length of the model's part, sqrt(trace J Sigma_p J^T) (length unit).
    pub model_rms: f64,
    /// Squared Mahalanobis length of the error, e^T C^-1 e (unitless).
    pub mahalanobis2: f64,
    /// Whether `mahalanobis2` is within [`CHI2_3_AT_2SIGMA`].
    pub within_2sigma: bool,
}

/// `coverage` of a result: how many held-out errors lie within their predicted 2 sigma.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Coverage {
    /// Fraction of held-out points whose error is within 2 predicted sigma (3-D chi-square).
    pub fraction_within_2sigma: f64,
    /// Held-out points.
    pub n: usize,
    /// The fraction a correct noise model gives in expectation (0.9545).
    pub expected: f64,
    /// The chi-square (3 dof) bound of e^T C^-1 e used (8.0249).
    pub chi2_bound: f64,
    /// The measurement noise std per axis counted in C (length unit).
    pub noise_std: f64,
    /// Where the noise comes from: `options.noise` or `training residual`.
    pub noise_from: String,
    /// Length unit of the point figures.
    pub unit: String,
    /// RMS length of the held-out errors, sqrt(mean |e|^2) (length unit).
    #[serde(default, deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub rms_error: f64,
    /// Predicted RMS length, sqrt(mean trace C): `rms_error` in expectation when the
    /// predicted covariances are right (length unit).
    #[serde(default, deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub rms_predicted: f64,
    /// Per held-out point, in validation order.
    pub points: Vec<PredictedPoint>,
}

impl Coverage {
    /// Whether the coverage is below [`MIN_COVERAGE`].
    pub fn optimistic(&self) -> bool {
        self.n > 0 && self.fraction_within_2sigma < MIN_COVERAGE
    }
}

/// The coverage of held-out `errors` (model minus measured, 3-D) whose prediction Jacobians
/// (3 x free unknowns, `jacobians`) and parameter covariance `sigma_p` (free x free) are
/// given, with per-axis measurement noise `noise_std`. `None` when a predicted covariance
/// is not positive semi-definite.
pub fn coverage(
    errors: &[Vector3<f64>],
    jacobians: &[DMatrix<f64>],
    sigma_p: &DMatrix<f64>,
    noise_std: f64,
    noise_from: &str,
    unit: &str,
) -> Option<Coverage> {
    let covariances = jacobians.iter().map(|j| {
        let m = j * sigma_p * j.transpose();
        let model = Matrix3::from_fn(|r, c| m[(r, c)]);
        (model, model + Matrix3::identity() * noise_std * noise_std)
    });
    of_covariances(errors, covariances, noise_std, noise_from, unit)
}

/// The coverage of held-out `errors` given, per point, the predicted covariance of the
/// model's part and of the whole error (model and noise).
pub fn of_covariances(
    errors: &[Vector3<f64>],
    covariances: impl IntoIterator<Item = (Matrix3<f64>, Matrix3<f64>)>,
    noise_std: f64,
    noise_from: &str,
    unit: &str,
) -> Option<Coverage> {
    let mut points = Vec::with_capacity(errors.len());
    for (e, (model, c)) in errors.iter().zip(covariances) {
        let d2 = mahalanobis2(&c, e)?;
        points.push(PredictedPoint {
            error: e.norm(),
            predicted_rms: c.trace().max(0.0).sqrt(),
            model_rms: model.trace().max(0.0).sqrt(),
            mahalanobis2: d2,
            within_2sigma: d2 <= CHI2_3_AT_2SIGMA,
        });
    }
    Some(Coverage::of_points(points, noise_std, noise_from, unit))
}

/// `e^T C^-1 e`; where a refit leaves `C` singular (a direction fully absorbed), over its
/// range only (pseudo-inverse). `None` when `C` is not positive semi-definite.
fn mahalanobis2(c: &Matrix3<f64>, e: &Vector3<f64>) -> Option<f64> {
    if let Some(ch) = c.cholesky() {
        return Some((e.transpose() * ch.inverse() * e)[(0, 0)]);
    }
    let eig = c.symmetric_eigen();
    let top = eig.eigenvalues.max();
    if !(top > 0.0) || eig.eigenvalues.min() < -1e-9 * top {
        return None;
    }
    Some(
        (0..3)
            .filter(|&k| eig.eigenvalues[k] > 1e-12 * top)
            .map(|k| eig.eigenvectors.column(k).dot(e).powi(2) / eig.eigenvalues[k])
            .sum(),
    )
}

impl Coverage {
    /// The coverage of `points` with the stated noise.
    pub fn of_points(
        points: Vec<PredictedPoint>,
        noise_std: f64,
        noise_from: &str,
        unit: &str,
    ) -> Coverage {
        let n = points.len();
        let within = points.iter().filter(|p| p.within_2sigma).count();
        let rms = |f: &dyn Fn(&PredictedPoint) -> f64| {
            (points.iter().map(|p| f(p).powi(2)).sum::<f64>() / n as f64).sqrt()
        };
        Coverage {
            rms_error: rms(&|p| p.error),
            rms_predicted: rms(&|p| p.predicted_rms),
            fraction_within_2sigma: if n > 0 {
                within as f64 / n as f64
            } else {
                f64::NAN
            },
            n,
            expected: TWO_SIGMA_PROBABILITY,
            chi2_bound: CHI2_3_AT_2SIGMA,
            noise_std,
            noise_from: noise_from.to_string(),
            unit: unit.to_string(),
            points,
        }
    }

    /// The coverage of several held-out parts together (the folds of a K-fold): their
    /// points in order, the noise the RMS of the parts' noise.
    pub fn pooled(parts: Vec<Coverage>, noise_from: &str, unit: &str) -> Coverage {
        let k = parts.len().max(1) as f64;
        let noise = (parts.iter().map(|c| c.noise_std.powi(2)).sum::<f64>() / k).sqrt();
        let points = parts.into_iter().flat_map(|c| c.points).collect();
        Coverage::of_points(points, noise, noise_from, unit)
    }
}

mod refit;
pub use refit::{covariances_after_refit, coverage_after_refit};

#[cfg(test)]
mod tests;
