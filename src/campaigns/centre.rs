//! `cell.centre`: the centring loop on one ball from a joint configuration; bounded in
//! iterations, step size and reading time, and every abort says why.

use serde::Deserialize;

use std::sync::Arc;

use super::spec::{CentringSpec, default_cell, trical_devices};
use crate::procedures::{CentringError, centre};
use crate::run::{Cx, JobError, Kind, Output, RunFuture, Table, parse_spec};
use crate::util::Monitor;

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    q_deg: Vec<f64>,
    #[serde(default)]
    options: CentringSpec,
}

/// A validated `cell.centre` job.
#[derive(Debug)]
pub struct CentreJob {
    cell: String,
    q: Vec<f64>,
    centring: CentringSpec,
}

/// Validate a `cell.centre` job.
pub fn prepare(doc: &serde_json::Value, _: &crate::run::Inputs<'_>) -> Result<CentreJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    if let Some((k, v)) = s.q_deg.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(JobError::invalid(
            format!("q_deg[{k}]"),
            format!("{v} is not a number"),
        ));
    }
    s.options.validate("options")?;
    Ok(CentreJob {
        cell: s.cell,
        q: s.q_deg.iter().map(|v| v.to_radians()).collect(),
        centring: s.options,
    })
}

impl Kind for CentreJob {
    fn devices(&self) -> Vec<String> {
        trical_devices(&self.cell)
    }

    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        Box::pin(async move { self.centre(&cx).await.map(Into::into) })
    }
}

impl CentreJob {
    async fn centre(&self, cx: &Cx) -> Result<Output, JobError> {
        let monitor: &dyn Monitor = cx;
        let cell = cx.lab().trical(&self.cell)?;
        let opts = self.centring.options("options", cell)?;
        if let Some((j, v, l)) = cell.current_model().to_chain()?.limit_violation(&self.q) {
            return Err(JobError::invalid(
                format!("q_deg[{j}]"),
                format!(
                    "{:.3} deg is outside the joint limits [{:.3}, {:.3}] deg",
                    v.to_degrees(),
                    l[0].to_degrees(),
                    l[1].to_degrees()
                ),
            ));
        }
        monitor.progress(0.0, "centring");
        let c = centre(&*cell.robot, &*cell.indicators, &self.q, &opts, monitor)
            .await
            .map_err(|e| match e {
                CentringError::Cancelled => JobError::Cancelled,
                other => JobError::Procedure {
                    procedure: "centring aborted",
                    source: other,
                },
            })?;
        let mut t = Table::new(&["reading", "rx_mm", "ry_mm", "rz_mm", "norm_mm"]);
        for (i, r) in c.readings.iter().enumerate() {
            let n = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
            t.push(vec![i as f64, r[0], r[1], r[2], n]);
        }
        let mut out = Output::typed(&Centred {
            cell: self.cell.clone(),
            q_deg: c.q.iter().map(|v| v.to_degrees()).collect(),
            iterations: c.iterations,
            residual_mm: c.residual_mm,
            readings: t.to_json_rows(),
        })?;
        out.main_table = Some(t);
        Ok(out)
    }
}

/// The result of `cell.centre`.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Centred {
    /// The cell.
    pub cell: String,
    /// Joints at the end of the loop (deg).
    pub q_deg: Vec<f64>,
    /// Corrective moves.
    pub iterations: usize,
    /// Final |r| (mm).
    pub residual_mm: f64,
    /// Every reading of the loop (rows of the main table).
    pub readings: serde_json::Value,
}
