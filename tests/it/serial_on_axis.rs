//! Issue 13, item 1: the measured point lies on the last joint's axis (tool offset along z6
//! only), so theta_offset6 and the tool rotation about z6 (tool.a) have no effect on the
//! data. They must be held at nominal and named as unidentifiable with an effect below the
//! noise, the fit must stay sane and validate at least as well as the nominal model, and a
//! forced degenerate fit must say `degenerate`, not `converged`.

use calibd::identify::{Solution, SolveOptions, solve};
use calibd::measure::{PointMeasurement, PointProblem, Target};
use calibd::model::{Chain, ParamId};
use calibd::twin::SerialTwin;
use calibd::util::{NoMonitor, Summary};

/// The IRB 120 twin with the TCP 105 mm along the flange axis z6 (nominal and true), and
/// `off_axis` mm away from it along x6.
fn on_axis_twin(off_axis: f64) -> SerialTwin {
    let mut twin = SerialTwin::irb120(3);
    for chain in [&mut twin.nominal, &mut twin.truth] {
        for (k, v) in [
            (0, off_axis),
            (1, 0.0),
            (2, 105.0),
            (3, 0.0),
            (4, 0.0),
            (5, 0.0),
        ] {
            chain.set_param(ParamId::Tool(k), v);
        }
    }
    twin
}

/// The 31 parameters of the model file plus the tool rotation about z6.
fn ids(twin: &SerialTwin) -> Vec<ParamId> {
    let mut names = twin.file.identify.clone();
    names.push("tool.a".into());
    names
        .iter()
        .map(|n| twin.nominal.param_by_name(n).expect("known name"))
        .collect()
}

/// Mean absolute position error of `c` on tracker points (torques of the nominal model).
fn held_out(twin: &SerialTwin, c: &Chain, val: &[PointMeasurement]) -> Summary {
    let e: Vec<f64> = val
        .iter()
        .filter_map(|m| match m.target {
            Target::Point(p) => {
                Some((c.tcp(&m.q, Some(&twin.nominal.static_torques(&m.q))).p - p).norm())
            }
            Target::Ball(_) => None,
        })
        .collect();
    Summary::of(&e, "mm")
}

/// Largest TCP displacement over the measurements when parameter `id` of the nominal model
/// moves by `delta`: the effect size computed by finite differences, independently of the
/// identification Jacobian.
fn effect_by_finite_difference(
    twin: &SerialTwin,
    id: ParamId,
    delta: f64,
    meas: &[PointMeasurement],
) -> f64 {
    let mut moved = twin.nominal.clone();
    moved.set_param(id, twin.nominal.param(id) + delta);
    meas.iter()
        .map(|m| {
            let tau = twin.nominal.static_torques(&m.q);
            (moved.tcp(&m.q, Some(&tau)).p - twin.nominal.tcp(&m.q, Some(&tau)).p).norm()
        })
        .fold(0.0, f64::max)
}

fn identify(
    twin: &SerialTwin,
    meas: Vec<PointMeasurement>,
    opts: SolveOptions,
) -> (PointProblem, Solution) {
    let problem = PointProblem::new(twin.nominal.clone(), ids(twin), twin.plate.clone(), meas)
        .expect("problem");
    let x0 = problem.initial();
    let opts = SolveOptions {
        nuisance: Some(problem.nuisance()),
        ..opts
    };
    let sol = solve(&problem, &problem.unknowns(), &x0, &opts, &NoMonitor).expect("solve");
    (problem, sol)
}

