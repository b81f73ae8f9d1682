//! K-fold held-out errors of a tree calibration and their coverage: each fold's fit
//! predicts the covariance of its held-out marker errors, `J Sigma_fold J^T + sigma^2 I`
//! (root pose and markers are the training fold's, not refitted: one session), and the
//! coverage counts the errors within 2 predicted sigma over all folds.

use nalgebra::DMatrix;

use super::{Cumulative, TreeObservation, cumulative, errors_mm, with_features};
use crate::identify::IdentifyError;
use crate::identify::coverage::{Coverage, coverage};
use crate::identify::duplicates::{duplicate_configurations, shuffled_groups};
use crate::measure::tree_prior::TreePrior;
use crate::model::elastic::ElasticTree;
use crate::util::Monitor;

/// Millimetres per metre: held-out errors and their coverage are reported in mm.
const MM_PER_M: f64 = 1e3;

/// The outcome of a K-fold.
#[derive(Debug, Clone)]
pub struct KFold {
    /// Marker position errors on the held-out folds (mm), fold by fold.
    pub errors_mm: Vec<f64>,
    /// Their coverage by each fold's predicted covariance (mm); `None` when a fold has no
    /// parameter covariance.
    pub coverage: Option<Coverage>,
}

/// K-fold held-out errors (mm) of the cumulative steps `0..=last` from `model`: seeded
/// split, each fold calibrated on the others and evaluated on itself (root pose and
/// markers from the training folds: one session).
pub fn k_fold(
    model: &ElasticTree,
    obs: &[TreeObservation],
    last: usize,
    k: usize,
    seed: u64,
    max_iterations: usize,
    prior: &TreePrior,
    monitor: &dyn Monitor,
) -> Result<Vec<f64>, IdentifyError> {
    let out = k_fold_with(obs, k, seed, prior.noise_m, |train| {
        cumulative(model, train, last, max_iterations, prior, monitor)
    })?;
    Ok(out.errors_mm)
}

/// K-fold held-out errors (mm) with `fit` calibrating each fold's training part: seeded
/// split, copies of one configuration in one fold, each fold evaluated with its training
/// root pose and markers; and their coverage, with the noise `noise_m` (m per axis) when
/// the user gave it, else each fold's training residual std.
pub fn k_fold_with(
    obs: &[TreeObservation],
    k: usize,
    seed: u64,
    noise_m: Option<f64>,
    mut fit: impl FnMut(&[TreeObservation]) -> Result<Cumulative, IdentifyError>,
) -> Result<KFold, IdentifyError> {
    let dup = duplicate_configurations(obs.iter().map(|o| o.sample.q.as_slice()));
    let groups = shuffled_groups(&dup.group, seed);
    let mut held_out = Vec::new();
    let mut parts = Some(Vec::new());
    for f in 0..k {
        let (mut train, mut test) = (Vec::new(), Vec::new());
        for (n, members) in groups.iter().enumerate() {
            let side = if n % k == f { &mut test } else { &mut train };
            side.extend(members.iter().map(|&i| obs[i].clone()));
        }
        let c = fit(&train)?;
        let test = with_features(&c.start, &test);
        held_out.extend(errors_mm(&c.last.model, &test));
        let part = fold_coverage(&c, &test, noise_m);
        parts = parts.zip(part).map(|(mut v, p)| {
            v.push(p);
            v
        });
    }
    let from = match noise_m {
        Some(_) => "options.noise_m",
        None => "training residual of each fold",
    };
    Ok(KFold {
        errors_mm: held_out,
        coverage: parts.map(|p| Coverage::pooled(p, from, "mm")),
    })
}

/// The coverage of the held-out `test` observations (gravity features set) by the fit `c`
/// of the other folds: its covariance over the identified unknowns and its noise.
fn fold_coverage(
    c: &Cumulative,
    test: &[TreeObservation],
    noise_m: Option<f64>,
) -> Option<Coverage> {
    let sol = &c.last.solution;
    let cov = sol.uncertainty.covariance.as_ref()?;
    let params: Vec<usize> = sol.free.iter().map(|&k| c.last.free[k]).collect();
    let (mut errors, mut jacobians) = (Vec::new(), Vec::new());
    for o in test {
        let pred = c.last.model.marker_positions(&o.sample);
        c.last.model.marker_jacobians(&o.sample, |m, _, jac| {
            let Some(y) = o.points.get(m).copied().flatten() else {
                return;
            };
            errors.push((pred[m] - y) * MM_PER_M);
            jacobians.push(DMatrix::from_fn(3, params.len(), |r, k| {
                jac[params[k]][r] * MM_PER_M
            }));
        });
    }
    let noise = noise_m.unwrap_or(sol.uncertainty.sigma);
    coverage(
        &errors,
        &jacobians,
        cov,
        noise * MM_PER_M,
        "training residual",
        "mm",
    )
}
