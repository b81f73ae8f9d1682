//! `cell.identify_tcp`: for each of (four) configurations on one ball, wait for the operator
//! to jog the device onto the ball, centre from there and journal the joints; then solve
//! `R_i t + p_i = c` over the flange poses of the cell's current model for the TCP `t` and
//! the ball centre `c`, and propose the model with the new tool translation to the cell
//! (evidence: spread of the centred points with the old TCP against the new).

use std::sync::Arc;

use nalgebra::Vector3;

use super::plan::{IdentifyTcpJob, campaign_kind};
use super::results::{TcpIdentification, TcpPoint};
use super::solve::{solve_tcp, spread_rms};
use super::{Centred, GuidedCentring, chain_mm, flange};
use crate::campaigns::engine;
use crate::lab::{Candidate, CellModel, Evidence};
use crate::model::dh::DhFile;
use crate::run::{Cx, JobError, Produced, Table};

/// Key of the TCP identification in a model file's `calibration` block.
pub const PROVENANCE: &str = "tcp_identification";

/// The model `file` with the tool translation `t` (mm) and, in its `calibration` block, the
/// TCP's standard deviation (read back by `cell.locate_balls`).
pub fn with_tcp(file: &DhFile, t: &Vector3<f64>, std_mm: [f64; 3]) -> DhFile {
    let mut out = file.clone();
    out.tool.x = t.x;
    out.tool.y = t.y;
    out.tool.z = t.z;
    let mut cal = match out.calibration.take() {
        Some(serde_json::Value::Object(m)) => m,
        _ => serde_json::Map::new(),
    };
    cal.insert(
        PROVENANCE.into(),
        serde_json::json!({ "tcp_mm": [t.x, t.y, t.z], "tcp_std_mm": std_mm }),
    );
    out.calibration = Some(serde_json::Value::Object(cal));
    out
}

/// Solve on the centred configurations with the current model.
fn identify(
    job: &IdentifyTcpJob,
    file: &DhFile,
    rec: &[Centred],
) -> Result<(TcpIdentification, DhFile, Table), JobError> {
    let chain = chain_mm(file)?;
    let poses: Vec<_> = rec.iter().map(|r| flange(&chain, &r.q)).collect();
    let fit = solve_tcp(
        &poses,
        job.options.min_rotation_deg,
        job.options.min_singular_value,
    )
    .map_err(|e| JobError::Failed(e.to_string()))?;
    let old = Vector3::new(file.tool.x, file.tool.y, file.tool.z);
    let old_pts: Vec<Vector3<f64>> = poses.iter().map(|f| f.apply(&old)).collect();
    let old_c = old_pts.iter().sum::<Vector3<f64>>() / old_pts.len().max(1) as f64;
    let mut t = Table::new(&[
        "configuration",
        "q1",
        "q2",
        "q3",
        "q4",
        "q5",
        "q6",
        "distance_mm",
        "previous_distance_mm",
    ]);
    let mut points = Vec::new();
    for (k, r) in rec.iter().enumerate() {
        let q_deg: Vec<f64> = r.q.iter().map(|v| v.to_degrees()).collect();
        let p = TcpPoint {
            configuration: k + 1,
            q_deg: q_deg.clone(),
            distance_mm: fit.spread[k],
            previous_distance_mm: (old_pts[k] - old_c).norm(),
            centring_residual_mm: r.residual_mm,
        };
        let mut row = vec![(k + 1) as f64];
        row.extend(q_deg);
        row.extend([p.distance_mm, p.previous_distance_mm]);
        t.push(row);
        points.push(p);
    }
    let result = TcpIdentification {
        cell: job.cell.clone(),
        ball: job.ball + 1,
        tcp_mm: [fit.t.x, fit.t.y, fit.t.z],
        tcp_std_mm: fit.t_std,
        previous_tcp_mm: [old.x, old.y, old.z],
        ball_in_robot_mm: [fit.c.x, fit.c.y, fit.c.z],
        spread_rms_mm: super::solve::rms(&fit.spread),
        previous_spread_rms_mm: spread_rms(&poses, &old),
        max_rotation_deg: fit.max_rotation_deg,
        min_singular_value: fit.min_singular_value,
        points,
    };
    Ok((result, with_tcp(file, &fit.t, fit.t_std), t))
}

/// Run a `cell.identify_tcp`.
pub async fn campaign(job: Arc<IdentifyTcpJob>, cx: Cx) -> Result<Produced, JobError> {
    let cell = cx.lab().trical(&job.cell)?;
    let copts = job.options.centring.options("options.centring", cell)?;
    let journal = cx.journal();
    let step = GuidedCentring {
        robot: &*cell.robot,
        indicators: &*cell.indicators,
        options: &copts,
        journal,
        what: "configuration",
        count: job.configurations,
    };
    let plan = vec![job.ball; job.configurations];
    let retry = job.options.retry.retry();
    engine::run(&step, &plan, 0, journal, &retry, &cx.phase(0.0, 0.95)).await?;
    let rec: Vec<Centred> = engine::recorded(journal, 0, plan.len())?;
    let file = cell.current_model();
    let (result, model, table) = {
        let (job, file) = (job.clone(), file.clone());
        cx.phase(0.95, 1.0)
            .compute(move |_| identify(&job, &file, &rec))
            .await?
    };
    let candidate = Candidate {
        cell: job.cell.clone(),
        model: CellModel::Serial(model),
        evidence: Some(Evidence {
            what: format!(
                "spread of the centred TCP points on ball {} (RMS)",
                job.ball + 1
            ),
            before: result.previous_spread_rms_mm,
            after: result.spread_rms_mm,
            unit: "mm",
        }),
        validation: serde_json::to_value(&result).unwrap_or_default(),
        assessment: None,
    };
    engine::conclude(&result, Vec::new(), table, None, candidate)
}

campaign_kind!(IdentifyTcpJob, campaign);
