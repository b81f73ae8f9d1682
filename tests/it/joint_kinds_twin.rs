//! Issue 13, item 4: a synthetic twin of an arm with a prismatic row and two coupling (mimic)
//! rows. Errors injected into the slide's offset (d3, a length), the coupled wrist's offset
//! and multiplier, the coupled slide's offset and multiplier and a few revolute parameters
//! are recovered to the noise level from laser-tracker points, and the serial
//! identification also runs on one named chain of a DH tree file; `serial.fk` reads a tree
//! file's chain with its prismatic columns in mm.

use crate::common;

use nalgebra::Vector3;

use calibd::identify::{SolveOptions, solve};
use calibd::measure::{BallPlate, PointMeasurement, PointProblem, Target};
use calibd::model::dh::DhFile;
use calibd::model::dh_tree::DhTreeFile;
use calibd::model::{Chain, JointKind, ParamId};
use calibd::util::{NoMonitor, Rng};

const SLIDE_DH: &str = include_str!("../data/robots/slide_arm.json");
const SLIDE_URDF: &str = include_str!("../data/robots/slide_gripper.urdf");
const TREE: &str = include_str!("../data/robots/two_arm_tree.json");
const NOISE_MM: f64 = 0.01;

/// Random joint values inside the central part of the limits (rad, or mm for a slide).
fn random_q(c: &Chain, rng: &mut Rng) -> Vec<f64> {
    c.actuated()
        .iter()
        .map(|&j| {
            let [lo, hi] = c.joints[j].limits.expect("limits");
            let m = 0.1 * (hi - lo);
            rng.range(lo + m, hi - m)
        })
        .collect()
}

/// Tracker noise in the chain's length unit.
fn noise(c: &Chain) -> f64 {
    NOISE_MM * 1e-3 / c.units.metre()
}

/// Tracker points of the true chain with Gaussian noise of `NOISE_MM`.
fn tracker(truth: &Chain, n: usize, seed: u64) -> Vec<PointMeasurement> {
    let mut rng = Rng::new(seed);
    let sigma = noise(truth);
    (0..n)
        .map(|_| {
            let q = random_q(truth, &mut rng);
            let e = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * sigma;
            PointMeasurement {
                target: Target::Point(truth.tcp(&q, None).p + e),
                q,
            }
        })
        .collect()
}

/// Inject `errors` (internal units) into a copy of `nominal`, identify `ids` from 120
/// tracker points; return (name, injected, recovered, std) per parameter (internal units)
/// and the status.
fn recover(nominal: &Chain, errors: &[(ParamId, f64)]) -> (Vec<(String, f64, f64, f64)>, String) {
    let mut truth = nominal.clone();
    for (id, dv) in errors {
        truth.set_param(*id, nominal.param(*id) + dv);
    }
    let ids: Vec<ParamId> = errors.iter().map(|e| e.0).collect();
    let plate = BallPlate::from_ballbar(200.0, 200.0, 200.0).expect("plate");
    let problem = PointProblem::new(nominal.clone(), ids.clone(), plate, tracker(&truth, 120, 5))
        .expect("problem");
    let opts = SolveOptions {
        noise: Some(noise(nominal)),
        ..SolveOptions::default()
    };
    let sol = solve(
        &problem,
        &problem.unknowns(),
        &problem.initial(),
        &opts,
        &NoMonitor,
    )
    .expect("solve");
    assert!(
        sol.unidentifiable.is_empty(),
        "held: {:?}",
        sol.unidentifiable
    );
    let fitted = problem.model(&sol.x);
    let rows = ids
        .iter()
        .zip(errors)
        .zip(&sol.params)
        .map(|((id, (_, dv)), p)| {
            // Reported std in file units, back to internal units.
            let std = p.std.unwrap_or(f64::NAN) / nominal.units.to_file(id.quantity());
            (
                nominal.param_name(*id),
                *dv,
                fitted.param(*id) - nominal.param(*id),
                std,
            )
        })
        .collect();
    (rows, sol.status().to_string())
}

/// Each recovered error within 4 standard deviations of the injected one, and within a
/// physical noise-level bound: 5 um for lengths, 1e-4 for angles (rad) and multipliers.
/// Printed in file units (deg for DH angles).
fn check(rows: &[(String, f64, f64, f64)], nominal: &Chain) {
    for (name, injected, got, std) in rows {
        let id = nominal.param_by_name(name).expect("name");
        let tol = match id.quantity() {
            calibd::model::Quantity::Length => 0.005e-3 / nominal.units.metre(),
            _ => 1e-4,
        };
        let f = nominal.units.to_file(id.quantity());
        println!(
            "{name:>16} [{}]: injected {:+.6}, recovered {:+.6}, diff {:+.2e}, std {:.2e}",
            nominal.units.name(id.quantity()),
            injected * f,
            got * f,
            (got - injected) * f,
            std * f
        );
        assert!(
            (got - injected).abs() < tol && (got - injected).abs() < 4.0 * std,
            "{name}: injected {injected} recovered {got} std {std}"
        );
    }
}

