//! Maximum a posteriori identification: a Gaussian prior on some unknowns (mean = the
//! start value, standard deviation `sigma_k`) added to the least-squares problem as extra
//! residual rows, and a K-fold choice of the prior's weight.
//!
//! The MAP objective is `sum_i r_i^2 / s^2 + lambda * sum_k (x_k - mu_k)^2 / sigma_k^2`
//! with `s` the measurement noise: [`MapProblem`] stacks the data rows divided by `s` and
//! one row `sqrt(lambda) (x_k - mu_k) / sigma_k` per unknown with a prior, and [`solve_map`]
//! runs the ordinary pipeline ([`super::solve`]) on it.
//!
//! Rank decision: rank detection, effect screening and the near-dependence check run on the
//! stacked Jacobian, prior rows included. An unknown with a prior is therefore determined
//! even when the data do not see it at all (the prior alone fixes it, and its posterior std
//! says by how much); an unknown without a prior is judged on the data as before. The noise
//! floor of that pipeline is 1 (the stacked rows are in noise units), so the singular values
//! of `near_dependent` and the condition number of a MAP solution are in noise units too.
//! Reported residuals, costs and effect sizes are the data's, in the problem's units; the
//! standard deviations are the posterior ones, `sqrt(diag((J^T J / s^2 + lambda Sigma^-1)^-1))`
//! (not rescaled by the fitted residual variance: the noise is taken as given).

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::trust::effect_sizes;
use super::trust::physical_scales;
use super::{IdentifyError, Problem, Solution, SolveOptions, Unknown, solve};
use crate::util::Monitor;

/// A Gaussian prior on some unknowns.
#[derive(Debug, Clone)]
pub struct Prior {
    /// Prior standard deviation per unknown (internal units); `None` for no prior.
    pub sigma: Vec<Option<f64>>,
    /// Prior mean per unknown (internal units), usually the start values.
    pub mean: Vec<f64>,
    /// Measurement noise `s` (residual units) dividing the data residuals.
    pub noise: f64,
    /// Overall weight `lambda` of the prior term (1 = the plain MAP problem).
    pub weight: f64,
}

impl Prior {
    /// Indices of the unknowns that carry a prior.
    pub fn rows(&self) -> Vec<usize> {
        (0..self.sigma.len())
            .filter(|&k| self.sigma[k].is_some_and(|s| s.is_finite() && s > 0.0))
            .collect()
    }
}

/// The stacked MAP problem: data rows divided by the noise, then the prior rows.
pub struct MapProblem<'a> {
    inner: &'a dyn Problem,
    prior: &'a Prior,
    rows: Vec<usize>,
}

impl std::fmt::Debug for MapProblem<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MapProblem")
            .field("rows", &self.rows)
            .finish()
    }
}

impl<'a> MapProblem<'a> {
    /// Stack `inner` and `prior`.
    pub fn new(inner: &'a dyn Problem, prior: &'a Prior) -> Self {
        Self {
            inner,
            prior,
            rows: prior.rows(),
        }
    }
}

impl Problem for MapProblem<'_> {
    fn residual_count(&self) -> usize {
        self.inner.residual_count() + self.rows.len()
    }
    fn unknown_count(&self) -> usize {
        self.inner.unknown_count()
    }
    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        let n = self.inner.residual_count();
        self.inner.residuals(x, &mut r[..n])?;
        for v in &mut r[..n] {
            *v /= self.prior.noise;
        }
        let w = self.prior.weight.sqrt();
        for (p, &k) in self.rows.iter().enumerate() {
            let s = self.prior.sigma[k].unwrap_or(f64::INFINITY);
            r[n + p] = w * (x[k] - self.prior.mean[k]) / s;
        }
        Ok(())
    }
    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        let (n, m) = (self.inner.residual_count(), self.inner.unknown_count());
        let mut jd = DMatrix::zeros(n, m);
        self.inner.jacobian(x, &mut jd)?;
        j.as_mut_slice().fill(0.0);
        j.rows_mut(0, n).copy_from(&(jd / self.prior.noise));
        let w = self.prior.weight.sqrt();
        for (p, &k) in self.rows.iter().enumerate() {
            j[(n + p, k)] = w / self.prior.sigma[k].unwrap_or(f64::INFINITY);
        }
        Ok(())
    }
}

