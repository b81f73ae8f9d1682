//! Observability indices of an identification Jacobian (Borm & Menq O1, Nahvi O2..O5), computed
//! on the Jacobian with columns scaled to unit norm.

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// The five indices of a set of configurations.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct Indices {
    /// (s1 ... sm)^(1/m) / sqrt(n).
    pub o1: f64,
    /// sm / s1 (inverse condition number).
    pub o2: f64,
    /// sm.
    pub o3: f64,
    /// sm^2 / s1.
    pub o4: f64,
    /// 1 / sum(1 / si).
    pub o5: f64,
    /// Number of configurations n.
    pub configurations: usize,
    /// Number of parameters m.
    pub parameters: usize,
}

/// Indices of `j` (rows of `configurations` configurations stacked, one column per
/// identifiable parameter); columns are scaled to unit norm first.
pub fn indices(j: &DMatrix<f64>, configurations: usize) -> Indices {
    let m = j.ncols();
    let mut js = j.clone();
    for k in 0..m {
        let n = js.column(k).norm();
        if n > 0.0 {
            js.column_mut(k).unscale_mut(n);
        }
    }
    let r = if js.nrows() > m { js.qr().r() } else { js };
    let mut s: Vec<f64> = r.singular_values().iter().copied().collect();
    s.sort_by(|a, b| b.total_cmp(a));
    s.truncate(m);
    let (s1, sm) = (
        s.first().copied().unwrap_or(0.0),
        s.last().copied().unwrap_or(0.0),
    );
    let log_prod: f64 = s.iter().map(|v| v.ln()).sum();
    Indices {
        o1: (log_prod / m as f64).exp() / (configurations as f64).sqrt(),
        o2: if s1 > 0.0 { sm / s1 } else { 0.0 },
        o3: sm,
        o4: if s1 > 0.0 { sm * sm / s1 } else { 0.0 },
        o5: 1.0 / s.iter().map(|v| 1.0 / v).sum::<f64>(),
        configurations,
        parameters: m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indices_of_a_diagonal_jacobian_are_closed_form() {
        // Columns already of unit norm and orthogonal: every singular value is 1.
        let j = DMatrix::from_fn(6, 3, |i, k| if i == 2 * k { 1.0 } else { 0.0 });
        let o = indices(&j, 2);
        assert!((o.o1 - 1.0 / 2f64.sqrt()).abs() < 1e-15);
        assert!((o.o2 - 1.0).abs() < 1e-15 && (o.o5 - 1.0 / 3.0).abs() < 1e-15);
        // Two columns at 60 degrees: singular values sqrt(1 +- cos 60).
        let c = 0.5f64;
        let j = DMatrix::from_row_slice(2, 2, &[1.0, c, 0.0, (1.0 - c * c).sqrt()]);
        let o = indices(&j, 1);
        let (s1, s2) = ((1.0 + c).sqrt(), (1.0 - c).sqrt());
        assert!((o.o1 - (s1 * s2).sqrt()).abs() < 1e-14);
        assert!((o.o4 - s2 * s2 / s1).abs() < 1e-14);
    }
}
