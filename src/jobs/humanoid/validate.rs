//! `humanoid.validate`: marker RMSE on a validation session of three models: non-calibrated
//! (nominal joints), geometric-only calibrated, and fully (elasto-geometric) calibrated,
//! taken from a `humanoid.identify` result. By default (`refit_frames: true`) the base frame
//! and marker positions are re-identified on the validation session with the joint
//! parameters held, because markers are re-mounted between sessions.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::samples::{SampleSet, load_samples};
use super::{
    BaseSpec, ColumnMap, FitSpec, LoadedModel, MarkerSpec, apply_parameters, load_model,
    marker_table,
};
use crate::jobs::{Cx, Inputs, JobError, Kind, Output, RunFuture, computed, parse_spec};
use crate::measure::marker_fit::{FitOptions, fit_frames};
use crate::measure::markers::marker_rmse;
use crate::model::humanoid::{HParam, Humanoid};
use crate::util::{Monitor, SubMonitor};

fn default_true() -> bool {
    true
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    urdf: Value,
    samples: Value,
    #[serde(default)]
    column_map: ColumnMap,
    root_link: String,
    joints: Vec<String>,
    markers: Vec<MarkerSpec>,
    #[serde(default)]
    base: BaseSpec,
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
    let cal = inputs.json("calibrated", &s.calibrated)?;
    let full_params = cal.get("parameters").ok_or_else(|| {
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
        let frames = cal.pointer("/frames_only/parameters").ok_or_else(|| {
            JobError::invalid(
                "calibrated",
                "has no `frames_only.parameters` (needed when refit_frames is false)",
            )
        })?;
        apply_parameters(&mut ncm, "calibrated.frames_only.parameters", frames, keep)?;
    }
    let mut full = loaded.model.clone();
    apply_parameters(&mut full, "calibrated.parameters", full_params, keep)?;
    let (gcm, gcm_source) = match cal.pointer("/geometric_only/parameters") {
        Some(g) => {
            let mut m = loaded.model.clone();
            apply_parameters(&mut m, "calibrated.geometric_only.parameters", g, keep)?;
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

impl Kind for ValidateJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::execute)
    }
}

impl ValidateJob {
    /// Compute the job's output (on the blocking pool, see [`Kind::run`]).
    pub fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
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
        let mut f = Map::new();
        f.insert("rmse_ncm_mm".into(), json!(overall[0] * 1e3));
        f.insert("rmse_gcm_mm".into(), json!(overall[1] * 1e3));
        f.insert("rmse_fcm_mm".into(), json!(overall[2] * 1e3));
        f.insert(
            "markers".into(),
            marker_table(
                &self.loaded.model,
                &[
                    ("rmse_ncm_mm", &per[0]),
                    ("rmse_gcm_mm", &per[1]),
                    ("rmse_fcm_mm", &per[2]),
                ],
            ),
        );
        f.insert("refit_frames".into(), json!(self.refit));
        f.insert("gcm_source".into(), json!(self.gcm_source));
        f.insert("samples".into(), self.set.report());
        Ok(Output {
            fields: f,
            main_table: None,
            artefacts: Vec::new(),
        })
    }
}
