//! The 3-PF Kirchhoff-rod model against independent expectations: an independent
//! high-accuracy solver, round trips, invariances, the pinwheel's symmetry, the Euler
//! buckling load, finite differences, and bad inputs.

use calibd::geometry::Pose2;
use calibd::model::ModelError;
use calibd::model::pcr::{Load, Pcr, PcrError, PcrFile, PcrParams, ROBOT_PARAMS, param_name};

fn nominal_file() -> PcrFile {
    let text = std::fs::read_to_string("tests/data/robots/pcr3pf.json").expect("test data");
    PcrFile::parse(&text).expect("nominal model parses")
}

fn nominal() -> Pcr {
    nominal_file().robot().expect("nominal robot")
}

/// Corners, edge midpoints and centre of the joint box.
fn box_grid() -> Vec<[f64; 3]> {
    let v = [-0.0025, 0.0, 0.0025];
    let mut out = vec![];
    for a in v {
        for b in v {
            for c in v {
                out.push([a, b, c]);
            }
        }
    }
    out
}

/// An independent solver: angle-form rod equations in SI units, the RK 3/8 rule with 2000
/// steps (error below 1e-13 m here), and Newton with a central-difference Jacobian.
mod independent {
    use calibd::model::pcr::PcrParams;

    fn rod_tip(p: &PcrParams, i: usize, q: f64, w: [f64; 3]) -> [f64; 4] {
        let l = &p.limbs[i];
        let ei = p.e * std::f64::consts::PI * l.d.powi(4) / 64.0;
        let f = |s: &[f64; 4]| -> [f64; 4] {
            let (sn, cs) = s[2].sin_cos();
            [cs, sn, s[3] / ei, w[0] * sn - w[1] * cs]
        };
        let n = 2000;
        let h = l.l / n as f64;
        let mut s = [
            l.ax + q * l.gamma.cos(),
            l.ay + q * l.gamma.sin(),
            l.gamma + l.alpha,
            w[2],
        ];
        let add = |s: &[f64; 4], parts: &[(f64, [f64; 4])]| -> [f64; 4] {
            let mut o = *s;
            for (c, k) in parts {
                for j in 0..4 {
                    o[j] += c * k[j];
                }
            }
            o
        };
        for _ in 0..n {
            let k1 = f(&s);
            let k2 = f(&add(&s, &[(h / 3.0, k1)]));
            let k3 = f(&add(&s, &[(-h / 3.0, k1), (h, k2)]));
            let k4 = f(&add(&s, &[(h, k1), (-h, k2), (h, k3)]));
            s = add(
                &s,
                &[
                    (h / 8.0, k1),
                    (3.0 * h / 8.0, k2),
                    (3.0 * h / 8.0, k3),
                    (h / 8.0, k4),
                ],
            );
        }
        s
    }

    /// Residual in SI units with unknowns (wrenches, pose); rows scaled to O(1).
    fn residual(p: &PcrParams, q: &[f64; 3], u: &[f64; 12]) -> [f64; 12] {
        let (x, y, th) = (u[9], u[10], u[11]);
        let (s, c) = th.sin_cos();
        let mut r = [0.0; 12];
        for i in 0..3 {
            let l = &p.limbs[i];
            let w = [u[3 * i], u[3 * i + 1], u[3 * i + 2]];
            let tip = rod_tip(p, i, q[i], w);
            let rb = [c * l.bx - s * l.by, s * l.bx + c * l.by];
            r[3 * i] = (tip[0] - x - rb[0]) / 0.03;
            r[3 * i + 1] = (tip[1] - y - rb[1]) / 0.03;
            let mut d = tip[2] - th - l.beta;
            d -= (d / std::f64::consts::TAU).round() * std::f64::consts::TAU;
            r[3 * i + 2] = d;
            r[9] += w[0] * 1e3;
            r[10] += w[1] * 1e3;
            r[11] += (rb[0] * w[1] - rb[1] * w[0] + tip[3]) * 3e4;
        }
        r
    }

