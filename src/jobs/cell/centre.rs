//! `cell.centre`: the centring loop on one ball from a joint configuration; bounded in
//! iterations, step size and reading time, and every abort says why.

use serde::Deserialize;
use serde_json::{Map, json};

use super::{CentringSpec, default_cell, trical_cell, trical_devices};
use crate::jobs::{JobError, Output, Prepared, RunContext, Table, parse_spec};
use crate::procedures::{CentringError, centre};
use crate::util::Monitor;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
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
pub fn prepare(doc: &serde_json::Value) -> Result<CentreJob, JobError> {
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

impl Prepared for CentreJob {
    fn execute(&self, _monitor: &dyn Monitor) -> Result<Output, JobError> {
        Err(JobError::NeedsLab {
            kind: "cell.centre".into(),
        })
    }

    fn execute_in(&self, ctx: &RunContext<'_>, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let (cell, rt) = trical_cell(ctx, "cell.centre", &self.cell)?;
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
        let c = rt
            .block_on(centre(
                &*cell.robot,
                &*cell.indicators,
                &self.q,
                &opts,
                monitor,
            ))
            .map_err(|e| match e {
                CentringError::Cancelled => JobError::Cancelled,
                other => JobError::Failed(format!("centring aborted: {other}")),
            })?;
        let mut t = Table::new(&["reading", "rx_mm", "ry_mm", "rz_mm", "norm_mm"]);
        for (i, r) in c.readings.iter().enumerate() {
            let n = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
            t.push(vec![i as f64, r[0], r[1], r[2], n]);
        }
        let mut f = Map::new();
        f.insert("cell".into(), json!(self.cell));
        f.insert(
            "q_deg".into(),
            json!(c.q.iter().map(|v| v.to_degrees()).collect::<Vec<_>>()),
        );
        f.insert("iterations".into(), json!(c.iterations));
        f.insert("residual_mm".into(), json!(c.residual_mm));
        f.insert("readings".into(), t.to_json_rows());
        Ok(Output {
            fields: f,
            main_table: Some(t),
            artefacts: vec![],
        })
    }

    fn devices(&self) -> Vec<String> {
        trical_devices(&self.cell)
    }
}
