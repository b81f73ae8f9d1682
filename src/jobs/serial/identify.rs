//! `serial.identify`: elasto-geometric identification of a serial arm from ball-centring
//! (or Cartesian) measurements, with rank detection, standard deviations, residual and
//! per-ball statistics, optional validation, and the calibrated model file.

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::{ChainSpec, PlateSpec, SerialModel, load_model};
use crate::identify::{Pivoting, Solution, SolveOptions};
use crate::jobs::{Artefact, Inputs, JobError, Output, Prepared, Table, parse_spec};
use crate::measure::{BallPlate, PointMeasurement, PointProblem, Target};
use crate::model::{Chain, ParamId};
use crate::util::{Monitor, Summary};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    model: Value,
    #[serde(default)]
    chain: Option<ChainSpec>,
    measurements: Value,
    #[serde(default)]
    ball_plate: Option<PlateSpec>,
    #[serde(default)]
    validation: Option<Value>,
    #[serde(default)]
    options: IdentifyOptions,
}

/// `options` of `serial.identify` (and of `serial.dispersion`).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentifyOptions {
    /// Parameters to identify (default: the model's list).
    #[serde(default)]
    pub identify: Option<Vec<String>>,
    /// Relative tolerance of the rank detection (default 1e-8).
    #[serde(default)]
    pub rank_tolerance: Option<f64>,
    /// Iteration limit of Levenberg-Marquardt (default 200).
    #[serde(default)]
    pub max_iterations: Option<usize>,
    /// Measurement noise (model length unit) below which an effect is not observable
    /// (default: the fitted residual standard deviation).
    #[serde(default)]
    pub noise: Option<f64>,
    /// Fraction of the noise below which a parameter's effect (or a combination's singular
    /// value) is not observable and the parameter is held at nominal (default 0.01).
    #[serde(default)]
    pub effect_fraction: Option<f64>,
    /// Seed of random choices (dispersion, the folds of `prior_weight: "cv"`).
    #[serde(default)]
    pub seed: Option<u64>,
    /// Gaussian prior around the starting model: MAP instead of least squares.
    #[serde(default)]
    pub prior: Option<crate::identify::PriorSpec>,
    /// Weight of the prior: a number (default 1) or "cv" (5-fold on the training set).
    #[serde(default)]
    pub prior_weight: Option<super::prior::PriorWeight>,
}

/// Everything an identification needs, validated.
#[derive(Debug)]
pub struct IdentifyInputs {
    /// The starting model.
    pub model: SerialModel,
    /// Parameters to identify.
    pub ids: Vec<ParamId>,
    /// Ball plate (empty for Cartesian-only data).
    pub plate: BallPlate,
    /// Calibration measurements.
    pub meas: Vec<PointMeasurement>,
    /// Validation measurements (Cartesian).
    pub validation: Option<Vec<PointMeasurement>>,
    /// Options.
    pub options: IdentifyOptions,
}