#[test]
fn prismatic_and_mimic_errors_are_recovered_on_a_twin() {
    let nominal = DhFile::parse(SLIDE_DH)
        .expect("parses")
        .to_chain()
        .expect("chain");
    assert_eq!(nominal.dof(), 4, "two coupling rows take no column");
    let deg = 1f64.to_radians();
    let by = |n: &str| nominal.param_by_name(n).expect("name");
    let errors = [
        (by("theta_offset2"), 0.05 * deg),
        (by("a2"), 0.3),
        (by("d3"), 0.4),
        (by("alpha3"), -0.04 * deg),
        (by("theta_offset4"), 0.06 * deg),
        (by("theta_offset5"), 0.1 * deg),
        (by("multiplier5"), -0.002),
        (by("d6"), 0.25),
        (by("multiplier6"), 0.003),
    ];
    let (rows, status) = recover(&nominal, &errors);
    println!("status {status}");
    assert_eq!(status, "converged");
    check(&rows, &nominal);
}

#[test]
fn urdf_prismatic_and_mimic_errors_are_recovered_on_a_twin() {
    let nominal = calibd::model::urdf::UrdfModel::parse(SLIDE_URDF)
        .expect("parses")
        .chain("base_link", "tcp")
        .expect("chain");
    let by = |n: &str| nominal.param_by_name(n).expect("name");
    let deg = 1f64.to_radians();
    let errors = [
        (by("lift.offset"), 0.05 * deg),
        (by("extend.offset"), 4e-4),
        (by("extend.rx"), -0.03 * deg),
        (by("bend2.offset"), 0.1 * deg),
        (by("bend2.multiplier"), 0.002),
        (by("grip2.offset"), 2e-4),
        (by("grip2.multiplier"), -0.004),
    ];
    let (rows, status) = recover(&nominal, &errors);
    println!("status {status}");
    assert_eq!(status, "converged");
    check(&rows, &nominal);
}

#[test]
fn serial_identification_runs_on_a_named_chain_of_a_tree_file() {
    let f = DhTreeFile::parse(TREE, "two_arm_tree.json").expect("parses");
    let nominal = f.chain("right_arm", "two_arm_tree.json").expect("chain");
    assert!(
        nominal
            .joints
            .iter()
            .any(|j| j.kind == JointKind::Prismatic)
    );
    assert!(nominal.joints.iter().any(|j| j.mimic.is_some()));
    let deg = 1f64.to_radians();
    let by = |n: &str| nominal.param_by_name(n).expect("name");
    // Entry 6 is r_forearm (prismatic: d6 is its offset), entry 8 the coupled r_wrist2.
    let errors = [
        (by("d6"), -0.3),
        (by("theta_offset4"), 0.05 * deg),
        (by("theta_offset8"), 0.08 * deg),
        (by("multiplier8"), 0.004),
    ];
    let (rows, status) = recover(&nominal, &errors);
    println!("status {status}");
    assert_eq!(status, "converged");
    check(&rows, &nominal);
}

/// `examples/serial_fk_tree.json`: the right arm of the tree file; q2 (lift) and q6 (forearm
/// slide) are mm, the others deg; the coupled wrist has no column. Poses equal the chain's.
#[test]
fn fk_job_reads_a_tree_chain_with_prismatic_columns_in_mm() {
    let doc = common::example("serial_fk_tree.json");
    let done = common::run_in_examples(&doc).expect("fk job");
    let poses = done.result["poses"].as_array().expect("poses");
    let f = DhTreeFile::parse(TREE, "two_arm_tree.json").expect("parses");
    let chain = f.chain("right_arm", "two_arm_tree.json").expect("chain");
    for (row, pose) in doc["joints"].as_array().expect("rows").iter().zip(poses) {
        let q: Vec<f64> = (1..=7)
            .map(|k| {
                let v = row[format!("q{k}")].as_f64().expect("number");
                if k == 2 || k == 6 { v } else { v.to_radians() }
            })
            .collect();
        let p = chain.tcp(&q, None).p;
        for (a, want) in ["x", "y", "z"].iter().zip(p.iter()) {
            let got = pose[*a].as_f64().expect("coordinate");
            assert!((got - want).abs() < 1e-9, "{a}: {got} vs {want}");
        }
    }
    // A tree model without a chain name is refused, naming the field.
    let mut bad = doc.clone();
    bad.as_object_mut().expect("object").remove("chain");
    let e = common::run_in_examples(&bad)
        .expect_err("refused")
        .to_string();
    assert!(e.contains("chain") && e.contains("name"), "{e}");
}
