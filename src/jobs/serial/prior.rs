//! `options.prior` / `options.prior_weight` of `serial.identify`: MAP identification with a
//! Gaussian prior around the starting model, the weight fixed or chosen by K-fold
//! cross-validation on the training measurements (see [`crate::identify::prior`]), for point and distance measurements alike.

use super::identify_inputs::IdentifyInputs;
pub use crate::identify::prior::{CV_FOLDS, PriorWeight};
use crate::identify::prior::{CV_WEIGHTS, Prior, PriorReport, choose_weight_grouped, solve_map};
use crate::identify::{IdentifyError, Problem, Solution, SolveOptions, Unknown, solve};
use crate::measure::distance::distance_errors;
use crate::measure::{DistanceProblem, PointProblem};
use crate::run::JobError;
use crate::util::{Monitor, NoMonitor, SubMonitor};

/// What the MAP path needs of a serial identification problem: points / ball centres
/// ([`PointProblem`]) or distances to an unknown anchor ([`DistanceProblem`]).
pub trait SerialFit: Problem + Sized {
    /// Number of measurements of the job.
    fn count(inp: &IdentifyInputs) -> usize;
    /// The problem over the measurements `idx`.
    fn build(inp: &IdentifyInputs, idx: &[usize]) -> Result<Self, JobError>;
    /// Starting unknowns.
    fn start(&self) -> Vec<f64>;
    /// Names, units and scales of the unknowns (the model's first: `ids`).
    fn names(&self) -> Vec<Unknown>;
    /// Solver settings of the job for this problem.
    fn options(&self, inp: &IdentifyInputs) -> SolveOptions;
    /// Sum of squared held-out residuals of the model fitted on `self` at `x`, and their
    /// count, over the job's measurements `test`.
    fn held_out(&self, inp: &IdentifyInputs, x: &[f64], test: &[usize]) -> (f64, usize);
    /// The least-squares solution `sol` (from `x0`) with a gauge the measurements leave held
    /// (its `held_gauge`), or as it is.
    fn hold_gauge(
        &self,
        _inp: &IdentifyInputs,
        _x0: &[f64],
        sol: Solution,
        _opts: &SolveOptions,
        _monitor: &dyn Monitor,
    ) -> Result<Solution, JobError> {
        Ok(sol)
    }
}

impl SerialFit for PointProblem {
    fn count(inp: &IdentifyInputs) -> usize {
        inp.meas.len()
    }
    fn build(inp: &IdentifyInputs, idx: &[usize]) -> Result<Self, JobError> {
        let p = PointProblem::with_torques(
            inp.model.chain.clone(),
            inp.ids.clone(),
            inp.plate.clone(),
            idx.iter().map(|&i| inp.meas[i].clone()).collect(),
            Some(inp.start_torques(idx)),
        )?;
        // A strict subset reads its start from the rows of all measurements (the whole set
        // gains nothing from them).
        let start = (idx.len() < inp.meas.len())
            .then(|| inp.point_start())
            .flatten();
        Ok(match start {
            Some(start) => p.with_start(start, idx.to_vec()),
            None => p,
        })
    }
    fn start(&self) -> Vec<f64> {
        self.initial()
    }
    fn names(&self) -> Vec<Unknown> {
        self.unknowns()
    }
    fn options(&self, inp: &IdentifyInputs) -> SolveOptions {
        inp.solve_options(self)
    }
    /// Three residuals per measurement; torques from the starting model.
    fn held_out(&self, inp: &IdentifyInputs, x: &[f64], test: &[usize]) -> (f64, usize) {
        let chain = self.model(x);
        let centres = self.centres(x);
        let sum = test
            .iter()
            .map(|&i| {
                let m = &inp.meas[i];
                let target = m.target_point(&centres);
                let tau = inp.model.chain.static_torques(&m.q);
                (chain.tcp(&m.q, Some(&tau)).p - target).norm_squared()
            })
            .sum();
        (sum, 3 * test.len())
    }
    /// The plate's free rotation held in the base frame ([`super::gauge`]).
    fn hold_gauge(
        &self,
        inp: &IdentifyInputs,
        x0: &[f64],
        sol: Solution,
        opts: &SolveOptions,
        monitor: &dyn Monitor,
    ) -> Result<Solution, JobError> {
        match super::gauge::hold_plate_gauge(&inp.ids, &inp.plate, self, x0, &sol, opts, monitor)? {
            Some((mut held, gauge)) => {
                held.held_gauge = Some(gauge);
                Ok(held)
            }
            None => Ok(sol),
        }
    }
}

