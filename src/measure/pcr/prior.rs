//! MAP identification of the 3-PF robot: a Gaussian prior on the unknowns (mean = the model
//! file's nominal values, std = the file's standard uncertainty or the job's), and the
//! choice of its weight by K-fold cross-validation on the calibration poses.
//!
//! In each step the prior adds one row `s sqrt(lambda) (x_k - mu_k) / sigma_k` per freed
//! unknown with a prior (`s` the position repeatability, so the data rows keep their units
//! and the objective is `s^2` times the one of [`crate::identify::prior`]). The gauge
//! freedoms are still fixed as in least squares (each unidentifiable combination held at
//! nominal): along a gauge the data are blind, so fixing its representative does not change
//! a single prediction, while letting a weak prior pick a point on a curved gauge orbit is
//! what makes Levenberg-Marquardt crawl.

use crate::identify::duplicates::{Duplicates, Tolerance, find_duplicates};
use crate::identify::prior::{CV_FOLDS, CV_WEIGHTS, FoldError, Prior, choose_weight_grouped};
use crate::identify::{Gauge, IdentifyError, Problem};
use crate::model::pcr::{Pcr, PcrFile};
use crate::util::Monitor;

use super::problem::PcrProblem;
use super::steps::{CalibrationOptions, identify_steps};
use super::{PcrMeasurement, UNKNOWNS};

/// A Gaussian prior on the 34 unknowns (robot parameters, then extrinsics).
#[derive(Debug, Clone, PartialEq)]
pub struct PcrPrior {
    /// Prior std per unknown (SI units); `None` for no prior.
    pub sigma: Vec<Option<f64>>,
    /// Measurement noise `s` (m): the data residuals are in noise units after dividing by it.
    pub noise: f64,
    /// Weight `lambda` of the prior term.
    pub weight: f64,
}

impl PcrPrior {
    /// Number of unknowns with a prior.
    pub fn count(&self) -> usize {
        self.sigma.iter().flatten().count()
    }

    /// The generic [`Prior`] over the unknowns `solved` (indices into the 34), with the
    /// data left in their units: the prior's std is divided by the noise instead.
    pub fn restricted(&self, solved: &[usize], mean: &[f64]) -> Prior {
        Prior {
            sigma: solved
                .iter()
                .map(|&k| self.sigma[k].map(|s| s / self.noise))
                .collect(),
            mean: solved.iter().map(|&k| mean[k]).collect(),
            noise: 1.0,
            weight: self.weight,
        }
    }

    /// Prior term `lambda * sum ((x_k - mu_k) / sigma_k)^2` (noise units) at `x`.
    pub fn cost(&self, x: &[f64], mean: &[f64]) -> f64 {
        (0..UNKNOWNS)
            .filter_map(|k| self.sigma[k].map(|s| ((x[k] - mean[k]) / s).powi(2)))
            .sum::<f64>()
            * self.weight
    }
}

/// Stage positions closer than this (m, on every stage) are one configuration: the
/// repeatability of a piezo stage is of the order of a micrometre.
pub const STAGE_DUPLICATE_TOLERANCE_M: f64 = 1e-6;

/// The duplicated configurations (stage positions within [`STAGE_DUPLICATE_TOLERANCE_M`])
/// among `measurements`.
pub fn stage_duplicates(measurements: &[PcrMeasurement]) -> Duplicates {
    let rows: Vec<(&[f64], usize)> = measurements.iter().map(|m| (m.q.as_slice(), 0)).collect();
    let mut d = find_duplicates(&rows, STAGE_DUPLICATE_TOLERANCE_M);
    d.tolerance = Tolerance::Length(STAGE_DUPLICATE_TOLERANCE_M * 1e3, "mm");
    d
}

/// Choose the prior weight among [`CV_WEIGHTS`] by [`CV_FOLDS`]-fold cross-validation on
/// the calibration poses only: each candidate runs the whole identification on the other
/// folds and scores the weighted pose residuals of the held-out fold. Returns the chosen
/// weight and every candidate's held-out RMS (m).
pub fn choose_pcr_weight(
    base: &Pcr,
    file: &PcrFile,
    calibration: &[PcrMeasurement],
    opts: &CalibrationOptions,
    seed: u64,
    monitor: &dyn Monitor,
) -> Result<(f64, Vec<FoldError>), IdentifyError> {
    let Some(prior) = &opts.prior else {
        return Err(IdentifyError::Model(
            "cross-validating a prior weight needs a prior".into(),
        ));
    };
    let angle_weight = file.repeatability.position / file.repeatability.orientation;
    let runs = (CV_WEIGHTS.len() * CV_FOLDS) as f64;
    let mut done = 0usize;
    // Copies of one configuration stay in one fold.
    let group = stage_duplicates(calibration).group;
    choose_weight_grouped(&CV_WEIGHTS, &group, CV_FOLDS, seed, |w, train, test| {
        if monitor.is_cancelled() {
            return Err(IdentifyError::Cancelled);
        }
        monitor.progress(done as f64 / runs, "choosing the prior weight by K-fold");
        done += 1;
        let fold_opts = CalibrationOptions {
            prior: Some(PcrPrior {
                weight: w,
                ..prior.clone()
            }),
            ..opts.clone()
        };
        let pick = |idx: &[usize]| -> Vec<PcrMeasurement> {
            idx.iter().map(|&i| calibration[i]).collect()
        };
        let fit = identify_steps(
            base,
            file,
            &pick(train),
            None,
            &fold_opts,
            &crate::util::NoMonitor,
        )?;
        let held = PcrProblem::new(base.clone(), pick(test), angle_weight);
        let mut r = vec![0.0; held.residual_count()];
        held.residuals(&fit.x, &mut r)?;
        Ok((r.iter().map(|v| v * v).sum(), r.len()))
    })
}

/// The gauge rows of a MAP step. Along a direction `n` the data cannot see, the MAP
/// optimum is where the prior term is stationary: `sum_k n_k (x_k - mu_k) / sigma_k^2 = 0`
/// over the unknowns with a prior. Each least-squares gauge (`scale` the file's
/// uncertainties of the solved unknowns, `sigma` their prior std) becomes that row, so a
/// strong prior is not fought by a gauge held at nominal; a direction with no unknown under
/// a prior keeps its least-squares row (nothing else fixes it).
pub fn map_gauges(gauges: Vec<Gauge>, scale: &[f64], sigma: &[Option<f64>]) -> Vec<Gauge> {
    gauges
        .into_iter()
        .map(|g| {
            // The null vector in unknown space, and its prior-weighted row.
            let n: Vec<f64> = g.direction.iter().zip(scale).map(|(v, s)| v * s).collect();
            let c: Vec<f64> = n
                .iter()
                .zip(sigma)
                .map(|(nk, s)| s.map_or(0.0, |s| nk / (s * s)))
                .collect();
            let seen: f64 = n
                .iter()
                .zip(sigma)
                .map(|(nk, s)| s.map_or(0.0, |s| (nk / s).powi(2)))
                .sum();
            let (norm_c, norm_g) = (norm(&c), norm(&g.coefficients));
            if seen < 1e-12 || norm_c == 0.0 {
                return g;
            }
            // Same constraint, scaled to the least-squares row's size.
            Gauge {
                direction: g.direction,
                coefficients: c.iter().map(|v| v * norm_g / norm_c).collect(),
            }
        })
        .collect()
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}
