//! A user's Gaussian prior on a tree's parameters (`tree.identify` MAP): per-name and default
//! standard deviations ([`PriorSpec`]), a weight (fixed, or chosen by K-fold on the samples),
//! and the measurement noise that balances the data against it.
//!
//! The user's prior joins the internal weak prior on elasticity (see
//! [`super::tree_markers::ELASTIC_PRIOR_SCALES`]): where the user states a std, it replaces the
//! internal one. Defaults by unit apply to the model's geometry and joint compliances, not to
//! the root pose and markers (nuisance unknowns) nor to lumped coefficients and link weights
//! (named entries reach those).

use crate::identify::duplicates::duplicate_configurations;
use crate::identify::prior::{CV_FOLDS, CV_WEIGHTS, FoldError, PriorSpec, choose_weight_grouped};
use crate::identify::{IdentifyError, Unknown};
use crate::model::elastic::{ElasticTree, TParam};
use crate::util::Monitor;

use super::tree_markers::{TreeObservation, cumulative, errors_mm, with_features};

/// The user's prior of a tree fit; the default is none (least squares with the internal
/// elastic regulariser).
#[derive(Debug, Clone, Default)]
pub struct TreePrior {
    /// Per-name and default standard deviations; `None` for no user prior.
    pub spec: Option<PriorSpec>,
    /// Weight `lambda` (folded into the std: `sigma / sqrt(lambda)`).
    pub weight: f64,
    /// Measurement noise `s` (m per coordinate); `None`: the residual RMS of the fit without
    /// the user's prior, run first.
    pub noise_m: Option<f64>,
}

impl TreePrior {
    /// Whether a user prior is given.
    pub fn is_some(&self) -> bool {
        self.spec.is_some()
    }

    /// The user's std per unknown (internal units, divided by `sqrt(weight)`), `None` where
    /// the user states none. Named entries for unknowns not in `unknowns` (another step's
    /// parameters) are skipped; see [`check_names`] for the job's check.
    pub fn sigmas(
        &self,
        model: &ElasticTree,
        free: &[usize],
        unknowns: &[Unknown],
    ) -> Result<Vec<Option<f64>>, IdentifyError> {
        let Some(spec) = &self.spec else {
            return Ok(vec![None; unknowns.len()]);
        };
        let mut here = spec.clone();
        here.std
            .retain(|name, _| unknowns.iter().any(|u| &u.name == name));
        let takes_default = |k: usize| match model.params[free[k]] {
            TParam::Base(_) | TParam::Marker(..) => false,
            TParam::Weight(..) | TParam::Elastic(..) => false,
            _ => true,
        };
        let root = self.weight.max(f64::MIN_POSITIVE).sqrt();
        Ok(here
            .sigmas(unknowns, takes_default)
            .map_err(IdentifyError::Model)?
            .into_iter()
            .map(|s| s.map(|s| s / root))
            .collect())
    }
}

/// Check that every named std names an unknown of `unknowns` (the last step's): the error
/// message names the entry.
pub fn check_names(spec: &PriorSpec, unknowns: &[Unknown]) -> Result<(), String> {
    match spec
        .std
        .keys()
        .find(|n| !unknowns.iter().any(|u| &u.name == *n))
    {
        Some(n) => Err(format!("std.{n}: no such parameter to identify")),
        None => Ok(()),
    }
}

/// Choose the weight among [`CV_WEIGHTS`] by [`CV_FOLDS`]-fold cross-validation over the
/// samples: each candidate runs the cumulative steps `0..=last` on the training folds and
/// scores the held-out marker errors (m^2 summed). Returns the weight and each candidate's
/// held-out RMS marker error (mm).
pub fn choose_tree_weight(
    model: &ElasticTree,
    obs: &[TreeObservation],
    last: usize,
    max_iterations: usize,
    prior: &TreePrior,
    seed: u64,
    monitor: &dyn Monitor,
) -> Result<(f64, Vec<FoldError>), IdentifyError> {
    let runs = (CV_WEIGHTS.len() * CV_FOLDS) as f64;
    let mut done = 0usize;
    // Copies of one configuration stay in one fold.
    let group = duplicate_configurations(obs.iter().map(|o| o.sample.q.as_slice())).group;
    choose_weight_grouped(&CV_WEIGHTS, &group, CV_FOLDS, seed, |w, train, test| {
        if monitor.is_cancelled() {
            return Err(IdentifyError::Cancelled);
        }
        monitor.progress(done as f64 / runs, "choosing the prior weight by K-fold");
        done += 1;
        let pick = |idx: &[usize]| -> Vec<TreeObservation> {
            idx.iter().map(|&i| obs[i].clone()).collect()
        };
        let candidate = TreePrior {
            weight: w,
            ..prior.clone()
        };
        let c = cumulative(
            model,
            &pick(train),
            last,
            max_iterations,
            &candidate,
            &crate::util::NoMonitor,
        )?;
        let e = errors_mm(&c.last.model, &with_features(&c.start, &pick(test)));
        Ok((e.iter().map(|v| v * v).sum(), e.len()))
    })
}
