use super::*;
use crate::util::Rng;

/// erf by its Maclaurin series (converges fast for |x| <= 3).
fn erf(x: f64) -> f64 {
    let (mut term, mut sum) = (x, x);
    for n in 1..200 {
        term *= -x * x / n as f64;
        sum += term / (2 * n + 1) as f64;
    }
    2.0 / std::f64::consts::PI.sqrt() * sum
}

/// The chi-square CDF with 3 degrees of freedom in closed form.
fn chi2_3_cdf(x: f64) -> f64 {
    erf((x / 2.0).sqrt()) - (2.0 * x / std::f64::consts::PI).sqrt() * (-x / 2.0).exp()
}

#[test]
fn the_bound_is_the_3_dof_quantile_of_the_1d_two_sigma_probability() {
    assert!((erf(2f64.sqrt()) - TWO_SIGMA_PROBABILITY).abs() < 1e-14);
    assert!((chi2_3_cdf(CHI2_3_AT_2SIGMA) - TWO_SIGMA_PROBABILITY).abs() < 1e-12);
}

/// A 3 x 2 prediction Jacobian and a correlated 2 x 2 parameter covariance.
fn setup() -> (DMatrix<f64>, DMatrix<f64>, Matrix3<f64>) {
    let j = DMatrix::from_row_slice(3, 2, &[1.0, 0.5, -0.3, 2.0, 0.8, 0.1]);
    let sp = DMatrix::from_row_slice(2, 2, &[0.04, 0.01, 0.01, 0.09]);
    let m = &j * &sp * j.transpose();
    let c = Matrix3::from_fn(|r, k| m[(r, k)]) + Matrix3::identity() * 0.2f64.powi(2);
    (j, sp, c)
}

/// Errors drawn from the predicted covariance itself are covered at 0.9545 (20,000 draws:
/// binomial std 0.0015); a covariance understated 10 times in std covers far fewer.
#[test]
fn errors_drawn_from_the_prediction_are_covered_at_the_two_sigma_probability() {
    let (j, sp, c) = setup();
    let l = c.cholesky().expect("positive definite").l();
    let mut rng = Rng::new(7);
    let n = 20_000;
    let errors: Vec<Vector3<f64>> = (0..n)
        .map(|_| l * Vector3::new(rng.normal(), rng.normal(), rng.normal()))
        .collect();
    let js = vec![j.clone(); n];
    let cov = coverage(&errors, &js, &sp, 0.2, "options.noise", "mm").expect("coverage");
    assert_eq!(cov.n, n);
    assert!(
        (cov.fraction_within_2sigma - TWO_SIGMA_PROBABILITY).abs() < 0.006,
        "{}",
        cov.fraction_within_2sigma
    );
    assert!(!cov.optimistic());
    // The predicted RMS length is sqrt(trace C).
    assert!((cov.points[0].predicted_rms - c.trace().sqrt()).abs() < 1e-12);
    let small = coverage(&errors, &js, &(&sp * 0.01), 0.02, "options.noise", "mm").unwrap();
    assert!(
        small.fraction_within_2sigma < 0.2,
        "{}",
        small.fraction_within_2sigma
    );
    assert!(small.optimistic());
}
