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

use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::plots::{ResidualPlots, axis_rms, residual_artefacts};
use super::{ChainSpec, PlateSpec, SerialModel, load_model};
use crate::identify::solve::Dependency;
use crate::identify::{
    Degeneracy, NearDependent, ParamReport, Pivoting, PriorReport, Solution, SolveOptions,
    StopReason, Unobservable,
};
use crate::jobs::{Artefact, Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::measure::distance::distance_errors;
use crate::measure::{
    BallPlate, DistanceMeasurement, DistanceProblem, PointMeasurement, PointProblem, Target,
};
use crate::model::dh::DhFile;
use crate::model::{Chain, ParamId};
use crate::report::Run;
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
    /// Static torques of every calibration measurement with the starting model, computed
    /// on first use (see [`IdentifyInputs::start_torques`]).
    torques: std::sync::OnceLock<Vec<Vec<f64>>>,
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
    let ids = resolve_ids(&model, &options)?;
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
        let inputs = IdentifyInputs {
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
            torques: Default::default(),
        };
        super::prior::validate(&inputs)?;
        return Ok(inputs);
    }
    warnings.extend(unused_columns(
        "measurements",
        &table,
        &model.joint_columns(),
        point_columns(&table),
    ));
    let plate = match plate {
        Some(p) => Some(p.plate()?),
        None if table.has("ball") => return Err(no_plate()),
        None => None,
    };
    let balls = plate.as_ref().map_or(0, BallPlate::len);
    let meas = model.measurements("measurements", &table, balls)?;
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
            Some(model.measurements("validation", &t, balls)?)
        }
        None => None,
    };
    point_inputs(model, meas, plate, validation, warnings, options)
}

/// The parameters to identify: `options.identify` or the model's default list.
fn resolve_ids(model: &SerialModel, options: &IdentifyOptions) -> Result<Vec<ParamId>, JobError> {
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
    Ok(ids)
}

fn no_plate() -> JobError {
    JobError::invalid("ball_plate", "ball-centring measurements need a ball plate")
}

