//! Fitting a humanoid model to marker samples with the shared pipeline (rank detection in the
//! spec's priority order, bounded LM, uncertainty): which parameters a fit frees, the
//! frames-only fit (the paper's non-calibrated model), the full fit, and the base-parameter
//! study of a marker layout over many configurations.

use nalgebra::DMatrix;

use super::markers::{MarkerProblem, MarkerSample, initial_base, marker_rmse};
use crate::identify::prior::{Prior, PriorReport, PriorSpec, solve_map};
use crate::identify::{
    IdentifyError, Pivoting, RankReport, Robust, Solution, SolveOptions, rank_revealing, solve,
    solve_robust,
};
use crate::model::JointField;
use crate::model::humanoid::{HParam, Humanoid, State};
use crate::util::Monitor;

/// Which joint parameters a fit frees (base and markers are always free).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Groups {
    /// Joint offsets.
    pub offsets: bool,
    /// Placement translations dx, dy, dz.
    pub translations: bool,
    /// Placement angles rx, ry, rz.
    pub angles: bool,
    /// Joint compliances of the elastic joints.
    pub compliance: bool,
    /// Base compliance (when the model has it).
    pub base_compliance: bool,
}

impl Groups {
    /// Everything.
    pub const ALL: Groups = Groups {
        offsets: true,
        translations: true,
        angles: true,
        compliance: true,
        base_compliance: true,
    };
    /// Geometry only (no elasticity).
    pub const GEOMETRIC: Groups = Groups {
        compliance: false,
        base_compliance: false,
        ..Groups::ALL
    };
    /// Nothing of the joints: base frame and markers only.
    pub const FRAMES: Groups = Groups {
        offsets: false,
        translations: false,
        angles: false,
        compliance: false,
        base_compliance: false,
    };

    /// Whether parameter `p` is free under these groups.
    pub fn frees(&self, p: HParam) -> bool {
        match p {
            HParam::Joint(_, JointField::Offset) => self.offsets,
            HParam::Joint(_, JointField::Err(k)) if k < 3 => self.translations,
            HParam::Joint(_, JointField::Err(_)) => self.angles,
            HParam::Joint(_, _) => self.compliance,
            HParam::BaseCompliance(_) => self.base_compliance,
            HParam::Base(_) | HParam::Marker(..) => true,
        }
    }

    /// Indices of the free parameters of `model`.
    pub fn select(&self, model: &Humanoid) -> Vec<usize> {
        (0..model.params.len())
            .filter(|&g| self.frees(model.params[g]))
            .collect()
    }
}

/// Settings of a fit.
#[derive(Debug, Clone)]
pub struct FitOptions {
    /// Relative tolerance of the rank detection on the column-scaled Jacobian. The default
    /// 1e-2 keeps a parameter only if at least 1 % of its column is independent of the
    /// higher-priority ones: with sparse marker data (one hand marker) weaker columns pass a
    /// structural test (1e-8) but are not determined by the data, and LM then wanders along
    /// them to physically absurd values (tens of degrees of compensating offsets) for a
    /// 0.1 % lower cost. The structural count is reported separately.
    pub rank_tolerance: f64,
    /// LM iteration limit.
    pub max_iterations: usize,
    /// Robust loss, if any.
    pub robust: Option<Robust>,
    /// Gaussian prior on the joint parameters (MAP), if any.
    pub prior: Option<MapOptions>,
}

/// A MAP fit's prior: per-parameter std (names or defaults by unit, applied to the joint
/// and base-compliance parameters; the base frame and the markers are nuisance unknowns
/// without a prior), its weight and the measurement noise.
#[derive(Debug, Clone)]
pub struct MapOptions {
    /// Standard deviations as the job states them.
    pub spec: PriorSpec,
    /// Weight `lambda` of the prior term.
    pub weight: f64,
    /// Marker noise (m) dividing the data residuals; `None`: the residual sigma of the
    /// least-squares fit of the same parameters.
    pub noise_m: Option<f64>,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            rank_tolerance: 1e-2,
            max_iterations: 200,
            robust: None,
            prior: None,
        }
    }
}

/// A fitted model and how it was found.
#[derive(Debug, Clone)]
pub struct MarkerFit {
    /// The model with the identified values.
    pub model: Humanoid,
    /// The problem that was solved.
    pub problem: MarkerProblem,
    /// The solver's report.
    pub solution: Solution,
    /// Overall 3-D marker RMSE (m) on the fitted samples.
    pub rmse: f64,
    /// Per-marker 3-D RMSE (m).
    pub per_marker: Vec<Option<f64>>,
    /// Least squares or MAP, and the prior's weight and cost.
    pub prior: PriorReport,
}