/// What the prior did, for the result (`mode`: `least_squares`, `map` or `map_cv`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PriorReport {
    /// `least_squares` (no prior), `map` (fixed weight) or `map_cv` (weight by K-fold);
    /// not read back (the report does not show it).
    #[serde(skip_deserializing)]
    pub mode: &'static str,
    /// The weight `lambda` used (null for least squares).
    pub weight: Option<f64>,
    /// The noise `s` dividing the data residuals (residual units).
    pub noise: Option<f64>,
    /// Number of unknowns with a prior.
    pub count: usize,
    /// MAP objective at the solution (data and prior terms), if MAP.
    pub objective: Option<f64>,
    /// Prior term `lambda * sum (x_k - mu_k)^2 / sigma_k^2` at the solution, if MAP.
    pub prior_cost: Option<f64>,
    /// Laplace approximation of the log evidence `ln p(data | prior, noise)` (up to the
    /// constant of the unknowns without a prior), if MAP.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub log_evidence: Option<f64>,
    /// K-fold: per candidate weight, the held-out RMS error.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub k_fold_errors: Option<Vec<FoldError>>,
    /// `scale: "auto"`: the stds the data chose and the held-out error over the grid.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub auto: Option<super::prior_grid::AutoPrior>,
}

/// Held-out error of one candidate weight.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FoldError {
    /// Candidate weight.
    pub weight: f64,
    /// RMS of the held-out residuals over all folds (residual units).
    pub rms: f64,
}

impl PriorReport {
    /// The report of a plain least-squares run.
    pub fn least_squares() -> Self {
        Self {
            mode: "least_squares",
            weight: None,
            noise: None,
            count: 0,
            objective: None,
            prior_cost: None,
            log_evidence: None,
            k_fold_errors: None,
            auto: None,
        }
    }
}

/// Posterior standard deviations of the columns of a stacked Jacobian (`sqrt(diag((J^T
/// J)^-1))`, columns equilibrated before the inversion); NaN where singular.
pub fn posterior_std(j: &DMatrix<f64>) -> Vec<f64> {
    match posterior_covariance(j) {
        Some(c) => (0..j.ncols()).map(|k| c[(k, k)].max(0.0).sqrt()).collect(),
        None => vec![f64::NAN; j.ncols()],
    }
}

/// `(J^T J)^-1` of the stacked, noise-normalised Jacobian `j` (columns scaled to unit norm
/// for the Cholesky factorisation): the posterior covariance; `None` when singular.
pub fn posterior_covariance(j: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    posterior(j).map(|(c, _)| c)
}

/// `(J^T J)^-1` of the stacked Jacobian `j` and `ln det(J^T J)` (the log-determinant of
/// the posterior precision, for the evidence); `None` when singular.
pub fn posterior(j: &DMatrix<f64>) -> Option<(DMatrix<f64>, f64)> {
    let m = j.ncols();
    let d: Vec<f64> = (0..m)
        .map(|k| j.column(k).norm())
        .map(|v| if v > 0.0 { v } else { 1.0 })
        .collect();
    let mut js = j.clone();
    for (k, &dk) in d.iter().enumerate() {
        js.column_mut(k).unscale_mut(dk);
    }
    let chol = js.tr_mul(&js).cholesky()?;
    let l = chol.l_dirty();
    let log_det = 2.0 * (0..m).map(|k| l[(k, k)].ln() + d[k].ln()).sum::<f64>();
    let inv = chol.inverse();
    Some((
        DMatrix::from_fn(m, m, |k, l| inv[(k, l)] / (d[k] * d[l])),
        log_det,
    ))
}

