//! Markers on an [`ElasticTree`]: residual = model marker position - measured position
//! (three rows per visible marker), fits of chosen parameter groups with the shared pipeline
//! (rank detection in priority order on physically scaled columns, LM, uncertainty), the
//! cumulative table of the elastic-humanoid paper and K-fold held-out errors.

use nalgebra::{DMatrix, Vector3};
use serde::{Deserialize, Serialize};

use super::tree_prior::TreePrior;
use crate::identify::prior::PriorReport;
use crate::identify::{
    IdentifyError, Pivoting, Prior, Problem, Solution, SolveOptions, Unknown, solve, solve_map,
};
use crate::model::elastic::{ElasticTree, Groups, TParam, TreeSample};
use crate::util::{Monitor, Summary};

/// One sample: joint values (with gravity features) and each marker's measured position.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeObservation {
    /// Joint values and gravity features.
    pub sample: TreeSample,
    /// Measured position of every model marker (m, measurement frame); `None` = occluded.
    pub points: Vec<Option<Vector3<f64>>>,
}

/// The least-squares problem over the unknowns `free` (indices into the model's params).
#[derive(Debug, Clone)]
pub struct TreeProblem {
    model: ElasticTree,
    free: Vec<usize>,
    obs: Vec<TreeObservation>,
    rows: Vec<(usize, usize)>,
    /// Square roots of per-marker weights (one per visible marker, in row order).
    sqrt_w: Option<Vec<f64>>,
}

/// (observation, marker) of every measured marker, in observation then marker order: the
/// rows of a [`TreeProblem`]'s residual, three each.
pub fn observed_points(obs: &[TreeObservation]) -> Vec<(usize, usize)> {
    obs.iter()
        .enumerate()
        .flat_map(|(i, o)| {
            o.points
                .iter()
                .enumerate()
                .filter(|(_, p)| p.is_some())
                .map(move |(m, _)| (i, m))
        })
        .collect()
}

impl TreeProblem {
    /// The problem with unknowns `free`, starting from the model's current values.
    pub fn new(model: ElasticTree, free: Vec<usize>, obs: Vec<TreeObservation>) -> Self {
        let rows = observed_points(&obs);
        Self {
            model,
            free,
            obs,
            rows,
            sqrt_w: None,
        }
    }

    /// The same problem with every visible marker's three rows multiplied by `sqrt_w` (one
    /// factor per visible marker, observations in order, markers in order within).
    pub fn weighted(mut self, sqrt_w: Vec<f64>) -> Self {
        self.sqrt_w = Some(sqrt_w);
        self
    }

    fn row_factor(&self, k: usize) -> f64 {
        self.sqrt_w
            .as_ref()
            .and_then(|w| w.get(k).copied())
            .unwrap_or(1.0)
    }

    /// Starting unknowns.
    pub fn initial(&self) -> Vec<f64> {
        self.free
            .iter()
            .map(|&g| self.model.value(self.model.params[g]))
            .collect()
    }

    /// The model with the unknowns set to `x`.
    pub fn model(&self, x: &[f64]) -> ElasticTree {
        let mut m = self.model.clone();
        m.set_values(&self.free, x);
        m
    }

    /// Names, units and physical scales of the unknowns.
    pub fn unknowns(&self) -> Vec<Unknown> {
        self.free
            .iter()
            .map(|&g| {
                let p = self.model.params[g];
                Unknown {
                    name: self.model.param_name(p),
                    unit: self.model.param_unit(p).into(),
                    to_report: 1.0,
                    nominal: self.model.value(p),
                    plausible_range: p.plausible_range(),
                    lower: None,
                    upper: None,
                }
            })
            .collect()
    }

    /// Rank-detection column order: the parameters' priority classes, model order within.
    pub fn priority_order(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.free.len()).collect();
        order.sort_by_key(|&k| (self.model.params[self.free[k]].priority(), k));
        order
    }

    /// Positions (within `free`) of the frame unknowns: the root pose and the markers.
    pub fn nuisance(&self) -> Vec<usize> {
        (0..self.free.len())
            .filter(|&k| {
                matches!(
                    self.model.params[self.free[k]],
                    TParam::Base(_) | TParam::Marker(..)
                )
            })
            .collect()
    }
}

impl Problem for TreeProblem {
    fn residual_count(&self) -> usize {
        3 * self.rows.len()
    }

    fn unknown_count(&self) -> usize {
        self.free.len()
    }

    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        let model = self.model(x);
        let mut k = 0;
        for (i, o) in self.obs.iter().enumerate() {
            let pred = model.marker_positions(&o.sample);
            while k < self.rows.len() && self.rows[k].0 == i {
                let m = self.rows[k].1;
                let e = (pred[m] - o.points[m].unwrap_or(pred[m])) * self.row_factor(k);
                r[3 * k..3 * k + 3].copy_from_slice(e.as_slice());
                k += 1;
            }
        }
        Ok(())
    }

    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        let model = self.model(x);
        let mut k = 0;
        for (i, o) in self.obs.iter().enumerate() {
            let start = k;
            while k < self.rows.len() && self.rows[k].0 == i {
                k += 1;
            }
            model.marker_jacobians(&o.sample, |m, _, jac| {
                if let Some(row) = (start..k).find(|&r| self.rows[r].1 == m) {
                    let w = self.row_factor(row);
                    for (c, &g) in self.free.iter().enumerate() {
                        for (a, v) in jac[g].iter().enumerate() {
                            j[(3 * row + a, c)] = *v * w;
                        }
                    }
                }
            });
        }
        Ok(())
    }
}

