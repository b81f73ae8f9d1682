//! A campaign's plan as checked before anything moves: every target and the path to it
//! against the cell's envelope, and the estimated duration (`POST /v1/jobs?dry_run=true`,
//! `calibd submit --dry-run`, and the refusal of a plan that leaves the envelope).

use serde::Serialize;

/// One target of a plan, in the order the campaign moves to them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlanTarget {
    /// Position in the plan (0-based; also the journal index).
    pub index: usize,
    /// `measurement` or `validation`.
    pub stage: &'static str,
    /// What is measured there, e.g. `ball 2`.
    pub target: String,
    /// Joint values (deg), in the order of [`Preflight::joints`].
    pub q_deg: Vec<f64>,
    /// Joint moves from the previous target, split within the cell's largest joint step.
    pub moves: usize,
}

/// A configuration of the plan (a target, or a point on the path to it) outside the
/// cell's envelope.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Offending {
    /// The target's position in the plan.
    pub index: usize,
    /// `measurement` or `validation`.
    pub stage: &'static str,
    /// `target` (the configuration itself) or `path` (on the way to it).
    pub at: &'static str,
    /// The target's joint values (deg).
    pub q_deg: Vec<f64>,
    /// What is outside, with the value and the limit.
    pub reason: String,
}

/// The plan against the cell's envelope.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EnvelopeCheck {
    /// No offending configuration.
    pub ok: bool,
    /// Targets checked (each with the path to it).
    pub checked: usize,
    /// The offending configurations.
    pub offending: Vec<Offending>,
}

/// What a campaign would do on its cell, checked, without moving anything.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Preflight {
    /// The cell.
    pub cell: String,
    /// Joint names of `q_deg`.
    pub joints: Vec<String>,
    /// The targets in order.
    pub plan: Vec<PlanTarget>,
    /// The envelope check of every target and path.
    pub envelope: EnvelopeCheck,
    /// Estimated duration of the measurements (s; identification not included).
    pub estimated_duration_s: f64,
}

impl Preflight {
    /// The refusal of a plan that leaves the envelope: every offending configuration.
    pub fn refusal(&self) -> Option<super::JobError> {
        if self.envelope.ok {
            return None;
        }
        let list: Vec<String> = self
            .envelope
            .offending
            .iter()
            .map(|o| {
                let q: Vec<String> = o.q_deg.iter().map(|v| format!("{v:.2}")).collect();
                format!(
                    "{} {} ({} [{}] deg): {}",
                    o.stage,
                    o.index + 1,
                    if o.at == "path" { "path to" } else { "at" },
                    q.join(", "),
                    o.reason
                )
            })
            .collect();
        Some(super::JobError::invalid(
            "plan",
            format!(
                "{} of {} configurations leave cell `{}`'s envelope: {}",
                self.envelope.offending.len(),
                self.envelope.checked,
                self.cell,
                list.join("; ")
            ),
        ))
    }
}
