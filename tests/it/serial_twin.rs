//! The serial identification against the IRB 120 twin: every identifiable true parameter
//! recovered within 3 reported standard deviations, validation at the noise level.

use calibd::identify::{SolveOptions, solve};
use calibd::measure::{PointProblem, Target};
use calibd::twin::SerialTwin;
use calibd::util::{NoMonitor, Summary};

#[test]
fn twin_identification_recovers_the_truth() {
    let twin = SerialTwin::irb120(1);
    let meas = twin.centring(120, 2);
    let ids: Vec<_> = twin
        .file
        .identify
        .iter()
        .map(|n| twin.nominal.param_by_name(n).unwrap())
        .collect();
    let problem =
        PointProblem::new(twin.nominal.clone(), ids.clone(), twin.plate.clone(), meas).unwrap();
    let x0 = problem.initial();
    let sol = solve(
        &problem,
        &problem.unknowns(),
        &x0,
        &SolveOptions::default(),
        &NoMonitor,
    )
    .unwrap();
    println!(
        "stop {:?} after {} iterations; unidentifiable {:?}; sigma {:.5} mm; cond {:.3e}",
        sol.stop,
        sol.iterations,
        sol.unidentifiable,
        sol.uncertainty.sigma,
        sol.uncertainty.condition_number
    );
    assert!(sol.stop.converged());
    assert!(sol.unidentifiable.is_empty(), "{:?}", sol.unidentifiable);
    let mut worst: f64 = 0.0;
    for (p, id) in sol.params.iter().zip(&ids) {
        let truth = twin.truth.param(*id) * twin.nominal.units.to_file(id.quantity());
        let z = (p.value - truth) / p.std.unwrap();
        println!(
            "{:>14} nominal {:>12.5} true {:>12.5} identified {:>12.5} std {:.2e} z {:+.2}",
            p.name,
            p.nominal,
            truth,
            p.value,
            p.std.unwrap(),
            z
        );
        worst = worst.max(z.abs());
    }
    assert!(worst < 3.0, "a parameter is {worst:.2} std from the truth");
    // Validation on the laser tracker: nominal is mm-level off, calibrated at the noise level.
    let calibrated = problem.model(&sol.x);
    let val = twin.tracker(200, 3);
    let errors = |c: &calibd::model::Chain| -> Vec<f64> {
        val.iter()
            .map(|m| {
                let Target::Point(p) = m.target else {
                    unreachable!()
                };
                (c.tcp(&m.q, Some(&twin.nominal.static_torques(&m.q))).p - p).norm()
            })
            .collect()
    };
    let before = Summary::of(&errors(&twin.nominal), "mm");
    let after = Summary::of(&errors(&calibrated), "mm");
    println!(
        "validation before {:.4}/{:.4} after {:.4}/{:.4} mm (mean/max)",
        before.mean, before.max, after.mean, after.max
    );
    // Noise of the tracker alone: |N(0, s^2 I3)| has mean s sqrt(8/pi) = 1.6 s.
    let noise_mean = twin.tracker_noise_mm * (8.0 / std::f64::consts::PI).sqrt();
    assert!(before.mean > 0.5, "{before:?}");
    assert!(
        after.mean < 1.5 * noise_mean,
        "after {:.4} vs noise {:.4}",
        after.mean,
        noise_mean
    );
}

/// Cartesian (laser tracker) measurements identify the same model: validated on the
/// ball-centring data of the same twin, the calibrated model puts the TCP on the balls.
#[test]
fn cartesian_identification_validates_on_the_balls() {
    let twin = SerialTwin::irb120(5);
    let ids: Vec<_> = twin
        .file
        .identify
        .iter()
        .map(|n| twin.nominal.param_by_name(n).unwrap())
        .collect();
    let tracker = twin.tracker(300, 6);
    let problem = PointProblem::new(
        twin.nominal.clone(),
        ids,
        calibd::measure::BallPlate::from_positions(&[[0.0; 3]]).unwrap(),
        tracker,
    )
    .unwrap();
    let sol = solve(
        &problem,
        &problem.unknowns(),
        &problem.initial(),
        &SolveOptions::default(),
        &NoMonitor,
    )
    .unwrap();
    assert!(
        sol.stop.converged() && sol.unidentifiable.is_empty(),
        "{:?}",
        sol.unidentifiable
    );
    let calibrated = problem.model(&sol.x);
    let centring = twin.centring(20, 7);
    let err = |c: &calibd::model::Chain| -> f64 {
        let e: Vec<f64> = centring
            .iter()
            .map(|m| {
                let Target::Ball(b) = m.target else {
                    unreachable!()
                };
                (c.tcp(&m.q, Some(&twin.nominal.static_torques(&m.q))).p
                    - twin.plate.centres[b].unwrap())
                .norm()
            })
            .collect();
        Summary::of(&e, "mm").mean
    };
    let (before, after) = (err(&twin.nominal), err(&calibrated));
    println!("ball error before {before:.4} mm, after {after:.4} mm");
    // Centring residual (<= 0.010 mm) plus tracker-noise-limited model error.
    assert!(before > 0.5 && after < 0.02, "{before} -> {after}");
}