/// Joint count, joint limits and ball numbers of typed point measurements.
fn check_points(
    field: &str,
    model: &SerialModel,
    meas: &[PointMeasurement],
    balls: usize,
) -> Result<(), JobError> {
    let dof = model.chain.dof();
    for (i, m) in meas.iter().enumerate() {
        if m.q.len() != dof {
            return Err(JobError::row(
                field,
                i + 1,
                format!("{} joint values for a model with {dof} joints", m.q.len()),
            ));
        }
        if let Some((j, v, l)) = model.chain.limit_violation(&m.q) {
            let k = model.chain.units.to_file(model.chain.variable_quantity(j));
            return Err(JobError::row(
                field,
                i + 1,
                format!(
                    "q{} = {} {} is outside the joint limits [{}, {}]",
                    j + 1,
                    v * k,
                    model.joint_unit(j),
                    l[0] * k,
                    l[1] * k
                ),
            ));
        }
        match m.target {
            Target::Ball(b) if b >= balls => {
                return Err(JobError::row(
                    field,
                    i + 1,
                    format!("ball = {}: the ball plate has balls 1..={balls}", b + 1),
                ));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Validate point-measurement inputs: the one path of the JSON and the typed constructors
/// (of `serial.identify` and `serial.design`).
pub(crate) fn point_inputs(
    model: SerialModel,
    meas: Vec<PointMeasurement>,
    plate: Option<BallPlate>,
    validation: Option<Vec<PointMeasurement>>,
    warnings: Vec<String>,
    options: IdentifyOptions,
) -> Result<IdentifyInputs, JobError> {
    let ids = resolve_ids(&model, &options)?;
    let has_ball = meas.iter().any(|m| matches!(m.target, Target::Ball(_)));
    let plate = match plate {
        Some(p) => p,
        None if has_ball => return Err(no_plate()),
        None => BallPlate {
            centres: vec![],
            distances: vec![],
            gauge: None,
        },
    };
    check_points("measurements", &model, &meas, plate.len())?;
    if let Some(v) = &validation {
        check_points("validation", &model, v, plate.len())?;
    }
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
        torques: Default::default(),
    };
    super::prior::validate(&inputs)?;
    Ok(inputs)
}

impl IdentifyOptions {
    /// Parse `options` given as JSON (a campaign's `options.identify`), naming the field.
    pub fn from_value(v: &Value) -> Result<IdentifyOptions, JobError> {
        serde_path_to_error::deserialize(v).map_err(|e| {
            JobError::invalid(format!("options.{}", e.path()), e.into_inner().to_string())
        })
    }
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
    /// Static torques of the calibration measurements `idx` with the starting model
    /// (compliance off), as [`PointProblem::new`] computes them: those of every
    /// measurement are computed once, on first use, and shared by the identifications of
    /// subsets (a dispersion study identifies thousands).
    pub fn start_torques(&self, idx: &[usize]) -> Vec<Vec<f64>> {
        let all = self
            .torques
            .get_or_init(|| crate::measure::point::start_torques(&self.model.chain, &self.meas));
        idx.iter().map(|&i| all[i].clone()).collect()
    }

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
    ) -> Result<(DistanceProblem, Solution, PriorReport), JobError> {
        super::prior::identify(self, None, monitor)
    }

    /// Identify from the measurements `subset` (all when `None`).
    pub fn identify(
        &self,
        subset: Option<&[usize]>,
        monitor: &dyn Monitor,
    ) -> Result<(PointProblem, Solution), JobError> {
        let (problem, sol, _) = super::prior::identify::<PointProblem>(self, subset, monitor)?;
        Ok((problem, sol))
    }

    /// [`IdentifyInputs::identify`] without standard deviations, condition numbers and
    /// near-dependent reports (`params[].std` null): the same identified values and
    /// convergence, for studies that use only those.
    pub fn identify_values(
        &self,
        subset: Option<&[usize]>,
        monitor: &dyn Monitor,
    ) -> Result<(PointProblem, Solution), JobError> {
        let (problem, sol, _) =
            super::prior::identify_with::<PointProblem>(self, subset, false, monitor)?;
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
) -> CoincidenceReport {
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
        let mut m2 = [nalgebra::Vector3::zeros(); 2];
        let mut spread2 = [0.0; 2];
        for (slot, chain) in [start, end].into_iter().enumerate() {
            let pts: Vec<_> = qs
                .iter()
                .map(|q| chain.tcp(q, Some(&start.static_torques(q))).p)
                .collect();
            let mean = pts.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p) / pts.len() as f64;
            spread2[slot] = (pts.iter().map(|p| (p - mean).norm_squared()).sum::<f64>()
                / pts.len() as f64)
                .sqrt();
            m2[slot] = mean;
        }
        balls.push(BallCoincidence {
            ball: b + 1,
            count: qs.len(),
            spread_rms_before: spread2[0],
            mean_position_before: [m2[0].x, m2[0].y, m2[0].z],
            spread_rms_after: spread2[1],
            mean_position_after: [m2[1].x, m2[1].y, m2[1].z],
            unit: unit.to_string(),
        });
        means.push(Some(m2));
    }
    let mut ball_distances = Vec::new();
    for i in 0..plate.len() {
        for j in i + 1..plate.len() {
            let (Some(a), Some(b), Some(known)) =
                (means[i], means[j], known_distance(plate, centres, i, j))
            else {
                continue;
            };
            ball_distances.push(BallDistanceError {
                balls: [i + 1, j + 1],
                known,
                error_before: (a[0] - b[0]).norm() - known,
                error_after: (a[1] - b[1]).norm() - known,
                unit: unit.to_string(),
            });
        }
    }
    CoincidenceReport {
        balls,
        ball_distances,
    }
}

/// The calibrated model file of a serial arm, of the same kind as the starting model:
/// serialises as the DH JSON object, or as the URDF text.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
#[allow(clippy::large_enum_variant)]
pub enum SerialModelFile {
    /// A DH model file.
    Dh(DhFile),
    /// URDF text.
    Urdf(String),
}

impl SerialModelFile {
    /// The DH model file, if the model is one.
    pub fn dh(&self) -> Option<&DhFile> {
        match self {
            SerialModelFile::Dh(d) => Some(d),
            SerialModelFile::Urdf(_) => None,
        }
    }
}

/// `observability` of a serial identification.
#[derive(Debug, Clone, Serialize)]
pub struct Observability {
    /// Condition number of the physically scaled Jacobian.
    pub condition_number: f64,
    /// Nearly dependent parameter groups.
    pub near_dependent: Vec<NearDependent>,
    /// How columns were scaled.
    pub scaling: &'static str,
}

/// `convergence` of a serial identification.
#[derive(Debug, Clone, Serialize)]
pub struct Convergence {
    /// Why the solver stopped.
    pub stop_reason: StopReason,
    /// Whether it converged.
    pub converged: bool,
    /// `ok` / `degenerate` / ... (see `Solution::status`).
    pub status: &'static str,
    /// Degeneracy, if any.
    pub degenerate: Option<Degeneracy>,
    /// Iterations used.
    pub iterations: usize,
    /// Cost at the start.
    pub cost_before: f64,
    /// Cost at the end.
    pub cost_after: f64,
    /// Cost with only the nuisance unknowns fitted.
    pub cost_nuisance_only: Option<f64>,
    /// Unit of the costs.
    pub cost_unit: String,
}

/// `rank` of a serial identification.
#[derive(Debug, Clone, Serialize)]
pub struct Rank {
    /// Identified (free) unknowns.
    pub rank: usize,
    /// All unknowns.
    pub unknowns: usize,
    /// Relative tolerance used.
    pub tolerance: f64,
}

/// `residual_std`: the fitted residual standard deviation.
#[derive(Debug, Clone, Serialize)]
pub struct ResidualStd {
    /// Value.
    pub value: f64,
    /// Length unit.
    pub unit: String,
    /// Degrees of freedom.
    pub dof: usize,
}

/// `before`/`after` error statistics (`residuals`, `validation`), with an optional note.
#[derive(Debug, Clone, Serialize)]
pub struct BeforeAfter {
    /// Errors of the starting model.
    pub before: Summary,
    /// Errors of the calibrated model.
    pub after: Summary,
    /// What the errors are, when not plain position errors.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub meaning: Option<&'static str>,
}

/// The validation summary of an identification (`validation.before.mean`, ...).
pub type ValidationSummary = BeforeAfter;

/// Point coincidence of one ball (see [`coincidence_report`]).
#[derive(Debug, Clone, Serialize)]
pub struct BallCoincidence {
    /// 1-based ball number.
    pub ball: usize,
    /// Measurements on it.
    pub count: usize,
    /// RMS spread of the starting model's TCP positions.
    pub spread_rms_before: f64,
    /// Their mean.
    pub mean_position_before: [f64; 3],
    /// RMS spread of the calibrated model's TCP positions.
    pub spread_rms_after: f64,
    /// Their mean.
    pub mean_position_after: [f64; 3],
    /// Length unit.
    pub unit: String,
}

/// Distance error between the mean positions of two balls.
#[derive(Debug, Clone, Serialize)]
pub struct BallDistanceError {
    /// 1-based ball numbers.
    pub balls: [usize; 2],
    /// Known distance.
    pub known: f64,
    /// Error of the starting model.
    pub error_before: f64,
    /// Error of the calibrated model.
    pub error_after: f64,
    /// Length unit.
    pub unit: String,
}

/// Point-coincidence statistics on ball measurements (`balls`, `ball_distances`).
#[derive(Debug, Clone, Serialize)]
pub struct CoincidenceReport {
    /// Per ball.
    pub balls: Vec<BallCoincidence>,
    /// Per pair of balls.
    pub ball_distances: Vec<BallDistanceError>,
}

/// `anchor` of a distance identification.
#[derive(Debug, Clone, Serialize)]
pub struct Anchor {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// Standard deviations of x, y, z.
    pub std: [Option<f64>; 3],
    /// Anchor fitted to the starting model.
    pub nominal_fit: [f64; 3],
    /// Frame (`W`).
    pub frame: &'static str,
    /// Length unit.
    pub unit: String,
}

/// `length_offset` of a distance identification.
#[derive(Debug, Clone, Serialize)]
pub struct LengthOffset {
    /// Value.
    pub value: f64,
    /// Standard deviation.
    pub std: Option<f64>,
    /// Offset fitted to the starting model.
    pub nominal_fit: f64,
    /// Length unit.
    pub unit: String,
    /// Definition.
    pub meaning: &'static str,
}

/// The result of `serial.identify`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct SerialCalibration {
    /// `distance` for `L_mm` measurements; absent for points.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measurement_type: Option<&'static str>,
    /// Every unknown with its estimate and standard deviation.
    pub parameters: Vec<ParamReport>,
    /// Unknowns held at nominal by the rank detection.
    pub unidentifiable: Vec<String>,
    /// How held unknowns depend on free ones.
    pub dependencies: Vec<Dependency>,
    /// Weakly observable unknowns.
    pub weakly_observable: Vec<String>,
    /// Unobservable unknowns (effect below the noise).
    pub unobservable: Vec<Unobservable>,
    /// Observability indices.
    pub observability: Observability,
    /// Solver convergence.
    pub convergence: Convergence,
    /// Rank detection.
    pub rank: Rank,
    /// Condition number of the identified unknowns.
    pub condition_number: f64,
    /// Residual standard deviation.
    pub residual_std: ResidualStd,
    /// Prior report (point measurements only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prior: Option<PriorReport>,
    /// Gauge freedom the plate leaves (point measurements only; inner `None` is null).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gauge_freedom: Option<Option<String>>,
    /// Residuals before/after.
    pub residuals: BeforeAfter,
    /// Point coincidence on the calibration balls (ball plates only).
    #[serde(flatten)]
    pub coincidence: Option<CoincidenceReport>,
    /// Anchor (distance measurements).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub anchor: Option<Anchor>,
    /// Length offset (distance measurements).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub length_offset: Option<LengthOffset>,
    /// Errors on the validation set (Cartesian or distance validation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation: Option<ValidationSummary>,
    /// Point coincidence on validation balls.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation_coincidence: Option<CoincidenceReport>,
    /// The calibrated model file.
    pub calibrated_model: SerialModelFile,
    /// Unused columns and similar (absent when none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warnings: Option<Vec<String>>,
}

