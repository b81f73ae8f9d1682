//! Reports of the 3-PF identification: model-error statistics, the paper's Table 3, and
//! what each step did.

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use crate::identify::StopReason;
use crate::identify::solve::Dependency;
use crate::util::Summary;
use crate::util::serde_num::f64_or_nan;

/// Max, mean and min of a set of errors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ErrorStats {
    /// Largest.
    #[serde(deserialize_with = "f64_or_nan")]
    pub max: f64,
    /// Mean.
    #[serde(deserialize_with = "f64_or_nan")]
    pub mean: f64,
    /// Smallest.
    #[serde(deserialize_with = "f64_or_nan")]
    pub min: f64,
}

impl ErrorStats {
    /// Max, mean and min of `v` multiplied by `factor` (a unit change).
    pub fn of(v: &[f64], factor: f64) -> Self {
        let s = Summary::of(v, "");
        Self {
            max: s.max * factor,
            mean: s.mean * factor,
            min: s.min * factor,
        }
    }
}

/// A row of Table 3: one error kind, nominal and identified model.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Table3Row {
    /// `um` or `mrad`.
    pub unit: Cow<'static, str>,
    /// Nominal robot parameters (extrinsics identified alone).
    pub nominal: ErrorStats,
    /// Identified model.
    pub identified: ErrorStats,
}

/// Table 3 for one set of measurements.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Table3Set {
    /// Number of poses.
    pub poses: usize,
    /// Position error |p_model - p_measured|.
    #[serde(rename = "e_P")]
    pub e_p: Table3Row,
    /// Orientation error |theta_model - theta_measured|.
    pub e_theta: Table3Row,
}

/// The paper's Table 3: model errors before and after, calibration and validation sets.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Table3 {
    /// On the calibration measurements.
    pub calibration: Table3Set,
    /// On the validation measurements, when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation: Option<Table3Set>,
}

/// What one step did.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StepReport {
    /// Step name.
    pub name: String,
    /// Unknowns freed.
    pub free: Vec<String>,
    /// Unknowns rank detection dropped: each one's column is a combination of kept columns
    /// (a gauge freedom), and that combination of parameter changes is held at nominal.
    pub unidentifiable: Vec<String>,
    /// What each unidentifiable unknown duplicates (column = sum coefficient * column).
    pub dependencies: Vec<Dependency>,
    /// Why Levenberg-Marquardt stopped.
    pub stop_reason: StopReason,
    /// Its iterations.
    pub iterations: usize,
    /// Objective before and after (m^2): the weighted sum of squares of the pose residuals,
    /// plus in MAP the prior term times the squared position repeatability.
    #[serde(deserialize_with = "f64_or_nan")]
    pub cost_before: f64,
    /// After.
    #[serde(deserialize_with = "f64_or_nan")]
    pub cost_after: f64,
    /// Mean position model error on the calibration set after the step (um).
    #[serde(deserialize_with = "f64_or_nan")]
    pub mean_e_p_um: f64,
}
