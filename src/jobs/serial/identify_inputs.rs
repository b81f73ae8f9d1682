//! The inputs of `serial.identify` and `serial.dispersion`: options, tables and model
//! parsed and checked into [`IdentifyInputs`], and the identification calls on them.

use serde::Deserialize;
use serde_json::Value;

use super::{ChainSpec, PlateSpec, SerialModel, load_model};
use crate::identify::{Pivoting, PriorReport, Solution, SolveOptions};
use crate::measure::{
    BallPlate, DistanceMeasurement, DistanceProblem, PointMeasurement, PointProblem, PointStart,
    Target,
};
use crate::model::ParamId;
use crate::run::{Inputs, JobError, Table};
use crate::util::Monitor;

/// `options` of `serial.identify` (and of `serial.dispersion`).
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
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
    /// Every calibration measurement's TCP and Jacobian rows at the start, computed on
    /// first use and shared by the fits of its subsets (see [`IdentifyInputs::point_start`]).
    point_start: std::sync::OnceLock<Option<std::sync::Arc<PointStart>>>,
}

/// Measurements up to which [`IdentifyInputs::point_start`] keeps every row at the start
/// for the fits of subsets (~24 bytes per row entry: 15 MB for 20,000 against 31 unknowns;
/// a large set's fits fold their Jacobian in blocks and never hold it).
pub const SHARED_START_MAX_MEASUREMENTS: usize = 20_000;

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
        check_options(&options, model.chain.units.metre())?;
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
            point_start: Default::default(),
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
    check_options(&options, model.chain.units.metre())?;
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
        point_start: Default::default(),
    };
    super::prior::validate(&inputs)?;
    Ok(inputs)
}

impl IdentifyInputs {
    /// The calibration rows' joints and targets (ball number + 1, or 0 for a point of its
    /// own).
    pub fn rows(&self) -> Vec<(&[f64], usize)> {
        if self.distances.is_empty() {
            self.meas
                .iter()
                .map(|m| {
                    let key = match m.target {
                        crate::measure::Target::Ball(b) => b + 1,
                        crate::measure::Target::Point(_) => 0,
                    };
                    (m.q.as_slice(), key)
                })
                .collect()
        } else {
            self.distances.iter().map(|d| (d.q.as_slice(), 0)).collect()
        }
    }

    /// The duplicated configurations among the calibration rows.
    pub fn duplicates(&self) -> crate::identify::duplicates::Duplicates {
        crate::identify::duplicates::find_duplicates(
            &self.rows(),
            crate::identify::duplicates::DUPLICATE_TOLERANCE_DEG.to_radians(),
        )
    }
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

/// Largest accepted `options.noise`, metres: a noise above it is not a calibration.
const MAX_NOISE_M: f64 = 1.0;

/// Refuses options outside a plausible range (a value like 1e308 would let the
/// identification "succeed" with no parameter identified), naming the option and the range.
/// `metre` is metres per model length unit.
fn check_options(options: &IdentifyOptions, metre: f64) -> Result<(), JobError> {
    let max_noise = MAX_NOISE_M / metre;
    let unit = if metre == 1.0 { "m" } else { "mm" };
    for (name, v, hi, inclusive, what) in [
        (
            "options.rank_tolerance",
            options.rank_tolerance,
            1.0,
            false,
            "a relative tolerance: above 0 and below 1".to_string(),
        ),
        (
            "options.noise",
            options.noise,
            max_noise,
            true,
            format!(
                "a measurement noise in the model's unit: above 0 and at most {max_noise} {unit} (1 m)"
            ),
        ),
        (
            "options.effect_fraction",
            options.effect_fraction,
            1.0,
            true,
            "a fraction of the noise: above 0 and at most 1".to_string(),
        ),
    ] {
        let Some(v) = v else { continue };
        let inside = v.is_finite() && v > 0.0 && if inclusive { v <= hi } else { v < hi };
        if !inside {
            return Err(JobError::invalid(
                name,
                format!("{v} is outside the plausible range: {what}"),
            ));
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

    /// The start rows of every calibration measurement (None when the measurements do
    /// not make a point problem, or are more than [`SHARED_START_MAX_MEASUREMENTS`]): a
    /// subset's fit gathers its rows at the start from them instead of evaluating the
    /// chain again (a dispersion study fits 2,000 subsets of 360).
    pub fn point_start(&self) -> Option<std::sync::Arc<PointStart>> {
        if self.meas.len() > SHARED_START_MAX_MEASUREMENTS {
            return None;
        }
        self.point_start
            .get_or_init(|| {
                let all: Vec<usize> = (0..self.meas.len()).collect();
                PointProblem::with_torques(
                    self.model.chain.clone(),
                    self.ids.clone(),
                    self.plate.clone(),
                    self.meas.clone(),
                    Some(self.start_torques(&all)),
                )
                .ok()
                .map(|p| std::sync::Arc::new(PointStart::of(&p)))
            })
            .clone()
    }

    /// Solver settings from the options.
    pub fn solve_options(&self, problem: &PointProblem) -> SolveOptions {
        let mut o = SolveOptions {
            pivoting: self.pivoting(problem),
            noise: self.options.noise,
            nuisance: Some(problem.nuisance()),
            hold: self.base_duplicates(),
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
        // A serial arm's fit from its nominal model is nearly linear (gain ratios ~1).
        o.lm.nearly_linear = true;
        o
    }

    /// For a URDF chain whose base frame is identified in full, joint 1's placement (and
    /// the fixed ones before it) and its offset, held with why: they duplicate the base
    /// frame, and a gauge row on the base (the plate's free rotation) would otherwise let
    /// them take the robot's pose ([`crate::model::base_duplicates`]).
    fn base_duplicates(&self) -> Vec<(usize, String)> {
        use crate::model::base_duplicates::{DUPLICATES_BASE, base_duplicates};
        match self.model.source {
            super::Source::Dh(_) => Vec::new(),
            super::Source::Urdf { .. } => base_duplicates(&self.model.chain, &self.ids)
                .into_iter()
                .map(|k| (k, DUPLICATES_BASE.to_string()))
                .collect(),
        }
    }

    /// Column order of rank detection: norm pivoting for DH models (whose parameter lists
    /// are minimal by construction, and where serial-robot.md keeps base parameters over
    /// link-1 ones); for URDF chains, whose six placement errors per joint over-parameterise
    /// on purpose, the base frame first, then the priority order of humanoid.md: a
    /// deterministic choice among equivalent columns, translations before angles, so that a
    /// rotation acting through a tiny lever (a strongly nonlinear direction) is the one held.
    pub fn pivoting(&self, problem: &PointProblem) -> Pivoting {
        match self.model.source {
            super::Source::Dh(_) => Pivoting::Norm,
            super::Source::Urdf { .. } => {
                // serial-robot.md keeps the base parameters over link-1 ones: the robot's
                // pose in {W} (and a plate's free rotation) stays in the base frame instead
                // of moving joint 1's placement.
                let mut order = problem.priority_order();
                order.sort_by_key(|&k| !matches!(self.ids.get(k), Some(ParamId::Base(_))));
                Pivoting::Priority(order)
            }
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
        // A serial arm's fit from its nominal model is nearly linear (gain ratios ~1).
        o.lm.nearly_linear = true;
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