    fn solve_linear(mut a: [[f64; 12]; 12], mut b: [f64; 12]) -> [f64; 12] {
        for k in 0..12 {
            let p = (k..12)
                .max_by(|&i, &j| a[i][k].abs().total_cmp(&a[j][k].abs()))
                .unwrap_or(k);
            a.swap(k, p);
            b.swap(k, p);
            for i in k + 1..12 {
                let f = a[i][k] / a[k][k];
                for j in k..12 {
                    a[i][j] -= f * a[k][j];
                }
                b[i] -= f * b[k];
            }
        }
        let mut x = [0.0; 12];
        for i in (0..12).rev() {
            let s: f64 = (i + 1..12).map(|j| a[i][j] * x[j]).sum();
            x[i] = (b[i] - s) / a[i][i];
        }
        x
    }

    /// Solves from a start; returns the unknowns (wrenches in N and N*m, pose) and the
    /// largest final residual.
    pub(super) fn fk(p: &PcrParams, q: &[f64; 3], start: [f64; 12]) -> ([f64; 12], f64) {
        let mut u = start;
        let scale = |k: usize| {
            if k >= 9 {
                1e-6
            } else if k % 3 == 2 {
                1e-9
            } else {
                1e-7
            }
        };
        for _ in 0..4 {
            let r = residual(p, q, &u);
            let mut jac = [[0.0; 12]; 12];
            for k in 0..12 {
                let h = scale(k);
                let (mut up, mut um) = (u, u);
                up[k] += h;
                um[k] -= h;
                let (rp, rm) = (residual(p, q, &up), residual(p, q, &um));
                for i in 0..12 {
                    jac[i][k] = (rp[i] - rm[i]) / (2.0 * h);
                }
            }
            let dz = solve_linear(jac, r.map(|v| -v));
            for k in 0..12 {
                u[k] += dz[k];
            }
        }
        let r = residual(p, q, &u);
        (u, r.iter().fold(0.0, |m, v| m.max(v.abs())))
    }
}

#[test]
fn fk_agrees_with_an_independent_high_accuracy_solver() {
    let robot = nominal();
    let p = *robot.params();
    let mut worst = (0.0_f64, 0.0_f64);
    // The corners of the joint box (the largest deformations) and an inner point.
    let mut grid: Vec<[f64; 3]> = box_grid()
        .into_iter()
        .filter(|q| q.iter().all(|v| *v != 0.0))
        .collect();
    grid.push([0.0012, -0.0007, 0.0021]);
    for q in grid {
        let eq = robot.fk(&q).expect("fk in the joint box");
        // Start the independent solver a few percent away from our answer.
        let mut start = [0.0; 12];
        for i in 0..3 {
            for k in 0..3 {
                start[3 * i + k] = eq.wrenches[i][k] * 1.03;
            }
        }
        start[9..].copy_from_slice(&[eq.pose.x + 2e-5, eq.pose.y - 1e-5, eq.pose.theta + 1e-3]);
        let (u, res) = independent::fk(&p, &q, start);
        assert!(
            res < 1e-12,
            "independent solver did not converge at {q:?}: {res:e}"
        );
        let dp = (u[9] - eq.pose.x).hypot(u[10] - eq.pose.y);
        let dt = (u[11] - eq.pose.theta).abs();
        worst = (worst.0.max(dp), worst.1.max(dt));
    }
    assert!(worst.0 < 1e-9, "position differs by {:e} m", worst.0);
    assert!(worst.1 < 1e-7, "angle differs by {:e} rad", worst.1);
}

