//! The result of `serial.identify` as typed data: what its JSON fields are (parameters,
//! rank, convergence, residuals, per-ball coincidence, the calibrated model file).

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use crate::identify::coverage::Coverage;
use crate::identify::gauge_orbit::HeldGauge;
use crate::identify::solve::Dependency;
use crate::identify::verdict::Assessment;
use crate::identify::{
    Degeneracy, NearDependent, ParamReport, PriorReport, StopReason, Unobservable,
};
use crate::model::dh::DhFile;
use crate::util::Summary;
use crate::util::serde_num::f64_or_nan;

/// The calibrated model file of a serial arm, of the same kind as the starting model:
/// serialises as the DH JSON object, or as the URDF text.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Observability {
    /// Condition number of the physically scaled Jacobian.
    #[serde(deserialize_with = "f64_or_nan")]
    pub condition_number: f64,
    /// Nearly dependent parameter groups.
    pub near_dependent: Vec<NearDependent>,
    /// How columns were scaled (not read back).
    #[serde(skip_deserializing)]
    pub scaling: &'static str,
}

/// `convergence` of a serial identification.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Convergence {
    /// Why the solver stopped.
    pub stop_reason: StopReason,
    /// Whether it converged.
    pub converged: bool,
    /// `converged` / `degenerate` / `not_converged` (see `Solution::status`).
    pub status: Cow<'static, str>,
    /// Degeneracy, if any.
    pub degenerate: Option<Degeneracy>,
    /// Iterations used.
    pub iterations: usize,
    /// Cost at the start.
    #[serde(deserialize_with = "f64_or_nan")]
    pub cost_before: f64,
    /// Cost at the end.
    #[serde(deserialize_with = "f64_or_nan")]
    pub cost_after: f64,
    /// Cost with only the nuisance unknowns fitted.
    pub cost_nuisance_only: Option<f64>,
    /// Unit of the costs.
    pub cost_unit: String,
}

/// `rank` of a serial identification.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Rank {
    /// Identified (free) unknowns.
    pub rank: usize,
    /// All unknowns.
    pub unknowns: usize,
    /// Relative tolerance used.
    pub tolerance: f64,
}

/// `residual_std`: the fitted residual standard deviation.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ResidualStd {
    /// Value, counted over distinct configurations (null with zero degrees of freedom:
    /// an exact fit says nothing about the noise).
    pub value: Option<f64>,
    /// Length unit.
    pub unit: String,
    /// Degrees of freedom (distinct equations minus identified unknowns).
    pub dof: usize,
}

/// `before`/`after` error statistics (`residuals`, `validation`), with an optional note.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BeforeAfter {
    /// Errors of the starting model.
    pub before: Summary,
    /// Errors of the calibrated model.
    pub after: Summary,
    /// What the errors are, when not plain position errors.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub meaning: Option<Cow<'static, str>>,
}

/// The validation summary of an identification (`validation.before.mean`, ...).
pub type ValidationSummary = BeforeAfter;

/// Point coincidence of one ball (see [`coincidence_report`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
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
#[derive(Debug, Clone, Serialize, Deserialize)]
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
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CoincidenceReport {
    /// Per ball.
    pub balls: Vec<BallCoincidence>,
    /// Per pair of balls.
    pub ball_distances: Vec<BallDistanceError>,
}

/// `anchor` of a distance identification.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
    /// Frame (`W`; not read back).
    #[serde(skip_deserializing)]
    pub frame: &'static str,
    /// Length unit.
    pub unit: String,
}

/// `length_offset` of a distance identification.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LengthOffset {
    /// Value.
    pub value: f64,
    /// Standard deviation.
    pub std: Option<f64>,
    /// Offset fitted to the starting model.
    pub nominal_fit: f64,
    /// Length unit.
    pub unit: String,
    /// Definition (not read back).
    #[serde(skip_deserializing)]
    pub meaning: &'static str,
}

/// The result of `serial.identify`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SerialCalibration {
    /// `verdict` (`accepted`, `review`, `rejected`) and its `reasons`.
    #[serde(flatten)]
    pub assessment: Assessment,
    /// Residual degrees of freedom: distinct equations minus identified unknowns.
    pub dof: usize,
    /// `distance` for `L_mm` measurements; absent for points.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub measurement_type: Option<Cow<'static, str>>,
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
    #[serde(deserialize_with = "f64_or_nan")]
    pub condition_number: f64,
    /// Residual standard deviation.
    pub residual_std: ResidualStd,
    /// Prior report (point measurements only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prior: Option<PriorReport>,
    /// Gauge freedom the plate leaves (point measurements only; inner `None` is null).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gauge_freedom: Option<Option<String>>,
    /// The plate's free rotation held in the base frame (absent when none was held).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub gauge_held: Option<HeldGauge>,
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
    /// Predicted accuracy at the Cartesian validation points and its coverage (absent
    /// without Cartesian validation or a parameter covariance).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub coverage: Option<Coverage>,
    /// Point coincidence on validation balls.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation_coincidence: Option<CoincidenceReport>,
    /// The calibrated model file (`rejected_model` when the verdict is `rejected`).
    #[serde(alias = "rejected_model")]
    pub calibrated_model: SerialModelFile,
    /// Unused columns and similar (absent when none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warnings: Option<Vec<String>>,
}
