//! Tests that need the solver's internals: the accuracy of the reference integration and of
//! the fast kinematics against it.

use super::rod::{self, Rod};
use super::setup::Setup;
use super::{Integrator, Load, PcrFile, SolverOptions};

/// The robot of the test data solved with the reference integrator: 256 RK4 steps per rod.
fn reference(robot: &super::Pcr) -> super::Pcr {
    robot
        .with_options(SolverOptions {
            integrator: Integrator::Rk4,
            steps: REFERENCE_STEPS,
            jacobian_steps: 12,
            ..*robot.options()
        })
        .expect("reference robot")
}

const REFERENCE_STEPS: usize = 256;

fn robot() -> super::Pcr {
    let text = std::fs::read_to_string("tests/data/robots/pcr3pf.json").expect("data");
    PcrFile::parse(&text).expect("file").robot().expect("robot")
}

/// The joint box's 3 x 3 x 3 grid (corners are the largest deformations).
fn grid() -> Vec<[f64; 3]> {
    let v = [-0.0025, 0.0, 0.0025];
    let mut out = Vec::new();
    for a in v {
        for b in v {
            for c in v {
                out.push([a, b, c]);
            }
        }
    }
    out
}

/// Richardson step halving on the rods of solved configurations across the joint box: the
/// error of the 256-step RK4 reference at the tip, estimated as |y_128 - y_256| / 15, is
/// far under 1 nm, and the differences shrink 16-fold per halving, so the estimate is in the
/// asymptotic regime and the reference can be trusted.
/// Warm IK along the first `n` of 400 poses on a 1.5 mm circle, by `fast` and by `plain`:
/// the largest joint difference (m) and each one's total iterations.
fn ik_along_a_circle(fast: &super::Pcr, plain: &super::Pcr, n: usize) -> (f64, usize, usize) {
    let poses: Vec<crate::geometry::Pose2> = (0..n)
        .map(|k| {
            let t = std::f64::consts::TAU * k as f64 / 400.0;
            crate::geometry::Pose2::new(0.0015 * t.cos(), 0.0015 * t.sin(), 0.0)
        })
        .collect();
    let (mut a, mut b) = (
        fast.ik(&poses[0]).expect("ik"),
        plain.ik(&poses[0]).expect("ik"),
    );
    let (mut worst_q, mut its_fast, mut its_plain) = (0.0_f64, 0, 0);
    for p in &poses[1..] {
        a = fast.ik_from(&a, p).expect("fast path ik");
        b = plain.ik_from(&b, p).expect("plain path ik");
        its_fast += a.iterations;
        its_plain += b.iterations;
        worst_q = (0..3).fold(worst_q, |m, k| m.max((a.q[k] - b.q[k]).abs()));
    }
    (worst_q, its_fast, its_plain)
}

#[test]
fn reference_integration_error_is_far_under_a_nanometre() {
    let robot = reference(&robot());
    let l_ref = robot.l_ref();
    let mut worst = (0.0_f64, 0.0_f64);
    for q in grid() {
        let eq = robot.fk(&q).expect("fk");
        let setup = Setup::new(robot.params(), &Load::default(), l_ref, 1, Integrator::Rk4);
        for i in 0..3 {
            let l = &setup.limbs[i];
            let y0 = rod::start_state(
                l.a[0] + q[i] / l_ref * l.u[0],
                l.a[1] + q[i] / l_ref * l.u[1],
                l.phi0,
                eq.scaled[3 * i + 2],
            );
            let tip = |n: usize| {
                let r = Rod {
                    n: [eq.scaled[3 * i], eq.scaled[3 * i + 1]],
                    flex: l.flex,
                    length: l.length,
                    steps: n,
                    integrator: Integrator::Rk4,
                };
                super::shooting::integrate(&[r], &[y0])[0]
            };
            let s = REFERENCE_STEPS / 4;
            let (t1, t2, t4) = (tip(s), tip(2 * s), tip(4 * s));
            let d12 = (t1[rod::X] - t2[rod::X]).hypot(t1[rod::Y] - t2[rod::Y]) * l_ref;
            let d24 = (t2[rod::X] - t4[rod::X]).hypot(t2[rod::Y] - t4[rod::Y]) * l_ref;
            let dphi = (t2[rod::PHI] - t4[rod::PHI]).abs();
            worst = (worst.0.max(d24 / 15.0), worst.1.max(dphi / 15.0));
            if d12 > 1e-13 {
                let order = d12 / d24;
                assert!(
                    (12.0..20.0).contains(&order),
                    "halving ratio {order} at {q:?}"
                );
            }
        }
    }
    assert!(worst.0 < 1e-11, "reference tip error {:e} m", worst.0);
    assert!(
        worst.1 < 1e-10,
        "reference tip angle error {:e} rad",
        worst.1
    );
    println!(
        "RK4 reference ({REFERENCE_STEPS} steps) tip error: {:.3e} m, {:.3e} rad",
        worst.0, worst.1
    );
}

