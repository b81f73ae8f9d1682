use nalgebra::{DMatrix, Matrix3, Vector3};

use super::*;
use crate::identify::coverage::{TWO_SIGMA_PROBABILITY, coverage};
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

/// The held-out session's refit (base frame and marker, joints held) by Monte Carlo: joint
/// parameters drawn from `Sigma_p` (one of them, the torso's first offset, 3 mrad: a turn
/// of the whole arm that a base frame copies), noise added to the measurements, the frames
/// refitted by [`refit_frames`] (nonlinear LM) per draw. The residuals' empirical covariance
/// matches [`covariances_after_refit`] (total trace to 4 %, each point to 12 % Frobenius),
/// their coverage is 0.9545 (to 0.015), and the prediction without the refit is several
/// times too wide.
#[test]
fn covariance_after_the_frame_refit_matches_monte_carlo() {
    use crate::identify::coverage::{covariances_after_refit, of_covariances};
    use crate::measure::marker_fit::Groups;
    use crate::util::monitor::NoMonitor;
    let h = arm();
    let params: Vec<usize> = (0..h.params.len())
        .filter(|&g| {
            matches!(
                h.params[g],
                HParam::Joint(_, JointField::Err(_) | JointField::Offset)
            )
        })
        .collect();
    let n = params.len();
    let torso = h
        .param_by_name("torso_1_joint.offset")
        .expect("torso offset");
    let t = params
        .iter()
        .position(|&g| g == torso)
        .expect("among the params");
    let mut rng = Rng::new(5);
    let a = DMatrix::from_fn(n, n, |_, _| rng.normal() * 5e-5 / (n as f64).sqrt());
    let mut sigma_p = &a * a.transpose() + DMatrix::identity(n, n) * 1e-10;
    sigma_p[(t, t)] += 3e-3f64.powi(2);
    let l = sigma_p.clone().cholesky().expect("spd").l();
    let noise = 2e-4;
    let limits = h.limits();
    let states: Vec<State> = (0..20)
        .map(|_| {
            let q = limits
                .iter()
                .map(|l| l.map_or(0.0, |[lo, hi]| lo + (0.2 + 0.6 * rng.uniform()) * (hi - lo)))
                .collect();
            State::from_q(q)
        })
        .collect();
    let truth: Vec<Vector3<f64>> = states.iter().map(|s| h.marker_positions(s)[0]).collect();
    let exact: Vec<MarkerSample> = states
        .iter()
        .zip(&truth)
        .map(|(s, y)| MarkerSample {
            state: s.clone(),
            points: vec![Some(*y)],
        })
        .collect();
    let frames = Groups::FRAMES.select(&h);
    let mut all: Vec<Option<usize>> = params.iter().map(|&g| Some(g)).collect();
    all.extend(frames.iter().map(|&g| Some(g)));
    let (_, jac) = marker_errors_and_jacobians(&h, &all, &exact);
    let js: Vec<DMatrix<f64>> = jac.iter().map(|j| j.columns(0, n).into_owned()).collect();
    let fs: Vec<DMatrix<f64>> = jac
        .iter()
        .map(|j| j.columns(n, frames.len()).into_owned())
        .collect();
    let predicted = covariances_after_refit(&js, &fs, &sigma_p, noise);
    let x0 = h.values();
    let draws = 1500;
    let mut mc = vec![Matrix3::zeros(); states.len()];
    let mut residuals = Vec::new();
    for _ in 0..draws {
        let dp = &l * DMatrix::from_fn(n, 1, |_, _| rng.normal());
        let mut x = x0.clone();
        for (c, &g) in params.iter().enumerate() {
            x[g] += dp[c];
        }
        let mut m = h.clone();
        m.set_all(&x);
        let samples: Vec<MarkerSample> =
            exact
                .iter()
                .map(|s| MarkerSample {
                    state: s.state.clone(),
                    points: vec![s.points[0].map(|y| {
                        y + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * noise
                    })],
                })
                .collect();
        let refit = refit_frames(&m, &samples, &FitOptions::default(), &NoMonitor).expect("refit");
        let (errors, _) = marker_errors_and_jacobians(&refit.model, &[], &samples);
        for (k, e) in errors.iter().enumerate() {
            mc[k] += e * e.transpose();
        }
        residuals.extend(errors);
    }
    let (mut trace_mc, mut trace_pred) = (0.0, 0.0);
    for (k, m) in mc.iter().enumerate() {
        let m = m / draws as f64;
        let c = predicted[k].1;
        trace_mc += m.trace();
        trace_pred += c.trace();
        let rel = (m - c).norm() / c.norm();
        assert!(rel < 0.12, "point {k}: Monte-Carlo {m:?} vs {c:?}: {rel}");
    }
    assert!(
        (trace_mc / trace_pred - 1.0).abs() < 0.04,
        "total trace: Monte-Carlo {trace_mc} vs predicted {trace_pred}"
    );
    let per_draw: Vec<_> = (0..draws).flat_map(|_| predicted.iter().copied()).collect();
    let cov = of_covariances(&residuals, per_draw, noise, "test", "m").expect("psd");
    assert!(
        (cov.fraction_within_2sigma - TWO_SIGMA_PROBABILITY).abs() < 0.015,
        "{}",
        cov.fraction_within_2sigma
    );
    // The joints' marginal covariance without the refit (the old prediction): the torso
    // turn alone is ~1 mm at the hand, against a refitted residual near the 0.2 mm noise.
    let plain: f64 = js
        .iter()
        .map(|j| (j * &sigma_p * j.transpose()).trace() + 3.0 * noise * noise)
        .sum();
    println!(
        "after refit: rms error {:.4} mm, predicted {:.4} mm; without the refit: {:.4} mm",
        cov.rms_error * 1e3,
        cov.rms_predicted * 1e3,
        (plain / js.len() as f64).sqrt() * 1e3
    );
    assert!(plain > 9.0 * trace_pred, "{plain} vs {trace_pred}");
}
