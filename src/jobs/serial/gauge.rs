//! The ball plate's gauge in a serial identification: two balls leave the world frame free
//! to turn about the line through them. That rotation belongs to the base frame (the
//! robot's pose in {W}), not to joint 1: when the base frame's six parameters are
//! identified, the free fit's solution is turned about the line to the base pose closest to
//! nominal and refitted with that combination held ([`crate::identify::gauge_orbit`]).

use nalgebra::Vector3;

use crate::geometry::Frame;
use crate::identify::gauge_orbit::{HeldGauge, Orbit, hold_orbit};
use crate::identify::{Solution, SolveOptions};
use crate::measure::{BallPlate, PointProblem};
use crate::model::ParamId;
use crate::run::JobError;
use crate::util::Monitor;

/// Where the six base parameters are among the unknowns, if all six are identified.
fn base_columns(ids: &[ParamId]) -> Option<[usize; 6]> {
    let mut out = [usize::MAX; 6];
    for (k, id) in ids.iter().enumerate() {
        if let ParamId::Base(c) = id {
            out[*c as usize] = k;
        }
    }
    out.iter().all(|&k| k != usize::MAX).then_some(out)
}

/// The base frame (and the unknown ball centres) of `x` turned by `t` rad about the line
/// through `at` along `axis`; Euler angles kept within a half turn of their old values.
fn turned(
    x: &[f64],
    t: f64,
    base: [usize; 6],
    balls: &[usize],
    at: &Vector3<f64>,
    axis: &Vector3<f64>,
) -> Vec<f64> {
    let r = Frame::rot_axis(axis, t);
    let about = Frame::trans(at.x, at.y, at.z)
        .mul(&r)
        .mul(&Frame::trans(-at.x, -at.y, -at.z));
    let old: [f64; 6] = base.map(|k| x[k]);
    let new = about.mul(&Frame::from_xyzabc(&old)).to_xyzabc();
    let mut y = x.to_vec();
    for c in 0..6 {
        let mut v = new[c];
        if c >= 3 {
            let turn = std::f64::consts::TAU;
            v -= turn * ((v - old[c]) / turn).round();
        }
        y[base[c]] = v;
    }
    for &o in balls {
        let p = about.apply(&Vector3::new(x[o], x[o + 1], x[o + 2]));
        y[o..o + 3].copy_from_slice(p.as_slice());
    }
    y
}

/// Hold the plate's free rotation of the least-squares solution `sol` of `problem` (from
/// `x0`, unknowns `ids` then the plate's unknown balls), when the plate leaves one (two
/// balls) and the base frame is identified; `None` leaves `sol` as it is.
pub(crate) fn hold_plate_gauge(
    ids: &[ParamId],
    plate: &BallPlate,
    problem: &PointProblem,
    x0: &[f64],
    sol: &Solution,
    opts: &SolveOptions,
    monitor: &dyn Monitor,
) -> Result<Option<(Solution, HeldGauge)>, JobError> {
    let (Some(freedom), Some(base)) = (plate.gauge.as_ref(), base_columns(ids)) else {
        return Ok(None);
    };
    let (Some(Some(a)), Some(Some(b))) = (plate.centres.first(), plate.centres.get(1)) else {
        return Ok(None);
    };
    let Some(axis) = (b - a).try_normalize(0.0) else {
        return Ok(None);
    };
    let n = ids.len();
    let balls: Vec<usize> = (0..plate.unknown_balls().len())
        .map(|k| n + 3 * k)
        .collect();
    let map = |x: &[f64], t: f64| turned(x, t, base, &balls, a, &axis);
    let orbit = Orbit {
        freedom: freedom.clone(),
        map: &map,
        half_range: std::f64::consts::PI,
        unit: ("deg", 180.0 / std::f64::consts::PI),
    };
    let unknowns = problem.unknowns();
    let held = hold_orbit(problem, &unknowns, x0, sol, &orbit, opts, monitor)?;
    Ok(Some(held))
}