/// Identification report fields shared by point and distance problems.
fn solution_result(
    sol: &Solution,
    unit: &str,
    tolerance: f64,
    residuals: BeforeAfter,
    calibrated_model: SerialModelFile,
) -> SerialCalibration {
    SerialCalibration {
        measurement_type: None,
        parameters: sol.params.clone(),
        unidentifiable: sol.unidentifiable.clone(),
        dependencies: sol.dependencies.clone(),
        weakly_observable: sol.weakly_observable.clone(),
        unobservable: sol.unobservable.clone(),
        observability: Observability {
            condition_number: sol.condition_number,
            near_dependent: sol.near_dependent.clone(),
            scaling: "physical: lengths 1 mm, angles 0.5 deg, compliances 0.005 deg/(N*m)",
        },
        convergence: Convergence {
            stop_reason: sol.stop,
            converged: sol.converged(),
            status: sol.status(),
            degenerate: sol.degenerate.clone(),
            iterations: sol.iterations,
            cost_before: sol.cost_before,
            cost_after: sol.cost_after,
            cost_nuisance_only: sol.nuisance_cost,
            cost_unit: format!("{unit}^2"),
        },
        rank: Rank {
            rank: sol.free.len(),
            unknowns: sol.params.len(),
            tolerance,
        },
        condition_number: sol.uncertainty.condition_number,
        residual_std: ResidualStd {
            value: sol.uncertainty.sigma,
            unit: unit.to_string(),
            dof: sol.uncertainty.dof,
        },
        prior: None,
        gauge_freedom: None,
        residuals,
        coincidence: None,
        anchor: None,
        length_offset: None,
        validation: None,
        validation_coincidence: None,
        calibrated_model,
        warnings: None,
    }
}

