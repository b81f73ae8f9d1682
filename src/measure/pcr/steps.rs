//! The bounded three-step identification of the 3-PF robot (`../shared/spec/pcr.md`):
//! (1) the extrinsics alone, (2) the extrinsics with the most influential robot parameters
//! (rod lengths, proximal angles gamma and alpha, clamp positions A and B), (3) everything,
//! each step starting from the previous result, every unknown bounded by nominal +/- 3
//! standard uncertainties. The result carries the paper's Table 3.
//!
//! Gauge freedoms (a rigid motion of the clamps A and the sensor frame, of the clamps B and
//! the pattern frame, the modulus E without load, a common scale of the diameters) are found
//! per step by rank detection on the uncertainty-scaled Jacobian, evaluated at the model's
//! own predictions so that they are exact. Each is held at nominal as a combination (see
//! [`crate::identify::gauge`]); the parameters rank detection drops are reported by name.

use nalgebra::DMatrix;

use super::prior::{PcrPrior, map_gauges};
use super::problem::{PcrProblem, extrinsics, robot_params, unknowns};
use super::report::{ErrorStats, StepReport, Table3, Table3Row, Table3Set};
use super::{PcrMeasurement, UNKNOWNS, measured_pose, pose_error, unknown_name, unknown_unit};
use crate::identify::prior::{MapProblem, PriorReport};
use crate::identify::solve::Dependency;
use crate::identify::{
    Gauged, IdentifyError, LmOptions, ParamReport, Pivoting, Problem, Restricted, Uncertainty,
    levenberg_marquardt, null_directions, rank_revealing, uncertainty,
};
use crate::model::pcr::params::{E_INDEX, LIMB_FIELDS};
use crate::model::pcr::{Pcr, PcrFile, ROBOT_PARAMS};
use crate::util::{Monitor, SubMonitor};

/// One identification step: a name and the unknowns it frees (indices, robot parameters
/// 0..28 then extrinsics 28..34).
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// Name for reports.
    pub name: String,
    /// Unknowns identified in this step.
    pub free: Vec<usize>,
}

fn of_types(types: &[&str]) -> Vec<usize> {
    (0..ROBOT_PARAMS)
        .filter(|&k| k != E_INDEX && types.contains(&LIMB_FIELDS[k % 9]))
        .collect()
}

impl Step {
    /// A step from names: an unknown (`Ax_1`, `sx`), a parameter type for all limbs (`l`,
    /// `gamma`, ...), `E`, `extrinsics`, or `all`.
    pub fn from_names(name: &str, names: &[String]) -> Result<Step, String> {
        let mut free = Vec::new();
        for n in names {
            let add: Vec<usize> = match n.as_str() {
                "all" => (0..UNKNOWNS).collect(),
                "extrinsics" => (ROBOT_PARAMS..UNKNOWNS).collect(),
                t if LIMB_FIELDS.contains(&t) => of_types(&[t]),
                other => match (0..UNKNOWNS).find(|&k| unknown_name(k) == other) {
                    Some(k) => vec![k],
                    None => return Err(format!("unknown parameter or type `{other}`")),
                },
            };
            free.extend(add);
        }
        free.sort_unstable();
        free.dedup();
        if free.is_empty() {
            return Err("a step needs at least one parameter".into());
        }
        Ok(Step {
            name: name.to_string(),
            free,
        })
    }
}

/// The paper's three steps.
pub fn default_steps() -> Vec<Step> {
    let ext: Vec<usize> = (ROBOT_PARAMS..UNKNOWNS).collect();
    let mut influential = of_types(&["l", "gamma", "alpha", "Ax", "Ay", "Bx", "By"]);
    influential.extend(&ext);
    vec![
        Step {
            name: "extrinsics".into(),
            free: ext,
        },
        Step {
            name: "influential".into(),
            free: influential,
        },
        Step {
            name: "all".into(),
            free: (0..UNKNOWNS).collect(),
        },
    ]
}

/// Settings of [`identify_steps`].
#[derive(Debug, Clone)]
pub struct CalibrationOptions {
    /// The steps, in order.
    pub steps: Vec<Step>,
    /// Relative tolerance of the rank detection.
    pub rank_tolerance: f64,
    /// Bounds are nominal +/- this many standard uncertainties.
    pub bound_sigmas: f64,
    /// Levenberg-Marquardt iteration limit per step.
    pub max_iterations: usize,
    /// Initial damping (Nielsen's tau) of the steps after the first, which start at the
    /// previous step's optimum: small, so the damping need not decay over many iterations.
    pub refine_damping: f64,
    /// Hold the unknowns rank detection drops at nominal themselves, instead of holding each
    /// unidentifiable combination at nominal (the default, minimum-norm gauge). Holding
    /// single parameters makes the others absorb their errors: with the file's 3-sigma bounds
    /// a lever (the 54 mm between clamps times an angle error) can push them onto a bound.
    pub hold_unidentifiable: bool,
    /// Worker threads for the forward kinematics and Jacobians of the measurements; `None`
    /// uses every available core.
    pub threads: Option<usize>,
    /// A Gaussian prior: MAP identification (see [`super::prior`]); `None` for least squares.
    pub prior: Option<PcrPrior>,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        Self {
            steps: default_steps(),
            rank_tolerance: 1e-8,
            bound_sigmas: 3.0,
            max_iterations: 100,
            refine_damping: 1e-9,
            hold_unidentifiable: false,
            threads: None,
            prior: None,
        }
    }
}