/// The fast forward kinematics (Taylor series, default options) equals the 256-step RK4
/// reference within 1 nm and 1e-7 rad across the joint box, unloaded and under a load, and
/// its inverse kinematics returns the joints.
#[test]
fn fast_kinematics_equal_the_rk4_reference() {
    let fast = robot();
    assert_eq!(fast.options().integrator, Integrator::Taylor);
    let load = Load {
        force: [0.002, -0.001],
        moment: 1e-5,
    };
    let mut worst = (0.0_f64, 0.0_f64, 0.0_f64);
    for robot in [fast.clone(), fast.with_load(load).expect("load")] {
        let slow = reference(&robot);
        let mut qs = grid();
        qs.extend([[0.0012, -0.0007, 0.0021], [-0.0019, 0.0023, 0.0004]]);
        for q in qs {
            let a = robot.fk(&q).expect("fast fk");
            let b = slow.fk(&q).expect("reference fk");
            let dp = (a.pose.x - b.pose.x).hypot(a.pose.y - b.pose.y);
            let dt = (a.pose.theta - b.pose.theta).abs();
            worst = (worst.0.max(dp), worst.1.max(dt), worst.2);
            // Inverse kinematics of the pose returns the joints (inside the limits: at a
            // limit, rounding may put the joint found a hair outside).
            if q.iter().all(|v| v.abs() < 0.0025) {
                let back = robot.ik(&a.pose).expect("ik");
                let dq = (0..3).fold(0.0_f64, |m, k| m.max((back.q[k] - q[k]).abs()));
                worst.2 = worst.2.max(dq);
            }
        }
    }
    println!(
        "fast vs reference FK: {:.3e} m, {:.3e} rad; IK round trip {:.3e} m",
        worst.0, worst.1, worst.2
    );
    assert!(worst.0 < 1e-9, "position differs by {:e} m", worst.0);
    assert!(worst.1 < 1e-7, "angle differs by {:e} rad", worst.1);
    assert!(worst.2 < 1e-10, "IK round trip off by {:e} m", worst.2);
}

/// The warm solves' shortcuts (solutions accepted on their predicted residual, Broyden
/// updates of the reused inverse) give the answers of the straightforward solve (every
/// solution integrated and checked, no updates) to the solver's tolerance, along a joint
/// path of 3 um steps and a circle of poses, and stay within 1 nm and 1e-7 rad of the
/// 256-step RK4 reference. The shortcuts are taken: fewer integrations in all.
#[test]
fn warm_shortcuts_equal_the_straightforward_solve() {
    let fast = robot();
    assert!(fast.options().accept_predicted && fast.options().broyden);
    let plain = fast
        .with_options(SolverOptions {
            accept_predicted: false,
            broyden: false,
            ..*fast.options()
        })
        .expect("plain robot");
    let slow = reference(&fast);
    let path: Vec<[f64; 3]> = (0..300)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 2000.0;
            [0.002 * a.cos(), 0.002 * a.sin(), 0.001 * (2.0 * a).sin()]
        })
        .collect();
    let (mut a, mut b) = (
        fast.fk(&path[0]).expect("fk"),
        plain.fk(&path[0]).expect("fk"),
    );
    let (mut worst, mut worst_ref) = ((0.0_f64, 0.0_f64), (0.0_f64, 0.0_f64));
    let (mut its_fast, mut its_plain) = (0, 0);
    for (k, q) in path.iter().enumerate().skip(1) {
        a = fast.fk_from(&a, q).expect("fast path fk");
        b = plain.fk_from(&b, q).expect("plain path fk");
        its_fast += a.iterations;
        its_plain += b.iterations;
        let dp = (a.pose.x - b.pose.x).hypot(a.pose.y - b.pose.y);
        worst = (
            worst.0.max(dp),
            worst.1.max((a.pose.theta - b.pose.theta).abs()),
        );
        if k % 60 == 0 {
            let r = slow.fk(q).expect("reference fk");
            let dp = (a.pose.x - r.pose.x).hypot(a.pose.y - r.pose.y);
            worst_ref = (
                worst_ref.0.max(dp),
                worst_ref.1.max((a.pose.theta - r.pose.theta).abs()),
            );
        }
    }
    let (worst_q, ik_fast, ik_plain) = ik_along_a_circle(&fast, &plain, 100);
    its_fast += ik_fast;
    its_plain += ik_plain;
    println!(
        "shortcuts vs plain: {:.3e} m, {:.3e} rad, IK {:.3e} m; vs reference {:.3e} m, {:.3e} rad; iterations {its_fast} vs {its_plain}",
        worst.0, worst.1, worst_q, worst_ref.0, worst_ref.1
    );
    assert!(worst.0 < 1e-11 && worst.1 < 1e-10, "FK differs: {worst:?}");
    assert!(worst_q < 1e-11, "IK differs by {worst_q:e} m");
    assert!(
        worst_ref.0 < 1e-9 && worst_ref.1 < 1e-7,
        "vs reference: {worst_ref:?}"
    );
    assert!(its_fast < its_plain, "{its_fast} vs {its_plain} iterations");
}