/// The calibrated model as a typed file and its artefact.
fn calibrated_file(
    model: &SerialModel,
    chain: &Chain,
    provenance: Value,
) -> Result<(SerialModelFile, Artefact), JobError> {
    let (value, art) = model.calibrated(chain, provenance)?;
    let file = match value {
        Value::String(text) => SerialModelFile::Urdf(text),
        v => SerialModelFile::Dh(
            serde_json::from_value(v).map_err(|e| JobError::Failed(e.to_string()))?,
        ),
    };
    Ok((file, art))
}

impl IdentifyJob {
    /// A `serial.identify` job from typed inputs (the campaigns' entry point; the JSON
    /// path parses its tables and calls this too): model, point measurements (radians),
    /// ball plate (required for ball targets), optional validation, options.
    pub fn new(
        model: SerialModel,
        measurements: Vec<PointMeasurement>,
        plate: Option<BallPlate>,
        validation: Option<Vec<PointMeasurement>>,
        options: IdentifyOptions,
    ) -> Result<IdentifyJob, JobError> {
        Ok(IdentifyJob {
            inputs: point_inputs(model, measurements, plate, validation, Vec::new(), options)?,
        })
    }

    /// A `serial.identify` job on a DH model with a three-ball plate given by its ball-bar
    /// distances `[d12, d13, d23]` (the TriCal campaign's case).
    pub fn from_dh(
        model: DhFile,
        measurements: Vec<PointMeasurement>,
        ballbar: [f64; 3],
        validation: Option<Vec<PointMeasurement>>,
        options: IdentifyOptions,
    ) -> Result<IdentifyJob, JobError> {
        let plate = BallPlate::from_ballbar(ballbar[0], ballbar[1], ballbar[2])
            .map_err(|e| JobError::invalid("ball_plate", e.to_string()))?;
        IdentifyJob::new(
            SerialModel::from_dh(model)?,
            measurements,
            Some(plate),
            validation,
            options,
        )
    }

