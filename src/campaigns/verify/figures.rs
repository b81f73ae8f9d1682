//! The figures of a verification: from the journalled indicator readings, the attained
//! TCP positions in {W} and ISO 9283 AP and RP per pose and AD per pair of poses on
//! different balls, for the nominal and the compensated model side by side.

use serde::{Deserialize, Serialize};

use super::plan::{Commanded, VerifyPose};
use crate::measure::iso9283::{distance_accuracy, position_accuracy};
use crate::util::stats::mean;

/// One reading at a commanded pose (the journal's format).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reading {
    /// Index in the journal.
    pub index: usize,
    /// Cycle (0-based).
    pub cycle: usize,
    /// Pose (0-based, in the plan).
    pub pose: usize,
    /// Which model commanded the joints.
    pub commanded: Commanded,
    /// The indicator readings (mm): ball centre relative to the TCP along the tool axes.
    pub r_mm: [f64; 3],
    /// An indicator was at the end of its travel: the error is larger than it can read.
    pub out_of_range: bool,
}

/// AP and RP of one pose under one model; `None` when every reading was out of range.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ModelFigures {
    /// Pose accuracy AP (mm).
    pub ap_mm: Option<f64>,
    /// Pose repeatability RP (mm).
    pub rp_mm: Option<f64>,
    /// Readings in range.
    pub cycles: usize,
    /// Readings out of the indicators' range (not used in AP and RP).
    pub out_of_range: usize,
}

/// One pose: where it is, and both models' figures.
#[derive(Debug, Clone, Serialize)]
pub struct PoseFigures {
    /// Pose (1-based).
    pub pose: usize,
    /// Ball (1-based).
    pub ball: usize,
    /// Commanded position: the ball centre in {W} (mm).
    pub commanded_mm: [f64; 3],
    /// Through the nominal model.
    pub nominal: ModelFigures,
    /// Through the compensated model.
    pub compensated: ModelFigures,
}

/// Distance accuracy between two poses on different balls.
#[derive(Debug, Clone, Serialize)]
pub struct DistanceFigures {
    /// The two poses (1-based).
    pub poses: [usize; 2],
    /// Commanded distance (mm).
    pub commanded_mm: f64,
    /// AD through the nominal model (mm, signed); `None` without a cycle in range.
    pub nominal_ad_mm: Option<f64>,
    /// AD through the compensated model (mm, signed).
    pub compensated_ad_mm: Option<f64>,
}

/// Summary of one model over every pose.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Totals {
    /// Mean AP over the poses in range (mm).
    pub ap_mean_mm: Option<f64>,
    /// Largest AP (mm).
    pub ap_max_mm: Option<f64>,
    /// Largest RP (mm).
    pub rp_max_mm: Option<f64>,
    /// Largest |AD| (mm).
    pub ad_max_abs_mm: Option<f64>,
    /// Poses with at least one reading out of range.
    pub out_of_range_poses: usize,
}

/// Attained TCP position in {W}: the ball centre minus the reading rotated into {W}.
fn attained(p: &VerifyPose, r: &[f64; 3]) -> Vec<f64> {
    let v = p.target.p - p.target.r * nalgebra::Vector3::from(*r);
    vec![v.x, v.y, v.z]
}

/// Attained positions per cycle of pose `k` under `m` (`None` out of range or missing).
fn per_cycle(
    poses: &[VerifyPose],
    readings: &[Reading],
    k: usize,
    m: Commanded,
    cycles: usize,
) -> Vec<Option<Vec<f64>>> {
    let mut out = vec![None; cycles];
    for r in readings {
        if r.pose == k && r.commanded == m && !r.out_of_range && r.cycle < cycles {
            out[r.cycle] = Some(attained(&poses[k], &r.r_mm));
        }
    }
    out
}

