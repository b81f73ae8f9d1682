//! `pcr.sensitivity`: the paper's Table 2, the largest finite-difference partial derivative
//! of x, y and theta with respect to each parameter type over a set of configurations
//! (default: the 26 central configurations).

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{PcrModel, load_model};
use crate::jobs::{Cx, Inputs, JobError, Kind, RunFuture, computed, parse_spec};
use crate::model::pcr::sensitivity::{
    SensitivityRow, central_configurations, default_steps, sensitivity,
};
use crate::report::Run;
use crate::util::Monitor;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    model: Value,
    #[serde(default)]
    joints: Option<Value>,
    #[serde(default)]
    options: SensitivityOptions,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SensitivityOptions {
    /// Fraction of each joint range spanned by the default 3 x 3 x 3 grid (default 0.4).
    #[serde(default)]
    central_fraction: Option<f64>,
}

/// A validated `pcr.sensitivity` job.
#[derive(Debug)]
pub struct SensitivityJob {
    model: PcrModel,
    configs: Vec<[f64; 3]>,
    default_set: bool,
}

/// Validate a `pcr.sensitivity` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<SensitivityJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let model = load_model(inputs, &spec.model)?;
    let fraction = spec.options.central_fraction.unwrap_or(0.4);
    if !(fraction.is_finite() && fraction > 0.0 && fraction <= 1.0) {
        return Err(JobError::invalid(
            "options.central_fraction",
            format!("{fraction} must be in (0, 1]"),
        ));
    }
    let (configs, default_set) = match &spec.joints {
        Some(j) => {
            let t = inputs.table("joints", j)?;
            let q = model.joints("joints", &t)?;
            if q.is_empty() {
                return Err(JobError::invalid("joints", "needs at least one row"));
            }
            (q, false)
        }
        None => (central_configurations(model.robot.limits(), fraction), true),
    };
    Ok(SensitivityJob {
        model,
        configs,
        default_set,
    })
}

/// `configurations` of `pcr.sensitivity`.
#[derive(Debug, Clone, Serialize)]
pub struct SensitivityConfigurations {
    /// Number of joint sets.
    pub count: usize,
    /// Whether they are the default central set.
    pub default_central_set: bool,
}

/// The result of `pcr.sensitivity` (Table 2): serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct PcrSensitivity {
    /// The configurations.
    pub configurations: SensitivityConfigurations,
    /// Per parameter type.
    pub sensitivity: Vec<SensitivityRow>,
    /// How it was computed.
    pub method: &'static str,
}

impl SensitivityJob {
    /// Compute the sensitivities: the typed result; no table or artefact.
    pub fn sensitivities(&self, monitor: &dyn Monitor) -> Result<Run<PcrSensitivity>, JobError> {
        let steps = default_steps(&self.model.file.uncertainty);
        let rows = sensitivity(&self.model.robot, &self.configs, &steps, monitor)
            .map_err(|e| JobError::Failed(e.to_string()))?;
        if monitor.is_cancelled() {
            return Err(JobError::Cancelled);
        }
        Ok(Run {
            result: PcrSensitivity {
                configurations: SensitivityConfigurations {
                    count: self.configs.len(),
                    default_central_set: self.default_set,
                },
                sensitivity: rows,
                method: "central finite differences of the forward kinematics, step 1 % of the model's standard uncertainty; per parameter type the largest magnitude over configurations and limbs",
            },
            main_table: None,
            artefacts: vec![],
        })
    }
}

impl Kind for SensitivityJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::sensitivities)
    }
}