/// Gravity features of every observation recomputed from `model` (the starting model of a
/// fit, elasticity off).
pub fn with_features(model: &ElasticTree, obs: &[TreeObservation]) -> Vec<TreeObservation> {
    obs.iter()
        .map(|o| TreeObservation {
            sample: model.sample(o.sample.q.clone()),
            points: o.points.clone(),
        })
        .collect()
}

/// Euclidean error (mm) of every visible marker of every observation.
pub fn errors_mm(model: &ElasticTree, obs: &[TreeObservation]) -> Vec<f64> {
    obs.iter()
        .flat_map(|o| {
            let pred = model.marker_positions(&o.sample);
            o.points
                .iter()
                .zip(pred)
                .filter_map(|(p, q)| p.map(|p| (q - p).norm() * 1e3))
                .collect::<Vec<_>>()
        })
        .collect()
}

/// A fit and its errors.
#[derive(Debug, Clone)]
pub struct TreeFit {
    /// The fitted model.
    pub model: ElasticTree,
    /// The pipeline's solution (held parameters, uncertainty, status).
    pub solution: Solution,
    /// Unknown names in solution order.
    pub names: Vec<String>,
    /// The unknowns as indices into the model's params, in solution order.
    pub free: Vec<usize>,
    /// The MAP report when the user's prior took part (its weight and noise, the objective
    /// with the internal elastic rows included).
    pub prior: Option<PriorReport>,
}

/// Starting compliance of the bodies lumping (rad/(N*m)): a stiff arm joint.
pub const SEED_COMPLIANCE: f64 = 2e-5;

/// Prior standard deviation of the elasticity parameters, in physical scales (1 mrad for
/// lumped coefficients; 5 N*m, 20 N, 5e-5 rad/(N*m) for weights and compliances).
pub const ELASTIC_PRIOR_SCALES: f64 = 10.0;

/// Fit the groups `groups` (plus root pose and markers) starting from `model` (bodies
/// lumping: compliances still at zero start from [`SEED_COMPLIANCE`]), with gravity
/// features from `model`, under the user's `prior` (none: least squares with the internal
/// elastic regulariser).
pub fn fit(
    model: &ElasticTree,
    obs: &[TreeObservation],
    groups: Groups,
    max_iterations: usize,
    prior: &TreePrior,
    monitor: &dyn Monitor,
) -> Result<TreeFit, IdentifyError> {
    fit_weighted(model, obs, groups, max_iterations, prior, None, monitor)
}

/// [`fit`] with every visible marker's residual multiplied by `sqrt_w` (see
/// [`TreeProblem::weighted`]; `None`: all 1).
pub fn fit_weighted(
    model: &ElasticTree,
    obs: &[TreeObservation],
    groups: Groups,
    max_iterations: usize,
    prior: &TreePrior,
    sqrt_w: Option<&[f64]>,
    monitor: &dyn Monitor,
) -> Result<TreeFit, IdentifyError> {
    let mut start = model.clone();
    start.seed_compliance(groups, SEED_COMPLIANCE);
    let mut problem = TreeProblem::new(start, model.free_params(groups), with_features(model, obs));
    if let Some(w) = sqrt_w {
        problem = problem.weighted(w.to_vec());
    }
    let x0 = problem.initial();
    let mut so = SolveOptions {
        pivoting: Pivoting::Priority(problem.priority_order()),
        nuisance: Some(problem.nuisance()),
        ..Default::default()
    };
    so.lm.max_iterations = max_iterations;
    // A relative cost change below 1e-10 per iteration is far below what thousands of
    // marker coordinates can distinguish; 1e-12 lets LM crawl along weakly determined
    // directions of these over-parameterised trees for hundreds of iterations.
    so.lm.ftol = 1e-10;
    let unknowns = problem.unknowns();
    let elastic = |p: TParam| {
        matches!(
            p,
            TParam::Weight(..) | TParam::Compliance(..) | TParam::Elastic(..)
        )
    };
    let user = prior.sigmas(model, &problem.free, &unknowns)?;
    let has_user = user.iter().any(Option::is_some);
    let has_elastic = problem.free.iter().any(|&g| elastic(model.params[g]));
    let rms = |x: &[f64]| -> Result<f64, IdentifyError> {
        let mut r = vec![0.0; problem.residual_count()];
        problem.residuals(x, &mut r)?;
        Ok((r.iter().map(|v| v * v).sum::<f64>() / r.len().max(1) as f64).sqrt())
    };
    // The data's noise: the user's, else the residual RMS of the fit without their prior
    // (run first), else (internal regulariser only) the start's residual RMS.
    let noise = match (prior.noise_m, has_user) {
        (Some(s), true) => s,
        (None, true) => {
            let ls = fit_weighted(
                model,
                obs,
                groups,
                max_iterations,
                &TreePrior::default(),
                sqrt_w,
                monitor,
            )?;
            rms(&ls.solution.x)?
        }
        _ => rms(&x0)?,
    };
    let (solution, report) = if has_elastic || has_user {
        // Elasticity is weakly determined along some directions (products of weights and
        // compliances; coefficients close to geometry): a weak Gaussian prior, 10 physical
        // scales around the start, keeps LM from crawling along them.
        let map = Prior {
            sigma: problem
                .free
                .iter()
                .zip(&user)
                .map(|(&g, u)| {
                    let p = model.params[g];
                    u.or_else(|| elastic(p).then(|| ELASTIC_PRIOR_SCALES * p.plausible_range()))
                })
                .collect(),
            mean: x0.clone(),
            noise: noise.max(1e-9),
            weight: 1.0,
        };
        let (sol, rep) = solve_map(&problem, &unknowns, &x0, &map, &so, monitor)?;
        (sol, has_user.then_some(rep))
    } else {
        (solve(&problem, &unknowns, &x0, &so, monitor)?, None)
    };
    Ok(TreeFit {
        model: problem.model(&solution.x),
        names: unknowns.into_iter().map(|u| u.name).collect(),
        free: problem.free.clone(),
        solution,
        prior: report,
    })
}

