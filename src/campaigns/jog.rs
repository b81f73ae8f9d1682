//! `cell.jog`: move a ball-centring cell's robot to given joints within the cell's
//! envelope, like a teach-pendant jog. The operator's stand-in for tests and the simulated
//! lab while a commissioning step waits ("jog the robot until the stems touch the ball").

use std::sync::Arc;

use serde::Deserialize;
use serde_json::Value;

use super::spec::default_cell;
use crate::campaigns::commission::results::Jogged;
use crate::procedures::centring::{CentringError, approach};
use crate::run::{Cx, Inputs, JobError, Kind, Output, RunFuture, parse_spec};

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    q_deg: Vec<f64>,
}

/// A validated `cell.jog` job.
#[derive(Debug)]
pub struct JogJob {
    cell: String,
    q: Vec<f64>,
}

/// Validate a `cell.jog` job.
pub fn prepare(doc: &Value, _: &Inputs<'_>) -> Result<JogJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    if let Some((k, v)) = s.q_deg.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(JobError::invalid(
            format!("q_deg[{k}]"),
            format!("{v} is not a number"),
        ));
    }
    Ok(JogJob {
        cell: s.cell,
        q: s.q_deg.iter().map(|v| v.to_radians()).collect(),
    })
}

impl Kind for JogJob {
    fn devices(&self) -> Vec<String> {
        vec![format!("{}.rws", self.cell)]
    }

    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        Box::pin(async move { self.jog(&cx).await.map(Into::into) })
    }
}

impl JogJob {
    async fn jog(&self, cx: &Cx) -> Result<Output, JobError> {
        let cell = cx.lab().trical(&self.cell)?;
        let lim = &cell.envelope.limits;
        if !lim.is_empty() && lim.len() != self.q.len() {
            return Err(JobError::invalid(
                "q_deg",
                format!(
                    "{} joint values for a {}-joint robot",
                    self.q.len(),
                    lim.len()
                ),
            ));
        }
        for (j, (v, l)) in self.q.iter().zip(lim).enumerate() {
            if *v < l[0] || *v > l[1] {
                return Err(JobError::invalid(
                    format!("q_deg[{j}]"),
                    format!(
                        "{:.3} deg is outside the cell's envelope [{:.3}, {:.3}] deg",
                        v.to_degrees(),
                        l[0].to_degrees(),
                        l[1].to_degrees()
                    ),
                ));
            }
        }
        let robot = &*cell.robot;
        let from = robot.joints().await?;
        approach(robot, &self.q, cell.envelope.max_joint_step, cx)
            .await
            .map_err(|e| match e {
                CentringError::Cancelled => JobError::Cancelled,
                other => JobError::Procedure {
                    procedure: "jog",
                    source: other,
                },
            })?;
        let q = robot.joints().await?;
        let moved = from
            .iter()
            .zip(&q)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        Output::typed(&Jogged {
            cell: self.cell.clone(),
            q_deg: q.iter().map(|v| v.to_degrees()).collect(),
            moved_deg: moved.to_degrees(),
        })
    }
}
