use super::*;
use crate::twin::SerialTwin;
use crate::util::Rng;

/// Angle between two frames (rad), without the ~1e-8 rad floor of an acos.
fn angle(a: &Frame, b: &Frame) -> f64 {
    let r = a.r.transpose() * b.r;
    let v = nalgebra::Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    );
    (v.norm() * 0.5).atan2((r.trace() - 1.0) * 0.5)
}

fn tolerances() -> Tolerances {
    Tolerances {
        position: 1e-6,
        angle: 1e-9,
        singular_sin: 1e-3,
        singular_shoulder: 0.5,
    }
}

/// The twin's true robot (geometry, beta, compliance) as the calibrated model.
fn calibrated() -> (SerialTwin, Compensator) {
    let twin = SerialTwin::irb120(7);
    let c = Compensator::new(twin.truth.clone(), tolerances(), 5.0).expect("OPW structure");
    (twin, c)
}

#[test]
fn round_trip_reaches_every_target_on_the_branch_of_the_generating_joints() {
    let (twin, comp) = calibrated();
    assert!(
        comp.compliant,
        "the twin's truth has compliances and masses"
    );
    let mut rng = Rng::new(11);
    let mut s = Scratch::default();
    let (mut worst_p, mut worst_a, mut n) = (0.0f64, 0.0f64, 0);
    for _ in 0..1000 {
        let q: [f64; 6] = twin.random_q(&mut rng).try_into().unwrap();
        // Independent expectation: the model's own FK with deflection, computed by the chain.
        let tau = twin.truth.static_torques(&q);
        let target = twin.truth.tcp(&q, Some(&tau));
        let a = comp.solve(&target, &q, &mut s);
        if a.status == Status::Singular {
            continue;
        }
        assert_eq!(a.status, Status::Reached, "{q:?}: {}", a.reason);
        n += 1;
        // Re-evaluate the answer through the chain, not through the solver's residual.
        let tau = twin.truth.static_torques(&a.q);
        let f = twin.truth.tcp(&a.q, Some(&tau));
        worst_p = worst_p.max((f.p - target.p).norm());
        worst_a = worst_a.max(angle(&f, &target));
        for k in 0..6 {
            assert!(
                (a.q[k] - q[k]).abs() < 1e-6,
                "branch differs at q{}: {} vs {} deg",
                k + 1,
                a.q[k].to_degrees(),
                q[k].to_degrees()
            );
        }
    }
    assert!(n > 990, "only {n} of 1000 non-singular");
    assert!(worst_p < 1e-3, "worst position residual {worst_p} mm");
    assert!(worst_a < 1e-6, "worst angle residual {worst_a} rad");
}

#[test]
fn from_home_every_target_is_reached_on_some_branch_within_limits() {
    let (twin, comp) = calibrated();
    let mut rng = Rng::new(12);
    let mut s = Scratch::default();
    for _ in 0..300 {
        let q = twin.random_q(&mut rng);
        let tau = twin.truth.static_torques(&q);
        let target = twin.truth.tcp(&q, Some(&tau));
        let a = comp.solve(&target, &[0.0; 6], &mut s);
        if a.status == Status::Singular {
            continue;
        }
        assert_eq!(a.status, Status::Reached, "{}", a.reason);
        assert!(twin.truth.limit_violation(&a.q).is_none());
        let tau = twin.truth.static_torques(&a.q);
        let f = twin.truth.tcp(&a.q, Some(&tau));
        assert!((f.p - target.p).norm() < 1e-3 && angle(&f, &target) < 1e-6);
    }
}

#[test]
fn far_targets_are_out_of_reach_and_limits_are_reported_not_clamped() {
    let (twin, comp) = calibrated();
    let mut s = Scratch::default();
    let q = [0.3, 0.2, -0.4, 0.5, 0.9, -0.7];
    let tau = twin.truth.static_torques(&q);
    let target = twin.truth.tcp(&q, Some(&tau));
    let mut far = target;
    far.p.x += 3000.0;
    let a = comp.solve(&far, &q, &mut s);
    assert_eq!(a.status, Status::OutOfReach, "{}", a.reason);
    assert!(a.residual_position > 2000.0, "{}", a.residual_position);
    assert!(a.reason.contains("out of reach"), "{}", a.reason);

    // Joint 1's limits exclude q1 and q1 + 180 deg: every branch of the target is outside.
    let mut narrow = twin.truth.clone();
    narrow.joints[0].limits = Some([q[0] + 0.01, q[0] + 0.3]);
    let comp = Compensator::new(narrow, tolerances(), 5.0).unwrap();
    let a = comp.solve(&target, &q, &mut s);
    assert_eq!(a.status, Status::OutOfJointLimits, "{}", a.reason);
    assert!(a.reason.starts_with("q1 = "), "{}", a.reason);
    // Not clamped: the joints returned still reach the target, outside the limits.
    assert!(a.residual_position < 1e-6, "{}", a.residual_position);
    assert!((a.q[0] - q[0]).abs() < 1e-6);
}

#[test]
fn a_wrist_singular_target_is_flagged() {
    let (twin, comp) = calibrated();
    let mut s = Scratch::default();
    // theta5 = 0: q5 = -theta_offset5 (the true offset of the twin).
    let q = [0.2, 0.1, -0.2, 0.4, -twin.truth.joints[4].offset, 0.3];
    let tau = twin.truth.static_torques(&q);
    let target = twin.truth.tcp(&q, Some(&tau));
    let a = comp.solve(&target, &q, &mut s);
    assert_eq!(a.status, Status::Singular, "{}", a.reason);
    assert!(a.reason.contains("wrist"), "{}", a.reason);
}

#[test]
fn rotation_vector_matches_axis_angle() {
    let u = nalgebra::Vector3::new(1.0, -2.0, 0.5).normalize();
    for angle in [1e-7, 0.3, 2.0, 3.0, std::f64::consts::PI] {
        let r = Frame::rot_axis(&u, angle).r;
        let v = rotation_vector(&r);
        let back = Frame::rot_axis(&v.normalize(), v.norm()).r;
        assert!((back - r).norm() < 1e-8, "angle {angle}: {v:?}");
    }
}
