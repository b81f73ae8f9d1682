//! `pcr.identify`: the bounded three-step identification of a 3-PF robot and its microscope
//! extrinsics from measurements (q1, q2, q3, and the readings x, y, theta), with the
//! paper's Table 3 on the calibration and validation sets and the calibrated model file.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::identify_options::prior_of;
pub use super::identify_options::{IdentifyOptions, PcrPriorSpec, calibration_options};
use super::sensitivity::{PcrSensitivity, central_table2, table2_plots};
use super::{PcrModel, load_model};
use crate::identify::ParamReport;
use crate::identify::prior::PriorReport;
use crate::identify::solve::Dependency;
use crate::identify::verdict::Assessment;
use crate::measure::pcr::prior::choose_pcr_weight;
use crate::measure::pcr::steps::{CalibrationOptions, calibrated_file};
use crate::measure::pcr::{PcrMeasurement, StepReport, Table3, identify_steps};
use crate::model::pcr::PcrFile;
use crate::report::ErrorSet;
use crate::run::Run;
use crate::run::{Artefact, Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::{Monitor, SubMonitor, Summary};

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::json_file")]
    model: Value,
    #[schemars(schema_with = "crate::run::schema::table")]
    measurements: Value,
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::table_opt")]
    validation: Option<Value>,
    #[serde(default)]
    options: IdentifyOptions,
}

/// Seed of the K-fold split of a cross-validated prior weight.
const CV_SEED: u64 = 0x5043_5250;

/// A validated `pcr.identify` job.
#[derive(Debug)]
pub struct IdentifyJob {
    model: PcrModel,
    measurements: Vec<PcrMeasurement>,
    validation: Option<Vec<PcrMeasurement>>,
    options: CalibrationOptions,
    /// Choose the prior's weight by K-fold before identifying.
    cv_weight: bool,
}

/// Validate a `pcr.identify` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<IdentifyJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let model = load_model(inputs, &spec.model)?;
    let t = inputs.table("measurements", &spec.measurements)?;
    let measurements = model.measurements("measurements", &t)?;
    check_count(&measurements)?;
    let validation = match &spec.validation {
        Some(v) => {
            let t = inputs.table("validation", v)?;
            Some(model.measurements("validation", &t)?)
        }
        None => None,
    };
    IdentifyJob::new(model, measurements, validation, &spec.options)
}

/// 34 unknowns, 3 residuals per measurement; the gauges leave 26 to determine.
fn check_count(measurements: &[PcrMeasurement]) -> Result<(), JobError> {
    if 3 * measurements.len() < 34 {
        return Err(JobError::invalid(
            "measurements",
            format!(
                "{} rows cannot determine the model: give at least 12",
                measurements.len()
            ),
        ));
    }
    Ok(())
}

/// Joint limits of typed measurements (the table path checks them while parsing).
fn check_joints(
    field: &str,
    model: &PcrModel,
    measurements: &[PcrMeasurement],
) -> Result<(), JobError> {
    for (i, m) in measurements.iter().enumerate() {
        model
            .robot
            .check_joints(&m.q)
            .map_err(|e| JobError::row(field, i + 1, e.to_string()))?;
    }
    Ok(())
}

/// One identified unknown of `pcr.identify`: the solver's report and its bounds.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PcrParameter {
    /// Estimate, nominal, standard deviation, ...
    #[serde(flatten)]
    pub report: ParamReport,
    /// Lower bound (nominal - bound_sigmas * uncertainty).
    pub lower: f64,
    /// Upper bound.
    pub upper: f64,
    /// Whether the estimate ended on a bound.
    pub bound_hit: bool,
}

/// `residual_std` of `pcr.identify`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PcrResidualStd {
    /// Value (m), counted over distinct configurations (null with zero degrees of freedom).
    pub value: Option<f64>,
    /// `m` (not read back: the report states it).
    #[serde(skip_deserializing)]
    pub unit: &'static str,
    /// Degrees of freedom.
    pub dof: usize,
    /// Weight of angle residuals (m/rad).
    pub angle_weight: f64,
    /// `m/rad` (not read back).
    #[serde(skip_deserializing)]
    pub angle_weight_unit: &'static str,
}

