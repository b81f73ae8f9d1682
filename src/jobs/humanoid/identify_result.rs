//! The result of `humanoid.identify` as typed data: what its JSON fields are (parameters
//! by kind, identifiability, marker RMSE, convergence, robust and cross-validation
//! summaries, the calibrated URDF).

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use crate::identify::verdict::Assessment;
use serde_json::Value;

use crate::identify::prior::PriorReport;
use crate::identify::solve::Dependency;
use crate::identify::{Degeneracy, ParamReport, RobustKind, StopReason};

/// Identified parameters by kind (`base_parameter_breakdown`).
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct Breakdown {
    /// Joint placement errors and offsets.
    pub joint_geometry: usize,
    /// Joint and base compliances.
    pub compliance: usize,
    /// Base frame.
    pub base: usize,
    /// Marker positions.
    pub markers: usize,
}

/// One fit's summary (`frames_only`, `geometric_only`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitReport {
    /// Every unknown.
    pub parameters: Vec<ParamReport>,
    /// Unknowns held.
    pub unidentifiable: Vec<String>,
    /// Identified unknowns.
    pub base_parameter_count: usize,
    /// Condition number.
    pub condition_number: f64,
    /// Marker RMSE after the fit (mm).
    pub rmse_after_mm: f64,
    /// Per marker (mm; null when never seen).
    pub per_marker_rmse_mm: Vec<Option<f64>>,
}

/// `identifiability` of `humanoid.identify`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Identifiability {
    /// Relative tolerance of the rank detection.
    pub rank_tolerance: f64,
    /// Identified unknowns.
    pub identified: usize,
    /// Structural rank at 1e-8.
    #[serde(rename = "structural_rank_1e-8")]
    pub structural_rank: usize,
    /// Unknowns.
    pub unknowns: usize,
}

/// Marker RMSE before and after calibration (mm; null when never seen).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MarkerRmse {
    /// Marker name.
    pub name: String,
    /// Its link.
    pub link: String,
    /// Non-calibrated model.
    pub rmse_before_mm: Option<f64>,
    /// Calibrated model.
    pub rmse_after_mm: Option<f64>,
}

/// `convergence` of `humanoid.identify`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HumanoidConvergence {
    /// Why the solver stopped.
    pub stop_reason: StopReason,
    /// Whether it converged.
    pub converged: bool,
    /// Status.
    pub status: Cow<'static, str>,
    /// Degeneracy, if any.
    pub degenerate: Option<Degeneracy>,
    /// Iterations.
    pub iterations: usize,
    /// Cost at the start.
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub cost_before: f64,
    /// Cost at the end.
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub cost_after: f64,
    /// `m^2` (not read back).
    #[serde(skip_deserializing)]
    pub cost_unit: &'static str,
    /// Rank tolerance.
    pub rank_tolerance: f64,
}

/// `robust` of `humanoid.identify`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RobustSummary {
    /// The loss.
    pub loss: RobustKind,
    /// Scale (mm).
    pub scale_mm: f64,
    /// Reweighting rounds.
    pub rounds: usize,
    /// Markers with weight below 0.5.
    pub downweighted_markers: usize,
    /// Marker measurements.
    pub marker_measurements: usize,
}

/// One fold of the cross-validation.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FoldReport {
    /// Samples predicted.
    pub held_out_samples: usize,
    /// RMSE of the frames-only model (mm).
    pub rmse_nominal_mm: f64,
    /// RMSE of the calibrated model (mm).
    pub rmse_calibrated_mm: f64,
}

/// `cross_validation` of `humanoid.identify`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CrossValidation {
    /// Folds.
    pub folds: usize,
    /// Shuffle seed.
    pub seed: u64,
    /// Overall RMSE of the frames-only models (mm).
    pub rmse_nominal_mm: f64,
    /// Overall RMSE of the calibrated models (mm).
    pub rmse_calibrated_mm: f64,
    /// Per fold.
    pub per_fold: Vec<FoldReport>,
}

/// The result of `humanoid.identify`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HumanoidCalibration {
    /// `verdict` (`accepted`, `review`, `rejected`) and its `reasons`.
    #[serde(flatten)]
    pub assessment: Assessment,
    /// Residual degrees of freedom: distinct marker equations minus identified unknowns.
    pub dof: usize,
    /// Every unknown of the full fit.
    pub parameters: Vec<ParamReport>,
    /// Unknowns held.
    pub unidentifiable: Vec<String>,
    /// Identified unknowns.
    pub base_parameter_count: usize,
    /// By kind.
    pub base_parameter_breakdown: Breakdown,
    /// Rank detection.
    pub identifiability: Identifiability,
    /// Condition number.
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub condition_number: f64,
    /// Marker RMSE of the non-calibrated model (mm).
    pub rmse_before_mm: f64,
    /// Marker RMSE of the calibrated model (mm).
    pub rmse_after_mm: f64,
    /// Per marker.
    pub markers: Vec<MarkerRmse>,
    /// Dependencies of the held unknowns.
    pub dependencies: Vec<Dependency>,
    /// Weakly observable unknowns.
    pub weakly_observable: Vec<String>,
    /// Convergence.
    pub convergence: HumanoidConvergence,
    /// Residual standard deviation (mm), counted over distinct postures (null with zero
    /// degrees of freedom).
    pub residual_std_mm: Option<f64>,
    /// Which mode ran: `least_squares`, `map` (fixed prior weight) or `map_cv` (weight by
    /// K-fold on the training samples, with each candidate's held-out RMS in m) or
    /// `map_auto` (`scale: "auto"`: `auto` holds the chosen stds and the grid's errors).
    pub prior: PriorReport,
    /// Robust loss report.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robust: Option<RobustSummary>,
    /// Frames-only fit.
    pub frames_only: FitReport,
    /// Geometric-only fit (elastic models).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub geometric_only: Option<FitReport>,
    /// The samples used and dropped (left as JSON: read by people, not code).
    pub samples: Value,
    /// Cross-validation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cross_validation: Option<CrossValidation>,
    /// Predicted accuracy on the held-out `validation` session and its coverage (mm).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub coverage: Option<crate::identify::coverage::Coverage>,
    /// The calibrated URDF text (`rejected_urdf` when the verdict is `rejected`).
    #[serde(alias = "rejected_urdf")]
    pub calibrated_urdf: String,
    /// The calibrated model (the same URDF text; `rejected_model` when rejected).
    #[serde(alias = "rejected_model")]
    pub calibrated_model: String,
    /// What the URDF holds (not read back: the report shows it as stored).
    #[serde(skip_deserializing)]
    pub calibrated_urdf_note: &'static str,
}