/// Outcome of the identification.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// Identified unknowns (robot parameters then extrinsics).
    pub x: Vec<f64>,
    /// Nominal robot parameters with the extrinsics identified alone.
    pub nominal_fit: Vec<f64>,
    /// Per unknown: name, unit, nominal, value, std, identifiable, effect, bound hit.
    pub params: Vec<ParamReport>,
    /// Names rank detection dropped in the last step.
    pub unidentifiable: Vec<String>,
    /// What they duplicate.
    pub dependencies: Vec<Dependency>,
    /// Per step.
    pub steps: Vec<StepReport>,
    /// Table 3.
    pub table3: Table3,
    /// Position errors (m) per calibration pose: nominal fit, identified.
    pub calibration_errors: [Vec<f64>; 2],
    /// Position errors (m) per validation pose: nominal fit, identified.
    pub validation_errors: Option<[Vec<f64>; 2]>,
    /// Uncertainty of the last step's unknowns.
    pub uncertainty: Uncertainty,
    /// Which mode ran (least squares or MAP) and the MAP objective's terms.
    pub prior: PriorReport,
}

/// Priority of unknowns for rank detection: the extrinsics first (they absorb the gauges),
/// then the robot parameters by decreasing influence, limb by limb; `E` last.
fn priority() -> Vec<usize> {
    let mut order: Vec<usize> = (ROBOT_PARAMS..UNKNOWNS).collect();
    for t in ["l", "gamma", "alpha", "Ax", "Ay", "Bx", "By", "beta", "d"] {
        order.extend(of_types(&[t]));
    }
    order.push(E_INDEX);
    order
}

/// Position (m) and angle (rad) model errors of `x` on `meas`.
pub fn model_errors(
    base: &Pcr,
    x: &[f64],
    meas: &[PcrMeasurement],
) -> Result<(Vec<f64>, Vec<f64>), IdentifyError> {
    let problem = PcrProblem::new(base.clone(), meas.to_vec(), 1.0);
    let (_, sols) = problem.solve(x)?;
    let ext = extrinsics(x);
    Ok(meas
        .iter()
        .zip(&sols)
        .map(|(m, eq)| pose_error(&eq.pose, &measured_pose(&ext, &m.z)))
        .unzip())
}

struct StepOutcome {
    x: Vec<f64>,
    report: StepReport,
    free: Vec<usize>,
    dropped: Vec<usize>,
    at_bound: Vec<i8>,
    uncertainty: Uncertainty,
    consistent_jacobian: DMatrix<f64>,
}

struct Context<'a> {
    problem: &'a PcrProblem,
    x_nom: &'a [f64],
    scale: &'a [f64],
    lower: Vec<f64>,
    upper: Vec<f64>,
    opts: &'a CalibrationOptions,
}