/// Identify `unknowns` by MAP with `prior` (see the module documentation), through the
/// ordinary pipeline on the stacked problem; the solution's residuals, costs, effect sizes
/// and `weakly_observable` are then restated for the data alone, and its standard
/// deviations are the posterior ones.
pub fn solve_map(
    problem: &dyn Problem,
    unknowns: &[Unknown],
    x0: &[f64],
    prior: &Prior,
    opts: &SolveOptions,
    monitor: &dyn Monitor,
) -> Result<(Solution, PriorReport), IdentifyError> {
    let m = problem.unknown_count();
    if prior.sigma.len() != m || prior.mean.len() != m {
        return Err(IdentifyError::Model(format!(
            "prior for {} unknowns, problem has {m}",
            prior.sigma.len()
        )));
    }
    if !(prior.noise.is_finite()
        && prior.noise > 0.0
        && prior.weight.is_finite()
        && prior.weight >= 0.0)
    {
        return Err(IdentifyError::Model(format!(
            "prior noise {} and weight {} must be positive",
            prior.noise, prior.weight
        )));
    }
    let mp = MapProblem::new(problem, prior);
    let o = SolveOptions {
        noise: Some(1.0),
        ..opts.clone()
    };
    let mut sol = solve(&mp, unknowns, x0, &o, monitor)?;
    let n = problem.residual_count();
    let s = prior.noise;
    let objective = sol.residuals.norm_squared();
    let prior_cost = sol.residuals.rows(n, mp.rows.len()).norm_squared();
    sol.residuals_before = sol.residuals_before.rows(0, n) * s;
    sol.residuals = sol.residuals.rows(0, n) * s;
    sol.cost_before = sol.residuals_before.norm_squared();
    sol.cost_after = sol.residuals.norm_squared();
    // Posterior std from the stacked Jacobian of the identified set at the solution.
    let mut ja = DMatrix::zeros(mp.residual_count(), m);
    mp.jacobian(&sol.x, &mut ja)?;
    let jf = DMatrix::from_fn(ja.nrows(), sol.free.len(), |r, c| ja[(r, sol.free[c])]);
    let (covariance, log_det) = match posterior(&jf) {
        Some((c, ld)) => (Some(c), Some(ld)),
        None => (None, None),
    };
    let log_evidence = log_det
        .filter(|_| prior.weight > 0.0)
        .map(|ld| log_evidence(objective, ld, n, s, prior, &mp.rows, &sol.free));
    let std: Vec<f64> = match &covariance {
        Some(c) => (0..jf.ncols()).map(|k| c[(k, k)].max(0.0).sqrt()).collect(),
        None => vec![f64::NAN; jf.ncols()],
    };
    let dof = n.saturating_sub(sol.free.len());
    // A parameter the prior holds spends less than one degree of freedom: the residual std
    // divides by n - tr(H), H the data's hat matrix J_d C J_d^T (C the posterior covariance
    // in the stacked problem's units), not by n - (free unknowns).
    let dof_effective = covariance
        .as_ref()
        .map(|c| {
            let jd = jf.rows(0, n);
            n as f64 - c.component_mul(&jd.tr_mul(&jd)).sum()
        })
        .filter(|d| d.is_finite())
        .unwrap_or(dof as f64);
    sol.uncertainty.std = std.clone();
    sol.uncertainty.covariance = covariance;
    sol.uncertainty.dof = dof;
    sol.uncertainty.sigma = (sol.cost_after / dof_effective.max(1.0)).sqrt();
    // Effect sizes of the data alone, at the start.
    let mut j0 = DMatrix::zeros(n, m);
    problem.jacobian(x0, &mut j0)?;
    let effect = effect_sizes(&j0, &physical_scales(unknowns));
    sol.weakly_observable.clear();
    for (k, p) in sol.params.iter_mut().enumerate() {
        p.effect_size = effect[k];
        if let Some(pos) = sol.free.iter().position(|&f| f == k) {
            p.std = Some(std[pos] * unknowns[k].to_report);
            if effect[k] < s {
                sol.weakly_observable.push(p.name.clone());
            }
        }
    }
    Ok((
        sol,
        PriorReport {
            mode: "map",
            weight: Some(prior.weight),
            noise: Some(s),
            count: mp.rows.len(),
            objective: Some(objective),
            prior_cost: Some(prior_cost),
            log_evidence,
            k_fold_errors: None,
            auto: None,
        },
    ))
}

