//! What `calibd lab check` prints per device: a typed identity per driver (each driver's
//! `identity()` returns its own struct) and the common row those structs convert into.
//!
//! Every identity struct derives `serde::Serialize` with unit-explicit field names
//! (`age_ms`, `frequency_hz`, `position_pm`, ...) and implements [`Identity`], which gives a
//! one-line summary for a table and the problems an operator has to fix before a run.

use serde::Serialize;

/// A device identity as one table row: kind, one-line summary, what to fix, and the typed
/// identity as JSON for `--json` output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceIdentity {
    /// Device family (`rws`, `uwave`, `mcs`, `mcs2`, `qtm`, `microscope`, `can`).
    pub device_kind: &'static str,
    /// One-line summary for a table cell.
    pub summary: String,
    /// What the operator has to fix before a calibration run (empty: ready).
    pub problems: Vec<String>,
    /// The typed identity serialized to JSON.
    pub details: serde_json::Value,
    /// What names this unit (see [`Identity::fingerprint`]).
    pub fingerprint: String,
}

/// Implemented by every driver's identity struct.
pub trait Identity: Serialize {
    /// Device family, as in [`crate::DriverError`] messages.
    const DEVICE_KIND: &'static str;

    /// One line for a table, e.g. `IRB120-sim, RobotWare 6.15.01.00, CalibServer loaded`.
    fn summary(&self) -> String;

    /// What names this unit of hardware and its firmware, none of its live state (readings,
    /// positions, motor state): equal before and after a reconnect when the same device came
    /// back, so a paused campaign may resume by itself.
    fn fingerprint(&self) -> String;

    /// What the operator has to fix before a calibration run, each with the fix; empty when
    /// the device is ready.
    fn problems(&self) -> Vec<String> {
        Vec::new()
    }

    /// The common table row.
    fn device_identity(&self) -> DeviceIdentity {
        DeviceIdentity {
            device_kind: Self::DEVICE_KIND,
            summary: self.summary(),
            problems: self.problems(),
            details: serde_json::to_value(self)
                .unwrap_or_else(|e| serde_json::json!({ "serialize_error": e.to_string() })),
            fingerprint: self.fingerprint(),
        }
    }
}