/// Parse the inputs shared by `serial.identify` and `serial.dispersion`.
pub fn parse_inputs(
    inputs: &Inputs<'_>,
    model: &Value,
    chain: Option<&ChainSpec>,
    measurements: &Value,
    plate: Option<&PlateSpec>,
    validation: Option<&Value>,
    options: IdentifyOptions,
) -> Result<IdentifyInputs, JobError> {
    let model = load_model(inputs, model, chain)?;
    let ids = match &options.identify {
        Some(names) => model.params("options.identify", names)?,
        None => model.default_identify(),
    };
    if ids.is_empty() {
        return Err(JobError::invalid(
            "options.identify",
            "no parameter to identify",
        ));
    }
    let table = inputs.table("measurements", measurements)?;
    let plate = match plate {
        Some(p) => p.plate()?,
        None if table.has("ball") => {
            return Err(JobError::invalid(
                "ball_plate",
                "ball-centring measurements need a ball plate",
            ));
        }
        None => BallPlate {
            centres: vec![],
            distances: vec![],
            gauge: None,
        },
    };
    let meas = model.measurements("measurements", &table, plate.len())?;
    let validation = match validation {
        Some(v) => {
            let t = inputs.table("validation", v)?;
            if !t.has("x") && !t.has("ball") {
                return Err(JobError::invalid(
                    "validation",
                    "needs columns x, y, z (TCP position in {W}) or `ball` (point coincidence)",
                ));
            }
            Some(model.measurements("validation", &t, plate.len())?)
        }
        None => None,
    };
    for (name, v) in [
        ("options.rank_tolerance", options.rank_tolerance),
        ("options.noise", options.noise),
        ("options.effect_fraction", options.effect_fraction),
    ] {
        if let Some(v) = v {
            if !(v.is_finite() && v > 0.0) {
                return Err(JobError::invalid(
                    name,
                    format!("{v} must be a positive number"),
                ));
            }
        }
    }
    let inputs = IdentifyInputs {
        model,
        ids,
        plate,
        meas,
        validation,
        options,
    };
    super::prior::validate(&inputs)?;
    Ok(inputs)
}

impl IdentifyInputs {
    /// Solver settings from the options.
    pub fn solve_options(&self, problem: &PointProblem) -> SolveOptions {
        let mut o = SolveOptions {
            pivoting: self.pivoting(problem),
            noise: self.options.noise,
            nuisance: Some(problem.nuisance()),
            ..Default::default()
        };
        if let Some(t) = self.options.rank_tolerance {
            o.rank_tolerance = t;
        }
        if let Some(f) = self.options.effect_fraction {
            o.effect_fraction = Some(f);
        }
        if let Some(n) = self.options.max_iterations {
            o.lm.max_iterations = n;
        }
        o
    }

    /// Column order of rank detection: norm pivoting for DH models (whose parameter lists
    /// are minimal by construction, and where serial-robot.md keeps base parameters over
    /// link-1 ones); the priority order of humanoid.md for URDF chains, whose six placement
    /// errors per joint over-parameterise on purpose: a deterministic choice among
    /// equivalent columns, translations before angles, so that a rotation acting through a
    /// tiny lever (a strongly nonlinear direction) is the one held.
    pub fn pivoting(&self, problem: &PointProblem) -> Pivoting {
        match self.model.source {
            super::Source::Dh(_) => Pivoting::Norm,
            super::Source::Urdf { .. } => Pivoting::Priority(problem.priority_order()),
        }
    }

    /// Identify from the measurements `subset` (all when `None`).
    pub fn identify(
        &self,
        subset: Option<&[usize]>,
        monitor: &dyn Monitor,
    ) -> Result<(PointProblem, Solution), JobError> {
        let (problem, sol, _) = super::prior::identify(self, subset, monitor)?;
        Ok((problem, sol))
    }
}

/// Absolute position errors of a model against Cartesian measurements (each model with its
/// own static deflection).
pub fn position_errors(chain: &Chain, meas: &[PointMeasurement]) -> Vec<f64> {
    meas.iter()
        .filter_map(|m| match m.target {
            Target::Point(p) => {
                Some((chain.tcp(&m.q, Some(&chain.static_torques(&m.q))).p - p).norm())
            }
            Target::Ball(_) => None,
        })
        .collect()
}

/// `{mean, median, std, max, unit}` (plus count, min, rms) of errors.
pub fn stats(v: &[f64], unit: &str) -> Value {
    serde_json::to_value(Summary::of(v, unit)).unwrap_or(Value::Null)
}

/// A validated `serial.identify` job.
#[derive(Debug)]
pub struct IdentifyJob {
    inputs: IdentifyInputs,
}