/// Laplace approximation of `ln p(data | prior, noise)` at the MAP solution: the data's
/// Gaussian likelihood (noise `s`, `n` residuals) times the prior's normalised density on
/// the free unknowns that carry one, integrated over the free unknowns (`ln_det_precision`
/// of the stacked problem's `J^T J`). Unknowns without a prior have a flat prior, a
/// constant that cancels between priors compared on the same problem.
fn log_evidence(
    objective: f64,
    ln_det_precision: f64,
    n: usize,
    s: f64,
    prior: &Prior,
    rows: &[usize],
    free: &[usize],
) -> f64 {
    let ln_2pi = (2.0 * std::f64::consts::PI).ln();
    let held: Vec<f64> = rows
        .iter()
        .filter(|k| free.contains(k))
        .filter_map(|&k| prior.sigma[k])
        .collect();
    let prior_norm: f64 = held
        .iter()
        .map(|sig| 0.5 * prior.weight.ln() - sig.ln() - 0.5 * ln_2pi)
        .sum();
    -0.5 * objective - n as f64 * (s.ln() + 0.5 * ln_2pi)
        + prior_norm
        + 0.5 * free.len() as f64 * ln_2pi
        - 0.5 * ln_det_precision
}

/// A prior as a job states it: per-name standard deviations in the reported (file) units,
/// and/or defaults per kind of parameter.
#[derive(Debug, Clone, Default, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PriorSpec {
    /// Standard deviation per unknown name, in that unknown's reported unit.
    #[serde(default)]
    pub std: std::collections::BTreeMap<String, f64>,
    /// Defaults for the model parameters without an entry in `std`.
    #[serde(default)]
    pub default_std: DefaultStd,
    /// `"auto"`: the length and angle defaults are chosen from the data (K-fold over a
    /// grid) instead of `default_std.length_mm` / `angle_deg`; `humanoid.identify` only.
    #[serde(default)]
    pub scale: Option<PriorScale>,
}

/// `options.prior.scale`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PriorScale {
    /// Chosen from the data.
    Auto,
}

/// Default prior standard deviations by kind of parameter.
#[derive(Debug, Clone, Default, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DefaultStd {
    /// Lengths, mm (converted for models in metres).
    #[serde(default)]
    pub length_mm: Option<f64>,
    /// Angles, deg.
    #[serde(default)]
    pub angle_deg: Option<f64>,
    /// Joint compliances, deg/(N*m).
    #[serde(default)]
    pub compliance: Option<f64>,
}

impl PriorSpec {
    /// Prior std per unknown in internal units. Per-name entries apply to any unknown (an
    /// unknown name is an error naming it); the defaults only to the unknowns `k` with
    /// `is_model(k)` (the model's parameters, not nuisance unknowns such as ball centres, a
    /// base frame or marker positions), chosen by unit: `mm`/`m`, `deg`/`rad`,
    /// `deg/(N*m)`/`rad/(N*m)`.
    pub fn sigmas(
        &self,
        unknowns: &[Unknown],
        is_model: impl Fn(usize) -> bool,
    ) -> Result<Vec<Option<f64>>, String> {
        if self.scale.is_some() {
            return Err("scale \"auto\" is not taken by this job kind: give default_std".into());
        }
        let positive = |what: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(format!("{what}: {v} must be a positive number"))
            }
        };
        for name in self.std.keys() {
            if !unknowns.iter().any(|u| &u.name == name) {
                return Err(format!("std.{name}: no such parameter to identify"));
            }
        }
        let d = &self.default_std;
        let length = d
            .length_mm
            .map(|v| positive("default_std.length_mm", v))
            .transpose()?;
        let angle = d
            .angle_deg
            .map(|v| positive("default_std.angle_deg", v))
            .transpose()?;
        let compliance = d
            .compliance
            .map(|v| positive("default_std.compliance", v))
            .transpose()?;
        unknowns
            .iter()
            .enumerate()
            .map(|(k, u)| {
                if let Some(&v) = self.std.get(&u.name) {
                    return Ok(Some(positive(&format!("std.{}", u.name), v)? / u.to_report));
                }
                if !is_model(k) {
                    return Ok(None);
                }
                Ok(match u.unit.as_str() {
                    "mm" => length,
                    "m" => length.map(|v| v * 1e-3),
                    "deg" | "rad" => angle.map(f64::to_radians),
                    "deg/(N*m)" | "rad/(N*m)" => compliance.map(f64::to_radians),
                    _ => None,
                })
            })
            .collect()
    }
}

