//! The R factor of nalgebra's unpivoted Householder QR (`QR::new(j).r()`), bit for bit,
//! with each reflection's dot products taken four columns at a time (one pass over the
//! reflection's axis for four columns, see `super::dots`) and no copy of the factored
//! matrix's Q part kept. The rank detection of every small identification reduces its
//! start Jacobian this way, so the same bits keep every decision it makes.

use super::dots::norm_squared;
use nalgebra::DMatrix;

/// nalgebra's `j.clone().qr().r()`, the same value bit for bit: `min(rows, cols)` x `cols`,
/// upper triangular, the diagonal as the moduli of the reflections' norms.
pub(crate) fn qr_r(j: &DMatrix<f64>) -> DMatrix<f64> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { qr_r_avx2(j) };
    }
    qr_r_in(j)
}

/// [`qr_r`] with the axis scaling and the column updates in 256-bit vectors (element by
/// element the same operations: IEEE division, product and sum, nothing fused).
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn qr_r_avx2(j: &DMatrix<f64>) -> DMatrix<f64> {
    qr_r_in(j)
}

#[inline(always)]
fn qr_r_in(j: &DMatrix<f64>) -> DMatrix<f64> {
    let (n, m) = j.shape();
    let k = n.min(m);
    let mut a = j.clone();
    let mut diag = vec![0.0; k];
    let mut axis = Vec::with_capacity(n);
    let mut f = vec![0.0; m];
    for i in 0..k {
        let (left, right) = a.as_mut_slice().split_at_mut((i + 1) * n);
        let col = &mut left[i * n + i..];
        let (norm, reflect) = reflection_axis(col);
        diag[i] = norm;
        if !reflect {
            continue;
        }
        axis.clear();
        axis.extend_from_slice(col);
        // nalgebra: sign = norm.signum(), m_two = sign * -2, each column j > i (rows i..)
        // gets factor = (axis . col - 0) * m_two, then col = factor * axis * 1 + sign * col.
        let sign = norm.signum();
        let m_two = sign * -2.0;
        let rest = m - i - 1;
        {
            let cols: Vec<&[f64]> = right.chunks_exact(n).map(|c| &c[i..]).collect();
            super::dots::dots(&cols, &axis, &mut f[..rest]);
        }
        for (c, &d) in right.chunks_exact_mut(n).zip(&f[..rest]) {
            let factor = (d - 0.0) * m_two;
            for (y, &x) in c[i..].iter_mut().zip(&axis) {
                *y = factor * x * 1.0 + sign * *y;
            }
        }
    }
    let mut r = DMatrix::zeros(k, m);
    for c in 0..m {
        for row in 0..k.min(c + 1) {
            r[(row, c)] = if row == c { diag[c].abs() } else { a[(row, c)] };
        }
    }
    r
}

/// nalgebra's `householder::reflection_axis_mut` on a column (its rows from the diagonal
/// down): the column becomes the unit axis of the reflection; answers the reflected
/// column's signed norm and whether there is a reflection.
#[inline(always)]
fn reflection_axis(col: &mut [f64]) -> (f64, bool) {
    let sq = norm_squared(col);
    let norm = sq.sqrt();
    // simba's `to_exp` of a real: (|x|, sign) with +0 taken as positive.
    let (modulus, sign) = if col[0] >= 0.0 {
        (col[0], 1.0)
    } else {
        (-col[0], -1.0)
    };
    let signed_norm = sign * norm;
    let factor = (sq + modulus * norm) * 2.0;
    col[0] += signed_norm;
    if factor == 0.0 {
        return (signed_norm, false);
    }
    let s = factor.sqrt();
    col.iter_mut().for_each(|e| *e /= s);
    // nalgebra normalises a second time (the norm of a nearly unit vector).
    let n2 = norm_squared(col).sqrt();
    col.iter_mut().for_each(|e| *e /= n2);
    (-signed_norm, true)
}

#[cfg(test)]
mod tests {
    use super::qr_r;
    use crate::util::Rng;
    use nalgebra::DMatrix;

    fn same_bits(a: &DMatrix<f64>, what: &str) {
        let want = a.clone().qr().r();
        let got = qr_r(a);
        assert_eq!(got.shape(), want.shape(), "{what}");
        for (x, y) in got.iter().zip(want.iter()) {
            assert_eq!(x.to_bits(), y.to_bits(), "{what}: {x} vs {y}");
        }
    }

    /// Tall, square and wide matrices of mixed scales, with zero, repeated and negated
    /// columns and zero leading entries: the R factor equals nalgebra's bit for bit.
    #[test]
    fn equals_nalgebra_bit_for_bit() {
        let mut rng = Rng::new(17);
        for &(n, m) in &[
            (1, 1),
            (2, 3),
            (7, 7),
            (9, 4),
            (40, 31),
            (63, 31),
            (64, 31),
            (65, 31),
            (300, 31),
            (361, 25),
            (5, 12),
        ] {
            let mut a =
                DMatrix::from_fn(n, m, |_, c| rng.normal() * 10f64.powi((c % 7) as i32 - 3));
            same_bits(&a, &format!("{n} x {m}"));
            if m > 3 {
                a.column_mut(1).fill(0.0);
                let c0 = a.column(0).into_owned();
                a.set_column(2, &c0);
                a.set_column(3, &(-c0 * 2.0));
                a[(0, 0)] = 0.0;
                same_bits(&a, &format!("{n} x {m}, dependent and zero columns"));
            }
        }
        same_bits(&DMatrix::zeros(6, 3), "zeros");
        same_bits(&DMatrix::zeros(0, 3), "no rows");
    }
}