/// `convergence` of `pcr.identify`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PcrConvergence {
    /// Every step converged.
    pub converged: bool,
    /// Iterations over all steps.
    pub iterations: usize,
}

/// Position errors (m) before and after on the validation set.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PcrValidation {
    /// Nominal model.
    pub before: Summary,
    /// Identified model.
    pub after: Summary,
}

/// The result of `pcr.identify`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PcrCalibration {
    /// `verdict` (`accepted`, `review`, `rejected`) and its `reasons`.
    #[serde(flatten)]
    pub assessment: Assessment,
    /// Residual degrees of freedom of the last step: distinct equations minus identified
    /// unknowns.
    pub dof: usize,
    /// Every unknown with its bounds.
    pub parameters: Vec<PcrParameter>,
    /// Unknowns held at nominal.
    pub unidentifiable: Vec<String>,
    /// Dependencies of the held unknowns.
    pub dependencies: Vec<Dependency>,
    /// How the gauge is fixed (not read back: the report shows it as stored).
    #[serde(skip_deserializing)]
    pub gauge: &'static str,
    /// Per step.
    pub steps: Vec<StepReport>,
    /// The paper's Table 3.
    pub model_error: Table3,
    /// Residual standard deviation.
    pub residual_std: PcrResidualStd,
    /// Condition number.
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub condition_number: f64,
    /// Convergence.
    pub convergence: PcrConvergence,
    /// Validation errors (when a validation set was given).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation: Option<PcrValidation>,
    /// The calibrated model file (`rejected_model` when the verdict is `rejected`).
    #[serde(alias = "rejected_model")]
    pub calibrated_model: PcrFile,
    /// The paper's Table 2 of the model the identification started from (as
    /// `pcr.sensitivity` reports it): which parameters the poses can see, with units.
    pub sensitivity: PcrSensitivity,
    /// Which mode ran (`least_squares`, `map`, `map_cv`), the weight, the noise (m) and the
    /// MAP objective's terms (noise units).
    pub prior: PriorReport,
}

impl IdentifyJob {
    /// A `pcr.identify` job from typed inputs (the campaign's entry point; the JSON path
    /// calls it too): the model, at least 12 measurements, optional validation, options.
    pub fn new(
        model: PcrModel,
        measurements: Vec<PcrMeasurement>,
        validation: Option<Vec<PcrMeasurement>>,
        options: &IdentifyOptions,
    ) -> Result<IdentifyJob, JobError> {
        check_joints("measurements", &model, &measurements)?;
        check_count(&measurements)?;
        if let Some(v) = &validation {
            check_joints("validation", &model, v)?;
        }
        let mut calibration = calibration_options(options)?;
        let mut cv_weight = false;
        if let Some((prior, cv)) = prior_of(options, &model.file) {
            calibration.prior = Some(prior);
            cv_weight = cv;
        }
        Ok(IdentifyJob {
            model,
            measurements,
            validation,
            options: calibration,
            cv_weight,
        })
    }

    /// A `pcr.identify` job from a parsed model file.
    pub fn from_file(
        file: PcrFile,
        measurements: Vec<PcrMeasurement>,
        validation: Option<Vec<PcrMeasurement>>,
        options: &IdentifyOptions,
    ) -> Result<IdentifyJob, JobError> {
        let robot = file
            .robot()
            .map_err(|e| JobError::invalid("model", e.to_string()))?;
        IdentifyJob::new(PcrModel { file, robot }, measurements, validation, options)
    }

