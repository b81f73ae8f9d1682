//! Automatic resume of a campaign paused on a device fault: the cell's policy (lab file
//! `resume` and `max_auto_resumes`) and the decision, from what each device said it was
//! before the fault and what it says now. A device that comes back as another unit (another
//! controller, another receiver) never resumes a campaign by itself: its measurements
//! would not belong to the same cell.

use std::collections::BTreeMap;

use serde::Serialize;

use super::Lab;
use super::devices::DeviceStatus;

/// Who resumes a campaign paused on a device fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ResumeMode {
    /// The operator (`POST /v1/jobs/{id}/resume`): the default.
    #[default]
    Operator,
    /// The daemon, once every device of the job answers again with the same identity.
    Auto,
}

/// A cell's resume setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct ResumePolicy {
    /// Who resumes.
    pub mode: ResumeMode,
    /// Automatic resumes allowed per job; beyond, the job waits for the operator.
    pub max_auto_resumes: u32,
}

/// Automatic resumes allowed per job unless the lab file says otherwise.
pub const DEFAULT_MAX_AUTO_RESUMES: u32 = 3;

impl Default for ResumePolicy {
    fn default() -> Self {
        Self {
            mode: ResumeMode::Operator,
            max_auto_resumes: DEFAULT_MAX_AUTO_RESUMES,
        }
    }
}

/// The fingerprint each device of a job had (None: no probe of it has succeeded yet).
pub type Fingerprints = BTreeMap<String, Option<String>>;

/// What became of the devices of a paused job.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// Every device answers with the identity it had: the job may resume.
    Same,
    /// A device does not answer (yet): wait.
    Down {
        /// The device.
        device: String,
        /// Its last check's error.
        error: String,
    },
    /// A device answers as another unit, or its identity before the fault is unknown: the
    /// operator must look.
    Changed {
        /// The device.
        device: String,
        /// What it was (None: unknown).
        was: Option<String>,
        /// What it is now.
        now: String,
    },
}

impl Verdict {
    /// Why a job stays paused for the operator (None for [`Verdict::Same`] and
    /// [`Verdict::Down`]).
    pub fn operator_reason(&self) -> Option<String> {
        match self {
            Verdict::Changed {
                device,
                was: Some(was),
                now,
            } => Some(format!(
                "not resumed automatically: {device} came back as another device ({now}; it was {was}): check the cell, then resume by hand"
            )),
            Verdict::Changed {
                device, was: None, ..
            } => Some(format!(
                "not resumed automatically: {device}'s identity before the fault is unknown, so it cannot be told to be the same device: check the cell, then resume by hand"
            )),
            _ => None,
        }
    }
}

impl Lab {
    /// The resume setting of `cell` (the default for a cell the lab does not have).
    pub fn resume_policy(&self, cell: &str) -> ResumePolicy {
        self.resume.get(cell).copied().unwrap_or_default()
    }

    /// The cell whose devices include one of `devices`, if any.
    pub fn cell_of(&self, devices: &[String]) -> Option<&str> {
        self.cells()
            .find(|c| c.devices().iter().any(|d| devices.contains(d)))
            .map(|c| c.name())
    }

    /// The last known identity of each of `devices`.
    pub fn fingerprints(&self, devices: &[String]) -> Fingerprints {
        self.links_for(devices)
            .into_iter()
            .map(|(_, l)| (l.name.clone(), l.last_identity().map(|i| i.fingerprint)))
            .collect()
    }
}

/// Compare the identities before a fault with the devices' checks now.
pub fn compare(before: &Fingerprints, now: &[(String, DeviceStatus)]) -> Verdict {
    for (device, status) in now {
        match status {
            DeviceStatus::Ok { identity, .. } => {
                let was = before.get(device).cloned().flatten();
                if was.as_deref() != Some(identity.fingerprint.as_str()) {
                    return Verdict::Changed {
                        device: device.clone(),
                        was,
                        now: identity.fingerprint.clone(),
                    };
                }
            }
            DeviceStatus::Failed { error, .. } => {
                return Verdict::Down {
                    device: device.clone(),
                    error: error.clone(),
                };
            }
            DeviceStatus::Unchecked => {
                return Verdict::Down {
                    device: device.clone(),
                    error: "not checked yet".into(),
                };
            }
        }
    }
    Verdict::Same
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lab::devices::Identity;

    fn ok(fp: &str) -> DeviceStatus {
        DeviceStatus::Ok {
            identity: Identity {
                summary: format!("{fp}, live readings"),
                details: serde_json::Value::Null,
                fingerprint: fp.into(),
            },
            checked_at: "now".into(),
        }
    }

    fn before() -> Fingerprints {
        [
            (
                "c.rws".to_string(),
                Some("IRC5-A, RobotWare 6.15".to_string()),
            ),
            ("c.uwave".to_string(), Some("U-WAVE-R 1".to_string())),
        ]
        .into()
    }

    #[test]
    fn the_same_devices_resume_and_a_swapped_one_waits_for_the_operator() {
        let same = [
            ("c.rws".to_string(), ok("IRC5-A, RobotWare 6.15")),
            ("c.uwave".to_string(), ok("U-WAVE-R 1")),
        ];
        assert_eq!(compare(&before(), &same), Verdict::Same);
        let swapped = [
            ("c.rws".to_string(), ok("IRC5-B, RobotWare 6.15")),
            ("c.uwave".to_string(), ok("U-WAVE-R 1")),
        ];
        let v = compare(&before(), &swapped);
        let why = v.operator_reason().expect("a reason");
        assert!(
            why.contains("c.rws came back as another device (IRC5-B")
                && why.contains("it was IRC5-A"),
            "{why}"
        );
        let down = [(
            "c.rws".to_string(),
            DeviceStatus::Failed {
                error: "connection refused".into(),
                fix: String::new(),
                checked_at: "now".into(),
            },
        )];
        assert!(
            matches!(compare(&before(), &down), Verdict::Down { device, .. } if device == "c.rws")
        );
        assert_eq!(compare(&before(), &down).operator_reason(), None);
        // Never identified before the fault: it cannot be told to be the same device.
        let unknown: Fingerprints = [("c.rws".to_string(), None)].into();
        let v = compare(&unknown, &same[..1]);
        assert!(matches!(&v, Verdict::Changed { was: None, .. }), "{v:?}");
    }
}
