//! Dot products of Jacobian columns in nalgebra's summation order (eight running sums,
//! combined as `((((0 + (s0 + s4)) + (s1 + s5)) + (s2 + s6)) + (s3 + s7))`, then the tail
//! one by one), several at a time: one column against four, so each element of the shared
//! column is loaded once and the eight sums of four dots run side by side (in AVX registers
//! where the processor has them). Each dot is bit for bit `a.dot(&b)` of nalgebra, so the
//! solver's iterates do not move.

/// `out[k] = cols[k] . b` for every `k`, each bit for bit nalgebra's `cols[k].dot(b)`.
pub(crate) fn dots(cols: &[&[f64]], b: &[f64], out: &mut [f64]) {
    for col in cols {
        assert_eq!(col.len(), b.len(), "dot of columns of different lengths");
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx") {
            let mut k = 0;
            while cols.len() - k >= 4 {
                let block = [cols[k], cols[k + 1], cols[k + 2], cols[k + 3]];
                // SAFETY: the processor has AVX (checked above); the columns have b's length.
                unsafe { avx::dots::<4>(block, b, &mut out[k..k + 4]) };
                k += 4;
            }
            while k < cols.len() {
                // SAFETY: as above.
                unsafe { avx::dots::<1>([cols[k]], b, &mut out[k..k + 1]) };
                k += 1;
            }
            return;
        }
    }
    for (o, col) in out.iter_mut().zip(cols) {
        let mut one = [0.0];
        dots_generic::<1>([col], b, &mut one);
        *o = one[0];
    }
}

/// `|a|^2` bit for bit as nalgebra's `norm_squared` of a vector forms it (`0 + a . a`).
pub(crate) fn norm_squared(a: &[f64]) -> f64 {
    let mut out = [0.0];
    dots(&[a], a, &mut out);
    0.0 + out[0]
}

#[cfg(target_arch = "x86_64")]
mod avx {
    use std::arch::x86_64::{
        __m256d, _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_setzero_pd, _mm256_storeu_pd,
    };

    /// `K` dots against `b` in nalgebra's order: running sums 0..4 in one register and
    /// 4..8 in another, separate multiplications and additions (no fused ones).
    ///
    /// # Safety
    /// The processor has AVX and every column has `b`'s length.
    #[target_feature(enable = "avx")]
    pub(super) unsafe fn dots<const K: usize>(a: [&[f64]; K], b: &[f64], out: &mut [f64]) {
        let n = b.len();
        let whole = n - n % 8;
        let mut lo: [__m256d; K] = [_mm256_setzero_pd(); K];
        let mut hi: [__m256d; K] = [_mm256_setzero_pd(); K];
        let mut i = 0;
        while i < whole {
            // SAFETY: i + 8 <= n, the length of b and of every column.
            unsafe {
                let b0 = _mm256_loadu_pd(b.as_ptr().add(i));
                let b1 = _mm256_loadu_pd(b.as_ptr().add(i + 4));
                for k in 0..K {
                    let a0 = _mm256_loadu_pd(a[k].as_ptr().add(i));
                    let a1 = _mm256_loadu_pd(a[k].as_ptr().add(i + 4));
                    lo[k] = _mm256_add_pd(lo[k], _mm256_mul_pd(a0, b0));
                    hi[k] = _mm256_add_pd(hi[k], _mm256_mul_pd(a1, b1));
                }
            }
            i += 8;
        }
        for k in 0..K {
            let mut s = [0.0; 4];
            // SAFETY: s holds four values.
            unsafe { _mm256_storeu_pd(s.as_mut_ptr(), _mm256_add_pd(lo[k], hi[k])) };
            let mut res = 0.0;
            res += s[0];
            res += s[1];
            res += s[2];
            res += s[3];
            for t in whole..n {
                res += a[k][t] * b[t];
            }
            out[k] = res;
        }
    }
}

/// `K` dots against `b`, each in nalgebra's order.
#[inline(always)]
fn dots_generic<const K: usize>(a: [&[f64]; K], b: &[f64], out: &mut [f64]) {
    let n = b.len();
    let mut acc = [[0.0_f64; 8]; K];
    let whole = n - n % 8;
    for (i, bb) in b[..whole].chunks_exact(8).enumerate() {
        let bb: &[f64; 8] = bb.try_into().unwrap_or(&[0.0; 8]);
        for (s, col) in acc.iter_mut().zip(&a) {
            let aa: &[f64; 8] = col[8 * i..8 * i + 8].try_into().unwrap_or(&[0.0; 8]);
            for l in 0..8 {
                s[l] += aa[l] * bb[l];
            }
        }
    }
    for ((o, s), col) in out.iter_mut().zip(&acc).zip(&a) {
        let mut res = 0.0;
        res += s[0] + s[4];
        res += s[1] + s[5];
        res += s[2] + s[6];
        res += s[3] + s[7];
        for t in whole..n {
            res += col[t] * b[t];
        }
        *o = res;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;

    /// Every length from 0 to 40 and blocks of 1 to 9 columns: each dot equals nalgebra's
    /// bit for bit (values of mixed signs and magnitudes, where the order of the sums shows).
    #[test]
    fn equals_nalgebra_bit_for_bit() {
        let value = |k: usize, i: usize| {
            let x = ((k * 7919 + i * 104_729) % 1000) as f64 / 997.0 - 0.5;
            x * 10f64.powi(((k + 3 * i) % 9) as i32 - 4)
        };
        for n in 0..=40 {
            let b: Vec<f64> = (0..n).map(|i| value(99, i)).collect();
            for m in 1..=9 {
                let cols: Vec<Vec<f64>> = (0..m)
                    .map(|k| (0..n).map(|i| value(k, i)).collect())
                    .collect();
                let refs: Vec<&[f64]> = cols.iter().map(|c| &c[..]).collect();
                let mut out = vec![f64::NAN; m];
                dots(&refs, &b, &mut out);
                for (k, c) in cols.iter().enumerate() {
                    let expect = DVector::from_vec(c.clone()).dot(&DVector::from_vec(b.clone()));
                    assert_eq!(out[k].to_bits(), expect.to_bits(), "n {n} column {k}");
                    let v = DVector::from_vec(c.clone());
                    assert_eq!(norm_squared(c).to_bits(), v.norm_squared().to_bits());
                    let mut one = [0.0];
                    dots_generic::<1>([c], &b, &mut one);
                    assert_eq!(one[0].to_bits(), expect.to_bits(), "n {n} column {k}");
                }
            }
        }
    }
}
