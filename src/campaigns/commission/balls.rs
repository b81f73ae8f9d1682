//! `cell.locate_balls`: for each ball of the plate, wait for the operator to jog the device
//! onto it, centre and journal the joints; the ball centres in {0} are `flange(q) * t` with
//! the cell's current TCP, with their uncertainty (the TCP's standard deviation and the
//! centring noise); their distances stand beside the ballbar's, and the rigid fit of the
//! balls onto the plate gives the base frame, proposed to the cell as a new model.

use std::sync::Arc;

use nalgebra::Vector3;

use super::plan::{LocateBallsJob, campaign_kind};
use super::results::{BallDistance, BallLocation, BaseFrame, LocatedBall};
use super::solve::{ball_position, distance, fit_base, residuals, rms};
use super::{Centred, GuidedCentring, chain_mm, flange};
use crate::campaigns::engine;
use crate::lab::{Candidate, CellModel, Evidence};
use crate::measure::BallPlate;
use crate::model::dh::{DhFile, Xyzabc};
use crate::run::{Cx, JobError, Produced, Table};

/// The TCP's standard deviation `cell.identify_tcp` wrote into the model, if any.
fn model_tcp_std(file: &DhFile) -> Option<[f64; 3]> {
    let v = file.calibration.as_ref()?.get(super::tcp::PROVENANCE)?;
    serde_json::from_value(v.get("tcp_std_mm")?.clone()).ok()
}

fn locate(
    job: &LocateBallsJob,
    file: &DhFile,
    ballbar: [f64; 3],
    rec: &[Centred],
) -> Result<(BallLocation, DhFile, Table), JobError> {
    let chain = chain_mm(file)?;
    let plate = BallPlate::from_ballbar(ballbar[0], ballbar[1], ballbar[2])?;
    let t = Vector3::new(file.tool.x, file.tool.y, file.tool.z);
    let t_std = job
        .options
        .tcp_std_mm
        .or_else(|| model_tcp_std(file))
        .unwrap_or([0.0; 3]);
    let noise = job.options.centring_noise_mm;
    let mut measured = Vec::new();
    let mut world = Vec::new();
    for r in rec {
        let w = plate
            .centres
            .get(r.ball)
            .copied()
            .flatten()
            .ok_or_else(|| JobError::CellMismatch {
                what: "plate",
                message: format!("the plate has no ball {}", r.ball + 1),
            })?;
        measured.push(ball_position(&flange(&chain, &r.q), &t, &t_std, noise));
        world.push(w);
    }
    let pts: Vec<Vector3<f64>> = measured.iter().map(|m| m.0).collect();
    let (base, res) = fit_base(&pts, &world).map_err(|e| JobError::Failed(e.to_string()))?;
    let before = residuals(&chain.base_frame(), &pts, &world);
    let mut table = Table::new(&[
        "ball",
        "x_mm",
        "y_mm",
        "z_mm",
        "std_x_mm",
        "std_y_mm",
        "std_z_mm",
        "residual_mm",
    ]);
    let mut balls = Vec::new();
    for (k, (r, (p, cov))) in rec.iter().zip(&measured).enumerate() {
        let std_mm = [0, 1, 2].map(|i| cov[(i, i)].max(0.0).sqrt());
        let w = base.apply(p);
        table.push(vec![
            (r.ball + 1) as f64,
            p.x,
            p.y,
            p.z,
            std_mm[0],
            std_mm[1],
            std_mm[2],
            res[k],
        ]);
        balls.push(LocatedBall {
            ball: r.ball + 1,
            in_robot_mm: [p.x, p.y, p.z],
            std_mm,
            in_world_mm: [w.x, w.y, w.z],
            fit_residual_mm: res[k],
            q_deg: r.q.iter().map(|v| v.to_degrees()).collect(),
        });
    }
    let mut distances = Vec::new();
    let pairs = [(0, 1, ballbar[0]), (0, 2, ballbar[1]), (1, 2, ballbar[2])];
    for (i, j, d) in &pairs {
        let (Some(a), Some(b)) = (
            rec.iter().position(|r| r.ball == *i),
            rec.iter().position(|r| r.ball == *j),
        ) else {
            continue;
        };
        let (m, s) = distance(&measured[a], &measured[b]);
        distances.push(BallDistance {
            pair: format!("{}-{}", i + 1, j + 1),
            measured_mm: m,
            std_mm: s,
            ballbar_mm: *d,
            difference_mm: m - d,
        });
    }
    let xyz = base.to_xyzabc();
    let mut model = file.clone();
    model.base = Xyzabc {
        x: xyz[0],
        y: xyz[1],
        z: xyz[2],
        a: xyz[3].to_degrees(),
        b: xyz[4].to_degrees(),
        c: xyz[5].to_degrees(),
    };
    if file.units.angle == "rad" {
        (model.base.a, model.base.b, model.base.c) = (xyz[3], xyz[4], xyz[5]);
    }
    let result = BallLocation {
        cell: job.cell.clone(),
        tcp_mm: [t.x, t.y, t.z],
        tcp_std_mm: t_std,
        centring_noise_mm: noise,
        balls,
        distances,
        base: BaseFrame::from_internal(&xyz),
        previous_base: BaseFrame::from_internal(&chain.base),
        fit_residual_rms_mm: rms(&res),
        previous_residual_rms_mm: rms(&before),
    };
    Ok((result, model, table))
}

/// Run a `cell.locate_balls`.
pub async fn campaign(job: Arc<LocateBallsJob>, cx: Cx) -> Result<Produced, JobError> {
    let cell = cx.lab().trical(&job.cell)?;
    let copts = job.options.centring.options("options.centring", cell)?;
    let journal = cx.journal();
    let step = GuidedCentring {
        robot: &*cell.robot,
        indicators: &*cell.indicators,
        options: &copts,
        journal,
        what: "ball",
        count: 3,
    };
    let plan: Vec<usize> = (0..3).collect();
    let retry = job.options.retry.retry();
    engine::run(&step, &plan, 0, journal, &retry, &cx.phase(0.0, 0.95)).await?;
    let rec: Vec<Centred> = engine::recorded(journal, 0, plan.len())?;
    let (file, ballbar) = (cell.current_model(), cell.ballbar);
    let (result, model, table) = {
        let (job, file) = (job.clone(), file.clone());
        cx.phase(0.95, 1.0)
            .compute(move |_| locate(&job, &file, ballbar, &rec))
            .await?
    };
    let candidate = Candidate {
        cell: job.cell.clone(),
        model: CellModel::Serial(model),
        evidence: Some(Evidence {
            what: "located balls against the plate in {W} (RMS)".into(),
            before: result.previous_residual_rms_mm,
            after: result.fit_residual_rms_mm,
            unit: "mm",
        }),
        validation: serde_json::to_value(&result).unwrap_or_default(),
        assessment: None,
    };
    engine::conclude(&result, Vec::new(), table, None, candidate)
}

campaign_kind!(LocateBallsJob, campaign);
