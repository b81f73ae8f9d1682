//! `calibd bench pcr`: the 3-PF shooting model and its identification on the twin: forward
//! kinematics per configuration warm-started along a joint path and cold from home, inverse
//! kinematics per pose (warm along a path and cold), the pose Jacobian with respect to the
//! 28 parameters, the full three-step identification on 99 poses, and the microscope's
//! pattern pose from a 1024 x 1024 image (`pattern_pose`, target 100 images/s on one core).

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
        Some(Duration::from_micros(1)),
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
        Some(Duration::from_nanos(1500)),
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
    figs.extend(lu_12(&mut sink));
    figs.push(pattern_pose(&mut sink));
    figs.push(camera_pose(&mut sink));
    std::hint::black_box(sink);
    figs
}

/// `n` rendered 1024 x 1024 16-bit frames of `kind` (10 um period at 1 um per pixel, 1 %
/// noise) at the poses `pose(k)` for k = 0, 1, ...
fn frames(
    kind: crate::measure::pattern::PatternKind,
    n: usize,
    pose: impl Fn(f64) -> crate::measure::pattern::PatternPose,
) -> Vec<crate::measure::pattern::GrayImage> {
    use crate::measure::pattern::{PatternKind, RenderSpec, render};
    let seed0 = match kind {
        PatternKind::Periodic => 0,
        PatternKind::Encoded => 40,
    };
    (0..n)
        .map(|k| {
            render(&RenderSpec {
                kind,
                pose: pose(k as f64),
                period_um: 10.0,
                pixel_um: 1.0,
                width: 1024,
                height: 1024,
                bit_depth: 16,
                noise_frac: 0.01,
                seed: seed0 + k as u64,
            })
            .expect("a valid render spec")
        })
        .collect()
}

/// `pcr.pattern_pose`'s phase method on rendered 1024 x 1024 16-bit frames (periodic
/// pattern, 10 px period, 1 % noise), one thread; the name carries the rate.
fn pattern_pose(sink: &mut f64) -> Figure {
    use crate::measure::pattern::{PatternKind, PatternPose, PhaseEstimator, Track};
    let frames = frames(PatternKind::Periodic, 8, |k| PatternPose {
        x: 0.3 + 1.7 * k,
        y: -0.2 + 0.9 * k,
        theta_rad: 0.05 + 1e-4 * k,
    });
    let mut est = PhaseEstimator::new(1024, 1024, 10.0).expect("a valid estimator");
    let mut fig = time("pattern_pose 1024x1024", 7, frames.len(), None, || {
        let mut track = Track::new();
        for f in &frames {
            let fit = est.fit(f).expect("a rendered frame has its pattern");
            *sink += track.push(fit.pose(10.0), 10.0).x;
        }
    });
    fig.cpu_target = Some(Duration::from_millis(10));
    fig.name = format!(
        "pattern_pose 1024x1024: {:.0} images/s (one core)",
        1.0 / fig.cpu.unwrap_or(fig.per_op).as_secs_f64()
    );
    fig
}

/// The microscope camera's path on the encoded pattern (what the mock camera serves and a
/// lab's camera frames go through): phase fit, absolute decode and the code-bias
/// correction (a noiseless render and fit per pass), one thread; the name carries the rate.
fn camera_pose(sink: &mut f64) -> Figure {
    use crate::measure::pattern::{PatternKind, PatternPose, PatternSetup, PoseReader};
    let frames = frames(PatternKind::Encoded, 4, |k| PatternPose {
        x: 13.0 + 17.1 * k,
        y: -8.0 + 9.3 * k,
        theta_rad: 0.02 + 1e-3 * k,
    });
    let mut reader = PoseReader::new(PatternSetup {
        kind: PatternKind::Encoded,
        period_um: 10.0,
        pixel_um: 1.0,
    })
    .expect("a valid setup");
    let mut fig = time(
        "camera pose 1024x1024 encoded",
        5,
        frames.len(),
        None,
        || {
            for f in &frames {
                *sink += reader.read(f).expect("a rendered frame has its pattern").x;
            }
        },
    );
    fig.name = format!(
        "camera pose 1024x1024 encoded, bias-corrected: {:.0} poses/s (one core)",
        1.0 / fig.cpu.unwrap_or(fig.per_op).as_secs_f64()
    );
    fig
}

/// The shooting Newton's 12 x 12 factor-and-invert, calibd's stack LU against nalgebra's
/// `SMatrix` LU on the same 1,000 random well-conditioned matrices (the choice recorded in
/// `model/pcr/lu.rs` rests on these two figures).
fn lu_12(sink: &mut f64) -> Vec<Figure> {
    use crate::model::pcr::lu::Lu;
    let mut rng = crate::util::Rng::new(12);
    let mats: Vec<[[f64; 12]; 12]> = (0..1000)
        .map(|_| {
            std::array::from_fn(|i| {
                std::array::from_fn(|j| rng.normal() + if i == j { 6.0 } else { 0.0 })
            })
        })
        .collect();
    let own = time(
        "12 x 12 LU + inverse, calibd's stack LU",
        9,
        mats.len(),
        None,
        || {
            for m in &mats {
                if let Some(lu) = Lu::factor(*m) {
                    *sink += lu.inverse()[3][7] * lu.det_sign + lu.pivot_ratio;
                }
            }
        },
    );
    let na: Vec<nalgebra::SMatrix<f64, 12, 12>> = mats
        .iter()
        .map(|m| nalgebra::SMatrix::<f64, 12, 12>::from_fn(|i, j| m[i][j]))
        .collect();
    let theirs = time(
        "12 x 12 LU + inverse, nalgebra SMatrix LU",
        9,
        na.len(),
        None,
        || {
            for m in &na {
                let lu = m.lu();
                let d = lu.determinant();
                if let Some(inv) = lu.try_inverse() {
                    *sink += inv[(3, 7)] * d.signum();
                }
            }
        },
    );
    vec![own, theirs]
}
