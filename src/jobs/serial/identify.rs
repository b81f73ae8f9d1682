//! `serial.identify`: elasto-geometric identification of a serial arm from ball-centring
//! (or Cartesian) measurements, with rank detection, standard deviations, residual and
//! per-ball statistics, optional validation, and the calibrated model file.
//!
//! Which measurement a table holds is decided by its columns: `L_mm` (a distance from the
//! TCP to an unknown fixed anchor, with an unknown length offset: draw-wire sensors,
//! interferometers, laser trackers in distance-only mode) takes precedence; otherwise `ball`
//! (ball-centring); otherwise `x, y, z` (Cartesian). With `L_mm` present, `x, y, z` are not
//! measurements (a controller's own positions are the nominal model, not data) and are
//! reported as unused; `L_mm` together with `ball` is refused as ambiguous. Every column a
//! table has and the job does not read is named in the result's `warnings`.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::{ChainSpec, PlateSpec, SerialModel, load_model};
use crate::identify::{Pivoting, Solution, SolveOptions, solve};
use crate::jobs::{
    Artefact, Cx, Inputs, JobError, Kind, Output, RunFuture, Table, computed, parse_spec,
};
use crate::measure::distance::distance_errors;
use crate::measure::{
    BallPlate, DistanceMeasurement, DistanceProblem, PointMeasurement, PointProblem, Target,
};
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
    /// Distance calibration measurements (`L_mm` tables; `meas` is then empty).
    pub distances: Vec<DistanceMeasurement>,
    /// Distance validation measurements.
    pub validation_distances: Option<Vec<DistanceMeasurement>>,
    /// Warnings for the result (unused table columns, ignored inputs).
    pub warnings: Vec<String>,
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
    let mut warnings = Vec::new();
    if table.has("L_mm") {
        if table.has("ball") {
            return Err(JobError::invalid(
                "measurements",
                "has both `L_mm` (distance) and `ball` (ball-centring) columns: give one kind",
            ));
        }
        let distances = model.distances("measurements", &table)?;
        warnings.extend(unused_columns(
            "measurements",
            &table,
            &model.joint_columns(),
            &["L_mm"],
        ));
        if plate.is_some() {
            warnings.push("ball_plate is not used with distance (L_mm) measurements".into());
        }
        let validation_distances = match validation {
            Some(v) => {
                let t = inputs.table("validation", v)?;
                if !t.has("L_mm") {
                    return Err(JobError::invalid(
                        "validation",
                        "distance (L_mm) measurements need a validation table with `L_mm`",
                    ));
                }
                warnings.extend(unused_columns(
                    "validation",
                    &t,
                    &model.joint_columns(),
                    &["L_mm"],
                ));
                Some(model.distances("validation", &t)?)
            }
            None => None,
        };
        check_options(&options)?;
        if options.prior.is_some() || options.prior_weight.is_some() {
            return Err(JobError::invalid(
                "options.prior",
                "a prior is not yet supported with distance (L_mm) measurements",
            ));
        }
        return Ok(IdentifyInputs {
            model,
            ids,
            plate: BallPlate {
                centres: vec![],
                distances: vec![],
                gauge: None,
            },
            meas: vec![],
            validation: None,
            distances,
            validation_distances,
            warnings,
            options,
        });
    }
    warnings.extend(unused_columns(
        "measurements",
        &table,
        &model.joint_columns(),
        point_columns(&table),
    ));
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
            warnings.extend(unused_columns(
                "validation",
                &t,
                &model.joint_columns(),
                point_columns(&t),
            ));
            Some(model.measurements("validation", &t, plate.len())?)
        }
        None => None,
    };
    check_options(&options)?;
    let inputs = IdentifyInputs {
        model,
        ids,
        plate,
        meas,
        validation,
        distances: vec![],
        validation_distances: None,
        warnings,
        options,
    };
    super::prior::validate(&inputs)?;
    Ok(inputs)
}

/// The measurement columns a point table is read for.
fn point_columns(t: &Table) -> &'static [&'static str] {
    if t.has("ball") {
        &["ball"]
    } else {
        &["x", "y", "z"]
    }
}

