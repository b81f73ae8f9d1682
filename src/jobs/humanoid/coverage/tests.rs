use nalgebra::{DMatrix, Matrix3, Vector3};

use super::*;
use crate::identify::coverage::TWO_SIGMA_PROBABILITY;
use crate::model::JointField;
use crate::model::humanoid::{BaseMode, Elasticity, MarkerDef, State};
use crate::model::urdf::UrdfModel;
use crate::util::Rng;

const TALOS: &str = include_str!("../../../../tests/data/robots/talos/talos_reduced.urdf");

/// TALOS's left arm with one hand marker, the base identified.
fn arm() -> Humanoid {
    let urdf = UrdfModel::parse(TALOS).expect("urdf");
    let mut vars = vec!["torso_1_joint".to_string(), "torso_2_joint".to_string()];
    vars.extend((1..=7).map(|k| format!("arm_left_{k}_joint")));
    let markers = [MarkerDef {
        name: "hand".into(),
        link: "gripper_left_base_link".into(),
        initial: Vector3::new(0.0, 0.0, 0.0),
    }];
    Humanoid::new(
        &urdf,
        "base_link",
        &vars,
        &markers,
        BaseMode::Identify,
        &Elasticity::default(),
    )
    .expect("humanoid")
}

/// The predicted covariance `J Sigma_p J^T + sigma^2 I` of a marker equals the covariance of
/// 20,000 Monte-Carlo draws of the nonlinear model (parameters ~ N(p, Sigma_p), noise
/// ~ N(0, sigma^2 I)) to 5 % (Frobenius), and those draws fall within the chi-square
/// 2-sigma region at the expected 0.9545 (to 0.01).
#[test]
fn predicted_covariance_matches_monte_carlo() {
    let h = arm();
    // Every joint placement error and offset of the arm: 8 to 60 parameters.
    let params: Vec<Option<usize>> = (0..h.params.len())
        .filter(|&g| {
            matches!(
                h.params[g],
                HParam::Joint(_, JointField::Err(_) | JointField::Offset)
            )
        })
        .map(Some)
        .collect();
    let n = params.len();
    assert!(n >= 8, "{n} parameters");
    // A correlated covariance: stds 0.3 mm / 0.3 mrad, random correlations.
    let mut rng = Rng::new(7);
    let a = DMatrix::from_fn(n, n, |_, _| rng.normal() * 3e-4 / (n as f64).sqrt());
    let sigma_p = &a * a.transpose() + DMatrix::identity(n, n) * 1e-8;
    let l = sigma_p.clone().cholesky().expect("spd").l();
    let noise = 2e-4;
    let q: Vec<f64> = h
        .limits()
        .iter()
        .map(|l| l.map_or(0.0, |[lo, hi]| lo + 0.37 * (hi - lo)))
        .collect();
    let state = State::from_q(q);
    let truth = h.marker_positions(&state)[0];
    let sample = MarkerSample {
        state: state.clone(),
        points: vec![Some(truth)],
    };
    let (errors, jac) = marker_errors_and_jacobians(&h, &params, &[sample]);
    assert!(errors[0].norm() < 1e-15);
    let j = &jac[0];
    let c = j * &sigma_p * j.transpose();
    let predicted = Matrix3::from_fn(|r, k| c[(r, k)]) + Matrix3::identity() * noise * noise;
    let x0 = h.values();
    let draws = 20_000;
    let mut mc = Matrix3::zeros();
    let mut samples = Vec::with_capacity(draws);
    for _ in 0..draws {
        let z = DMatrix::from_fn(n, 1, |_, _| rng.normal());
        let dp = &l * z;
        let mut x = x0.clone();
        for (c, g) in params.iter().enumerate() {
            x[g.expect("a parameter")] += dp[c];
        }
        let mut m = h.clone();
        m.set_all(&x);
        let e = m.marker_positions(&state)[0] - truth
            + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * noise;
        mc += e * e.transpose();
        samples.push(e);
    }
    mc /= draws as f64;
    let rel = (mc - predicted).norm() / predicted.norm();
    assert!(
        rel < 0.05,
        "Monte-Carlo {mc:?} vs predicted {predicted:?}: {rel}"
    );
    // The coverage module over the draws: the chi-square bound holds 0.9545 of them.
    let jacobians = vec![j.clone(); draws];
    let cov = coverage(&samples, &jacobians, &sigma_p, noise, "test", "m").expect("spd");
    assert!(
        (cov.fraction_within_2sigma - TWO_SIGMA_PROBABILITY).abs() < 0.01,
        "{}",
        cov.fraction_within_2sigma
    );
    let rms = cov.points[0].predicted_rms;
    assert!((rms * rms - predicted.trace()).abs() < 1e-12 * predicted.trace());
}
