//! `coverage` of `serial.identify`: the predicted error covariance at each Cartesian
//! validation point, `J Sigma_p J^T + sigma^2 I`, and the fraction of held-out errors within
//! their predicted 2 sigma (see [`crate::identify::coverage`]).

use nalgebra::{DMatrix, Vector3};

use super::identify_inputs::IdentifyInputs;
use crate::identify::coverage::{Coverage, coverage};
use crate::identify::{Problem, Solution};
use crate::measure::{BallPlate, PointMeasurement, PointProblem, Target};
use crate::model::Chain;

/// The coverage of the Cartesian validation points of `inp` by the identification `sol`
/// (calibrated chain `calibrated`). `variance_factor` rescales the parameter covariance
/// (duplicated rows recounted); the noise is `options.noise`, else `residual_std`, the
/// training residual counted on distinct configurations. `None` without Cartesian
/// validation points or a covariance.
pub(crate) fn point_coverage(
    inp: &IdentifyInputs,
    sol: &Solution,
    calibrated: &Chain,
    variance_factor: f64,
    residual_std: Option<f64>,
) -> Option<Coverage> {
    let val: Vec<PointMeasurement> = inp
        .validation
        .as_ref()?
        .iter()
        .filter(|m| matches!(m.target, Target::Point(_)))
        .cloned()
        .collect();
    if val.is_empty() {
        return None;
    }
    let (noise, from) = match (inp.options.noise, residual_std) {
        (Some(n), _) => (n, "options.noise"),
        (None, Some(s)) if s.is_finite() => (s, "training residual"),
        _ => return None,
    };
    let sigma_p = sol.uncertainty.covariance.as_ref()? * variance_factor;
    // The chain parameters come first among the unknowns; ball centres do not move a
    // Cartesian prediction (their columns are zero).
    let n_chain = inp.ids.len();
    let empty = BallPlate {
        centres: vec![],
        distances: vec![],
        gauge: None,
    };
    let p = PointProblem::new(inp.model.chain.clone(), inp.ids.clone(), empty, val.clone()).ok()?;
    let mut j = DMatrix::zeros(p.residual_count(), p.unknown_count());
    p.jacobian(&sol.x[..n_chain], &mut j).ok()?;
    let jacobians: Vec<DMatrix<f64>> = (0..val.len())
        .map(|i| {
            DMatrix::from_fn(3, sol.free.len(), |r, c| {
                let k = sol.free[c];
                if k < n_chain { j[(3 * i + r, k)] } else { 0.0 }
            })
        })
        .collect();
    let errors: Vec<Vector3<f64>> = val
        .iter()
        .filter_map(|m| match m.target {
            Target::Point(t) => Some(
                calibrated
                    .tcp(&m.q, Some(&calibrated.static_torques(&m.q)))
                    .p
                    - t,
            ),
            Target::Ball(_) => None,
        })
        .collect();
    coverage(
        &errors,
        &jacobians,
        &sigma_p,
        noise,
        from,
        inp.model.length_unit(),
    )
}

#[cfg(test)]
mod tests;