fn run_step(
    ctx: &Context<'_>,
    x: &[f64],
    step: &Step,
    first: bool,
    monitor: &dyn Monitor,
) -> Result<StepOutcome, IdentifyError> {
    let problem = ctx.problem;
    let free: Vec<usize> = step
        .free
        .iter()
        .copied()
        .filter(|&k| ctx.scale[k] > 0.0)
        .collect();
    let n = problem.residual_count();
    let mut jc = DMatrix::zeros(n, UNKNOWNS);
    problem.jacobian_at(x, true, &mut jc)?;
    let mut jf = DMatrix::zeros(n, free.len());
    for (c, &k) in free.iter().enumerate() {
        jf.set_column(c, &jc.column(k));
    }
    let order: Vec<usize> = priority()
        .iter()
        .filter_map(|k| free.iter().position(|f| f == k))
        .collect();
    let rank = rank_revealing(&jf, &Pivoting::Priority(order), ctx.opts.rank_tolerance);
    let scale: Vec<f64> = free.iter().map(|&k| ctx.scale[k]).collect();
    let mut dropped: Vec<usize> = rank.dropped.iter().map(|&c| free[c]).collect();
    dropped.sort_unstable();
    let weight = (0..free.len())
        .map(|c| jf.column(c).norm() * scale[c])
        .fold(0.0, f64::max);
    // Either hold each unidentifiable combination at nominal (minimum-norm gauge), or the
    // dropped unknowns themselves.
    let (solved, gauges, start) = if ctx.opts.hold_unidentifiable {
        let keep: Vec<usize> = free
            .iter()
            .copied()
            .filter(|k| !dropped.contains(k))
            .collect();
        let mut start = x.to_vec();
        for &k in &dropped {
            start[k] = ctx.x_nom[k];
        }
        (keep, Vec::new(), start)
    } else {
        let mut g = null_directions(&jf, &scale, rank.dropped.len())?;
        if let Some(p) = &ctx.opts.prior {
            let sigma: Vec<Option<f64>> = free.iter().map(|&k| p.sigma[k]).collect();
            g = map_gauges(g, &scale, &sigma);
        }
        (free.clone(), g, x.to_vec())
    };
    let restricted = Restricted::new(problem, start.clone(), solved.clone());
    let x_ref: Vec<f64> = solved.iter().map(|&k| ctx.x_nom[k]).collect();
    let prior = ctx
        .opts
        .prior
        .as_ref()
        .map(|p| p.restricted(&solved, ctx.x_nom));
    let map = prior.as_ref().map(|p| MapProblem::new(&restricted, p));
    let data: &dyn Problem = match &map {
        Some(m) => m,
        None => &restricted,
    };
    let gauged = Gauged::new(data, gauges, x_ref, weight.max(f64::MIN_POSITIVE));
    let lm = LmOptions {
        max_iterations: ctx.opts.max_iterations,
        initial_damping: if first { 1e-3 } else { ctx.opts.refine_damping },
        lower: Some(solved.iter().map(|&k| ctx.lower[k]).collect()),
        upper: Some(solved.iter().map(|&k| ctx.upper[k]).collect()),
        ..LmOptions::default()
    };
    let xs: Vec<f64> = solved.iter().map(|&k| start[k]).collect();
    let rep = levenberg_marquardt(&gauged, &xs, &lm, monitor)?;
    let x_new = restricted.expand(&rep.x);
    let m = problem.measurements().len();
    let mean_e_p = (0..m)
        .map(|j| rep.residuals[3 * j + 1].hypot(rep.residuals[3 * j + 2]))
        .sum::<f64>()
        / m.max(1) as f64;
    let report = StepReport {
        name: step.name.clone(),
        free: free.iter().map(|&k| unknown_name(k)).collect(),
        unidentifiable: dropped.iter().map(|&k| unknown_name(k)).collect(),
        dependencies: rank
            .dropped
            .iter()
            .zip(&rank.dependencies)
            .map(|(&c, dep)| Dependency {
                name: unknown_name(free[c]),
                combination: dep
                    .iter()
                    .take(8)
                    .map(|&(k, v)| (unknown_name(free[k]), v))
                    .collect(),
                reason: None,
            })
            .collect(),
        stop_reason: rep.stop,
        iterations: rep.iterations,
        cost_before: rep.initial_cost,
        cost_after: rep.cost,
        mean_e_p_um: mean_e_p * 1e6,
    };
    Ok(StepOutcome {
        x: x_new,
        report,
        dropped,
        at_bound: rep.at_bound.clone(),
        uncertainty: uncertainty(&rep.jacobian, &rep.residuals),
        consistent_jacobian: jc,
        free: solved,
    })
}