/// Fit the parameters `free` of `model` to `samples`: rank detection in priority order,
/// LM (robust if asked), uncertainty. The model's current values are the start. With a
/// prior on some of the free parameters, the MAP problem is solved instead (see
/// [`crate::identify::prior`]); a robust loss and a prior do not combine.
pub fn fit(
    model: &Humanoid,
    free: Vec<usize>,
    samples: &[MarkerSample],
    opts: &FitOptions,
    monitor: &dyn Monitor,
) -> Result<MarkerFit, IdentifyError> {
    let problem = MarkerProblem::new(model.clone(), free, samples.to_vec());
    let x0 = problem.initial();
    let mut so = SolveOptions {
        pivoting: Pivoting::Priority(problem.priority_order()),
        rank_tolerance: opts.rank_tolerance,
        // The 1e-2 tolerance is relative to each column's own norm (see `FitOptions`).
        physical_rank: false,
        ..Default::default()
    };
    so.lm.max_iterations = opts.max_iterations;
    let unknowns = problem.unknowns();
    let sigma = match &opts.prior {
        Some(map) => map
            .spec
            .sigmas(&unknowns, |k| {
                matches!(
                    model.params[problem.free()[k]],
                    HParam::Joint(..) | HParam::BaseCompliance(_)
                )
            })
            .map_err(IdentifyError::Model)?,
        None => Vec::new(),
    };
    let map = opts
        .prior
        .as_ref()
        .filter(|_| sigma.iter().any(Option::is_some));
    let (solution, prior) = match (map, &opts.robust) {
        (Some(map), None) => {
            let noise = match map.noise_m {
                Some(n) => n,
                None => {
                    solve(&problem, &unknowns, &x0, &so, monitor)?
                        .uncertainty
                        .sigma
                }
            };
            if !(noise.is_finite() && noise > 0.0) {
                return Err(IdentifyError::Model(format!(
                    "the marker noise ({noise} m) is not known: give options.noise_m (the \
                     least-squares fit has no residual degrees of freedom or fits exactly)"
                )));
            }
            let prior = Prior {
                sigma,
                mean: x0.clone(),
                noise,
                weight: map.weight,
            };
            // The prior determines every parameter it covers: the rank decision is the
            // stacked problem's, at a structural tolerance (columns in noise units).
            let o = SolveOptions {
                rank_tolerance: so.rank_tolerance.min(1e-8),
                ..so.clone()
            };
            solve_map(&problem, &unknowns, &x0, &prior, &o, monitor)?
        }
        (Some(_), Some(_)) => {
            return Err(IdentifyError::Model(
                "a prior and a robust loss cannot be combined: choose one".into(),
            ));
        }
        (_, Some(r)) => (
            solve_robust(&problem, &unknowns, &x0, &so, r, monitor)?,
            PriorReport::least_squares(),
        ),
        (_, None) => (
            solve(&problem, &unknowns, &x0, &so, monitor)?,
            PriorReport::least_squares(),
        ),
    };
    let fitted = problem.model(&solution.x);
    let (rmse, per_marker) = marker_rmse(&fitted, samples);
    Ok(MarkerFit {
        model: fitted,
        problem,
        solution,
        rmse,
        per_marker,
        prior,
    })
}

/// The non-calibrated model of the paper: nominal joints, with a closed-form start and a fit
/// of the base frame and marker positions only.
pub fn fit_frames(
    model: &Humanoid,
    samples: &[MarkerSample],
    opts: &FitOptions,
    monitor: &dyn Monitor,
) -> Result<MarkerFit, IdentifyError> {
    let mut start = model.clone();
    if let Some(b) = initial_base(&start, samples) {
        start.base = b;
    }
    fit(
        &start,
        Groups::FRAMES.select(&start),
        samples,
        opts,
        monitor,
    )
}

/// Refit the base frame and markers of a calibrated model on new samples (markers are
/// re-mounted between sessions), joint parameters held.
pub fn refit_frames(
    model: &Humanoid,
    samples: &[MarkerSample],
    opts: &FitOptions,
    monitor: &dyn Monitor,
) -> Result<MarkerFit, IdentifyError> {
    fit_frames(model, samples, opts, monitor)
}

/// Number of parameters of `fit`'s problem that pass a structural rank test (relative
/// tolerance `tolerance`, e.g. 1e-8) on its Jacobian at the solution, in priority order.
pub fn structural_count(f: &MarkerFit, tolerance: f64) -> Result<usize, IdentifyError> {
    use crate::identify::Problem;
    let p = &f.problem;
    let x: Vec<f64> = p
        .free()
        .iter()
        .map(|&g| f.model.value(f.model.params[g]))
        .collect();
    let mut j = DMatrix::zeros(p.residual_count(), p.unknown_count());
    p.jacobian(&x, &mut j)?;
    Ok(rank_revealing(&j, &Pivoting::Priority(p.priority_order()), tolerance).rank)
}

/// The base parameters of a marker layout: the Jacobian of every marker at every state
/// (noise-free, all markers visible) with respect to `free`, compressed to its R factor in
/// batches, then QR with column pivoting in the spec's priority order.
pub fn base_parameters(
    model: &Humanoid,
    free: &[usize],
    states: &[State],
    tolerance: f64,
    monitor: &dyn Monitor,
) -> Result<(RankReport, Vec<usize>), IdentifyError> {
    let m = free.len();
    let nm = model.markers.len();
    let mut r = DMatrix::<f64>::zeros(0, m);
    let all: Vec<usize> = (0..nm).collect();
    let batch = (4 * m / (3 * nm).max(1)).max(1);
    for (b, chunk) in states.chunks(batch).enumerate() {
        if monitor.is_cancelled() {
            return Err(IdentifyError::Cancelled);
        }
        monitor.progress(
            (b * batch) as f64 / states.len().max(1) as f64,
            "base parameters",
        );
        let rows = r.nrows() + 3 * nm * chunk.len();
        let mut a = DMatrix::zeros(rows, m);
        a.rows_mut(0, r.nrows()).copy_from(&r);
        let mut row = r.nrows();
        for s in chunk {
            model.marker_jacobians(s, &all, |_, _, buf| {
                for (c, &g) in free.iter().enumerate() {
                    for k in 0..3 {
                        a[(row + k, c)] = buf[g][k];
                    }
                }
                row += 3;
            });
        }
        r = if a.nrows() > m { a.qr().r() } else { a };
    }
    let problem = MarkerProblem::new(model.clone(), free.to_vec(), Vec::new());
    let rank = rank_revealing(&r, &Pivoting::Priority(problem.priority_order()), tolerance);
    let mut kept: Vec<usize> = rank.kept.iter().map(|&k| free[k]).collect();
    kept.sort_unstable();
    Ok((rank, kept))
}