impl PriorSpec {
    /// With `scale: "auto"`: check that no length or angle default is also given (the
    /// message names them). Without it: nothing to check.
    pub fn check_auto(&self) -> Result<(), String> {
        let d = &self.default_std;
        if self.scale.is_some() && (d.length_mm.is_some() || d.angle_deg.is_some()) {
            return Err(
                "scale \"auto\" chooses default_std.length_mm and angle_deg: \
                        give either the scale or those defaults"
                    .into(),
            );
        }
        Ok(())
    }

    /// This spec with the length and angle defaults set (and `scale` cleared): one cell
    /// of the automatic choice.
    pub fn with_scale(&self, length_mm: f64, angle_deg: f64) -> PriorSpec {
        let mut s = self.clone();
        s.scale = None;
        s.default_std.length_mm = Some(length_mm);
        s.default_std.angle_deg = Some(angle_deg);
        s
    }
}

/// `options.prior_weight` of a job: a positive number, or `"cv"` (chosen by K-fold among
/// [`CV_WEIGHTS`] on the training data).
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(untagged)]
pub enum PriorWeight {
    /// A fixed weight.
    Fixed(f64),
    /// `"cv"`: chosen by K-fold among [`CV_WEIGHTS`].
    Named(String),
}

/// What [`PriorWeight::fixed`] accepts: a positive number or `"cv"`.
impl schemars::JsonSchema for PriorWeight {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        "PriorWeight".into()
    }

    fn json_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
        schemars::json_schema!({
            "description": "a positive weight, or \"cv\" (chosen by K-fold)",
            "anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"const": "cv"}],
        })
    }
}

impl PriorWeight {
    /// Check the value: `Ok(None)` for `"cv"`, `Ok(Some(w))` for a positive number, else
    /// the message to report under `options.prior_weight`.
    pub fn fixed(&self) -> Result<Option<f64>, String> {
        match self {
            PriorWeight::Fixed(w) if w.is_finite() && *w > 0.0 => Ok(Some(*w)),
            PriorWeight::Fixed(w) => Err(format!("{w} must be positive")),
            PriorWeight::Named(s) if s == "cv" => Ok(None),
            PriorWeight::Named(s) => Err(format!("`{s}`: a positive number or \"cv\"")),
        }
    }
}

/// Folds of a cross-validated prior weight.
pub const CV_FOLDS: usize = 5;

/// Candidate weights of the K-fold choice.
pub const CV_WEIGHTS: [f64; 5] = [0.01, 0.1, 1.0, 10.0, 100.0];

/// K folds of `count` items: a seeded shuffle cut into `k` nearly equal parts.
pub fn folds(count: usize, k: usize, seed: u64) -> Vec<Vec<usize>> {
    let mut idx: Vec<usize> = (0..count).collect();
    // SplitMix64-driven Fisher-Yates: reproducible without a dependency.
    let mut state = seed;
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    for i in (1..count).rev() {
        let j = (next() % (i as u64 + 1)) as usize;
        idx.swap(i, j);
    }
    let k = k.clamp(1, count.max(1));
    (0..k)
        .map(|f| idx.iter().copied().skip(f).step_by(k).collect())
        .collect()
}

/// K folds of items that come in groups (`group[i]`: the group of item `i`, numbered
/// `0..groups`): the groups are dealt into folds as [`folds`] deals items, so every item of
/// a group (the copies of one configuration) lands in the same fold. With every item its
/// own group these are exactly the folds of [`folds`].
pub fn grouped_folds(group: &[usize], k: usize, seed: u64) -> Vec<Vec<usize>> {
    let groups = group.iter().map(|g| g + 1).max().unwrap_or(0);
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); groups];
    for (i, &g) in group.iter().enumerate() {
        members[g].push(i);
    }
    folds(groups, k, seed)
        .into_iter()
        .map(|f| {
            f.into_iter()
                .flat_map(|g| members[g].iter().copied())
                .collect()
        })
        .filter(|f: &Vec<usize>| !f.is_empty())
        .collect()
}