/// A warning naming the columns of `t` that are neither joints nor `used`.
fn unused_columns(field: &str, t: &Table, joints: &[String], used: &[&str]) -> Option<String> {
    let unused: Vec<&str> = t
        .columns
        .iter()
        .filter(|c| !joints.contains(c) && !used.contains(&c.as_str()))
        .map(String::as_str)
        .collect();
    if unused.is_empty() {
        return None;
    }
    let mut why = Vec::new();
    if used.contains(&"L_mm") && unused.iter().any(|c| ["x", "y", "z"].contains(c)) {
        why.push("with `L_mm` the table holds distance measurements; x, y, z of a controller are its nominal model, not measurements");
    }
    if unused.contains(&"L") {
        why.push("a distance (draw-wire) column must be named `L_mm` to be used");
    }
    let (noun, verb) = if unused.len() == 1 {
        ("column", "is")
    } else {
        ("columns", "are")
    };
    let mut msg = format!("{field}: {noun} {} {verb} not used", unused.join(", "));
    if !why.is_empty() {
        msg.push_str(&format!(" ({})", why.join("; ")));
    }
    Some(msg)
}

fn check_options(options: &IdentifyOptions) -> Result<(), JobError> {
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
    Ok(())
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

    /// Refuse distance (`L_mm`) measurements in a job kind that only handles points.
    pub fn require_points(&self, kind: &str) -> Result<(), JobError> {
        if self.distances.is_empty() {
            Ok(())
        } else {
            Err(JobError::invalid(
                "measurements",
                format!(
                    "{kind} does not support distance (L_mm) measurements; serial.identify does"
                ),
            ))
        }
    }

    /// Solver settings for a distance problem.
    pub fn distance_solve_options(&self, problem: &DistanceProblem) -> SolveOptions {
        let mut o = SolveOptions {
            // Strict priority for every model kind: anchor and offset, tool, joints, base
            // (see `DistanceProblem::priority_order`).
            pivoting: Pivoting::Priority(problem.priority_order()),
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

    /// Identify from the distance measurements.
    pub fn identify_distance(
        &self,
        monitor: &dyn Monitor,
    ) -> Result<(DistanceProblem, Solution), JobError> {
        let problem = DistanceProblem::new(
            self.model.chain.clone(),
            self.ids.clone(),
            self.distances.clone(),
        )?;
        let x0 = problem.initial();
        let sol = solve(
            &problem,
            &problem.unknowns(),
            &x0,
            &self.distance_solve_options(&problem),
            monitor,
        )?;
        Ok((problem, sol))
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

/// Identification report fields shared by point and distance problems.
fn solution_fields(f: &mut Map<String, Value>, sol: &Solution, unit: &str, tolerance: f64) {
    f.insert(
        "parameters".into(),
        serde_json::to_value(&sol.params).unwrap_or(Value::Null),
    );
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
    f.insert(
        "convergence".into(),
        json!({
            "stop_reason": sol.stop, "converged": sol.converged(), "status": sol.status(),
            "degenerate": sol.degenerate, "iterations": sol.iterations,
            "cost_before": sol.cost_before, "cost_after": sol.cost_after,
            "cost_nuisance_only": sol.nuisance_cost, "cost_unit": format!("{unit}^2"),
        }),
    );
    f.insert(
        "rank".into(),
        json!({"rank": sol.free.len(), "unknowns": sol.params.len(), "tolerance": tolerance}),
    );
    f.insert(
        "condition_number".into(),
        json!(sol.uncertainty.condition_number),
    );
    f.insert(
        "residual_std".into(),
        json!({"value": sol.uncertainty.sigma, "unit": unit, "dof": sol.uncertainty.dof}),
    );
}

impl IdentifyJob {
    /// Distance (`L_mm`) identification: parameters, anchor and length offset, signed
    /// distance residuals, validation before (nominal model with its own fitted anchor and
    /// offset) and after, the calibrated model.
    fn execute_distance(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let inp = &self.inputs;
        let (problem, sol) = inp.identify_distance(monitor)?;
        let calibrated = problem.model(&sol.x);
        let unit = inp.model.length_unit();
        let mut f = Map::new();
        f.insert("measurement_type".into(), json!("distance"));
        solution_fields(
            &mut f,
            &sol,
            unit,
            inp.distance_solve_options(&problem).rank_tolerance,
        );
        let (anchor, offset) = problem.anchor(&sol.x);
        let x0 = problem.initial();
        let (anchor0, offset0) = problem.anchor(&x0);
        let o = problem.chain_unknowns();
        let std_of = |k: usize| sol.params.get(o + k).and_then(|p| p.std);
        f.insert(
            "anchor".into(),
            json!({"x": anchor.x, "y": anchor.y, "z": anchor.z,
                   "std": [std_of(0), std_of(1), std_of(2)],
                   "nominal_fit": [anchor0.x, anchor0.y, anchor0.z],
                   "frame": "W", "unit": unit}),
        );
        f.insert(
            "length_offset".into(),
            json!({"value": offset, "std": std_of(3), "nominal_fit": offset0, "unit": unit,
                   "meaning": "measured length = |TCP - anchor| + length_offset"}),
        );
        let abs = |r: &nalgebra::DVector<f64>| -> Vec<f64> { r.iter().map(|v| v.abs()).collect() };
        f.insert(
            "residuals".into(),
            json!({
                "before": stats(&abs(&sol.residuals_before), unit),
                "after": stats(&abs(&sol.residuals), unit),
                "meaning": "absolute distance residuals | |TCP - anchor| + length_offset - L |",
            }),
        );
        if let Some(v) = &inp.validation_distances {
            let before: Vec<f64> = distance_errors(&inp.model.chain, &anchor0, offset0, v)
                .iter()
                .map(|e| e.abs())
                .collect();
            let after: Vec<f64> = distance_errors(&calibrated, &anchor, offset, v)
                .iter()
                .map(|e| e.abs())
                .collect();
            f.insert(
                "validation".into(),
                json!({
                    "before": stats(&before, unit),
                    "after": stats(&after, unit),
                    "meaning": "absolute held-out distance errors; before: the starting model with the anchor and offset fitted to it",
                }),
            );
        }
        let provenance = json!({"method": "serial.identify", "measurement_type": "distance", "calibd_version": crate::jobs::envelope::VERSION, "measurements": problem.measurements().len()});
        let (model_value, model_file) = inp.model.calibrated(&calibrated, provenance)?;
        f.insert("calibrated_model".into(), model_value);
        if !inp.warnings.is_empty() {
            f.insert("warnings".into(), json!(inp.warnings));
        }
        let mut res = Table::new(&["measurement", "before", "after"]);
        for (i, (a, b)) in sol
            .residuals_before
            .iter()
            .zip(sol.residuals.iter())
            .enumerate()
        {
            res.push(vec![(i + 1) as f64, *a, *b]);
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

impl Kind for IdentifyJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::execute)
    }
}

impl IdentifyJob {
    /// Compute the job's output (on the blocking pool, see [`Kind::run`]).
    pub fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let inp = &self.inputs;
        if !inp.distances.is_empty() {
            return self.execute_distance(monitor);
        }
        let (problem, sol, prior) = super::prior::identify(inp, None, monitor)?;
        let calibrated = problem.model(&sol.x);
        let unit = inp.model.length_unit();
        let norms = |r: &nalgebra::DVector<f64>| -> Vec<f64> {
            (0..problem.measurements().len())
                .map(|i| r.rows(3 * i, 3).norm())
                .collect()
        };
        let mut f = Map::new();
        solution_fields(
            &mut f,
            &sol,
            unit,
            inp.solve_options(&problem).rank_tolerance,
        );
        f.insert("prior".into(), json!(prior));
        f.insert("gauge_freedom".into(), json!(inp.plate.gauge));
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
        if !inp.warnings.is_empty() {
            f.insert("warnings".into(), json!(inp.warnings));
        }
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
