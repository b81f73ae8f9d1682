//! `pcr.identify`: the bounded three-step identification of a 3-PF robot and its microscope
//! extrinsics from measurements (q1, q2, q3, and the readings x, y, theta), with the
//! paper's Table 3 on the calibration and validation sets and the calibrated model file.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::{PcrModel, load_model};
use crate::jobs::{
    Artefact, Cx, Inputs, JobError, Kind, Output, RunFuture, Table, computed, parse_spec,
};
use crate::measure::pcr::steps::{CalibrationOptions, Step, calibrated_file, default_steps};
use crate::measure::pcr::{PcrMeasurement, identify_steps};
use crate::util::{Monitor, Summary};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    model: Value,
    measurements: Value,
    #[serde(default)]
    validation: Option<Value>,
    #[serde(default)]
    options: IdentifyOptions,
}

/// `options` of `pcr.identify`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentifyOptions {
    /// The steps: each a list of unknown names (`Ax_1`, `sx`), parameter types (`l`,
    /// `gamma`, ...), `extrinsics` or `all`. Default: the paper's three steps.
    #[serde(default)]
    pub steps: Option<Vec<Vec<String>>>,
    /// Relative tolerance of the rank detection (default 1e-8).
    #[serde(default)]
    pub rank_tolerance: Option<f64>,
    /// Levenberg-Marquardt iteration limit per step (default 100).
    #[serde(default)]
    pub max_iterations: Option<usize>,
    /// Bounds are nominal +/- this many standard uncertainties (default 3).
    #[serde(default)]
    pub bound_sigmas: Option<f64>,
    /// `min_norm` (default): each unidentifiable combination is held at nominal; `hold`: the
    /// unknowns rank detection drops are held at nominal themselves.
    #[serde(default)]
    pub gauge: Option<String>,
}

/// A validated `pcr.identify` job.
#[derive(Debug)]
pub struct IdentifyJob {
    model: PcrModel,
    measurements: Vec<PcrMeasurement>,
    validation: Option<Vec<PcrMeasurement>>,
    options: CalibrationOptions,
}

/// Turn job options into calibration options (errors name the option).
pub fn calibration_options(o: &IdentifyOptions) -> Result<CalibrationOptions, JobError> {
    let mut c = CalibrationOptions::default();
    if let Some(steps) = &o.steps {
        if steps.is_empty() {
            return Err(JobError::invalid(
                "options.steps",
                "needs at least one step",
            ));
        }
        c.steps = steps
            .iter()
            .enumerate()
            .map(|(i, names)| {
                Step::from_names(&format!("step {}", i + 1), names)
                    .map_err(|e| JobError::invalid(format!("options.steps[{i}]"), e))
            })
            .collect::<Result<_, _>>()?;
    } else {
        c.steps = default_steps();
    }
    for (name, v) in [
        ("options.rank_tolerance", o.rank_tolerance),
        ("options.bound_sigmas", o.bound_sigmas),
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
    if let Some(t) = o.rank_tolerance {
        c.rank_tolerance = t;
    }
    if let Some(b) = o.bound_sigmas {
        c.bound_sigmas = b;
    }
    match o.gauge.as_deref() {
        None | Some("min_norm") => {}
        Some("hold") => c.hold_unidentifiable = true,
        Some(other) => {
            return Err(JobError::invalid(
                "options.gauge",
                format!("`{other}`: expected \"min_norm\" or \"hold\""),
            ));
        }
    }
    if let Some(n) = o.max_iterations {
        if n == 0 {
            return Err(JobError::invalid(
                "options.max_iterations",
                "must be at least 1",
            ));
        }
        c.max_iterations = n;
    }
    Ok(c)
}

/// Validate a `pcr.identify` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<IdentifyJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let model = load_model(inputs, &spec.model)?;
    let t = inputs.table("measurements", &spec.measurements)?;
    let measurements = model.measurements("measurements", &t)?;
    // 34 unknowns, 3 residuals per measurement; the gauges leave 26 to determine.
    if 3 * measurements.len() < 34 {
        return Err(JobError::invalid(
            "measurements",
            format!(
                "{} rows cannot determine the model: give at least 12",
                measurements.len()
            ),
        ));
    }
    let validation = match &spec.validation {
        Some(v) => {
            let t = inputs.table("validation", v)?;
            Some(model.measurements("validation", &t)?)
        }
        None => None,
    };
    let options = calibration_options(&spec.options)?;
    Ok(IdentifyJob {
        model,
        measurements,
        validation,
        options,
    })
}

