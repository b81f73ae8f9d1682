//! Box bounds in Levenberg-Marquardt: the damped Gauss-Newton step kept inside the box by
//! holding the unknowns it would carry across a bound on that bound and re-solving the
//! others (a projected step can point uphill when several unknowns are clipped at once,
//! which makes the damping climb and the solver crawl).

use nalgebra::{DMatrix, DVector};

use super::LmOptions;

/// The damped Gauss-Newton step over the unknowns `free` (scaled normal matrix `a`, scaled
/// gradient `gs`, column scales `d`), kept inside the box: an unknown the step would carry
/// across a bound is moved onto the bound and held there, and the others are solved again
/// with it held (at most one re-solve per unknown). Returns the step in unscaled units for
/// all unknowns, or `None` if the damped matrix is not positive definite.
pub(crate) fn bounded_step(
    a: &DMatrix<f64>,
    gs: &DVector<f64>,
    x: &[f64],
    free: &[usize],
    d: &[f64],
    mu: f64,
    opts: &LmOptions,
) -> Option<Vec<f64>> {
    let mf = free.len();
    let mut pinned: Vec<Option<f64>> = vec![None; mf];
    loop {
        let act: Vec<usize> = (0..mf).filter(|&c| pinned[c].is_none()).collect();
        let na = act.len();
        let mut damped = DMatrix::zeros(na, na);
        let mut rhs = DVector::zeros(na);
        for (i, &ci) in act.iter().enumerate() {
            for (k, &ck) in act.iter().enumerate() {
                damped[(i, k)] = a[(ci, ck)];
            }
            damped[(i, i)] += mu;
            let coupled: f64 = (0..mf)
                .filter_map(|c| pinned[c].map(|p| a[(ci, c)] * p))
                .sum();
            rhs[i] = -(gs[ci] + coupled);
        }
        let ds = if na > 0 {
            damped.cholesky()?.solve(&rhs)
        } else {
            rhs
        };
        let mut crossed = false;
        for (i, &c) in act.iter().enumerate() {
            let k = free[c];
            let target = x[k] + ds[i] / d[k];
            let bound = if opts.lower.as_ref().is_some_and(|l| target < l[k]) {
                opts.lower.as_ref().map(|l| l[k])
            } else if opts.upper.as_ref().is_some_and(|u| target > u[k]) {
                opts.upper.as_ref().map(|u| u[k])
            } else {
                None
            };
            if let Some(b) = bound {
                pinned[c] = Some((b - x[k]) * d[k]);
                crossed = true;
            }
        }
        if !crossed {
            let mut step = vec![0.0; x.len()];
            for (i, &c) in act.iter().enumerate() {
                step[free[c]] = ds[i] / d[free[c]];
            }
            for (c, p) in pinned.iter().enumerate() {
                if let Some(p) = p {
                    step[free[c]] = p / d[free[c]];
                }
            }
            return Some(step);
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector};

    use crate::identify::{IdentifyError, LmOptions, Problem, levenberg_marquardt};
    use crate::util::NoMonitor;

    /// A linear least-squares problem whose unconstrained optimum lies outside the box in
    /// several coordinates at once.
    struct Boxed;
    const A: [[f64; 3]; 4] = [
        [1.0, 0.5, 0.0],
        [0.2, 1.0, 0.3],
        [0.0, 0.4, 1.0],
        [0.7, 0.0, 0.6],
    ];
    const B: [f64; 4] = [2.5, 3.0, -1.0, 0.4];
    impl Problem for Boxed {
        fn residual_count(&self) -> usize {
            4
        }
        fn unknown_count(&self) -> usize {
            3
        }
        fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
            for i in 0..4 {
                r[i] = (0..3).map(|k| A[i][k] * x[k]).sum::<f64>() - B[i];
            }
            Ok(())
        }
    }

    /// The box-constrained optimum by enumeration: every variable at its lower bound, its
    /// upper bound or free (27 cases), the free ones solved by least squares; the feasible
    /// case with the lowest cost.
    fn boxed_by_enumeration(lo: f64, hi: f64) -> Vec<f64> {
        let mut best = (f64::INFINITY, vec![]);
        for case in 0..27 {
            let state: Vec<usize> = (0..3).map(|k| (case / 3usize.pow(k as u32)) % 3).collect();
            let free: Vec<usize> = (0..3).filter(|&k| state[k] == 2).collect();
            let mut x: Vec<f64> = state
                .iter()
                .map(|&s| if s == 0 { lo } else { hi })
                .collect();
            if !free.is_empty() {
                let a = DMatrix::from_fn(4, free.len(), |i, c| A[i][free[c]]);
                let rhs = DVector::from_fn(4, |i, _| {
                    B[i] - (0..3)
                        .filter(|k| state[*k] != 2)
                        .map(|k| A[i][k] * x[k])
                        .sum::<f64>()
                });
                let sol = a.svd(true, true).solve(&rhs, 1e-14).expect("least squares");
                for (c, &k) in free.iter().enumerate() {
                    x[k] = sol[c];
                }
            }
            if x.iter().any(|v| *v < lo - 1e-12 || *v > hi + 1e-12) {
                continue;
            }
            let mut r = [0.0; 4];
            Boxed.residuals(&x, &mut r).expect("residuals");
            let cost: f64 = r.iter().map(|v| v * v).sum();
            if cost < best.0 {
                best = (cost, x);
            }
        }
        best.1
    }

    #[test]
    fn box_constrained_optimum_matches_enumeration() {
        let expected = boxed_by_enumeration(0.0, 1.0);
        let o = LmOptions {
            lower: Some(vec![0.0; 3]),
            upper: Some(vec![1.0; 3]),
            ..Default::default()
        };
        let rep = levenberg_marquardt(&Boxed, &[0.5, 0.5, 0.5], &o, &NoMonitor).unwrap();
        for k in 0..3 {
            assert!(
                (rep.x[k] - expected[k]).abs() < 1e-9,
                "{:?} vs {expected:?}",
                rep.x
            );
        }
        assert!(rep.iterations <= 8, "{} iterations", rep.iterations);
        assert!(
            rep.at_bound.iter().filter(|b| **b != 0).count() >= 2,
            "{:?}",
            rep.at_bound
        );
    }
}
