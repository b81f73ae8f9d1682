//! `calibd bench pcr`: the 3-PF shooting model and its identification on the twin: forward
//! kinematics per configuration warm-started along a joint path and cold from home, inverse
//! kinematics per pose (warm along a path and cold), the pose Jacobian with respect to the
//! 28 parameters, and the full three-step identification on 99 poses.

use std::time::Duration;

use super::{Figure, time};
use crate::design::poisson_disc_n;
use crate::design::trajectory::circle;
use crate::geometry::Pose2;
use crate::measure::pcr::{CalibrationOptions, identify_steps};
use crate::twin::PcrTwin;
use crate::util::NoMonitor;

/// Run the 3-PF benchmarks.
pub fn run() -> Vec<Figure> {
    let twin = PcrTwin::nominal(3).expect("the embedded 3-PF model is valid");
    let robot = twin.file.robot().expect("the nominal robot solves");
    let mut sink = 0.0;
    let mut figs = Vec::new();
    // A closed joint path of 2,000 configurations 3 um apart.
    let n = 2000;
    let path: Vec<[f64; 3]> = (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            [0.001 * a.cos(), 0.001 * a.sin(), 0.0005 * (2.0 * a).sin()]
        })
        .collect();
    let start = robot.fk(&path[0]).expect("fk");
    figs.push(time(
        "FK per configuration, warm along a path (steps of 3 um)",
        9,
        n,
        Some(Duration::from_micros(2)),
        || {
            let mut e = start.clone();
            for q in &path {
                e = robot.fk_from(&e, q).expect("path fk");
                sink += e.pose.x;
            }
        },
    ));
    let lim = twin.file.limits();
    let (lo, hi) = (
        [lim[0][0], lim[1][0], lim[2][0]],
        [lim[0][1], lim[1][1], lim[2][1]],
    );
    let (scattered, _) = poisson_disc_n(lo, hi, 99, 1).expect("sampling");
    figs.push(time(
        "FK per configuration, warm from a scattered neighbour (99 Poisson-disc)",
        9,
        scattered.len(),
        None,
        || {
            let mut e = start.clone();
            for q in &scattered {
                e = robot.fk_from(&e, q).expect("fk");
                sink += e.pose.x;
            }
        },
    ));
    figs.push(time(
        "FK per configuration, cold from home (99 Poisson-disc)",
        9,
        scattered.len(),
        None,
        || {
            for q in &scattered {
                sink += robot.fk(q).expect("cold fk").pose.x;
            }
        },
    ));
    let poses = circle(&Pose2::default(), 0.003, 400);
    let ik0 = robot.ik(&poses[0]).expect("ik");
    figs.push(time(
        "IK per pose, warm along a 3 mm circle (400 poses)",
        9,
        poses.len(),
        Some(Duration::from_micros(3)),
        || {
            let mut e = ik0.clone();
            for p in &poses {
                e = robot.ik_from(&e, p).expect("path ik");
                sink += e.q[0];
            }
        },
    ));
    let few: Vec<Pose2> = poses.iter().step_by(25).copied().collect();
    figs.push(time(
        "IK per pose, cold from home (16 poses on a 3 mm circle)",
        9,
        few.len(),
        None,
        || {
            for p in &few {
                sink += robot.ik(p).expect("cold ik").q[0];
            }
        },
    ));
    let sols: Vec<_> = scattered.iter().map(|q| robot.fk(q).expect("fk")).collect();
    figs.push(time(
        "pose Jacobian w.r.t. 28 parameters (implicit function theorem)",
        9,
        sols.len(),
        None,
        || {
            for s in &sols {
                sink += robot.pose_jacobian(s).expect("jacobian")[0][0];
            }
        },
    ));
    let cal = twin.measure(&scattered, 10).expect("twin readings");
    for (name, threads, target) in [
        (
            "3-step identification, 34 unknowns, 99 poses (all cores)",
            None,
            Some(Duration::from_millis(100)),
        ),
        (
            "3-step identification, 34 unknowns, 99 poses (one thread)",
            Some(1),
            None,
        ),
    ] {
        let opts = CalibrationOptions {
            threads,
            ..Default::default()
        };
        figs.push(time(name, 5, 1, target, || {
            let c = identify_steps(&robot, &twin.file, &cal, None, &opts, &NoMonitor)
                .expect("twin identification converges");
            sink += c.x[0];
        }));
    }
    std::hint::black_box(sink);
    figs
}