    /// Run the three-step identification: the typed result and its artefacts (calibrated
    /// model, `model_errors.csv`); no main table.
    pub fn calibrate(&self, monitor: &dyn Monitor) -> Result<Run<PcrCalibration>, JobError> {
        let mut options = self.options.clone();
        let mut k_fold = None;
        let fit_from = if self.cv_weight { 0.5 } else { 0.0 };
        if let (true, Some(prior)) = (self.cv_weight, options.prior.as_mut()) {
            let (w, errors) = choose_pcr_weight(
                &self.model.robot,
                &self.model.file,
                &self.measurements,
                &self.options,
                CV_SEED,
                &SubMonitor::new(monitor, 0.0, fit_from),
            )?;
            prior.weight = w;
            k_fold = Some(errors);
        }
        let mut cal = identify_steps(
            &self.model.robot,
            &self.model.file,
            &self.measurements,
            self.validation.as_deref(),
            &options,
            &SubMonitor::new(monitor, fit_from, 0.9),
        )?;
        if let Some(errors) = k_fold {
            cal.prior.mode = "map_cv";
            cal.prior.k_fold_errors = Some(errors);
        }
        let sensitivity = central_table2(&self.model, &SubMonitor::new(monitor, 0.9, 1.0))?;
        let u: Vec<f64> = self
            .model
            .file
            .uncertainty
            .robot()
            .into_iter()
            .chain(self.model.file.uncertainty.extrinsics())
            .collect();
        let b = self.options.bound_sigmas;
        let parameters: Vec<PcrParameter> = cal
            .params
            .iter()
            .zip(&u)
            .map(|(p, uk)| PcrParameter {
                report: p.clone(),
                lower: p.nominal - b * uk,
                upper: p.nominal + b * uk,
                bound_hit: p.at_bound.is_some(),
            })
            .collect();
        let gauge = if self.options.hold_unidentifiable {
            "hold: the unidentifiable parameters (columns of the uncertainty-scaled Jacobian that duplicate others) are held at nominal themselves"
        } else {
            "min_norm: each unidentifiable combination of parameters (a column of the uncertainty-scaled Jacobian that duplicates others: a rigid motion of the clamps with the sensor or pattern frame, E without load, a common scale of the diameters) is held at nominal: the identified change has no component along the null space, measured in standard uncertainties"
        };
        let mut file = calibrated_file(&self.model.file, &cal.x);
        file.calibration = Some(json!({
            "method": "pcr.identify",
            "calibd_version": crate::run::VERSION,
            "measurements": self.measurements.len(),
            "steps": cal.steps.iter().map(|s| s.name.clone()).collect::<Vec<_>>(),
            "unidentifiable_held_at_nominal": cal.unidentifiable,
        }));
        let mut res = Table::new(&["measurement", "e_p_nominal", "e_p_identified"]);
        for (i, (a, b)) in cal.calibration_errors[0]
            .iter()
            .zip(&cal.calibration_errors[1])
            .enumerate()
        {
            res.push(vec![(i + 1) as f64, *a, *b]);
        }
        let model_value = serde_json::to_value(&file)
            .map_err(|e| JobError::internal("serialising the calibrated model", e))?;
        let um = |v: &[f64]| -> Vec<f64> { v.iter().map(|x| x * 1e6).collect() };
        let (cb, ca) = (
            um(&cal.calibration_errors[0]),
            um(&cal.calibration_errors[1]),
        );
        let cal_label = format!(
            "calibration set: {} poses (nominal: the nominal model with its frames fitted)",
            cb.len()
        );
        let held = cal.validation_errors.as_ref().map(|[b, a]| (um(b), um(a)));
        let val_label = held.as_ref().map(|(b, _)| {
            format!(
                "validation set: {} held-out poses (not used in the fit)",
                b.len()
            )
        });
        let plots = crate::report::calibration_plots(
            "Position error e_P",
            &ErrorSet {
                before: &cb,
                after: &ca,
                unit: "µm",
                dataset: &cal_label,
            },
            held.as_ref()
                .zip(val_label.as_deref())
                .map(|((b, a), label)| ErrorSet {
                    before: b,
                    after: a,
                    unit: "µm",
                    dataset: label,
                })
                .as_ref(),
        );
        let mut artefacts = vec![
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
        artefacts.extend(plots);
        artefacts.extend(table2_plots(
            &sensitivity,
            &format!("nominal model {}", self.model.file.name),
        ));
        let mut result = PcrCalibration {
            assessment: Assessment::of(Vec::new()),
            dof: cal.uncertainty.dof,
            parameters,
            unidentifiable: cal.unidentifiable.clone(),
            dependencies: cal.dependencies.clone(),
            gauge,
            convergence: PcrConvergence {
                converged: cal.steps.iter().all(|s| s.stop_reason.converged()),
                iterations: cal.steps.iter().map(|s| s.iterations).sum::<usize>(),
            },
            steps: cal.steps,
            model_error: cal.table3,
            residual_std: PcrResidualStd {
                value: Some(cal.uncertainty.sigma).filter(|s| s.is_finite()),
                unit: "m",
                dof: cal.uncertainty.dof,
                angle_weight: self.model.file.repeatability.position
                    / self.model.file.repeatability.orientation,
                angle_weight_unit: "m/rad",
            },
            condition_number: cal.uncertainty.condition_number,
            validation: cal
                .validation_errors
                .as_ref()
                .map(|[before, after]| PcrValidation {
                    before: Summary::of(before, "m"),
                    after: Summary::of(after, "m"),
                }),
            calibrated_model: file,
            sensitivity,
            prior: cal.prior,
        };
        super::verdict::judge(
            &self.measurements,
            self.validation.as_deref(),
            &u,
            &mut result,
        );
        Ok(Run {
            result,
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
    use crate::run::DirResolver;
    use crate::util::monitor::NoMonitor;

    /// The result fields of `examples/pcr_identify.json` (with validation) as the
    /// hand-built map of 7e62456 had them.
    const FIELDS: &[&str] = &[
        "calibrated_model",
        "condition_number",
        "convergence",
        "dependencies",
        "dof",
        "gauge",
        "model_error",
        "parameters",
        "prior",
        "reasons",
        "residual_std",
        "sensitivity",
        "steps",
        "unidentifiable",
        "validation",
        "verdict",
    ];

    #[test]
    fn the_typed_result_serialises_to_the_fields_of_before() {
        let dir = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples"));
        let doc: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("pcr_identify.json")).unwrap())
                .unwrap();
        let job = prepare(&doc, &Inputs::new(&DirResolver { dir })).unwrap();
        let run = job.calibrate(&NoMonitor).unwrap();
        let out = run.clone().into_output().unwrap();
        let mut keys: Vec<&str> = out.fields.keys().map(String::as_str).collect();
        keys.sort_unstable();
        assert_eq!(keys, FIELDS);
        let p = out.fields["parameters"][0].as_object().unwrap();
        assert!(
            ["lower", "upper", "bound_hit", "name", "value"]
                .iter()
                .all(|k| p.contains_key(*k))
        );
        let v = run.result.validation.as_ref().unwrap();
        assert_eq!(
            out.fields["validation"]["after"]["mean"],
            json!(v.after.mean)
        );
        assert_eq!(
            out.fields["calibrated_model"],
            serde_json::to_value(&run.result.calibrated_model).unwrap()
        );
        // The typed constructor gives the same result.
        let typed = IdentifyJob::from_file(
            job.model.file.clone(),
            job.measurements.clone(),
            job.validation.clone(),
            &IdentifyOptions {
                steps: Some(vec![
                    vec!["extrinsics".into()],
                    ["extrinsics", "l", "gamma", "alpha", "Ax", "Ay", "Bx", "By"]
                        .map(String::from)
                        .to_vec(),
                    vec!["all".into()],
                ]),
                ..Default::default()
            },
        )
        .unwrap();
        let b = typed.calibrate(&NoMonitor).unwrap().into_output().unwrap();
        assert_eq!(out.fields, b.fields);
    }
}
