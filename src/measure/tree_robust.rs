//! A robust loss for the tree fits (`tree.identify` `options.robust`): the last cumulative
//! step refitted with per-marker weights `psi(e)/e` of its own 3-D errors (iteratively
//! reweighted), so that a few badly measured samples pull the model less.

use serde::{Deserialize, Serialize};

use super::tree_markers::{
    Cumulative, KFold, STEPS, Step, TreeObservation, cumulative, errors_mm, fit_weighted,
    k_fold_with, with_features,
};
use super::tree_prior::TreePrior;
use crate::identify::IdentifyError;
use crate::identify::robust::RobustKind;
use crate::model::elastic::ElasticTree;
use crate::util::{Monitor, Summary};

/// `options.robust` of `tree.identify`.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TreeRobust {
    /// `huber` or `cauchy`.
    pub loss: RobustKind,
    /// Scale (mm of 3-D marker error); default the tuning constant x 1.4826 x the median
    /// error of the unweighted last step.
    #[serde(default)]
    pub scale_mm: Option<f64>,
    /// Reweighting rounds (default 10; stops earlier when no weight changes by 1e-3).
    #[serde(default)]
    pub rounds: Option<usize>,
}

/// One marker measurement the robust fit weighted below 0.5.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Downweighted {
    /// Sample (0-based row of the samples table).
    pub sample: usize,
    /// Marker index.
    pub marker: usize,
    /// Its final weight.
    pub weight: f64,
    /// Its 3-D error under the robust model (mm).
    pub error_mm: f64,
}

/// What the robust refit did.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RobustOutcome {
    /// The loss.
    pub loss: RobustKind,
    /// The scale used (mm).
    pub scale_mm: f64,
    /// Reweighting rounds run.
    pub rounds: usize,
    /// Marker measurements with weight below 0.5, largest error first.
    pub downweighted: Vec<Downweighted>,
    /// Marker measurements in all.
    pub markers: usize,
}

impl TreeRobust {
    fn weight(&self, e: f64, s: f64) -> f64 {
        let u = e / s;
        match self.loss {
            RobustKind::Huber => 1.0 / u.max(1.0),
            RobustKind::Cauchy => 1.0 / (1.0 + u * u),
        }
    }

    fn tuning(&self) -> f64 {
        match self.loss {
            RobustKind::Huber => 1.345,
            RobustKind::Cauchy => 2.385,
        }
    }
}

/// [`cumulative`], then (with `robust`) the last step refitted by reweighting, appended as
/// one more step (its errors unweighted, over every marker) and made the last fit.
pub fn cumulative_robust(
    model: &ElasticTree,
    obs: &[TreeObservation],
    last: usize,
    max_iterations: usize,
    prior: &TreePrior,
    robust: Option<&TreeRobust>,
    monitor: &dyn Monitor,
) -> Result<(Cumulative, Option<RobustOutcome>), IdentifyError> {
    let mut c = cumulative(model, obs, last, max_iterations, prior, monitor)?;
    let Some(r) = robust else {
        return Ok((c, None));
    };
    let groups = STEPS[last.min(STEPS.len() - 1)].1;
    let feats = with_features(&c.start, obs);
    let e0 = errors_mm(&c.last.model, &feats);
    let scale = match r.scale_mm {
        Some(s) => s,
        None => r.tuning() * 1.4826 * median(&e0),
    };
    if !(scale.is_finite() && scale > 0.0) {
        return Err(IdentifyError::Model(format!(
            "robust scale {scale} mm must be positive (the fit has no error to scale by)"
        )));
    }
    let mut w: Vec<f64> = e0.iter().map(|&e| r.weight(e, scale)).collect();
    let mut rounds = 0;
    for _ in 0..r.rounds.unwrap_or(10).max(1) {
        if monitor.is_cancelled() {
            return Err(IdentifyError::Cancelled);
        }
        let sqrt_w: Vec<f64> = w.iter().map(|v| v.sqrt()).collect();
        c.last = fit_weighted(
            &c.start,
            obs,
            groups,
            max_iterations,
            prior,
            Some(&sqrt_w),
            monitor,
        )?;
        rounds += 1;
        let e = errors_mm(&c.last.model, &feats);
        let next: Vec<f64> = e.iter().map(|&v| r.weight(v, scale)).collect();
        let change = next
            .iter()
            .zip(&w)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        w = next;
        if change < 1e-3 {
            break;
        }
    }
    let e = errors_mm(&c.last.model, &feats);
    let ids = super::tree_markers::observed_points(&obs);
    let mut downweighted: Vec<Downweighted> = ids
        .iter()
        .zip(w.iter().zip(&e))
        .filter(|(_, (w, _))| **w < 0.5)
        .map(|(&(sample, marker), (&weight, &error_mm))| Downweighted {
            sample,
            marker,
            weight,
            error_mm,
        })
        .collect();
    downweighted.sort_by(|a, b| b.error_mm.total_cmp(&a.error_mm));
    let s = &c.last.solution;
    c.steps.push(Step {
        name: format!("+ robust {:?} loss (per-marker weights)", r.loss).to_lowercase(),
        error_mm: Summary::of(&e, "mm"),
        unknowns: c.last.names.len(),
        held: s.unidentifiable.clone(),
        status: s.status().into(),
        condition_number: s.condition_number,
    });
    Ok((
        c,
        Some(RobustOutcome {
            loss: r.loss,
            scale_mm: scale,
            rounds,
            downweighted,
            markers: e.len(),
        }),
    ))
}

/// K-fold held-out errors (mm) and their coverage as [`super::tree_markers::k_fold_with`],
/// each fold calibrated by [`cumulative_robust`].
#[allow(clippy::too_many_arguments)]
pub fn k_fold_robust(
    model: &ElasticTree,
    obs: &[TreeObservation],
    last: usize,
    k: usize,
    seed: u64,
    max_iterations: usize,
    prior: &TreePrior,
    robust: Option<&TreeRobust>,
    monitor: &dyn Monitor,
) -> Result<KFold, IdentifyError> {
    k_fold_with(obs, k, seed, prior.noise_m, |train| {
        cumulative_robust(model, train, last, max_iterations, prior, robust, monitor)
            .map(|(c, _)| c)
    })
}

fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return f64::NAN;
    }
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}