/// Choose the weight among `weights` by K-fold cross-validation over `count` items (the
/// training set only): `score(weight, train, test)` fits on `train` and returns the sum of
/// squared held-out residuals and their count. The smallest held-out RMS wins (the first
/// on ties); a fold whose fit fails scores infinity.
pub fn choose_weight(
    weights: &[f64],
    count: usize,
    k: usize,
    seed: u64,
    score: impl FnMut(f64, &[usize], &[usize]) -> Result<(f64, usize), IdentifyError>,
) -> Result<(f64, Vec<FoldError>), IdentifyError> {
    let group: Vec<usize> = (0..count).collect();
    choose_weight_grouped(weights, &group, k, seed, score)
}

/// [`choose_weight`] over items in groups (`group[i]` as in [`grouped_folds`]): the copies
/// of one configuration are never split between training and held-out folds.
pub fn choose_weight_grouped(
    weights: &[f64],
    group: &[usize],
    k: usize,
    seed: u64,
    mut score: impl FnMut(f64, &[usize], &[usize]) -> Result<(f64, usize), IdentifyError>,
) -> Result<(f64, Vec<FoldError>), IdentifyError> {
    let parts = grouped_folds(group, k, seed);
    let mut errors = Vec::with_capacity(weights.len());
    for &w in weights {
        let rms = held_out_rms(&parts, |train, test| score(w, train, test))?;
        errors.push(FoldError { weight: w, rms });
    }
    let best = errors
        .iter()
        .filter(|e| e.rms.is_finite())
        .min_by(|a, b| a.rms.total_cmp(&b.rms))
        .map(|e| e.weight)
        .ok_or_else(|| IdentifyError::Model("every fold fit failed for every weight".into()))?;
    Ok((best, errors))
}