/// Models are shared across threads (identification workers, the daemon's pool).
#[test]
fn robots_and_solutions_are_send_and_sync() {
    fn check<T: Send + Sync>() {}
    check::<super::Pcr>();
    check::<super::Equilibrium>();
    check::<super::PcrFile>();
}

/// A warm solve (from the previous configuration's inverse Jacobian and distal states) finds
/// the equilibrium a cold solve from home finds, to the solver's tolerance: forward
/// kinematics along a joint path of 3 um steps and inverse kinematics along a circle.
#[test]
fn warm_solves_equal_cold_solves() {
    let robot = robot();
    let path: Vec<[f64; 3]> = (0..200)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 2000.0;
            [0.001 * a.cos(), 0.001 * a.sin(), 0.0005 * (2.0 * a).sin()]
        })
        .collect();
    let mut warm = robot.fk(&path[0]).expect("fk");
    let (mut worst_p, mut worst_t, mut compared) = (0.0_f64, 0.0_f64, 0);
    for (k, q) in path.iter().enumerate().skip(1) {
        warm = robot.fk_from(&warm, q).expect("warm fk");
        if k % 10 == 0 {
            let cold = robot.fk(q).expect("cold fk");
            worst_p = worst_p.max((warm.pose.x - cold.pose.x).hypot(warm.pose.y - cold.pose.y));
            worst_t = worst_t.max((warm.pose.theta - cold.pose.theta).abs());
            compared += 1;
        }
    }
    let poses: Vec<crate::geometry::Pose2> = (0..100)
        .map(|k| {
            let t = std::f64::consts::TAU * k as f64 / 400.0;
            crate::geometry::Pose2::new(0.0015 * t.cos(), 0.0015 * t.sin(), 0.0)
        })
        .collect();
    let mut warm = robot.ik(&poses[0]).expect("ik");
    let mut worst_q = 0.0_f64;
    for (k, p) in poses.iter().enumerate().skip(1) {
        warm = robot.ik_from(&warm, p).expect("warm ik");
        if k % 10 == 0 {
            let cold = robot.ik(p).expect("cold ik");
            worst_q = (0..3).fold(worst_q, |m, j| m.max((warm.q[j] - cold.q[j]).abs()));
            compared += 1;
        }
    }
    println!("warm vs cold: FK {worst_p:.3e} m, {worst_t:.3e} rad; IK {worst_q:.3e} m");
    assert_eq!(compared, 19 + 9);
    // Residuals within 1e-12 m and 1e-12 rad leave the solution within about 10x that.
    assert!(
        worst_p < 1e-11 && worst_t < 1e-10,
        "FK: {worst_p:e} m, {worst_t:e} rad"
    );
    assert!(worst_q < 1e-11, "IK: {worst_q:e} m");
}