#[test]
fn ik_then_fk_returns_the_pose() {
    let robot = nominal();
    let poses = [
        Pose2::new(0.0, 0.0, 0.0),
        Pose2::new(0.001, 0.0, 0.0),
        Pose2::new(-0.0007, 0.0012, 0.0),
        Pose2::new(0.0015, 0.0015, 0.0),
        Pose2::new(0.0003, -0.0011, 0.05),
        Pose2::new(0.0, 0.0, -0.12),
    ];
    for x in poses {
        let ik = robot.ik(&x).expect("reachable pose");
        let fk = robot.fk(&ik.q).expect("fk of ik joints");
        let err = (fk.pose.x - x.x).hypot(fk.pose.y - x.y);
        assert!(err < 1e-10, "{x:?}: position error {err:e} m");
        assert!(
            (fk.pose.theta - x.theta).abs() < 1e-10,
            "{x:?}: angle error"
        );
        // The wrenches agree too: the same equilibrium.
        for i in 0..3 {
            for k in 0..3 {
                let (a, b) = (ik.wrenches[i][k], fk.wrenches[i][k]);
                assert!(
                    (a - b).abs() < 1e-9 * (1.0 + a.abs()) * 1e3,
                    "wrench {i} {k}: {a} {b}"
                );
            }
        }
    }
}

#[test]
fn kinematics_do_not_depend_on_e_without_load_and_scale_with_e_under_load() {
    let file = nominal_file();
    let robot = nominal();
    let mut stiff = file.params();
    stiff.e *= 3.7;
    let stiff_robot = robot.with_params(stiff).expect("valid");
    let q = [0.002, -0.001, 0.0015];
    let (a, b) = (robot.fk(&q).expect("fk"), stiff_robot.fk(&q).expect("fk"));
    assert_eq!(
        a.pose, b.pose,
        "no load: the pose is independent of E bit for bit"
    );
    for i in 0..3 {
        for k in 0..3 {
            let ratio = b.wrenches[i][k] / a.wrenches[i][k];
            assert!((ratio - 3.7).abs() < 1e-9, "wrenches scale with E: {ratio}");
        }
    }
    // Under load, scaling E and the load together leaves the pose unchanged.
    let load = Load {
        force: [0.004, -0.002],
        moment: 1e-5,
    };
    let scaled = Load {
        force: [0.004 * 3.7, -0.002 * 3.7],
        moment: 3.7e-5,
    };
    let la = robot
        .with_load(load)
        .and_then(|r| r.fk(&q))
        .expect("loaded fk");
    let lb = stiff_robot
        .with_load(scaled)
        .and_then(|r| r.fk(&q))
        .expect("loaded fk");
    let moved = (la.pose.x - a.pose.x).hypot(la.pose.y - a.pose.y);
    assert!(moved > 1e-7, "the load moves the platform ({moved:e} m)");
    assert!((la.pose.x - lb.pose.x).abs() < 1e-13 && (la.pose.y - lb.pose.y).abs() < 1e-13);
    assert!((la.pose.theta - lb.pose.theta).abs() < 1e-12);
}

#[test]
fn equal_stage_motions_rotate_the_pinwheel_without_translating_it() {
    let robot = nominal();
    let r = 0.01; // rods tangent to a 10 mm circle
    for q in [1e-5, 5e-4, -0.002] {
        let eq = robot.fk(&[q, q, q]).expect("fk");
        // First order: the rods are inextensible, so B_i moves along rod i by q, tangent to
        // the circle: theta = q / r (counter-clockwise for q > 0), no translation.
        let first_order = q / r;
        assert!(
            eq.pose.x.abs() < 1e-12 && eq.pose.y.abs() < 1e-12,
            "translation {:?}",
            eq.pose
        );
        if q.abs() < 1e-4 {
            assert!(
                (eq.pose.theta - first_order).abs() < 1e-3 * first_order.abs(),
                "{eq:?}"
            );
        }
    }
    // Three-fold symmetry: permuting the stages rotates the whole answer by 120 degrees.
    let q = [0.0021, -0.0004, 0.0013];
    let a = robot.fk(&q).expect("fk");
    let b = robot.fk(&[q[2], q[0], q[1]]).expect("fk");
    let (s, c) = (std::f64::consts::TAU / 3.0).sin_cos();
    let (rx, ry) = (c * a.pose.x - s * a.pose.y, s * a.pose.x + c * a.pose.y);
    assert!(
        (rx - b.pose.x).abs() < 1e-10 && (ry - b.pose.y).abs() < 1e-10,
        "{a:?} {b:?}"
    );
    assert!((a.pose.theta - b.pose.theta).abs() < 1e-9);
}

