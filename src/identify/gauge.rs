//! Gauge freedoms: combinations of unknowns that change no prediction (a rigid motion of
//! every frame the sensor cannot see, a modulus the kinematics do not depend on). Rank
//! detection says how many there are; [`null_directions`] finds them in the scaled unknowns
//! and [`Gauged`] holds each combination at its reference (nominal) value with an extra
//! residual row, so Levenberg-Marquardt returns the minimum-norm representative of the
//! solution set: the one closest to nominal in units of the parameters' uncertainties.
//!
//! Holding single parameters at nominal instead (the classic choice) fixes the gauge on one
//! parameter's own error, which a lever can amplify far beyond the other parameters'
//! bounds; holding the combination spreads it the least.

use nalgebra::DMatrix;
use serde::Serialize;

use super::{IdentifyError, Problem};

/// One gauge freedom.
#[derive(Debug, Clone, Serialize)]
pub struct Gauge {
    /// Unit direction in scaled unknowns (unknown / scale).
    pub direction: Vec<f64>,
    /// Coefficients of the held combination `sum c_k (x_k - x_ref_k)` (unknown units).
    pub coefficients: Vec<f64>,
}

/// The `count` directions of `j * diag(scale)` with the smallest singular values (the null
/// space when `count` is the rank deficiency), as gauges.
pub fn null_directions(
    j: &DMatrix<f64>,
    scale: &[f64],
    count: usize,
) -> Result<Vec<Gauge>, IdentifyError> {
    let m = j.ncols();
    if count == 0 || m == 0 {
        return Ok(vec![]);
    }
    let mut js = j.clone();
    for (k, s) in scale.iter().enumerate().take(m) {
        js.column_mut(k).scale_mut(*s);
    }
    // The right singular vectors of R (from a QR of the tall matrix) are those of J.
    let r = if js.nrows() > m {
        super::dense::r_factor(&js)
    } else {
        js
    };
    let svd = r.svd(false, true);
    let vt = svd
        .v_t
        .ok_or_else(|| IdentifyError::Model("SVD of the scaled Jacobian failed".into()))?;
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|a, b| svd.singular_values[*a].total_cmp(&svd.singular_values[*b]));
    let mut out = Vec::with_capacity(count);
    for &i in order.iter().take(count) {
        let mut v: Vec<f64> = (0..m).map(|k| vt[(i, k)]).collect();
        // A sign convention for reports: largest component positive.
        let big = v
            .iter()
            .copied()
            .fold(0.0_f64, |a, b| if b.abs() > a.abs() { b } else { a });
        if big < 0.0 {
            v.iter_mut().for_each(|x| *x = -*x);
        }
        let coefficients = v.iter().zip(scale).map(|(d, s)| d / s).collect();
        out.push(Gauge {
            direction: v,
            coefficients,
        });
    }
    Ok(out)
}

/// A problem with one extra residual per gauge, `weight * sum c_k (x_k - x_ref_k)`.
pub struct Gauged<'a> {
    inner: &'a dyn Problem,
    gauges: Vec<Gauge>,
    x_ref: Vec<f64>,
    weight: f64,
    /// Whether rank detection leaves the gauge rows out ([`Gauged::outside_rank`]).
    outside_rank: bool,
}

impl std::fmt::Debug for Gauged<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gauged")
            .field("gauges", &self.gauges.len())
            .finish()
    }
}

impl<'a> Gauged<'a> {
    /// Hold `gauges` of `inner` at `x_ref`, each row scaled by `weight` (choose it like the
    /// data's largest singular value so the rows neither dominate nor vanish).
    pub fn new(inner: &'a dyn Problem, gauges: Vec<Gauge>, x_ref: Vec<f64>, weight: f64) -> Self {
        Self {
            inner,
            gauges,
            x_ref,
            weight,
            outside_rank: false,
        }
    }

    /// Rank detection sees the data rows only: a gauge given by its structure (a row on the
    /// base frame) must not make a column that duplicates the base in the data look
    /// identifiable (issue 30 item 7: joint 2's `dz` along joint 1's axis).
    pub fn outside_rank(mut self) -> Self {
        self.outside_rank = true;
        self
    }
}

impl Problem for Gauged<'_> {
    fn residual_count(&self) -> usize {
        self.inner.residual_count() + self.gauges.len()
    }
    fn unknown_count(&self) -> usize {
        self.inner.unknown_count()
    }
    fn gauge_rows(&self) -> usize {
        if self.outside_rank {
            self.gauges.len()
        } else {
            0
        }
    }
    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        let n = self.inner.residual_count();
        self.inner.residuals(x, &mut r[..n])?;
        for (g, out) in self.gauges.iter().zip(&mut r[n..]) {
            let s: f64 = g
                .coefficients
                .iter()
                .zip(x)
                .zip(&self.x_ref)
                .map(|((c, a), b)| c * (a - b))
                .sum();
            *out = self.weight * s;
        }
        Ok(())
    }
    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        let n = self.inner.residual_count();
        let mut top = DMatrix::zeros(n, self.unknown_count());
        self.inner.jacobian(x, &mut top)?;
        j.view_mut((0, 0), (n, self.unknown_count()))
            .copy_from(&top);
        for (i, g) in self.gauges.iter().enumerate() {
            for (k, c) in g.coefficients.iter().enumerate() {
                j[(n + i, k)] = self.weight * c;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::{LmOptions, Pivoting, levenberg_marquardt, rank_revealing};
    use crate::util::NoMonitor;

    /// Data see only x0 + x1 (a gauge: x0 - x1 is free) and x2; scales 1 and 3. The
    /// minimum-norm solution of x0 + x1 = 4 in scaled units (x0, x1 / 3) from reference
    /// (0, 0) is x0 = 0.4, x1 = 3.6.
    struct Sum;
    impl Problem for Sum {
        fn residual_count(&self) -> usize {
            3
        }
        fn unknown_count(&self) -> usize {
            3
        }
        fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
            r[0] = x[0] + x[1] - 4.0;
            r[1] = 2.0 * (x[0] + x[1]) - 8.0;
            r[2] = x[2] - 1.0;
            Ok(())
        }
    }

    #[test]
    fn holds_the_gauge_combination_at_the_reference() {
        let x0 = [0.0, 0.0, 0.0];
        let mut j = DMatrix::zeros(3, 3);
        Sum.jacobian(&x0, &mut j).expect("jacobian");
        let rank = rank_revealing(&j, &Pivoting::Norm, 1e-8);
        assert_eq!(rank.dropped.len(), 1);
        let scale = [1.0, 3.0, 1.0];
        let g = null_directions(&j, &scale, 1).expect("svd");
        // Scaled direction (1, -1/3 * 3 ...): x0 - x1 / 3 * ... normalised.
        let d = &g[0].direction;
        assert!(
            (d[0] * 1.0 + d[1] * 3.0).abs() < 1e-12 && d[2].abs() < 1e-12,
            "{d:?}"
        );
        let gauged = Gauged::new(&Sum, g, x0.to_vec(), 1.0);
        let rep = levenberg_marquardt(&gauged, &x0, &LmOptions::default(), &NoMonitor).expect("lm");
        assert!(
            (rep.x[0] - 0.4).abs() < 1e-9 && (rep.x[1] - 3.6).abs() < 1e-9,
            "{:?}",
            rep.x
        );
        assert!((rep.x[2] - 1.0).abs() < 1e-12);
    }
}