/// One column of the cumulative table.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Step {
    /// What the step adds.
    pub name: String,
    /// Marker position errors over all observations (mm).
    pub error_mm: Summary,
    /// Unknowns of the fit, and how many were held at their start value.
    pub unknowns: usize,
    /// Held unknowns (named).
    pub held: Vec<String>,
    /// `converged`, `degenerate` or `not_converged`.
    pub status: String,
    /// Condition number of the physically scaled Jacobian of the identified set.
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub condition_number: f64,
}

/// The groups of the five cumulative steps: frames; + offsets; + geometry; + joint
/// compliance; + lateral compliance.
pub const STEPS: [(&str, Groups); 5] = [
    (
        "frames only (root pose, markers)",
        Groups {
            offsets: false,
            geometry: false,
            joint: false,
            lateral: false,
        },
    ),
    (
        "+ joint offsets",
        Groups {
            offsets: true,
            geometry: false,
            joint: false,
            lateral: false,
        },
    ),
    (
        "+ full geometry (alpha, a, beta, d, mounts)",
        Groups {
            offsets: true,
            geometry: true,
            joint: false,
            lateral: false,
        },
    ),
    (
        "+ joint compliance (lumped)",
        Groups {
            offsets: true,
            geometry: true,
            joint: true,
            lateral: false,
        },
    ),
    (
        "+ lateral compliance (lumped)",
        Groups {
            offsets: true,
            geometry: true,
            joint: true,
            lateral: true,
        },
    ),
];

/// The outcome of [`cumulative`].
#[derive(Debug, Clone)]
pub struct Cumulative {
    /// One line per step.
    pub steps: Vec<Step>,
    /// The last step's fit.
    pub last: TreeFit,
    /// The model the last step started from (its gravity features come from it).
    pub start: ElasticTree,
}

/// Run the cumulative steps `0..=last` of [`STEPS`], each starting from the previous
/// step's model.
pub fn cumulative(
    model: &ElasticTree,
    obs: &[TreeObservation],
    last: usize,
    max_iterations: usize,
    prior: &TreePrior,
    monitor: &dyn Monitor,
) -> Result<Cumulative, IdentifyError> {
    let mut start = model.clone();
    let mut steps = Vec::new();
    let mut fitted: Option<TreeFit> = None;
    for (name, groups) in STEPS.iter().take(last.min(4) + 1) {
        if let Some(f) = fitted.take() {
            start = f.model;
        }
        let f = fit(&start, obs, *groups, max_iterations, prior, monitor)?;
        let e = errors_mm(&f.model, &with_features(&start, obs));
        steps.push(Step {
            name: (*name).into(),
            error_mm: Summary::of(&e, "mm"),
            unknowns: f.names.len(),
            held: f.solution.unidentifiable.clone(),
            status: f.solution.status().into(),
            condition_number: f.solution.condition_number,
        });
        let m = &steps[steps.len() - 1].error_mm;
        monitor.progress(
            steps.len() as f64 / (last.min(4) + 1) as f64,
            &format!(
                "{name}: {:.2} / {:.2} / {:.2} mm (mean / std / max)",
                m.mean, m.std, m.max
            ),
        );
        fitted = Some(f);
    }
    match fitted {
        Some(last) => Ok(Cumulative { steps, last, start }),
        None => Err(IdentifyError::Model("no step to run".into())),
    }
}

mod kfold;
pub use kfold::{KFold, k_fold, k_fold_with};

#[cfg(test)]
mod tests;