/// Identify a 3-PF robot and its extrinsics from `calibration` measurements, starting at the
/// model file's nominal values, step by step; validate on `validation` if given.
pub fn identify_steps(
    base: &Pcr,
    file: &PcrFile,
    calibration: &[PcrMeasurement],
    validation: Option<&[PcrMeasurement]>,
    opts: &CalibrationOptions,
    monitor: &dyn Monitor,
) -> Result<Calibration, IdentifyError> {
    if opts.steps.is_empty() {
        return Err(IdentifyError::Model("no identification step".into()));
    }
    let weight = file.repeatability.position / file.repeatability.orientation;
    let x_nom = unknowns(&file.params(), &file.extrinsics);
    let scale: Vec<f64> = file
        .uncertainty
        .robot()
        .into_iter()
        .chain(file.uncertainty.extrinsics())
        .collect();
    let base = base
        .with_params(file.params())
        .map_err(|e| IdentifyError::Model(e.to_string()))?;
    let mut problem = PcrProblem::new(base.clone(), calibration.to_vec(), weight);
    if let Some(threads) = opts.threads {
        problem = problem.with_threads(threads);
    }
    let ctx = Context {
        problem: &problem,
        x_nom: &x_nom,
        scale: &scale,
        lower: x_nom
            .iter()
            .zip(&scale)
            .map(|(x, u)| x - opts.bound_sigmas * u)
            .collect(),
        upper: x_nom
            .iter()
            .zip(&scale)
            .map(|(x, u)| x + opts.bound_sigmas * u)
            .collect(),
        opts,
    };
    let ext_only: Vec<usize> = (ROBOT_PARAMS..UNKNOWNS).collect();
    let total = opts.steps.len() + usize::from(opts.steps[0].free != ext_only);
    let mut x = x_nom.clone();
    let mut nominal_fit = None;
    let mut reports = Vec::new();
    let mut last = None;
    for (s, step) in opts.steps.iter().enumerate() {
        let sub = SubMonitor::new(
            monitor,
            s as f64 / total as f64,
            (s + 1) as f64 / total as f64,
        );
        let out = run_step(&ctx, &x, step, s == 0, &sub)?;
        x = out.x.clone();
        if s == 0 && step.free == ext_only {
            nominal_fit = Some(x.clone());
        }
        reports.push(out.report.clone());
        last = Some(out);
    }
    let nominal_fit = match nominal_fit {
        Some(v) => v,
        None => {
            let sub = SubMonitor::new(monitor, (total - 1) as f64 / total as f64, 1.0);
            let step = Step {
                name: "extrinsics".into(),
                free: ext_only,
            };
            run_step(&ctx, &x_nom, &step, true, &sub)?.x
        }
    };
    let Some(last) = last else {
        return Err(IdentifyError::Model("no identification step".into()));
    };
    let params = (0..UNKNOWNS)
        .map(|k| {
            let pos = last.free.iter().position(|&f| f == k);
            let effect =
                last.consistent_jacobian.column(k).amax() * 2.0 * opts.bound_sigmas * scale[k];
            ParamReport {
                name: unknown_name(k),
                unit: unknown_unit(k).to_string(),
                nominal: x_nom[k],
                value: x[k],
                std: pos
                    .filter(|_| !last.dropped.contains(&k))
                    .map(|p| last.uncertainty.std[p]),
                identifiable: pos.is_some() && !last.dropped.contains(&k),
                effect_size: effect,
                at_bound: pos.and_then(|p| match last.at_bound[p] {
                    -1 => Some("lower".into()),
                    1 => Some("upper".into()),
                    _ => None,
                }),
            }
        })
        .collect();
    let (cal_nom, cal_nom_t) = model_errors(&base, &nominal_fit, calibration)?;
    let (cal_id, cal_id_t) = model_errors(&base, &x, calibration)?;
    let set = |p0: &[f64], t0: &[f64], p1: &[f64], t1: &[f64]| Table3Set {
        poses: p0.len(),
        e_p: Table3Row {
            unit: "um".into(),
            nominal: ErrorStats::of(p0, 1e6),
            identified: ErrorStats::of(p1, 1e6),
        },
        e_theta: Table3Row {
            unit: "mrad".into(),
            nominal: ErrorStats::of(t0, 1e3),
            identified: ErrorStats::of(t1, 1e3),
        },
    };
    let mut validation_errors = None;
    let mut val_set = None;
    if let Some(v) = validation.filter(|v| !v.is_empty()) {
        let (vp0, vt0) = model_errors(&base, &nominal_fit, v)?;
        let (vp1, vt1) = model_errors(&base, &x, v)?;
        val_set = Some(set(&vp0, &vt0, &vp1, &vt1));
        validation_errors = Some([vp0, vp1]);
    }
    let prior = match &opts.prior {
        None => PriorReport::least_squares(),
        Some(p) => {
            let mut r = vec![0.0; problem.residual_count()];
            problem.residuals(&x, &mut r)?;
            let data = r.iter().map(|v| v * v).sum::<f64>() / (p.noise * p.noise);
            let prior_cost = p.cost(&x, &x_nom);
            PriorReport {
                mode: "map",
                weight: Some(p.weight),
                noise: Some(p.noise),
                count: p.count(),
                objective: Some(data + prior_cost),
                prior_cost: Some(prior_cost),
                log_evidence: None,
                k_fold_errors: None,
                auto: None,
            }
        }
    };
    monitor.progress(1.0, "identification done");
    Ok(Calibration {
        params,
        unidentifiable: last.report.unidentifiable.clone(),
        dependencies: last.report.dependencies.clone(),
        steps: reports,
        table3: Table3 {
            calibration: set(&cal_nom, &cal_nom_t, &cal_id, &cal_id_t),
            validation: val_set,
        },
        calibration_errors: [cal_nom, cal_id],
        validation_errors,
        uncertainty: last.uncertainty,
        prior,
        nominal_fit,
        x,
    })
}

/// The calibrated model file: `file` with the identified values of `x`.
pub fn calibrated_file(file: &PcrFile, x: &[f64]) -> PcrFile {
    file.with_values(&robot_params(x), &extrinsics(x))
}
