//! The typed results of the three campaigns: the identification's result (flattened, as
//! `serial.identify`, `pcr.identify` and `humanoid.identify` report it), the cell, and the
//! figures of the measuring.

use serde::{Deserialize, Serialize};

use super::instruments::{Instrument, ToleranceCheck};
use crate::jobs::humanoid::identify::HumanoidCalibration;
use crate::jobs::pcr::accuracy::PcrAccuracy;
use crate::jobs::pcr::identify::PcrCalibration;
use crate::jobs::serial::identify::SerialCalibration;
use crate::run::Table;

/// Figures of a TriCal campaign's measuring.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TricalStats {
    /// Configurations planned for the identification.
    pub planned: usize,
    /// Centred (including earlier runs).
    pub recorded: usize,
    /// Skipped (ball lost, not converged).
    pub skipped: usize,
    /// Held-out configurations planned.
    pub validation_planned: usize,
    /// Held-out configurations centred.
    pub validation_recorded: usize,
    /// Held-out configurations skipped.
    pub validation_skipped: usize,
    /// Mean corrective moves per configuration.
    pub mean_moves: f64,
    /// Largest final residual (mm).
    pub max_residual_mm: f64,
    /// Time measuring (s).
    pub measuring_s: f64,
    /// Time identifying (s).
    pub identify_s: f64,
    /// Whole campaign (s).
    pub wall_time_s: f64,
    /// Journal entries.
    pub journal_entries: usize,
}

/// The result of a `cell.trical_campaign`: the identification's result and the campaign's.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TricalCampaign {
    /// The `serial.identify` result on the centred configurations.
    #[serde(flatten)]
    pub calibration: SerialCalibration,
    /// The cell.
    pub cell: String,
    /// What the "before" figures were computed with: the model the campaign started from
    /// (`nominal (the lab file's model)`, `calibration #k of DATE (job J)`, or the job's).
    #[serde(default)]
    pub started_from: String,
    /// Measuring figures.
    pub campaign: TricalStats,
    /// The model the campaign started from.
    pub start_model: crate::model::dh::DhFile,
    /// The cell's devices as they identified themselves at the start (controller,
    /// receivers).
    #[serde(default)]
    pub instruments: Vec<Instrument>,
    /// The held-out maximum error against `options.tolerance_mm`, when the job declared one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<ToleranceCheck>,
    /// The centred configurations (rows of the main table).
    #[serde(serialize_with = "crate::report::json_rows", skip_deserializing)]
    pub measurements: Table,
}

/// Figures of a 3-PF campaign's measuring.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PcrStats {
    /// Joint sets planned (calibration + validation).
    pub planned: usize,
    /// Calibration joint sets measured.
    pub calibration: usize,
    /// Validation joint sets measured.
    pub validation: usize,
    /// Measured (including earlier runs).
    pub recorded: usize,
    /// Skipped (outside the envelope).
    pub skipped: usize,
    /// Accuracy poses measured.
    pub accuracy_measurements: usize,
    /// Seed of the Poisson-disc plan.
    pub seed: u64,
    /// Time measuring (s).
    pub measuring_s: f64,
    /// Time identifying (s).
    pub identify_s: f64,
    /// Whole campaign (s).
    pub wall_time_s: f64,
    /// Journal entries.
    pub journal_entries: usize,
}

/// The result of a `cell.pcr_campaign`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PcrCampaign {
    /// The `pcr.identify` result.
    #[serde(flatten)]
    pub calibration: PcrCalibration,
    /// The `pcr.accuracy` result of the identified model, if asked for.
    #[serde(skip_serializing_if = "Option::is_none", skip_deserializing)]
    pub accuracy: Option<PcrAccuracy>,
    /// The cell.
    pub cell: String,
    /// What the "before" figures were computed with: the model the campaign started from
    /// (`nominal (the lab file's model)`, `calibration #k of DATE (job J)`, or the job's).
    #[serde(default)]
    pub started_from: String,
    /// Measuring figures.
    pub campaign: PcrStats,
    /// The cell's devices as they identified themselves at the start.
    #[serde(default)]
    pub instruments: Vec<Instrument>,
    /// The held-out error against `options.tolerance_um`, when the job declared one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<ToleranceCheck>,
    /// The calibration and validation joint sets (rows of the main table).
    #[serde(serialize_with = "crate::report::json_rows", skip_deserializing)]
    pub measurements: Table,
}

/// Figures of a motion-capture campaign.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MocapStats {
    /// Postures planned.
    pub planned: usize,
    /// Postures recorded (including earlier runs).
    pub recorded: usize,
    /// Postures skipped (refused by the robot).
    pub skipped: usize,
    /// Mean frames per recording window.
    pub mean_frames_per_posture: f64,
    /// Mean stable samples averaged per posture.
    pub mean_stable_samples: f64,
    /// Time designing the postures (s).
    pub design_s: f64,
    /// Time measuring (s).
    pub measuring_s: f64,
    /// Time identifying (s).
    pub identify_s: f64,
    /// Whole campaign (s).
    pub wall_time_s: f64,
    /// Journal entries.
    pub journal_entries: usize,
}

/// The result of a `cell.mocap_campaign`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MocapCampaign {
    /// The `humanoid.identify` result.
    #[serde(flatten)]
    pub calibration: HumanoidCalibration,
    /// The cell.
    pub cell: String,
    /// What the "before" figures were computed with: the model the campaign started from
    /// (`nominal (the lab file's model)`, `calibration #k of DATE (job J)`, or the job's).
    #[serde(default)]
    pub started_from: String,
    /// Campaign figures.
    pub campaign: MocapStats,
    /// The cell's devices as they identified themselves at the start.
    #[serde(default)]
    pub instruments: Vec<Instrument>,
    /// The held-out error against `options.tolerance_mm`, when the job declared one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<ToleranceCheck>,
    /// The averaged postures (rows of the main table).
    #[serde(serialize_with = "crate::report::json_rows", skip_deserializing)]
    pub measurements: Table,
}

/// Mean errors of the starting and the calibrated model, kept in a cell's history as the
/// validation of a model whose identification reports only means (`before.mean`, ...).
#[derive(Debug, Clone, Serialize)]
pub struct MeanErrors {
    /// The starting model.
    pub before: Mean,
    /// The calibrated model.
    pub after: Mean,
}

/// One mean error.
#[derive(Debug, Clone, Serialize)]
pub struct Mean {
    /// Mean error (in the evidence's unit).
    pub mean: f64,
}

impl MeanErrors {
    /// The means `before` and `after`.
    pub fn new(before: f64, after: f64) -> Self {
        Self {
            before: Mean { mean: before },
            after: Mean { mean: after },
        }
    }
}
