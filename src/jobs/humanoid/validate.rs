//! `humanoid.validate`: marker RMSE on a validation session of three models: non-calibrated
//! (nominal joints), geometric-only calibrated, and fully (elasto-geometric) calibrated,
//! taken from a `humanoid.identify` result. By default (`refit_frames: true`) the base frame
//! and marker positions are re-identified on the validation session with the joint
//! parameters held, because markers are re-mounted between sessions.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::samples::{SampleSet, load_samples};
use super::{BaseSpec, ColumnMap, FitSpec, LoadedModel, MarkerSpec, apply_parameters, load_model};
use crate::measure::marker_fit::{FitOptions, fit_frames};
use crate::measure::markers::marker_rmse;
use crate::model::humanoid::{HParam, Humanoid};
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, computed, parse_spec};
use crate::util::{Monitor, SubMonitor};

fn default_true() -> bool {
    true
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::urdf")]
    urdf: Value,
    #[schemars(schema_with = "crate::run::schema::table_with_gaps")]
    samples: Value,
    #[serde(default)]
    column_map: ColumnMap,
    root_link: String,
    joints: Vec<String>,
    markers: Vec<MarkerSpec>,
    #[serde(default)]
    base: BaseSpec,
    #[schemars(schema_with = "crate::run::schema::json_file")]
    calibrated: Value,
    #[serde(default = "default_true")]
    refit_frames: bool,
    #[serde(default)]
    options: FitSpec,
}

/// A validated `humanoid.validate` job: the three models and the validation samples.
#[derive(Debug)]
pub struct ValidateJob {
    loaded: LoadedModel,
    set: SampleSet,
    /// Non-calibrated, geometric-only, full.
    models: [Humanoid; 3],
    gcm_source: &'static str,
    refit: bool,
    fit: FitOptions,
}

/// The parts of a `humanoid.identify` result that validation reads back (the parameter
/// lists stay JSON here: [`apply_parameters`] validates them line by line).
#[derive(Debug, Default, Deserialize)]
struct CalibratedDoc {
    #[serde(default)]
    parameters: Option<Value>,
    #[serde(default)]
    frames_only: Option<FitParameters>,
    #[serde(default)]
    geometric_only: Option<FitParameters>,
}

#[derive(Debug, Default, Deserialize)]
struct FitParameters {
    #[serde(default)]
    parameters: Option<Value>,
}

/// Validate a `humanoid.validate` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<ValidateJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    if s.options.cross_validation.is_some() {
        return Err(JobError::invalid(
            "options.cross_validation",
            "belongs to humanoid.identify",
        ));
    }
    let loaded = load_model(
        inputs,
        &s.urdf,
        &s.root_link,
        &s.joints,
        &s.markers,
        &s.base,
        &s.options.elastic,
    )?;
    let set = load_samples(
        inputs,
        "samples",
        &s.samples,
        &s.column_map,
        &loaded,
        s.options.preprocess.as_ref(),
    )?;
    let cal: CalibratedDoc =
        serde_json::from_value(inputs.json("calibrated", &s.calibrated)?).unwrap_or_default();
    let full_params = cal.parameters.as_ref().ok_or_else(|| {
        JobError::invalid(
            "calibrated",
            "has no `parameters`: give a humanoid.identify result",
        )
    })?;
    let joints_only = |p: HParam| matches!(p, HParam::Joint(..) | HParam::BaseCompliance(_));
    let everything = |_: HParam| true;
    let keep: &dyn Fn(HParam) -> bool = if s.refit_frames {
        &joints_only
    } else {
        &everything
    };
    let mut ncm = loaded.model.clone();
    if !s.refit_frames {
        let frames = cal.frames_only.and_then(|f| f.parameters).ok_or_else(|| {
            JobError::invalid(
                "calibrated",
                "has no `frames_only.parameters` (needed when refit_frames is false)",
            )
        })?;
        apply_parameters(&mut ncm, "calibrated.frames_only.parameters", &frames, keep)?;
    }
    let mut full = loaded.model.clone();
    apply_parameters(&mut full, "calibrated.parameters", full_params, keep)?;
    let (gcm, gcm_source) = match cal.geometric_only.and_then(|g| g.parameters) {
        Some(g) => {
            let mut m = loaded.model.clone();
            apply_parameters(&mut m, "calibrated.geometric_only.parameters", &g, keep)?;
            (m, "geometric_only")
        }
        None => (
            full.clone(),
            "parameters (the calibration modelled no elasticity)",
        ),
    };
    Ok(ValidateJob {
        fit: s.options.fit_options()?,
        loaded,
        set,
        models: [ncm, gcm, full],
        gcm_source,
        refit: s.refit_frames,
    })
}

/// Marker RMSE of the three models (mm; null when never seen).
#[derive(Debug, Clone, Serialize)]
pub struct MarkerValidation {
    /// Marker name.
    pub name: String,
    /// Its link.
    pub link: String,
    /// Non-calibrated model.
    pub rmse_ncm_mm: Option<f64>,
    /// Geometric calibration.
    pub rmse_gcm_mm: Option<f64>,
    /// Full calibration.
    pub rmse_fcm_mm: Option<f64>,
}

/// The result of `humanoid.validate`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct HumanoidValidation {
    /// Marker RMSE of the non-calibrated model (mm).
    pub rmse_ncm_mm: f64,
    /// ... of the geometric calibration (mm).
    pub rmse_gcm_mm: f64,
    /// ... of the full calibration (mm).
    pub rmse_fcm_mm: f64,
    /// Per marker.
    pub markers: Vec<MarkerValidation>,
    /// Whether base frame and markers were refitted on the session.
    pub refit_frames: bool,
    /// Where the geometric model came from.
    pub gcm_source: &'static str,
    /// The samples used and dropped (left as JSON: read by people, not code).
    pub samples: Value,
}

impl ValidateJob {
    /// Compare the three models on the session: the typed result; no table or artefact.
    pub fn validate(
        &self,
        monitor: &dyn Monitor,
    ) -> Result<crate::run::Run<HumanoidValidation>, JobError> {
        let samples = &self.set.samples;
        let mut overall = [0.0; 3];
        let mut per: Vec<Vec<Option<f64>>> = Vec::new();
        for (k, m) in self.models.iter().enumerate() {
            let (rmse, pm) = if self.refit {
                let sub = SubMonitor::new(monitor, k as f64 / 3.0, (k + 1) as f64 / 3.0);
                let f = fit_frames(m, samples, &self.fit, &sub)?;
                (f.rmse, f.per_marker)
            } else {
                marker_rmse(m, samples)
            };
            overall[k] = rmse;
            per.push(pm);
        }
        let mm = |v: Option<f64>| v.map(|x| x * 1e3);
        let markers = self
            .loaded
            .model
            .markers
            .iter()
            .enumerate()
            .map(|(m, d)| MarkerValidation {
                name: d.name.clone(),
                link: d.link.clone(),
                rmse_ncm_mm: mm(per[0][m]),
                rmse_gcm_mm: mm(per[1][m]),
                rmse_fcm_mm: mm(per[2][m]),
            })
            .collect();
        Ok(crate::run::Run {
            result: HumanoidValidation {
                rmse_ncm_mm: overall[0] * 1e3,
                rmse_gcm_mm: overall[1] * 1e3,
                rmse_fcm_mm: overall[2] * 1e3,
                markers,
                refit_frames: self.refit,
                gcm_source: self.gcm_source,
                samples: self.set.report(),
            },
            main_table: None,
            artefacts: Vec::new(),
        })
    }
}

impl Kind for ValidateJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::validate)
    }
}
