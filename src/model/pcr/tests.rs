//! Tests that need the solver's internals: the integration accuracy at the rod tip.

use super::rod::{self, Rod};
use super::setup::Setup;
use super::{Load, PcrFile};

/// Richardson step halving on the rods of solved configurations across the joint box: the
/// RK4 error at the tip, estimated as |y_N - y_2N| * 16 / 15, is under 1 nm (and under
/// 1e-7 rad for the tangent), and the differences shrink 16-fold per halving, so the
/// estimate is in the asymptotic regime and can be trusted.
#[test]
fn rod_tip_integration_error_is_under_a_nanometre() {
    let text = std::fs::read_to_string("tests/data/robots/pcr3pf.json").expect("data");
    let robot = PcrFile::parse(&text).expect("file").robot().expect("robot");
    let steps = robot.options().steps;
    let l_ref = robot.l_ref();
    let v = [-0.0025, 0.0, 0.0025];
    let mut worst = (0.0_f64, 0.0_f64);
    for a in v {
        for b in v {
            for c in v {
                let q = [a, b, c];
                let eq = robot.fk(&q).expect("fk");
                let setup = Setup::new(robot.params(), &Load::default(), l_ref, steps);
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
                        };
                        rod::integrate(&[r], &[y0])[0]
                    };
                    let (t1, t2, t4) = (tip(steps), tip(2 * steps), tip(4 * steps));
                    let d12 = (t1[rod::X] - t2[rod::X]).hypot(t1[rod::Y] - t2[rod::Y]) * l_ref;
                    let d24 = (t2[rod::X] - t4[rod::X]).hypot(t2[rod::Y] - t4[rod::Y]) * l_ref;
                    let dphi = (t1[rod::PHI] - t2[rod::PHI]).abs();
                    worst = (
                        worst.0.max(d12 * 16.0 / 15.0),
                        worst.1.max(dphi * 16.0 / 15.0),
                    );
                    if d12 > 1e-12 {
                        let order = d12 / d24;
                        assert!(
                            (12.0..20.0).contains(&order),
                            "halving ratio {order} at {q:?}"
                        );
                    }
                }
            }
        }
    }
    assert!(worst.0 < 1e-9, "tip position error {:e} m", worst.0);
    assert!(worst.1 < 1e-7, "tip angle error {:e} rad", worst.1);
    println!(
        "worst RK4 tip error with {steps} steps: {:.3e} m, {:.3e} rad",
        worst.0, worst.1
    );
}

/// Models are shared across threads (identification workers, the daemon's pool).
#[test]
fn robots_and_solutions_are_send_and_sync() {
    fn check<T: Send + Sync>() {}
    check::<super::Pcr>();
    check::<super::Equilibrium>();
    check::<super::PcrFile>();
}
