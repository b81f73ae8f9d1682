//! A joint-space plan checked against a cell's envelope before anything moves: each target
//! and the straight path to it from the previous one (or from where the robot stands),
//! split as the approach splits it; the offending configurations are listed.

use crate::procedures::Envelope;
use crate::run::preflight::{EnvelopeCheck, Offending, PlanTarget};

/// One target of a plan: its stage, what it measures and its joints (rad).
#[derive(Debug, Clone)]
pub struct Target {
    /// `measurement` or `validation`.
    pub stage: &'static str,
    /// What is measured there, e.g. `ball 2`.
    pub what: String,
    /// Joints (rad).
    pub q: Vec<f64>,
}

fn deg(q: &[f64]) -> Vec<f64> {
    q.iter().map(|v| v.to_degrees()).collect()
}

/// Check `targets` in order (the path to the first from `start` when the robot's joints
/// are known): the plan with each target's moves, and the envelope check.
pub fn check(
    targets: &[Target],
    start: Option<&[f64]>,
    envelope: &Envelope,
) -> (Vec<PlanTarget>, EnvelopeCheck) {
    let mut plan = Vec::with_capacity(targets.len());
    let mut offending = Vec::new();
    let mut from = start;
    // The path from an offending target is not listed again.
    let mut prev_bad = false;
    for (index, t) in targets.iter().enumerate() {
        let bad = |at: &'static str, reason: String| Offending {
            index,
            stage: t.stage,
            at,
            q_deg: deg(&t.q),
            reason,
        };
        let n = offending.len();
        if let Some(why) = envelope.outside(&t.q) {
            offending.push(bad("target", why));
        } else if let Some(why) = from
            .filter(|_| !prev_bad)
            .and_then(|f| envelope.path_outside(f, &t.q))
        {
            offending.push(bad("path", why));
        }
        prev_bad = offending.len() > n && offending[n].at == "target";
        plan.push(PlanTarget {
            index,
            stage: t.stage,
            target: t.what.clone(),
            q_deg: deg(&t.q),
            moves: from.map_or(1, |f| envelope.steps(f, &t.q)),
        });
        from = Some(&t.q);
    }
    let check = EnvelopeCheck {
        ok: offending.is_empty(),
        checked: targets.len(),
        offending,
    };
    (plan, check)
}

/// Joint travel (rad) of the plan: the largest joint change of each move, summed.
pub fn travel(targets: &[Target], start: Option<&[f64]>) -> f64 {
    let mut from = start;
    let mut sum = 0.0;
    for t in targets {
        if let Some(f) = from {
            sum += f
                .iter()
                .zip(&t.q)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
        }
        from = Some(&t.q);
    }
    sum
}