    /// The validated inputs.
    pub fn inputs(&self) -> &IdentifyInputs {
        &self.inputs
    }

    /// Run the identification: the typed result and its artefacts (calibrated model,
    /// `residuals.csv`, error plots); no main table.
    pub fn calibrate(&self, monitor: &dyn Monitor) -> Result<Run<SerialCalibration>, JobError> {
        if !self.inputs.distances.is_empty() {
            return self.calibrate_distance(monitor);
        }
        let inp = &self.inputs;
        let (problem, sol, prior) = super::prior::identify::<PointProblem>(inp, None, monitor)?;
        let calibrated = problem.model(&sol.x);
        let unit = inp.model.length_unit();
        let norms = |r: &nalgebra::DVector<f64>| -> Vec<f64> {
            (0..problem.measurements().len())
                .map(|i| r.rows(3 * i, 3).norm())
                .collect()
        };
        let (before, after) = (norms(&sol.residuals_before), norms(&sol.residuals));
        let provenance = json!({"method": "serial.identify", "calibd_version": crate::jobs::envelope::VERSION, "measurements": problem.measurements().len()});
        let (model_file, model_art) = calibrated_file(&inp.model, &calibrated, provenance)?;
        let mut r = solution_result(
            &sol,
            unit,
            inp.solve_options(&problem).rank_tolerance,
            BeforeAfter {
                before: Summary::of(&before, unit),
                after: Summary::of(&after, unit),
                meaning: None,
            },
            model_file,
        );
        r.prior = Some(prior);
        r.gauge_freedom = Some(inp.plate.gauge.clone());
        let centres = problem.centres(&sol.x);
        if !inp.plate.is_empty() {
            r.coincidence = Some(coincidence_report(
                problem.measurements(),
                &inp.model.chain,
                &calibrated,
                &inp.plate,
                &centres,
                unit,
            ));
        }
        let mut held_out = None;
        if let Some(v) = &inp.validation {
            let cartesian: Vec<PointMeasurement> = v
                .iter()
                .filter(|m| matches!(m.target, Target::Point(_)))
                .cloned()
                .collect();
            if !cartesian.is_empty() {
                let (vb, va) = (
                    position_errors(&inp.model.chain, &cartesian),
                    position_errors(&calibrated, &cartesian),
                );
                r.validation = Some(BeforeAfter {
                    before: Summary::of(&vb, unit),
                    after: Summary::of(&va, unit),
                    meaning: None,
                });
                held_out = Some((vb, va));
            }
            if v.iter().any(|m| matches!(m.target, Target::Ball(_))) {
                r.validation_coincidence = Some(coincidence_report(
                    v,
                    &inp.model.chain,
                    &calibrated,
                    &inp.plate,
                    &centres,
                    unit,
                ));
            }
        }
        if !inp.warnings.is_empty() {
            r.warnings = Some(inp.warnings.clone());
        }
        let mut artefacts = vec![model_art];
        // The first 3 rows per measurement are its x, y, z residuals (a prior adds rows).
        let n3 = 3 * problem.measurements().len();
        let rb: Vec<f64> = sol.residuals_before.iter().take(n3).copied().collect();
        let ra: Vec<f64> = sol.residuals.iter().take(n3).copied().collect();
        artefacts.extend(residual_artefacts(&ResidualPlots {
            before: &before,
            after: &after,
            unit,
            what: "Position error",
            validation: held_out,
            per_axis: Some((axis_rms(&rb), axis_rms(&ra))),
        }));
        Ok(Run {
            result: r,
            main_table: None,
            artefacts,
        })
    }

