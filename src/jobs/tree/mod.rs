//! `tree.identify`: elasto-geometric calibration of a tree of modified-DH rows (a humanoid
//! upper body: torso and arms) from marker positions, with elasticity identified *without
//! torques or masses*: lumped joint and lateral compliance (issue 13, item 5). Runs the
//! cumulative steps (frames; + offsets; + full geometry; + joint compliance; + lateral
//! compliance), reports the last fit's parameters and, optionally, a K-fold held-out error.

use std::collections::BTreeSet;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::geometry::Frame;
use crate::identify::ParamReport;
use crate::identify::duplicates::duplicate_configurations;
use crate::identify::prior::{PriorReport, PriorSpec, PriorWeight};
use crate::identify::verdict::{self, Assessment, Facts};
use crate::jobs::map_options::{MapWeight, check_map_options};
use crate::measure::tree_markers::{STEPS, Step, TreeObservation, TreeProblem, with_features};
use crate::measure::tree_prior::{TreePrior, check_names, choose_tree_weight};
use crate::measure::tree_robust::{RobustOutcome, TreeRobust, cumulative_robust, k_fold_robust};
use crate::model::elastic::{
    Drive, ElasticOptions, ElasticTree, Lumping, RowKind, TreeMarker, TreeRow,
};
use crate::run::Run;
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, computed, parse_spec};
use crate::util::{Monitor, Summary};

mod justin;
mod report;
mod spec;
pub(crate) use spec::Spec;
pub use spec::prepare;

/// A validated `tree.identify` job.
#[derive(Debug)]
pub struct TreeIdentifyJob {
    model: ElasticTree,
    obs: Vec<TreeObservation>,
    last: usize,
    folds: Option<usize>,
    seed: u64,
    max_iterations: usize,
    prior: TreePrior,
    /// Choose the prior's weight by K-fold before the fits.
    cv_weight: bool,
    warnings: Vec<String>,
    /// The model came from the Agile Justin data set's files (`justin`).
    justin: bool,
    /// A robust refit of the last step.
    robust: Option<TreeRobust>,
}

/// One of the largest marker errors of the last model.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct WorstSample {
    /// Sample (0-based data row of the samples table).
    pub sample: usize,
    /// Marker name.
    pub marker: String,
    /// 3-D error (mm).
    pub error_mm: f64,
    /// The sample's joint values, as in the table (`variables` order).
    pub q: Vec<f64>,
}

/// How many of the largest errors the result lists.
const WORST: usize = 10;

/// Held-out figure of the last model.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HeldOut {
    /// K.
    pub folds: usize,
    /// Seed of the split.
    pub seed: u64,
    /// Marker position errors on the held-out folds (mm).
    pub error_mm: Summary,
}

/// The result of `tree.identify`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TreeCalibration {
    /// `verdict` (`accepted`, `review`, `rejected`) and its `reasons`.
    #[serde(flatten)]
    pub assessment: Assessment,
    /// Residual degrees of freedom of the last fit: distinct marker equations minus
    /// identified unknowns.
    pub dof: usize,
    /// Residual standard deviation of the last fit (mm), counted over distinct
    /// configurations (null with zero degrees of freedom).
    pub residual_std_mm: Option<f64>,
    /// Cumulative steps: frames; + offsets; + geometry; + joint; + lateral compliance.
    pub steps: Vec<Step>,
    /// The last fit's parameters (lengths m, angles rad, lumped coefficients rad at full
    /// gravity load).
    pub parameters: Vec<ParamReport>,
    /// Parameters held at their start value in the last fit.
    pub unidentifiable: Vec<String>,
    /// `converged`, `degenerate` or `not_converged` (last fit).
    pub status: String,
    /// Condition number of the physically scaled Jacobian (last fit).
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub condition_number: f64,
    /// Mean marker error of the last model (mm).
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub error_after_mean_mm: f64,
    /// K-fold held-out errors of the last model, when asked for.
    pub held_out: Option<HeldOut>,
    /// The K-fold's predicted accuracy: per held-out marker, its error against the fold
    /// fit's predicted covariance, and the fraction within 2 sigma (mm; with `folds`).
    #[serde(default)]
    pub coverage: Option<crate::identify::coverage::Coverage>,
    /// What the lumped coefficients mean (not read back).
    #[serde(skip_deserializing)]
    pub elasticity_note: &'static str,
    /// Unused table columns.
    pub warnings: Vec<String>,
    /// Which mode ran for the user's prior (`least_squares`: none; `map`; `map_cv`), its
    /// weight and noise (m), and the last fit's objective terms (noise units).
    pub prior: PriorReport,
    /// The ten largest marker errors of the last model, largest first.
    pub worst_samples: Vec<WorstSample>,
    /// `options.robust`: the loss, its scale and the down-weighted measurements.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robust: Option<RobustOutcome>,
    /// `justin`: the published figures beside the first five steps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub published: Option<Vec<justin::Published>>,
}

const NOTE: &str = "gravity along -z of the tree root; lumping `subtree`: coefficients kz_g*, kx_g*, ky_g* (rad at full gravity load) multiply the unit gravity direction in the joint frame (joint deflection about z, lateral about x and y); lumping `bodies`: compliances c_z, c_x, c_y (rad/(N*m)) times the gravity torque of link weights w (N) and weight moments w_m* (N*m), only their products determined";