/// Held-out RMS over the folds `parts` (each fold held out once, the others trained on);
/// infinite when a fold's fit fails (a cancel is passed on).
pub(super) fn held_out_rms(
    parts: &[Vec<usize>],
    mut score: impl FnMut(&[usize], &[usize]) -> Result<(f64, usize), IdentifyError>,
) -> Result<f64, IdentifyError> {
    let (mut sum, mut cnt) = (0.0, 0usize);
    for (f, test) in parts.iter().enumerate() {
        let train: Vec<usize> = parts
            .iter()
            .enumerate()
            .filter(|(g, _)| *g != f)
            .flat_map(|(_, p)| p.iter().copied())
            .collect();
        match score(&train, test) {
            Ok((s, c)) => {
                sum += s;
                cnt += c;
            }
            Err(IdentifyError::Cancelled) => return Err(IdentifyError::Cancelled),
            Err(_) => return Ok(f64::INFINITY),
        }
    }
    Ok(if cnt > 0 {
        (sum / cnt as f64).sqrt()
    } else {
        f64::INFINITY
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::NoMonitor;
    use nalgebra::DVector;

    /// r = J x - b.
    struct Linear {
        j: DMatrix<f64>,
        b: DVector<f64>,
    }
    impl Problem for Linear {
        fn residual_count(&self) -> usize {
            self.j.nrows()
        }
        fn unknown_count(&self) -> usize {
            self.j.ncols()
        }
        fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
            let v = &self.j * DVector::from_column_slice(x) - &self.b;
            r.copy_from_slice(v.as_slice());
            Ok(())
        }
        fn jacobian(&self, _x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
            j.copy_from(&self.j);
            Ok(())
        }
    }

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    fn unknowns(m: usize) -> Vec<Unknown> {
        (0..m)
            .map(|k| Unknown {
                name: format!("x{k}"),
                unit: "mm".into(),
                to_report: 1.0,
                nominal: 0.0,
                plausible_range: 1.0,
                lower: None,
                upper: None,
            })
            .collect()
    }

    /// MAP with a prior equals the closed form on a linear problem: x = (J^T J / s^2 +
    /// lambda Sigma^-1)^-1 (J^T b / s^2 + lambda Sigma^-1 mu), posterior std = sqrt(diag of
    /// that inverse). One unknown has no prior; one column is nearly invisible in the data
    /// (its prior determines it); a non-unit weight exercises lambda.
    #[test]
    fn map_with_a_prior_equals_the_closed_form_on_a_linear_problem() {
        let (n, m) = (12, 5);
        let mut st = 13u64;
        let mut j = DMatrix::from_fn(n, m, |_, _| lcg(&mut st));
        // Column 4: nearly invisible to the data (1e-9 of the others).
        for r in 0..n {
            j[(r, 4)] *= 1e-9;
        }
        let b = DVector::from_fn(n, |_, _| lcg(&mut st));
        let mu: Vec<f64> = (0..m).map(|_| lcg(&mut st)).collect();
        let sigma = vec![Some(0.3), None, Some(2.0), Some(0.05), Some(0.7)];
        for &weight in &[1.0, 2.5] {
            let prior = Prior {
                sigma: sigma.clone(),
                mean: mu.clone(),
                noise: 0.2,
                weight,
            };
            let p = Linear {
                j: j.clone(),
                b: b.clone(),
            };
            let (sol, rep) = solve_map(
                &p,
                &unknowns(m),
                &mu,
                &prior,
                &SolveOptions::default(),
                &NoMonitor,
            )
            .unwrap();
            assert_eq!(rep.mode, "map");
            assert_eq!(rep.count, 4);
            assert_eq!(sol.free, vec![0, 1, 2, 3, 4], "{:?}", sol.unidentifiable);
            let s2 = prior.noise * prior.noise;
            let mut a = j.tr_mul(&j) / s2;
            let mut rhs = j.tr_mul(&b) / s2;
            for k in 0..m {
                if let Some(sk) = sigma[k] {
                    a[(k, k)] += weight / (sk * sk);
                    rhs[k] += weight * mu[k] / (sk * sk);
                }
            }
            let inv = a.try_inverse().unwrap();
            let x = &inv * rhs;
            for k in 0..m {
                assert!(
                    (sol.x[k] - x[k]).abs() < 1e-9 * x[k].abs().max(1.0),
                    "x{k}: {} vs {}",
                    sol.x[k],
                    x[k]
                );
                let sd = inv[(k, k)].sqrt();
                let got = sol.params[k].std.unwrap();
                assert!((got - sd).abs() < 1e-9 * sd, "std{k}: {got} vs {sd}");
            }
            // Residuals and costs are the data's.
            let r = &j * DVector::from_column_slice(&sol.x) - &b;
            assert!((sol.cost_after - r.norm_squared()).abs() < 1e-12);
            // The residual std counts the degrees of freedom the prior leaves: n - tr(H),
            // H = J A^-1 J^T / s^2 (the unknown without a prior spends ~1, the invisible
            // column ~0, the held ones between).
            let p_eff = (&j * &inv * j.transpose()).trace() / s2;
            assert!(p_eff > 1.0 && p_eff < m as f64 - 1.0, "{p_eff}");
            let sigma_expected = (r.norm_squared() / (n as f64 - p_eff)).sqrt();
            let got = sol.uncertainty.sigma;
            assert!(
                (got - sigma_expected).abs() < 1e-9 * sigma_expected,
                "sigma {got} vs {sigma_expected} (p_eff {p_eff})"
            );
        }
    }

    /// On a linear problem the Laplace evidence is exact: with every unknown under a prior,
    /// b ~ N(J mu, s^2 I + J Sigma J^T / lambda), whose log density is computed directly.
    #[test]
    fn the_log_evidence_equals_the_gaussian_marginal_on_a_linear_problem() {
        let (n, m) = (15, 4);
        let mut st = 29u64;
        let j = DMatrix::from_fn(n, m, |_, _| lcg(&mut st));
        let b = DVector::from_fn(n, |_, _| lcg(&mut st));
        let mu: Vec<f64> = (0..m).map(|_| lcg(&mut st)).collect();
        let sigma = vec![Some(0.3), Some(1.5), Some(0.05), Some(0.7)];
        let mut seen = Vec::new();
        for &(weight, noise) in &[(1.0, 0.2), (0.4, 0.2), (1.0, 0.5)] {
            let prior = Prior {
                sigma: sigma.clone(),
                mean: mu.clone(),
                noise,
                weight,
            };
            let p = Linear {
                j: j.clone(),
                b: b.clone(),
            };
            let (_, rep) = solve_map(
                &p,
                &unknowns(m),
                &mu,
                &prior,
                &SolveOptions::default(),
                &NoMonitor,
            )
            .unwrap();
            let got = rep.log_evidence.unwrap();
            let sig = DMatrix::from_fn(m, m, |k, l| {
                if k == l {
                    sigma[k].unwrap().powi(2) / weight
                } else {
                    0.0
                }
            });
            let c = DMatrix::identity(n, n) * (noise * noise) + &j * sig * j.transpose();
            let d = &b - &j * DVector::from_column_slice(&mu);
            let chol = c.clone().cholesky().unwrap();
            let quad = d.dot(&chol.solve(&d));
            let log_det: f64 = 2.0 * (0..n).map(|k| chol.l()[(k, k)].ln()).sum::<f64>();
            let expected =
                -0.5 * quad - 0.5 * log_det - 0.5 * n as f64 * (2.0 * std::f64::consts::PI).ln();
            assert!(
                (got - expected).abs() < 1e-9 * expected.abs(),
                "weight {weight}, noise {noise}: {got} vs {expected}"
            );
            seen.push(got);
        }
        // The three settings are told apart.
        assert!((seen[0] - seen[1]).abs() > 1e-3 && (seen[0] - seen[2]).abs() > 1e-3);
    }

    #[test]
    fn a_spec_maps_names_and_defaults_to_internal_units() {
        let mut u = unknowns(4);
        u[1].unit = "deg".into();
        u[1].to_report = 180.0 / std::f64::consts::PI;
        u[2].unit = "deg/(N*m)".into();
        u[2].to_report = 180.0 / std::f64::consts::PI;
        let spec: PriorSpec = serde_json::from_value(serde_json::json!({
            "std": {"x0": 0.5},
            "default_std": {"length_mm": 1.0, "angle_deg": 0.5}
        }))
        .unwrap();
        let s = spec.sigmas(&u, |k| k < 3).unwrap();
        assert_eq!(s[0], Some(0.5));
        assert!((s[1].unwrap() - 0.5f64.to_radians()).abs() < 1e-15);
        assert_eq!(s[2], None);
        // Unknown 3 is a nuisance point: no default.
        assert_eq!(s[3], None);
        let bad: PriorSpec =
            serde_json::from_value(serde_json::json!({"std": {"nope": 1.0}})).unwrap();
        assert!(bad.sigmas(&u, |k| k < 3).unwrap_err().contains("nope"));
    }

    #[test]
    fn folds_partition_and_are_reproducible() {
        let f = folds(23, 5, 7);
        assert_eq!(f.len(), 5);
        let mut all: Vec<usize> = f.iter().flatten().copied().collect();
        all.sort_unstable();
        assert_eq!(all, (0..23).collect::<Vec<_>>());
        assert_eq!(f, folds(23, 5, 7));
        assert_ne!(f, folds(23, 5, 8));
        // Every item its own group: the same folds.
        let own: Vec<usize> = (0..23).collect();
        assert_eq!(grouped_folds(&own, 5, 7), f);
        // Copies of a configuration share a fold.
        let group: Vec<usize> = (0..40).map(|i| i % 8).collect();
        let g = grouped_folds(&group, 5, 7);
        assert_eq!(g.iter().map(Vec::len).sum::<usize>(), 40);
        for fold in &g {
            for other in g.iter().filter(|o| *o != fold) {
                assert!(
                    fold.iter()
                        .all(|i| other.iter().all(|j| group[*i] != group[*j]))
                );
            }
        }
    }
}
