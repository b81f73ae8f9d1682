use nalgebra::{DMatrix, DVector};

use super::*;
use crate::identify::{LmOptions, Restricted, levenberg_marquardt};
use crate::twin::SerialTwin;
use crate::util::NoMonitor;

/// The IRB 120 twin's ball-centring problem with a fourth ball of unknown centre (tied to
/// ball 1 by a distance), on which every fifth measurement is taken.
fn problem() -> PointProblem {
    let twin = SerialTwin::irb120(1);
    let mut plate = twin.plate.clone();
    plate.centres.push(None);
    plate.distances.push((0, 3, 150.0));
    let mut meas = twin.centring(8, 3);
    for m in meas.iter_mut().step_by(5) {
        m.target = Target::Ball(3);
    }
    let ids: Vec<_> = twin
        .file
        .identify
        .iter()
        .filter_map(|n| twin.nominal.param_by_name(n).ok())
        .collect();
    PointProblem::new(twin.nominal.clone(), ids, plate, meas).expect("consistent")
}

/// The start moved by `step` (relative) in every unknown, so that frames and centres are
/// not at their nominal values.
fn moved(x0: &[f64], step: f64) -> Vec<f64> {
    x0.iter()
        .enumerate()
        .map(|(k, v)| v + step * (1.0 + v.abs()) * ((k % 5) as f64 - 2.0))
        .collect()
}

#[test]
fn frames_fit_equals_the_restricted_problem() {
    let p = problem();
    let x0 = moved(&p.initial(), 1e-3);
    let free = p.nuisance();
    // Frame parameters, then the three coordinates of the unknown ball.
    let nid = p.ids.len();
    assert!(free.len() > 3 && free[..free.len() - 3].iter().all(|&k| k < nid));
    assert_eq!(free[free.len() - 3..], [nid, nid + 1, nid + 2]);
    let fit = p.held(&x0, &free).expect("frames and centres only");
    let restricted = Restricted::new(&p, x0.clone(), free.clone());
    let xs: Vec<f64> = moved(&free.iter().map(|&k| x0[k]).collect::<Vec<_>>(), 2e-3);
    let n = p.residual_count();
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    fit.residuals(&xs, &mut a).unwrap();
    restricted.residuals(&xs, &mut b).unwrap();
    // The same frame products: equal bit for bit.
    assert_eq!(a, b);
    let (mut ja, mut jb) = (DMatrix::zeros(n, free.len()), DMatrix::zeros(n, free.len()));
    fit.jacobian(&xs, &mut ja).unwrap();
    restricted.jacobian(&xs, &mut jb).unwrap();
    for c in 0..free.len() {
        let size = jb.column(c).amax();
        assert!(size > 0.0, "column {c}");
        let diff = (ja.column(c) - jb.column(c)).amax();
        assert!(diff <= 1e-12 * size, "column {c}: {diff:e} of {size:e}");
    }
    // The distance row moves with the free ball only.
    assert!(ja.row(n - 1).iter().filter(|v| **v != 0.0).count() == 3);
}

#[test]
fn frames_fit_reaches_the_same_cost() {
    let p = problem();
    let x0 = moved(&p.initial(), 1e-3);
    let free = p.nuisance();
    let xs0: Vec<f64> = free.iter().map(|&k| x0[k]).collect();
    let fit = p.held(&x0, &free).expect("frames and centres only");
    let restricted = Restricted::new(&p, x0.clone(), free.clone());
    let o = LmOptions::default();
    let a = levenberg_marquardt(fit.as_ref(), &xs0, &o, &NoMonitor).unwrap();
    let b = levenberg_marquardt(&restricted, &xs0, &o, &NoMonitor).unwrap();
    assert!(a.stop.converged() && b.stop.converged());
    assert!(
        a.cost < 0.5 * a.initial_cost,
        "{} {}",
        a.cost,
        a.initial_cost
    );
    let rel = (a.cost - b.cost).abs() / b.cost;
    assert!(rel < 1e-9, "{} vs {} ({rel:e})", a.cost, b.cost);
    let dx = DVector::from_vec(a.x.clone()) - DVector::from_vec(b.x.clone());
    assert!(dx.amax() < 1e-6, "{dx}");
}

#[test]
fn a_free_joint_parameter_has_no_cheap_form() {
    let p = problem();
    let x0 = p.initial();
    let mut free = p.nuisance();
    let joint = (0..p.ids.len())
        .find(|k| !free.contains(k))
        .expect("a joint parameter");
    free.push(joint);
    assert!(p.held(&x0, &free).is_none());
    assert!(p.held(&x0, &[]).is_some());
}