/// Validate a `serial.identify` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<IdentifyJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    Ok(IdentifyJob {
        inputs: parse_inputs(
            inputs,
            &s.model,
            s.chain.as_ref(),
            &s.measurements,
            s.ball_plate.as_ref(),
            s.validation.as_ref(),
            s.options,
        )?,
    })
}

/// Known distance between balls i and j of a plate, if the plate fixes it.
fn known_distance(
    plate: &BallPlate,
    centres: &[nalgebra::Vector3<f64>],
    i: usize,
    j: usize,
) -> Option<f64> {
    match (plate.centres[i], plate.centres[j]) {
        (Some(a), Some(b)) => Some((a - b).norm()),
        _ => plate
            .distances
            .iter()
            .find(|d| (d.0, d.1) == (i, j) || (d.0, d.1) == (j, i))
            .map(|d| d.2)
            .or_else(|| Some((centres[i] - centres[j]).norm())),
    }
}

/// Point-coincidence statistics of two models on ball measurements: per ball the RMS
/// distance of the model TCP positions from their mean (spread), and per pair of balls the
/// distance between those means minus the known distance. Torques from the start model.
pub fn coincidence_report(
    meas: &[PointMeasurement],
    start: &Chain,
    end: &Chain,
    plate: &BallPlate,
    centres: &[nalgebra::Vector3<f64>],
    unit: &str,
) -> Value {
    let mut balls = Vec::new();
    let mut means: Vec<Option<[nalgebra::Vector3<f64>; 2]>> = Vec::new();
    for b in 0..plate.len() {
        let qs: Vec<&Vec<f64>> = meas
            .iter()
            .filter(|m| m.target == Target::Ball(b))
            .map(|m| &m.q)
            .collect();
        if qs.is_empty() {
            means.push(None);
            continue;
        }
        let mut entry = Map::new();
        entry.insert("ball".into(), json!(b + 1));
        entry.insert("count".into(), json!(qs.len()));
        let mut m2 = [nalgebra::Vector3::zeros(); 2];
        for (slot, (label, chain)) in [("before", start), ("after", end)].into_iter().enumerate() {
            let pts: Vec<_> = qs
                .iter()
                .map(|q| chain.tcp(q, Some(&start.static_torques(q))).p)
                .collect();
            let mean = pts.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p) / pts.len() as f64;
            let spread = (pts.iter().map(|p| (p - mean).norm_squared()).sum::<f64>()
                / pts.len() as f64)
                .sqrt();
            entry.insert(format!("spread_rms_{label}"), json!(spread));
            entry.insert(
                format!("mean_position_{label}"),
                json!([mean.x, mean.y, mean.z]),
            );
            m2[slot] = mean;
        }
        entry.insert("unit".into(), json!(unit));
        balls.push(Value::Object(entry));
        means.push(Some(m2));
    }
    let mut dists = Vec::new();
    for i in 0..plate.len() {
        for j in i + 1..plate.len() {
            let (Some(a), Some(b), Some(known)) =
                (means[i], means[j], known_distance(plate, centres, i, j))
            else {
                continue;
            };
            dists.push(json!({
                "balls": [i + 1, j + 1],
                "known": known,
                "error_before": (a[0] - b[0]).norm() - known,
                "error_after": (a[1] - b[1]).norm() - known,
                "unit": unit,
            }));
        }
    }
    json!({"balls": balls, "ball_distances": dists})
}