impl SerialFit for DistanceProblem {
    fn count(inp: &IdentifyInputs) -> usize {
        inp.distances.len()
    }
    fn build(inp: &IdentifyInputs, idx: &[usize]) -> Result<Self, JobError> {
        Ok(DistanceProblem::new(
            inp.model.chain.clone(),
            inp.ids.clone(),
            idx.iter().map(|&i| inp.distances[i].clone()).collect(),
        )?)
    }
    fn start(&self) -> Vec<f64> {
        self.initial()
    }
    fn names(&self) -> Vec<Unknown> {
        self.unknowns()
    }
    fn options(&self, inp: &IdentifyInputs) -> SolveOptions {
        inp.distance_solve_options(self)
    }
    /// One residual per measurement: the fitted model, anchor and offset.
    fn held_out(&self, inp: &IdentifyInputs, x: &[f64], test: &[usize]) -> (f64, usize) {
        let (anchor, offset) = self.anchor(x);
        let test: Vec<_> = test.iter().map(|&i| inp.distances[i].clone()).collect();
        let e = distance_errors(&self.model(x), &anchor, offset, &test);
        (e.iter().map(|v| v * v).sum(), e.len())
    }
}

/// Check `options.prior` (names, positive values) and `options.prior_weight`.
pub fn validate(inp: &IdentifyInputs) -> Result<(), JobError> {
    match (&inp.options.prior, &inp.options.prior_weight) {
        (None, Some(_)) => Err(JobError::invalid(
            "options.prior_weight",
            "needs options.prior",
        )),
        (_, Some(w)) => w
            .fixed()
            .map(|_| ())
            .map_err(|m| JobError::invalid("options.prior_weight", m)),
        _ => Ok(()),
    }?;
    if let Some(spec) = &inp.options.prior {
        let unknowns = if inp.distances.is_empty() {
            let all: Vec<usize> = (0..inp.meas.len()).collect();
            PointProblem::build(inp, &all)?.names()
        } else {
            let all: Vec<usize> = (0..inp.distances.len()).collect();
            DistanceProblem::build(inp, &all)?.names()
        };
        spec.sigmas(&unknowns, |k| k < inp.ids.len())
            .map_err(|m| JobError::invalid("options.prior", m))?;
    }
    Ok(())
}

fn map_fit<P: SerialFit>(
    inp: &IdentifyInputs,
    p: &P,
    noise: f64,
    weight: f64,
    uncertainty: bool,
    monitor: &dyn Monitor,
) -> Result<(Solution, PriorReport), JobError> {
    let spec = inp.options.prior.clone().unwrap_or_default();
    let unknowns = p.names();
    let sigma = spec
        .sigmas(&unknowns, |k| k < inp.ids.len())
        .map_err(|m| JobError::invalid("options.prior", m))?;
    let x0 = p.start();
    let prior = Prior {
        sigma,
        mean: x0.clone(),
        noise,
        weight,
    };
    let options = SolveOptions {
        uncertainty,
        ..p.options(inp)
    };
    Ok(solve_map(p, &unknowns, &x0, &prior, &options, monitor)?)
}

/// The configuration groups of the rows `idx` (`group` of all rows), renumbered `0..` in
/// order of first appearance among `idx`.
fn dense_groups(group: &[usize], idx: &[usize]) -> Vec<usize> {
    let mut id = std::collections::HashMap::new();
    idx.iter()
        .map(|&i| {
            let n = id.len();
            *id.entry(group[i]).or_insert(n)
        })
        .collect()
}