#[test]
fn pose_jacobian_matches_finite_differences() {
    // Tight tolerances keep the finite differences' noise (solution error / h) small.
    let tight = calibd::model::pcr::SolverOptions {
        tolerance_position: 1e-14,
        tolerance_angle: 1e-14,
        ..*nominal().options()
    };
    let robot = nominal()
        .with_options(tight)
        .and_then(|r| {
            r.with_load(Load {
                force: [0.003, 0.001],
                moment: -2e-5,
            })
        })
        .expect("load");
    let q = [0.0015, -0.002, 0.0005];
    let eq = robot.fk(&q).expect("fk");
    let jac = robot.pose_jacobian(&eq).expect("jacobian");
    let p0 = *robot.params();
    for k in 0..ROBOT_PARAMS {
        let h = match k {
            27 => 1e8,
            _ if matches!(k % 9, 2 | 3 | 6) => 1e-5,
            _ if k % 9 == 8 => 1e-9,
            _ => 1e-7,
        };
        let solve = |sign: f64| {
            let mut p: PcrParams = p0;
            p.set(k, p0.get(k) + sign * h);
            let r = robot.with_params(p).expect("valid");
            let e = r.fk_from(&eq, &q).expect("fk");
            [e.pose.x, e.pose.y, e.pose.theta]
        };
        let (a, b) = (solve(1.0), solve(-1.0));
        // Scale of the column: positions in m, the angle through a 10 mm lever.
        let scale = jac[0][k]
            .abs()
            .max(jac[1][k].abs())
            .max(0.01 * jac[2][k].abs());
        assert!(scale > 0.0, "{} has no influence", param_name(k));
        for c in 0..3 {
            let fd = (a[c] - b[c]) / (2.0 * h);
            let an = jac[c][k];
            let tol = 1e-4 * scale * if c == 2 { 100.0 } else { 1.0 };
            assert!(
                (fd - an).abs() < tol,
                "{} row {c}: fd {fd:e} analytic {an:e}",
                param_name(k)
            );
        }
    }
}

#[test]
fn buckling_under_a_platform_moment_is_reported_not_solved() {
    // At q = 0 the rods are straight and tangent to the 10 mm circle; a moment mz loads each
    // inextensible rod axially with mz / (3 r), and the platform cannot move to first
    // order, so the rods buckle as clamped-clamped columns at 4 pi^2 E I / l^2.
    let robot = nominal();
    let p = robot.params();
    let ei = p.e * std::f64::consts::PI * p.limbs[0].d.powi(4) / 64.0;
    let critical = 3.0 * 0.01 * 4.0 * std::f64::consts::PI.powi(2) * ei / p.limbs[0].l.powi(2);
    let below = robot.with_load(Load {
        force: [0.0, 0.0],
        moment: -0.97 * critical,
    });
    assert!(below.is_ok(), "below the buckling load: {below:?}");
    let above = robot.with_load(Load {
        force: [0.0, 0.0],
        moment: -1.03 * critical,
    });
    assert!(
        matches!(above, Err(PcrError::BranchJump { .. })),
        "above: {above:?}"
    );
    // In tension nothing buckles.
    assert!(
        robot
            .with_load(Load {
                force: [0.0, 0.0],
                moment: 1.5 * critical
            })
            .is_ok()
    );
}

