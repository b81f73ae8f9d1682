//! `options.prior` / `options.prior_weight` of `serial.identify`: MAP identification with a
//! Gaussian prior around the starting model, the weight fixed or chosen by K-fold
//! cross-validation on the training measurements (see [`crate::identify::prior`]).

use super::identify::IdentifyInputs;
pub use crate::identify::prior::{CV_FOLDS, PriorWeight};
use crate::identify::prior::{CV_WEIGHTS, Prior, PriorReport, choose_weight, solve_map};
use crate::identify::{IdentifyError, Solution, solve};
use crate::jobs::JobError;
use crate::measure::{PointMeasurement, PointProblem, Target};
use crate::util::{Monitor, NoMonitor, SubMonitor};

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
        let all: Vec<usize> = (0..inp.meas.len()).collect();
        spec.sigmas(&problem(inp, &all)?.unknowns(), |k| k < inp.ids.len())
            .map_err(|m| JobError::invalid("options.prior", m))?;
    }
    Ok(())
}

fn problem(inp: &IdentifyInputs, idx: &[usize]) -> Result<PointProblem, JobError> {
    Ok(PointProblem::new(
        inp.model.chain.clone(),
        inp.ids.clone(),
        inp.plate.clone(),
        idx.iter().map(|&i| inp.meas[i].clone()).collect(),
    )?)
}

fn map_fit(
    inp: &IdentifyInputs,
    p: &PointProblem,
    noise: f64,
    weight: f64,
    monitor: &dyn Monitor,
) -> Result<(Solution, PriorReport), JobError> {
    let spec = inp.options.prior.clone().unwrap_or_default();
    let unknowns = p.unknowns();
    let sigma = spec
        .sigmas(&unknowns, |k| k < inp.ids.len())
        .map_err(|m| JobError::invalid("options.prior", m))?;
    let x0 = p.initial();
    let prior = Prior {
        sigma,
        mean: x0.clone(),
        noise,
        weight,
    };
    Ok(solve_map(
        p,
        &unknowns,
        &x0,
        &prior,
        &inp.solve_options(p),
        monitor,
    )?)
}

/// Sum of squared held-out residuals of the model fitted on `p` at `x`, and their count
/// (three per measurement; torques from the starting model).
fn held_out(inp: &IdentifyInputs, p: &PointProblem, x: &[f64], test: &[usize]) -> (f64, usize) {
    let chain = p.model(x);
    let centres = p.centres(x);
    let test: Vec<&PointMeasurement> = test.iter().map(|&i| &inp.meas[i]).collect();
    let sum = test
        .iter()
        .map(|m| {
            let target = match m.target {
                Target::Point(q) => q,
                Target::Ball(b) => centres[b],
            };
            let tau = inp.model.chain.static_torques(&m.q);
            (chain.tcp(&m.q, Some(&tau)).p - target).norm_squared()
        })
        .sum();
    (sum, 3 * test.len())
}

/// Identify from the measurements `subset` (all when `None`): least squares without
/// `options.prior`, MAP with it. The noise dividing the data is `options.noise`, else the
/// residual sigma of the least-squares fit.
pub fn identify(
    inp: &IdentifyInputs,
    subset: Option<&[usize]>,
    monitor: &dyn Monitor,
) -> Result<(PointProblem, Solution, PriorReport), JobError> {
    let all: Vec<usize> = match subset {
        Some(s) => s.to_vec(),
        None => (0..inp.meas.len()).collect(),
    };
    let p = problem(inp, &all)?;
    let x0 = p.initial();
    if inp.options.prior.is_none() {
        let sol = solve(&p, &p.unknowns(), &x0, &inp.solve_options(&p), monitor)?;
        return Ok((p, sol, PriorReport::least_squares()));
    }
    let noise = match inp.options.noise {
        Some(n) => n,
        None => {
            let sub = SubMonitor::new(monitor, 0.0, 0.2);
            let ls = solve(&p, &p.unknowns(), &x0, &inp.solve_options(&p), &sub)?;
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
            let (w, e) = choose_weight(&CV_WEIGHTS, all.len(), CV_FOLDS, seed, |w, tr, te| {
                if monitor.is_cancelled() {
                    return Err(IdentifyError::Cancelled);
                }
                let tr: Vec<usize> = tr.iter().map(|&i| all[i]).collect();
                let te: Vec<usize> = te.iter().map(|&i| all[i]).collect();
                let fit = problem(inp, &tr)
                    .and_then(|q| map_fit(inp, &q, noise, w, &NoMonitor).map(|f| (q, f)));
                match fit {
                    Ok((q, (sol, _))) => Ok(held_out(inp, &q, &sol.x, &te)),
                    Err(e) => Err(IdentifyError::Model(e.to_string())),
                }
            })?;
            (w, Some(e))
        }
        Some(PriorWeight::Fixed(w)) => (*w, None),
        None => (1.0, None),
    };
    let sub = SubMonitor::new(monitor, 0.2, 1.0);
    let (sol, mut rep) = map_fit(inp, &p, noise, weight, &sub)?;
    if errors.is_some() {
        rep.mode = "map_cv";
        rep.k_fold_errors = errors;
    }
    Ok((p, sol, rep))
}