/// `{mean, median, std, max, unit}` (plus count, min, rms) of errors in metres.
fn stats(v: &[f64]) -> Value {
    serde_json::to_value(Summary::of(v, "m")).unwrap_or(Value::Null)
}

impl Kind for IdentifyJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::execute)
    }
}

impl IdentifyJob {
    /// Compute the job's output (on the blocking pool, see [`Kind::run`]).
    pub fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let cal = identify_steps(
            &self.model.robot,
            &self.model.file,
            &self.measurements,
            self.validation.as_deref(),
            &self.options,
            monitor,
        )?;
        let u: Vec<f64> = self
            .model
            .file
            .uncertainty
            .robot()
            .into_iter()
            .chain(self.model.file.uncertainty.extrinsics())
            .collect();
        let b = self.options.bound_sigmas;
        let params: Vec<Value> = cal
            .params
            .iter()
            .zip(&u)
            .map(|(p, uk)| {
                let mut v = serde_json::to_value(p).unwrap_or(Value::Null);
                if let Value::Object(m) = &mut v {
                    m.insert("lower".into(), json!(p.nominal - b * uk));
                    m.insert("upper".into(), json!(p.nominal + b * uk));
                    m.insert("bound_hit".into(), json!(p.at_bound.is_some()));
                }
                v
            })
            .collect();
        let mut f = Map::new();
        f.insert("parameters".into(), Value::Array(params));
        f.insert("unidentifiable".into(), json!(cal.unidentifiable));
        f.insert(
            "dependencies".into(),
            serde_json::to_value(&cal.dependencies).unwrap_or(Value::Null),
        );
        let gauge = if self.options.hold_unidentifiable {
            "hold: the unidentifiable parameters (columns of the uncertainty-scaled Jacobian that duplicate others) are held at nominal themselves"
        } else {
            "min_norm: each unidentifiable combination of parameters (a column of the uncertainty-scaled Jacobian that duplicates others: a rigid motion of the clamps with the sensor or pattern frame, E without load, a common scale of the diameters) is held at nominal: the identified change has no component along the null space, measured in standard uncertainties"
        };
        f.insert("gauge".into(), json!(gauge));
        f.insert(
            "steps".into(),
            serde_json::to_value(&cal.steps).unwrap_or(Value::Null),
        );
        f.insert(
            "model_error".into(),
            serde_json::to_value(&cal.table3).unwrap_or(Value::Null),
        );
        f.insert(
            "residual_std".into(),
            json!({"value": cal.uncertainty.sigma, "unit": "m", "dof": cal.uncertainty.dof, "angle_weight": self.model.file.repeatability.position / self.model.file.repeatability.orientation, "angle_weight_unit": "m/rad"}),
        );
        f.insert(
            "condition_number".into(),
            json!(cal.uncertainty.condition_number),
        );
        f.insert(
            "convergence".into(),
            json!({"converged": cal.steps.iter().all(|s| s.stop_reason.converged()), "iterations": cal.steps.iter().map(|s| s.iterations).sum::<usize>()}),
        );
        if let Some([before, after]) = &cal.validation_errors {
            f.insert(
                "validation".into(),
                json!({"before": stats(before), "after": stats(after)}),
            );
        }
        let mut file = calibrated_file(&self.model.file, &cal.x);
        file.calibration = Some(json!({
            "method": "pcr.identify",
            "calibd_version": crate::jobs::envelope::VERSION,
            "measurements": self.measurements.len(),
            "steps": cal.steps.iter().map(|s| s.name.clone()).collect::<Vec<_>>(),
            "unidentifiable_held_at_nominal": cal.unidentifiable,
        }));
        let model_value =
            serde_json::to_value(&file).map_err(|e| JobError::Failed(e.to_string()))?;
        f.insert("calibrated_model".into(), model_value.clone());
        let mut res = Table::new(&["measurement", "e_p_nominal", "e_p_identified"]);
        for (i, (a, b)) in cal.calibration_errors[0]
            .iter()
            .zip(&cal.calibration_errors[1])
            .enumerate()
        {
            res.push(vec![(i + 1) as f64, *a, *b]);
        }
        let artefacts = vec![
            Artefact {
                name: "calibrated_model.json".into(),
                media_type: "application/json".into(),
                content: serde_json::to_vec_pretty(&model_value).unwrap_or_default(),
            },
            Artefact {
                name: "model_errors.csv".into(),
                media_type: "text/csv".into(),
                content: res.to_csv().into_bytes(),
            },
        ];
        Ok(Output {
            fields: f,
            main_table: None,
            artefacts,
        })
    }
}