impl Prepared for IdentifyJob {
    fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let inp = &self.inputs;
        let (problem, sol, prior) = super::prior::identify(inp, None, monitor)?;
        let calibrated = problem.model(&sol.x);
        let unit = inp.model.length_unit();
        let norms = |r: &nalgebra::DVector<f64>| -> Vec<f64> {
            (0..problem.measurements().len())
                .map(|i| r.rows(3 * i, 3).norm())
                .collect()
        };
        let mut f = Map::new();
        f.insert(
            "parameters".into(),
            serde_json::to_value(&sol.params).unwrap_or(Value::Null),
        );
        f.insert("prior".into(), json!(prior));
        f.insert("unidentifiable".into(), json!(sol.unidentifiable));
        f.insert(
            "dependencies".into(),
            serde_json::to_value(&sol.dependencies).unwrap_or(Value::Null),
        );
        f.insert("weakly_observable".into(), json!(sol.weakly_observable));
        f.insert(
            "unobservable".into(),
            serde_json::to_value(&sol.unobservable).unwrap_or(Value::Null),
        );
        f.insert(
            "observability".into(),
            json!({
                "condition_number": sol.condition_number,
                "near_dependent": sol.near_dependent,
                "scaling": "physical: lengths 1 mm, angles 0.5 deg, compliances 0.005 deg/(N*m)",
            }),
        );
        f.insert("gauge_freedom".into(), json!(inp.plate.gauge));
        f.insert(
            "convergence".into(),
            json!({
                "stop_reason": sol.stop, "converged": sol.converged(), "status": sol.status(),
                "degenerate": sol.degenerate, "iterations": sol.iterations,
                "cost_before": sol.cost_before, "cost_after": sol.cost_after,
                "cost_nuisance_only": sol.nuisance_cost, "cost_unit": format!("{unit}^2"),
            }),
        );
        f.insert("rank".into(), json!({"rank": sol.free.len(), "unknowns": sol.params.len(), "tolerance": inp.solve_options(&problem).rank_tolerance}));
        f.insert(
            "condition_number".into(),
            json!(sol.uncertainty.condition_number),
        );
        f.insert(
            "residual_std".into(),
            json!({"value": sol.uncertainty.sigma, "unit": unit, "dof": sol.uncertainty.dof}),
        );
        f.insert(
            "residuals".into(),
            json!({
                "before": stats(&norms(&sol.residuals_before), unit),
                "after": stats(&norms(&sol.residuals), unit),
            }),
        );
        let centres = problem.centres(&sol.x);
        if !inp.plate.is_empty() {
            let r = coincidence_report(
                problem.measurements(),
                &inp.model.chain,
                &calibrated,
                &inp.plate,
                &centres,
                unit,
            );
            if let Value::Object(m) = r {
                f.extend(m);
            }
        }
        if let Some(v) = &inp.validation {
            let cartesian: Vec<PointMeasurement> = v
                .iter()
                .filter(|m| matches!(m.target, Target::Point(_)))
                .cloned()
                .collect();
            if !cartesian.is_empty() {
                f.insert(
                    "validation".into(),
                    json!({
                        "before": stats(&position_errors(&inp.model.chain, &cartesian), unit),
                        "after": stats(&position_errors(&calibrated, &cartesian), unit),
                    }),
                );
            }
            if v.iter().any(|m| matches!(m.target, Target::Ball(_))) {
                f.insert(
                    "validation_coincidence".into(),
                    coincidence_report(
                        v,
                        &inp.model.chain,
                        &calibrated,
                        &inp.plate,
                        &centres,
                        unit,
                    ),
                );
            }
        }
        let provenance = json!({"method": "serial.identify", "calibd_version": crate::jobs::envelope::VERSION, "measurements": problem.measurements().len()});
        let (model_value, model_file) = inp.model.calibrated(&calibrated, provenance)?;
        f.insert("calibrated_model".into(), model_value);
        let mut res = Table::new(&["measurement", "before", "after"]);
        for (i, (a, b)) in norms(&sol.residuals_before)
            .into_iter()
            .zip(norms(&sol.residuals))
            .enumerate()
        {
            res.push(vec![(i + 1) as f64, a, b]);
        }
        let residual_csv = Artefact {
            name: "residuals.csv".into(),
            media_type: "text/csv".into(),
            content: res.to_csv().into_bytes(),
        };
        Ok(Output {
            fields: f,
            main_table: None,
            artefacts: vec![model_file, residual_csv],
        })
    }
}
