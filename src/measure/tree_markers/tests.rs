use super::*;
use crate::model::elastic::ElasticOptions;
use crate::twin::elastic::{ElasticTwin, revolute_rows};
use crate::util::NoMonitor;

fn all_elastic() -> ElasticOptions {
    ElasticOptions {
        joint: revolute_rows(),
        lateral: revolute_rows(),
        ..Default::default()
    }
}

/// A twin with lumped joint and lateral elasticity from known compliances and mass moments
/// (deflections of several mm at the hands) is recovered to the noise level: training errors
/// at the noise, held-out truth errors below it, and every coefficient the rank step keeps
/// within 5 standard deviations of the truth's lumped value.
#[test]
fn twin_with_lumped_and_lateral_elasticity_is_recovered_to_noise_level() {
    let noise = 1e-4;
    let twin = ElasticTwin::new(&all_elastic(), 300, noise, 7);
    let c = cumulative(
        &twin.nominal,
        &twin.observations,
        3,
        400,
        &TreePrior::default(),
        &NoMonitor,
    )
    .expect("cumulative fit");
    let (steps, geometric) = (c.steps, c.last.model);
    let f = fit(
        &geometric,
        &twin.observations,
        STEPS[4].1,
        400,
        &TreePrior::default(),
        &NoMonitor,
    )
    .expect("full fit");
    let train = errors_mm(&f.model, &with_features(&geometric, &twin.observations));
    let train = Summary::of(&train, "mm");
    let val = twin.validation(200, 99);
    let held = Summary::of(&errors_mm(&f.model, &with_features(&geometric, &val)), "mm");
    println!(
        "twin: geometric {:.3} mm, + joint {:.3} mm, full {:.3} mm (noise {:.3} mm per axis), held-out vs truth {:.3} mm mean {:.3} max",
        steps[2].error_mm.mean,
        steps[3].error_mm.mean,
        train.mean,
        noise * 1e3,
        held.mean,
        held.max
    );
    assert_eq!(
        f.solution.status(),
        "converged",
        "{:?} {:?} after {}",
        f.solution.degenerate,
        f.solution.stop,
        f.solution.iterations
    );
    // Mean of a 3-D Gaussian error norm: 1.6 sigma.
    assert!(
        train.mean < 1.8 * noise * 1e3,
        "training {:.4} mm",
        train.mean
    );
    assert!(
        steps[2].error_mm.mean > 5.0 * train.mean,
        "elasticity must matter in this twin"
    );
    assert!(
        held.mean < 0.5 * noise * 1e3,
        "held-out vs truth {:.4} mm",
        held.mean
    );
    let mut compared = 0;
    let mut worst: f64 = 0.0;
    for (k, p) in f.solution.params.iter().enumerate() {
        let g = f.model.param_by_name(&f.names[k]).unwrap_or(usize::MAX);
        if !matches!(f.model.params.get(g), Some(TParam::Elastic(..))) || !p.identifiable {
            continue;
        }
        let truth = twin.truth.value(f.model.params[g]);
        let std = p.std.unwrap_or(f64::INFINITY);
        let z = (p.value - truth).abs() / std;
        worst = worst.max(z);
        assert!(
            z < 5.0,
            "{}: {:.3e} vs truth {:.3e} (std {:.1e})",
            p.name,
            p.value,
            truth,
            std
        );
        compared += 1;
    }
    println!(
        "twin: {compared} lumped coefficients identified (worst {worst:.2} sigma), held: {:?}",
        f.solution.unidentifiable
    );
    assert!(compared >= 40, "only {compared} coefficients identified");
}

/// The analytic problem Jacobian equals central differences of its residuals.
#[test]
fn tree_problem_jacobian_matches_central_differences() {
    let twin = ElasticTwin::new(&all_elastic(), 5, 1e-4, 3);
    let mut m = twin.truth.clone();
    m.base[5] = 0.2;
    let obs = with_features(&m, &twin.observations);
    let free = m.free_params(STEPS[4].1);
    let p = TreeProblem::new(m, free, obs);
    let x = p.initial();
    let (n, u) = (p.residual_count(), p.unknown_count());
    let (mut a, mut b) = (DMatrix::zeros(n, u), DMatrix::zeros(n, u));
    p.jacobian(&x, &mut a).expect("analytic");
    crate::identify::problem::central_differences(&p, &x, &mut b).expect("numeric");
    let err = (&a - &b).abs().max();
    assert!(err < 1e-6, "largest difference {err:.2e}");
}

/// A twin whose elasticity comes from link weights shared by the joints (the physics the
/// subtree lumping only approximates) is recovered to the noise level by the bodies lumping,
/// starting from the default weights and compliances; the subtree lumping leaves more.
#[test]
fn twin_with_link_weights_is_recovered_by_the_bodies_lumping() {
    let noise = 1e-4;
    let bodies = ElasticOptions {
        lumping: crate::model::elastic::Lumping::Bodies,
        ..all_elastic()
    };
    let twin = ElasticTwin::new(&bodies, 300, noise, 11);
    let c = cumulative(
        &twin.nominal,
        &twin.observations,
        4,
        400,
        &TreePrior::default(),
        &NoMonitor,
    )
    .expect("fits");
    let val = twin.validation(200, 98);
    let held = Summary::of(
        &errors_mm(&c.last.model, &with_features(&c.start, &val)),
        "mm",
    );
    let means: Vec<f64> = c.steps.iter().map(|s| s.error_mm.mean).collect();
    // The same data through the subtree lumping (a model of the nominal tree without weights).
    let mut sub = crate::twin::elastic::nominal(&all_elastic());
    sub.base = twin.nominal.base;
    let s = cumulative(
        &sub,
        &twin.observations,
        4,
        400,
        &TreePrior::default(),
        &NoMonitor,
    )
    .expect("fits");
    println!(
        "bodies twin: steps {means:.3?} mm, held-out vs truth {:.3} mm mean; subtree lumping {:.3} mm; held {:?}",
        held.mean, s.steps[4].error_mm.mean, c.last.solution.unidentifiable
    );
    let sol = &c.last.solution;
    assert_eq!(
        sol.status(),
        "converged",
        "{:?} {:?} after {}",
        sol.degenerate,
        sol.stop,
        sol.iterations
    );
    assert!(means[4] < 1.8 * noise * 1e3, "training {:.4} mm", means[4]);
    assert!(
        held.mean < 0.8 * noise * 1e3,
        "held-out vs truth {:.4} mm",
        held.mean
    );
    assert!(
        means[2] > 10.0 * means[4],
        "elasticity must matter in this twin"
    );
}