/// Identify from the measurements `subset` (all when `None`): least squares without
/// `options.prior`, MAP with it. The noise dividing the data is `options.noise`, else the
/// residual sigma of the least-squares fit.
pub fn identify<P: SerialFit>(
    inp: &IdentifyInputs,
    subset: Option<&[usize]>,
    monitor: &dyn Monitor,
) -> Result<(P, Solution, PriorReport), JobError> {
    identify_with(inp, subset, true, monitor)
}

/// [`identify`]; `uncertainty` false skips the standard deviations, condition numbers and
/// near-dependent reports of the result ([`SolveOptions::uncertainty`],
/// [`SolveOptions::near_dependent`]): the same identified values.
pub fn identify_with<P: SerialFit>(
    inp: &IdentifyInputs,
    subset: Option<&[usize]>,
    uncertainty: bool,
    monitor: &dyn Monitor,
) -> Result<(P, Solution, PriorReport), JobError> {
    let all: Vec<usize> = match subset {
        Some(s) => s.to_vec(),
        None => (0..P::count(inp)).collect(),
    };
    let p = P::build(inp, &all)?;
    let x0 = p.start();
    // Values only: neither standard deviations nor near-dependent combinations.
    let options = |uncertainty: bool| SolveOptions {
        uncertainty,
        near_dependent: uncertainty,
        ..p.options(inp)
    };
    if inp.options.prior.is_none() {
        let sol = solve(&p, &p.names(), &x0, &options(uncertainty), monitor)?;
        let sol = p.hold_gauge(inp, &x0, sol, &options(uncertainty), monitor)?;
        return Ok((p, sol, PriorReport::least_squares()));
    }
    let noise = match inp.options.noise {
        Some(n) => n,
        None => {
            // Only the residual sigma of this fit is used.
            let sub = SubMonitor::new(monitor, 0.0, 0.2);
            let ls = solve(&p, &p.names(), &x0, &options(false), &sub)?;
            ls.uncertainty.sigma
        }
    };
    if !(noise.is_finite() && noise > 0.0) {
        return Err(JobError::invalid(
            "options.prior",
            format!(
                "the noise ({noise}) is not known: give options.noise (the least-squares fit \
                 has no residual degrees of freedom or fits exactly)"
            ),
        ));
    }
    let (weight, errors) = match &inp.options.prior_weight {
        Some(PriorWeight::Named(_)) => {
            let seed = inp.options.seed.unwrap_or(1);
            // Copies of one configuration stay in one fold.
            let group = dense_groups(&inp.duplicates().group, &all);
            let (w, e) =
                choose_weight_grouped(&CV_WEIGHTS, &group, CV_FOLDS, seed, |w, tr, te| {
                    if monitor.is_cancelled() {
                        return Err(IdentifyError::Cancelled);
                    }
                    let tr: Vec<usize> = tr.iter().map(|&i| all[i]).collect();
                    let te: Vec<usize> = te.iter().map(|&i| all[i]).collect();
                    let fit = P::build(inp, &tr).and_then(|q| {
                        map_fit(inp, &q, noise, w, false, &NoMonitor).map(|f| (q, f))
                    });
                    match fit {
                        Ok((q, (sol, _))) => Ok(q.held_out(inp, &sol.x, &te)),
                        Err(e) => Err(IdentifyError::Model(e.to_string())),
                    }
                })?;
            (w, Some(e))
        }
        Some(PriorWeight::Fixed(w)) => (*w, None),
        None => (1.0, None),
    };
    let sub = SubMonitor::new(monitor, 0.2, 1.0);
    let (sol, mut rep) = map_fit(inp, &p, noise, weight, uncertainty, &sub)?;
    if errors.is_some() {
        rep.mode = "map_cv";
        rep.k_fold_errors = errors;
    }
    Ok((p, sol, rep))
}
