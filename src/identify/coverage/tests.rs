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

/// Linear refit by Monte Carlo: held parameters drawn from `Sigma_p`, noise added, the
/// refitted unknowns solved by least squares (normal equations, a second method) on all
/// points; the empirical covariance of each point's residual matches
/// [`covariances_after_refit`] to 5 % (Frobenius), and the errors are covered at 0.9545.
#[test]
fn covariance_after_a_refit_matches_a_least_squares_monte_carlo() {
    let mut rng = Rng::new(11);
    let (points, held, refitted) = (6, 4, 3);
    let js: Vec<DMatrix<f64>> = (0..points)
        .map(|_| DMatrix::from_fn(3, held, |_, _| rng.normal()))
        .collect();
    // The refit moves a translation (identity) that the first held parameter partly mimics.
    let fs: Vec<DMatrix<f64>> = js
        .iter()
        .map(|j| {
            let mut f = DMatrix::identity(3, refitted);
            f.column_mut(0).axpy(0.5, &j.column(0), 1.0);
            f
        })
        .collect();
    let a = DMatrix::from_fn(held, held, |_, _| rng.normal() * 0.3);
    let sigma_p = &a * a.transpose() + DMatrix::identity(held, held) * 0.01;
    let noise = 0.2;
    let predicted = covariances_after_refit(&js, &fs, &sigma_p, noise);
    let mut f = DMatrix::zeros(3 * points, refitted);
    for (i, b) in fs.iter().enumerate() {
        f.view_mut((3 * i, 0), (3, refitted)).copy_from(b);
    }
    let ftf = (f.transpose() * &f).cholesky().expect("full rank");
    let l = sigma_p.clone().cholesky().expect("spd").l();
    let draws = 40_000;
    let mut mc = vec![Matrix3::zeros(); points];
    let mut errors = Vec::new();
    for _ in 0..draws {
        let dp = &l * DMatrix::from_fn(held, 1, |_, _| rng.normal());
        let mut y = DMatrix::zeros(3 * points, 1);
        for (i, j) in js.iter().enumerate() {
            let e = j * &dp + DMatrix::from_fn(3, 1, |_, _| rng.normal() * noise);
            y.view_mut((3 * i, 0), (3, 1)).copy_from(&e);
        }
        let phi = ftf.solve(&(f.transpose() * &y));
        let r = y - &f * phi;
        for (i, m) in mc.iter_mut().enumerate() {
            let e = Vector3::new(r[3 * i], r[3 * i + 1], r[3 * i + 2]);
            *m += e * e.transpose();
            if i == 0 {
                errors.push(e);
            }
        }
    }
    for (i, m) in mc.iter().enumerate() {
        let m = m / draws as f64;
        let c = predicted[i].1;
        let rel = (m - c).norm() / c.norm();
        assert!(rel < 0.05, "point {i}: Monte-Carlo {m:?} vs {c:?}: {rel}");
    }
    // The first point's residuals, one per draw, against its own prediction: the same
    // prediction for every draw, so the per-point covariances are those of point 0.
    let per_draw = vec![predicted[0]; draws];
    let cov = of_covariances(&errors, per_draw, noise, "test", "m").expect("psd");
    assert!(
        (cov.fraction_within_2sigma - TWO_SIGMA_PROBABILITY).abs() < 0.006,
        "{}",
        cov.fraction_within_2sigma
    );
    assert!((cov.rms_predicted / cov.rms_error - 1.0).abs() < 0.03);
}