    /// Distance (`L_mm`) identification: parameters, anchor and length offset, signed
    /// distance residuals, validation before (nominal model with its own fitted anchor and
    /// offset) and after, the calibrated model.
    fn calibrate_distance(
        &self,
        monitor: &dyn Monitor,
    ) -> Result<Run<SerialCalibration>, JobError> {
        let inp = &self.inputs;
        let (problem, sol, prior) = inp.identify_distance(monitor)?;
        let calibrated = problem.model(&sol.x);
        let unit = inp.model.length_unit();
        let (anchor, offset) = problem.anchor(&sol.x);
        let x0 = problem.initial();
        let (anchor0, offset0) = problem.anchor(&x0);
        let o = problem.chain_unknowns();
        let std_of = |k: usize| sol.params.get(o + k).and_then(|p| p.std);
        let abs = |r: &nalgebra::DVector<f64>| -> Vec<f64> { r.iter().map(|v| v.abs()).collect() };
        let provenance = json!({"method": "serial.identify", "measurement_type": "distance", "calibd_version": crate::jobs::envelope::VERSION, "measurements": problem.measurements().len()});
        let (model_file, model_art) = calibrated_file(&inp.model, &calibrated, provenance)?;
        let mut r = solution_result(
            &sol,
            unit,
            inp.distance_solve_options(&problem).rank_tolerance,
            BeforeAfter {
                before: Summary::of(&abs(&sol.residuals_before), unit),
                after: Summary::of(&abs(&sol.residuals), unit),
                meaning: Some("absolute distance residuals | |TCP - anchor| + length_offset - L |"),
            },
            model_file,
        );
        r.measurement_type = Some("distance");
        r.prior = Some(prior);
        r.anchor = Some(Anchor {
            x: anchor.x,
            y: anchor.y,
            z: anchor.z,
            std: [std_of(0), std_of(1), std_of(2)],
            nominal_fit: [anchor0.x, anchor0.y, anchor0.z],
            frame: "W",
            unit: unit.to_string(),
        });
        r.length_offset = Some(LengthOffset {
            value: offset,
            std: std_of(3),
            nominal_fit: offset0,
            unit: unit.to_string(),
            meaning: "measured length = |TCP - anchor| + length_offset",
        });
        let mut held_out = None;
        if let Some(v) = &inp.validation_distances {
            let before: Vec<f64> = distance_errors(&inp.model.chain, &anchor0, offset0, v)
                .iter()
                .map(|e| e.abs())
                .collect();
            let after: Vec<f64> = distance_errors(&calibrated, &anchor, offset, v)
                .iter()
                .map(|e| e.abs())
                .collect();
            held_out = Some((before.clone(), after.clone()));
            r.validation = Some(BeforeAfter {
                before: Summary::of(&before, unit),
                after: Summary::of(&after, unit),
                meaning: Some(
                    "absolute held-out distance errors; before: the starting model with the anchor and offset fitted to it",
                ),
            });
        }
        if !inp.warnings.is_empty() {
            r.warnings = Some(inp.warnings.clone());
        }
        let before: Vec<f64> = sol.residuals_before.iter().copied().collect();
        let after: Vec<f64> = sol.residuals.iter().copied().collect();
        let mut artefacts = vec![model_art];
        artefacts.extend(residual_artefacts(&ResidualPlots {
            before: &before,
            after: &after,
            unit,
            what: "Distance error",
            validation: held_out,
            per_axis: None,
        }));
        Ok(Run {
            result: r,
            main_table: None,
            artefacts,
        })
    }
}