fn figures(
    poses: &[VerifyPose],
    readings: &[Reading],
    k: usize,
    m: Commanded,
    cycles: usize,
) -> ModelFigures {
    let got: Vec<Vec<f64>> = per_cycle(poses, readings, k, m, cycles)
        .into_iter()
        .flatten()
        .collect();
    let out_of_range = readings
        .iter()
        .filter(|r| r.pose == k && r.commanded == m && r.out_of_range)
        .count();
    let c = poses[k].target.p;
    let a = (!got.is_empty()).then(|| position_accuracy(&[c.x, c.y, c.z], &got));
    ModelFigures {
        ap_mm: a.as_ref().map(|a| a.ap),
        rp_mm: a.as_ref().map(|a| a.rp),
        cycles: got.len(),
        out_of_range,
    }
}

fn ad(
    poses: &[VerifyPose],
    readings: &[Reading],
    (i, k): (usize, usize),
    m: Commanded,
    cycles: usize,
) -> Option<f64> {
    let a = per_cycle(poses, readings, i, m, cycles);
    let b = per_cycle(poses, readings, k, m, cycles);
    let (pa, pb): (Vec<_>, Vec<_>) = a
        .into_iter()
        .zip(b)
        .filter_map(|(x, y)| Some((x?, y?)))
        .unzip();
    if pa.is_empty() {
        return None;
    }
    let (ci, ck) = (poses[i].target.p, poses[k].target.p);
    Some(distance_accuracy(
        (&[ci.x, ci.y, ci.z], &[ck.x, ck.y, ck.z]),
        (&pa, &pb),
    ))
}

fn totals(p: &[ModelFigures], ad: &[Option<f64>]) -> Totals {
    let ap: Vec<f64> = p.iter().filter_map(|f| f.ap_mm).collect();
    let max = |v: &mut dyn Iterator<Item = f64>| v.reduce(f64::max);
    Totals {
        ap_mean_mm: (!ap.is_empty()).then(|| mean(&ap)),
        ap_max_mm: max(&mut ap.iter().copied()),
        rp_max_mm: max(&mut p.iter().filter_map(|f| f.rp_mm)),
        ad_max_abs_mm: max(&mut ad.iter().flatten().map(|v| v.abs())),
        out_of_range_poses: p.iter().filter(|f| f.out_of_range > 0).count(),
    }
}

/// Per-pose figures, distance figures, and each model's totals (nominal, compensated).
pub fn evaluate(
    poses: &[VerifyPose],
    readings: &[Reading],
    cycles: usize,
) -> (Vec<PoseFigures>, Vec<DistanceFigures>, [Totals; 2]) {
    use Commanded::{Compensated, Nominal};
    let per: Vec<PoseFigures> = (0..poses.len())
        .map(|k| {
            let c = poses[k].target.p;
            PoseFigures {
                pose: k + 1,
                ball: poses[k].ball + 1,
                commanded_mm: [c.x, c.y, c.z],
                nominal: figures(poses, readings, k, Nominal, cycles),
                compensated: figures(poses, readings, k, Compensated, cycles),
            }
        })
        .collect();
    let mut dist = Vec::new();
    for i in 0..poses.len() {
        for k in i + 1..poses.len() {
            if poses[i].ball == poses[k].ball {
                continue;
            }
            dist.push(DistanceFigures {
                poses: [i + 1, k + 1],
                commanded_mm: (poses[i].target.p - poses[k].target.p).norm(),
                nominal_ad_mm: ad(poses, readings, (i, k), Nominal, cycles),
                compensated_ad_mm: ad(poses, readings, (i, k), Compensated, cycles),
            });
        }
    }
    let nom: Vec<_> = per.iter().map(|p| p.nominal.clone()).collect();
    let comp: Vec<_> = per.iter().map(|p| p.compensated.clone()).collect();
    let nad: Vec<_> = dist.iter().map(|d| d.nominal_ad_mm).collect();
    let cad: Vec<_> = dist.iter().map(|d| d.compensated_ad_mm).collect();
    let t = [totals(&nom, &nad), totals(&comp, &cad)];
    (per, dist, t)
}