#[test]
fn a_jump_between_neighbouring_configurations_is_reported() {
    let robot = nominal();
    let near = robot.fk(&[0.0010, 0.0, 0.0]).expect("fk");
    // Without subdivision, and with at most 0.3 mm of motion per step, a target 3 mm away
    // is a sudden large change: refused.
    let opts = calibd::model::pcr::SolverOptions {
        min_fraction: 1.0,
        max_step: 0.01,
        ..*robot.options()
    };
    let strict = robot.with_options(opts).expect("options");
    let far = strict.fk_from(&near, &[-0.0025, 0.0025, -0.0025]);
    assert!(matches!(far, Err(PcrError::BranchJump { .. })), "{far:?}");
    // A neighbouring configuration is fine, and equals the continuation answer.
    let next = strict
        .fk_from(&near, &[0.00101, 0.0, 0.0])
        .expect("neighbour");
    let cold = robot.fk(&[0.00101, 0.0, 0.0]).expect("cold");
    assert!(
        (next.pose.x - cold.pose.x).abs() < 1e-12
            && (next.pose.theta - cold.pose.theta).abs() < 1e-12
    );
    // With too small an iteration budget the solver says it did not converge.
    let starved = robot.with_options(calibd::model::pcr::SolverOptions {
        max_iterations: 1,
        ..*robot.options()
    });
    let starved = starved.and_then(|r| r.fk(&[0.002, 0.002, -0.002]));
    assert!(
        matches!(starved, Err(PcrError::NotConverged { .. })),
        "{starved:?}"
    );
}

#[test]
fn bad_inputs_get_clear_errors() {
    let robot = nominal();
    let e = robot
        .fk(&[0.0, 0.003, 0.0])
        .expect_err("outside the limits");
    assert!(
        matches!(e, PcrError::JointOutOfLimits { joint: 2, .. }),
        "{e}"
    );
    assert!(e.to_string().contains("q2 = 0.003"), "{e}");
    let e = robot.fk(&[f64::NAN, 0.0, 0.0]).expect_err("NaN");
    assert!(
        matches!(e, PcrError::NotFinite { .. }) && e.to_string().contains("q1"),
        "{e}"
    );
    let e = robot
        .ik(&Pose2::new(0.0, 0.045, 0.0))
        .expect_err("too far for the rods");
    assert!(matches!(e, PcrError::Unreachable { .. }), "{e}");
    let e = robot
        .ik(&Pose2::new(0.0045, 0.0, 0.0))
        .expect_err("needs stages beyond limits");
    assert!(
        matches!(e, PcrError::Unreachable { .. }) && e.to_string().contains("outside"),
        "{e}"
    );
    let e = robot
        .ik(&Pose2::new(0.0, f64::INFINITY, 0.0))
        .expect_err("inf");
    assert!(matches!(e, PcrError::NotFinite { .. }), "{e}");
    let mut p = *robot.params();
    p.limbs[1].l = -0.03;
    let e = robot.with_params(p).expect_err("negative length");
    assert!(e.to_string().contains("l_2"), "{e}");
}

#[test]
fn model_files_are_checked_field_by_field() {
    let text = std::fs::read_to_string("tests/data/robots/pcr3pf.json").expect("data");
    let bad = text.replacen("\"alpha\": 0.0,", "\"alpha\": 0.0, \"alfa\": 1.0,", 1);
    let e = PcrFile::parse(&bad).expect_err("unknown field");
    assert!(
        e.to_string().contains("alfa") && e.to_string().contains("limbs[0]"),
        "{e}"
    );
    let bad = text.replacen("\"d\": 0.000125", "\"d\": -0.000125", 1);
    let e = PcrFile::parse(&bad).expect_err("negative diameter");
    assert!(
        matches!(&e, ModelError::Field { field, .. } if field == "limbs[0].d"),
        "{e}"
    );
    let bad = text.replacen("\"length\": \"m\"", "\"length\": \"mm\"", 1);
    let e = PcrFile::parse(&bad).expect_err("units");
    assert!(e.to_string().contains("units.length"), "{e}");
    let value: serde_json::Value = serde_json::from_str(&text).expect("json");
    let file = PcrFile::from_value(value).expect("inline model");
    let round = PcrFile::parse(&serde_json::to_string(&file).expect("serialise")).expect("parse");
    assert_eq!(round, file);
}