impl Kind for IdentifyJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::calibrate)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::jobs::{DirResolver, Inputs};
    use crate::util::monitor::NoMonitor;

    /// The result fields of `examples/serial_identify.json` (ball plate, Cartesian
    /// validation) as the hand-built map of 7e62456 had them.
    const FIELDS: &[&str] = &[
        "ball_distances",
        "balls",
        "calibrated_model",
        "condition_number",
        "convergence",
        "dependencies",
        "gauge_freedom",
        "observability",
        "parameters",
        "prior",
        "rank",
        "residual_std",
        "residuals",
        "unidentifiable",
        "unobservable",
        "validation",
        "weakly_observable",
    ];

    fn example() -> IdentifyJob {
        let dir = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples"));
        let doc: Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("serial_identify.json")).unwrap(),
        )
        .unwrap();
        prepare(&doc, &Inputs::new(&DirResolver { dir })).unwrap()
    }

    #[test]
    fn the_typed_result_serialises_to_the_fields_of_before() {
        let run = example().calibrate(&NoMonitor).unwrap();
        let out = run.clone().into_output().unwrap();
        let mut keys: Vec<&str> = out.fields.keys().map(String::as_str).collect();
        keys.sort_unstable();
        assert_eq!(keys, FIELDS);
        let conv = out.fields["convergence"].as_object().unwrap();
        let mut ck: Vec<&str> = conv.keys().map(String::as_str).collect();
        ck.sort_unstable();
        assert_eq!(
            ck,
            [
                "converged",
                "cost_after",
                "cost_before",
                "cost_nuisance_only",
                "cost_unit",
                "degenerate",
                "iterations",
                "status",
                "stop_reason"
            ]
        );
        // The typed fields the campaigns read.
        let v = run.result.validation.as_ref().unwrap();
        assert_eq!(
            out.fields["validation"]["after"]["mean"],
            json!(v.after.mean)
        );
        assert!(v.after.mean < v.before.mean);
        assert!(matches!(
            run.result.calibrated_model,
            SerialModelFile::Dh(_)
        ));
        // The kind draws its own plots.
        let names: Vec<&str> = run.artefacts.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "calibrated_model.json",
                "residuals.csv",
                "errors_per_configuration.svg",
                "error_histogram.svg",
                "error_cdf.svg",
                "validation_errors.svg",
                "validation_cdf.svg",
                "errors_per_axis.svg"
            ]
        );
    }

    #[test]
    fn the_typed_constructor_gives_the_result_of_the_json_path() {
        let json = example();
        let inp = json.inputs();
        let crate::jobs::serial::Source::Dh(file) = &inp.model.source else {
            panic!("a DH model")
        };
        let typed = IdentifyJob::from_dh(
            file.clone(),
            inp.meas.clone(),
            [200.012, 199.987, 200.003],
            inp.validation.clone(),
            inp.options.clone(),
        )
        .unwrap();
        let a = json.calibrate(&NoMonitor).unwrap().into_output().unwrap();
        let b = typed.calibrate(&NoMonitor).unwrap().into_output().unwrap();
        assert_eq!(a.fields, b.fields);
    }
}
