//! `pcr.sensitivity`: the paper's Table 2, the largest finite-difference partial derivative
//! of x, y and theta with respect to each parameter type over a set of configurations
//! (default: the 26 central configurations), and its bars.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{PcrModel, load_model};
use crate::model::pcr::sensitivity::{
    SensitivityRow, central_configurations, default_steps, sensitivity,
};
use crate::report::plots::{self, Series};
use crate::report::svg_artefact;
use crate::run::Run;
use crate::run::{Artefact, Cx, Inputs, JobError, Kind, RunFuture, computed, parse_spec};
use crate::util::Monitor;

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::json_file")]
    model: Value,
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::table_opt")]
    joints: Option<Value>,
    #[serde(default)]
    options: SensitivityOptions,
}

#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
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
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SensitivityConfigurations {
    /// Number of joint sets.
    pub count: usize,
    /// Whether they are the default central set.
    pub default_central_set: bool,
}

/// The result of `pcr.sensitivity` (Table 2): serialises to the job's result fields.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PcrSensitivity {
    /// The configurations.
    pub configurations: SensitivityConfigurations,
    /// Per parameter type.
    pub sensitivity: Vec<SensitivityRow>,
    /// How it was computed (not read back).
    #[serde(skip_deserializing)]
    pub method: &'static str,
}

/// Table 2 of `model` over `configs` (`default_set`: they are the default central set).
pub fn table2(
    model: &PcrModel,
    configs: &[[f64; 3]],
    default_set: bool,
    monitor: &dyn Monitor,
) -> Result<PcrSensitivity, JobError> {
    let steps = default_steps(&model.file.uncertainty);
    let rows = sensitivity(&model.robot, configs, &steps, monitor)
        .map_err(|e| JobError::Failed(e.to_string()))?;
    if monitor.is_cancelled() {
        return Err(JobError::Cancelled);
    }
    Ok(PcrSensitivity {
        configurations: SensitivityConfigurations {
            count: configs.len(),
            default_central_set: default_set,
        },
        sensitivity: rows,
        method: "central finite differences of the forward kinematics, step 1 % of the model's standard uncertainty; per parameter type the largest magnitude over configurations and limbs",
    })
}

/// Table 2 of `model` over its default 26 central configurations (what `pcr.identify`
/// reports for the model it starts from).
pub fn central_table2(model: &PcrModel, monitor: &dyn Monitor) -> Result<PcrSensitivity, JobError> {
    let configs = central_configurations(model.robot.limits(), 0.4);
    table2(model, &configs, true, monitor)
}

/// The Table 2 bars: `sensitivity_position.svg` (largest |dx/dp| and |dy/dp|) and
/// `sensitivity_orientation.svg` (largest |dtheta/dp|), one group per parameter type on a
/// log axis; a zero sensitivity (E without load) draws no bar and its label says `= 0`.
pub fn table2_plots(t: &PcrSensitivity, model_name: &str) -> Vec<Artefact> {
    let rows = &t.sensitivity;
    let cat = |f: fn(&SensitivityRow) -> f64, r: &SensitivityRow, unit: &str| {
        let zero = if f(r) == 0.0 { " = 0" } else { "" };
        format!("{} ({unit}){zero}", r.parameter)
    };
    let some = |v: f64| (v > 0.0 && v.is_finite()).then_some(v);
    let dataset = format!(
        "{model_name}: {} {}configurations",
        t.configurations.count,
        if t.configurations.default_central_set {
            "central "
        } else {
            ""
        }
    );
    let dx: Vec<Option<f64>> = rows.iter().map(|r| some(r.dx)).collect();
    let dy: Vec<Option<f64>> = rows.iter().map(|r| some(r.dy)).collect();
    let dt: Vec<Option<f64>> = rows.iter().map(|r| some(r.dtheta)).collect();
    let position = plots::category_bars(
        "Table 2: position sensitivity per parameter type (log scale)",
        &dataset,
        "largest |dx/dp|, |dy/dp| (m per parameter unit)",
        &rows
            .iter()
            .map(|r| cat(|r| r.dx.max(r.dy), r, &r.position_unit))
            .collect::<Vec<_>>(),
        &[
            Series {
                name: "dx",
                legend: "|dx/dp|",
                values: &dx,
            },
            Series {
                name: "dy",
                legend: "|dy/dp|",
                values: &dy,
            },
        ],
    );
    let orientation = plots::category_bars(
        "Table 2: orientation sensitivity per parameter type (log scale)",
        &dataset,
        "largest |dθ/dp| (rad per parameter unit)",
        &rows
            .iter()
            .map(|r| cat(|r| r.dtheta, r, &r.angle_unit))
            .collect::<Vec<_>>(),
        &[Series {
            name: "dtheta",
            legend: "|dθ/dp|",
            values: &dt,
        }],
    );
    vec![
        svg_artefact("sensitivity_position.svg", position),
        svg_artefact("sensitivity_orientation.svg", orientation),
    ]
}

impl SensitivityJob {
    /// Compute the sensitivities: the typed result and its bars; no table.
    pub fn sensitivities(&self, monitor: &dyn Monitor) -> Result<Run<PcrSensitivity>, JobError> {
        let result = table2(&self.model, &self.configs, self.default_set, monitor)?;
        let artefacts = table2_plots(&result, &format!("model {}", self.model.file.name));
        Ok(Run {
            result,
            main_table: None,
            artefacts,
        })
    }
}

impl Kind for SensitivityJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::sensitivities)
    }
}