impl TreeIdentifyJob {
    /// Verdict, `dof`, and the residual std (m) with the factor on standard deviations
    /// (`Some` only when configurations repeat) of the last fit `sol`, counting distinct
    /// configurations.
    fn judge(
        &self,
        sol: &crate::identify::Solution,
        coverage: Option<&crate::identify::coverage::Coverage>,
    ) -> (Assessment, usize, (Option<f64>, Option<f64>)) {
        let equations: usize = 3 * self
            .obs
            .iter()
            .map(|o| o.points.iter().flatten().count())
            .sum::<usize>();
        let free = sol.free.len();
        let dup = duplicate_configurations(self.obs.iter().map(|o| o.sample.q.as_slice()));
        let mut dof = verdict::dof(equations, free);
        let mut sigma = (Some(sol.uncertainty.sigma).filter(|s| s.is_finite()), None);
        if dup.repeated() > 0 {
            let ssr: f64 = sol.residuals.iter().take(equations).map(|v| v * v).sum();
            let e = dup.effective(equations, free, ssr, sol.uncertainty.sigma);
            dof = e.dof;
            sigma = (e.sigma, Some(e.std_factor.unwrap_or(f64::NAN)));
        }
        if dof == 0 {
            sigma.0 = None;
        }
        let facts = Facts {
            status: sol.status().to_string(),
            degenerate: sol.degenerate.as_ref().map(|d| d.reasons.join("; ")),
            equations,
            unknowns: free,
            dof,
            duplicates: Some(dup),
            coverage: coverage.cloned(),
            ..Default::default()
        };
        (verdict::assess(&facts), dof, sigma)
    }

    /// The [`WORST`] largest marker errors of `model` (gravity features from `start`).
    fn worst(&self, model: &ElasticTree, start: &ElasticTree) -> Vec<WorstSample> {
        let feats = with_features(start, &self.obs);
        let mut all: Vec<WorstSample> = feats
            .iter()
            .enumerate()
            .flat_map(|(i, o)| {
                let pred = model.marker_positions(&o.sample);
                o.points
                    .iter()
                    .zip(pred)
                    .enumerate()
                    .filter_map(|(m, (p, q))| p.map(|p| (m, (q - p).norm() * 1e3)))
                    .map(|(m, e)| WorstSample {
                        sample: i,
                        marker: model.markers[m].name.clone(),
                        error_mm: e,
                        q: o.sample.q.clone(),
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        all.sort_by(|a, b| b.error_mm.total_cmp(&a.error_mm));
        all.truncate(WORST);
        all
    }

    /// Run the cumulative fits and the optional K-fold.
    pub fn calibrate(&self, monitor: &dyn Monitor) -> Result<Run<TreeCalibration>, JobError> {
        let fail = JobError::from;
        let mut prior = self.prior.clone();
        let mut k_fold_errors = None;
        if self.cv_weight {
            let (w, errors) = choose_tree_weight(
                &self.model,
                &self.obs,
                self.last,
                self.max_iterations,
                &prior,
                self.seed,
                monitor,
            )
            .map_err(fail)?;
            prior.weight = w;
            k_fold_errors = Some(errors);
        }
        let (c, robust) = cumulative_robust(
            &self.model,
            &self.obs,
            self.last,
            self.max_iterations,
            &prior,
            self.robust.as_ref(),
            monitor,
        )
        .map_err(fail)?;
        let (held_out, coverage) = match self.folds {
            Some(k) => {
                let kf = k_fold_robust(
                    &self.model,
                    &self.obs,
                    self.last,
                    k,
                    self.seed,
                    self.max_iterations,
                    &prior,
                    self.robust.as_ref(),
                    monitor,
                )
                .map_err(fail)?;
                let h = HeldOut {
                    folds: k,
                    seed: self.seed,
                    error_mm: Summary::of(&kf.errors_mm, "mm"),
                };
                (Some(h), kf.coverage)
            }
            None => (None, None),
        };
        let sol = &c.last.solution;
        let (assessment, dof, sigma) = self.judge(sol, coverage.as_ref());
        let mut parameters = sol.params.clone();
        if let Some(f) = sigma.1 {
            for p in &mut parameters {
                p.std = p.std.filter(|_| f.is_finite()).map(|s| s * f);
            }
        }
        let artefacts = coverage
            .iter()
            .map(|c| {
                crate::report::svg_artefact(
                    "predicted_accuracy.svg",
                    crate::report::coverage::predicted_accuracy(c),
                )
            })
            .collect();
        Ok(Run {
            result: TreeCalibration {
                assessment,
                dof,
                residual_std_mm: sigma.0.map(|s| s * 1e3),
                error_after_mean_mm: c.steps.last().map_or(f64::NAN, |s| s.error_mm.mean),
                steps: c.steps.clone(),
                parameters,
                unidentifiable: sol.unidentifiable.clone(),
                status: sol.status().into(),
                condition_number: sol.condition_number,
                held_out,
                coverage,
                elasticity_note: NOTE,
                warnings: self.warnings.clone(),
                prior: match c.last.prior.clone() {
                    Some(mut r) => {
                        r.weight = Some(prior.weight);
                        if let Some(e) = k_fold_errors {
                            r.mode = "map_cv";
                            r.k_fold_errors = Some(e);
                        }
                        r
                    }
                    None => PriorReport::least_squares(),
                },
                worst_samples: self.worst(&c.last.model, &c.start),
                robust,
                published: self.justin.then(justin::published),
            },
            main_table: None,
            artefacts,
        })
    }
}

impl Kind for TreeIdentifyJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::calibrate)
    }
}

#[cfg(test)]
mod tests;