/// The trail's prediction is exact for unknowns quintic in the distance along a straight
/// path of inputs (uneven steps), and there is none off a smooth path, after a much longer
/// or shorter step, or with fewer than six solutions.
#[test]
fn trail_extrapolates_quintics_exactly_and_only_along_a_path() {
    use super::trail::Trail;
    let dir = [0.6, -0.48, 0.64];
    let at = |s: f64| dir.map(|d| 1e-3 + d * s);
    // Distances in units of 1e-4 keep the polynomial's terms comparable.
    let z = |s: f64| -> [f64; 12] {
        let u = s * 1e4;
        std::array::from_fn(|k| {
            let c = k as f64;
            0.3 - 0.1 * c + (c - 5.0) * 1e-2 * u + 7e-3 * (k % 3) as f64 * u * u
                - 2e-3 * (c - 6.0) * u.powi(3)
                + 3e-4 * (k % 4) as f64 * u.powi(4)
                - 1e-5 * (c + 1.0) * u.powi(5)
        })
    };
    let mut trail = Trail::EMPTY;
    let known = [0.0, 1e-4, 2.5e-4, 3.7e-4, 5.2e-4, 6.4e-4];
    for s in known {
        assert_eq!(trail.predict(&at(s)), None, "fewer than six solutions");
        trail.push(at(s), z(s));
    }
    let s = 7.9e-4;
    let p = trail.predict(&at(s)).expect("on the path");
    let worst = (0..12).fold(0.0_f64, |m, k| m.max((p[k] - z(s)[k]).abs()));
    assert!(worst < 1e-10, "quintic extrapolated with error {worst:e}");
    // A degree more is not reproduced: the prediction does extrapolate, it does not look up.
    let z6 = |s: f64| z(s).map(|v| v + (s * 1e4).powi(6) * 1e-4);
    let mut sextic = Trail::EMPTY;
    for s in known {
        sextic.push(at(s), z6(s));
    }
    let p6 = sextic.predict(&at(s)).expect("on the path");
    assert!((p6[0] - z6(s)[0]).abs() > 1e-3, "a sextic term is missed");
    // Off the path: the step turned by 90 degrees.
    let (base, side) = (at(6.4e-4), [0.625, 0.78125, 0.0]);
    let off: [f64; 3] = std::array::from_fn(|k| base[k] + 1.2e-4 * side[k]);
    assert_eq!(trail.predict(&off), None, "off the path");
    assert_eq!(
        trail.predict(&at(6.4e-4 + 3e-4)),
        None,
        "a step 2.5 times the last"
    );
    assert_eq!(
        trail.predict(&at(6.4e-4 + 0.4e-4)),
        None,
        "a step a third of the last"
    );
    // Only the newest six count.
    let mut newer = trail;
    newer.push(at(s), z(s));
    let q = newer.predict(&at(9.1e-4)).expect("on the path");
    let worst = (0..12).fold(0.0_f64, |m, k| m.max((q[k] - z(9.1e-4)[k]).abs()));
    assert!(worst < 1e-10, "after a seventh solution: {worst:e}");
}

/// Warm solves started from the trail's prediction give the answers of warm solves without
/// it to the solver's tolerance, along the 3 um joint path and the circle of poses of the
/// benchmark, in fewer Newton iterations.
#[test]
fn predicted_warm_solves_equal_unpredicted_ones() {
    let fast = robot();
    assert!(fast.options().predict);
    let plain = fast
        .with_options(SolverOptions {
            predict: false,
            ..*fast.options()
        })
        .expect("plain robot");
    let path: Vec<[f64; 3]> = (0..400)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 2000.0;
            [0.001 * a.cos(), 0.001 * a.sin(), 0.0005 * (2.0 * a).sin()]
        })
        .collect();
    let (mut a, mut b) = (
        fast.fk(&path[0]).expect("fk"),
        plain.fk(&path[0]).expect("fk"),
    );
    let (mut worst_p, mut worst_t) = (0.0_f64, 0.0_f64);
    let (mut its_fk, mut its_fk_plain) = (0, 0);
    for q in &path[1..] {
        a = fast.fk_from(&a, q).expect("predicted fk");
        b = plain.fk_from(&b, q).expect("plain fk");
        its_fk += a.iterations;
        its_fk_plain += b.iterations;
        worst_p = worst_p.max((a.pose.x - b.pose.x).hypot(a.pose.y - b.pose.y));
        worst_t = worst_t.max((a.pose.theta - b.pose.theta).abs());
    }
    let (worst_q, its_ik, its_ik_plain) = ik_along_a_circle(&fast, &plain, 400);
    println!(
        "predicted vs plain: FK {worst_p:.3e} m, {worst_t:.3e} rad, {its_fk} vs {its_fk_plain} iterations; IK {worst_q:.3e} m, {its_ik} vs {its_ik_plain} iterations"
    );
    assert!(
        worst_p < 1e-11 && worst_t < 1e-10,
        "FK: {worst_p:e} m, {worst_t:e} rad"
    );
    assert!(worst_q < 1e-11, "IK: {worst_q:e} m");
    assert!(
        its_fk < its_fk_plain,
        "FK: {its_fk} vs {its_fk_plain} iterations"
    );
    assert!(
        its_ik < its_ik_plain,
        "IK: {its_ik} vs {its_ik_plain} iterations"
    );
}