#[test]
fn point_on_the_last_axis_holds_its_offset_and_tool_roll_at_nominal() {
    let twin = on_axis_twin(0.0);
    let meas = twin.tracker(150, 21);
    let val = twin.tracker(300, 22);
    let (problem, sol) = identify(&twin, meas.clone(), SolveOptions::default());
    let noise = twin.tracker_noise_mm;
    println!(
        "status {:?}, stop {:?}, unidentifiable {:?}, unobservable {:?}, near-dependent {:?}, \
         cond {:.3e}, sigma {:.5}",
        sol.status(),
        sol.stop,
        sol.unidentifiable,
        sol.unobservable,
        sol.near_dependent,
        sol.condition_number,
        sol.uncertainty.sigma
    );
    for name in ["theta_offset6", "tool.a"] {
        assert!(
            sol.unidentifiable.iter().any(|n| n == name),
            "{name} not held"
        );
        let p = sol
            .params
            .iter()
            .find(|p| p.name == name)
            .expect("reported");
        assert!(
            !p.identifiable && p.value == p.nominal && p.std.is_none(),
            "{p:?}"
        );
        let id = twin.nominal.param_by_name(name).expect("name");
        let fd = effect_by_finite_difference(&twin, id, 0.5f64.to_radians(), &meas);
        println!(
            "{name}: reported effect {:.3e} mm, finite differences {fd:.3e} mm",
            p.effect_size
        );
        assert!(
            p.effect_size < 0.1 * noise && fd < 0.1 * noise,
            "{p:?} fd {fd}"
        );
    }
    // The same finite difference sees theta_offset5 (the tool is 105 mm off axis 5).
    let fd5 = effect_by_finite_difference(
        &twin,
        twin.nominal.param_by_name("theta_offset5").expect("name"),
        0.5f64.to_radians(),
        &meas,
    );
    assert!(fd5 > 0.5, "theta_offset5 effect {fd5}");
    assert!(
        sol.converged() && sol.status() == "converged",
        "{:?}",
        sol.degenerate
    );
    for (p, id) in sol.params.iter().zip(ids(&twin)) {
        let moved = (p.value - p.nominal) / twin.nominal.units.to_file(id.quantity());
        let sane = match id.quantity() {
            calibd::model::Quantity::Length => 10.0,
            _ => 1f64.to_radians(),
        };
        assert!(
            moved.is_finite() && moved.abs() < sane,
            "{} moved {moved}",
            p.name
        );
    }
    let before = held_out(&twin, &twin.nominal, &val);
    let after = held_out(&twin, &problem.model(&sol.x), &val);
    println!(
        "held-out mean/max: nominal {:.4}/{:.4} mm, calibrated {:.4}/{:.4} mm",
        before.mean, before.max, after.mean, after.max
    );
    let noise_mean = noise * (8.0 / std::f64::consts::PI).sqrt();
    assert!(
        after.mean <= before.mean && after.mean < 1.5 * noise_mean,
        "{after:?}"
    );
}

#[test]
fn forced_degenerate_fit_is_reported_as_degenerate() {
    // The TCP 1 nm off axis 6: theta_offset6 moves the data by 1e-9 mm per rad, a million
    // times below the noise. With both guards disabled (rank tolerance and noise far below
    // rounding) it is kept and the fit explains noise with it by turning joint 6 around.
    let twin = on_axis_twin(1e-9);
    let meas = twin.tracker(150, 21);
    let opts = SolveOptions {
        rank_tolerance: 1e-300,
        noise: Some(1e-300),
        ..Default::default()
    };
    let (_, sol) = identify(&twin, meas, opts);
    let p = sol
        .params
        .iter()
        .find(|p| p.name == "theta_offset6")
        .expect("reported");
    println!(
        "status {}, theta_offset6 {:.3e} deg, degenerate {:?}",
        sol.status(),
        p.value,
        sol.degenerate
    );
    assert_eq!(sol.status(), "degenerate");
    assert!(!sol.converged());
    let d = sol.degenerate.as_ref().expect("degeneracy report");
    assert!(d.names.iter().any(|n| n == "theta_offset6"), "{d:?}");
    // With the guards on, the same data hold theta_offset6 (and c6, which acts through
    // theta6) at nominal, with their effect sizes: the physical rank drops them.
    let (_, sol) = identify(&twin, twin.tracker(150, 21), SolveOptions::default());
    println!(
        "guards on: status {}, unidentifiable {:?}, unobservable {:?}",
        sol.status(),
        sol.unidentifiable,
        sol.unobservable
    );
    for name in ["theta_offset6", "c6"] {
        let p = sol
            .params
            .iter()
            .find(|p| p.name == name)
            .expect("reported");
        println!("{name}: effect {:.3e} mm", p.effect_size);
        assert!(
            !p.identifiable && p.value == p.nominal && p.effect_size < 1e-6,
            "{p:?}"
        );
    }
    assert_eq!(sol.status(), "converged");
}
