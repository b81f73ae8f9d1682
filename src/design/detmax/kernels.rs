//! Small dense kernels of the exchange algorithm: Cholesky of the information matrix, the
//! log determinant of I ± D for one candidate without allocation, and strided products
//! through `matrixmultiply` (runtime SIMD dispatch, any shape).

/// Symmetric information matrix (row-major; the lower triangle is what is read).
pub(super) struct Info {
    pub(super) m: usize,
    pub(super) a: Vec<f64>,
}

/// Cholesky factor L (lower, row-major) of an information matrix.
pub(super) struct Factor {
    m: usize,
    l: Vec<f64>,
}

impl Info {
    /// The information matrix `a` (row-major m x m) plus `ridge` I.
    pub(super) fn ridged(m: usize, mut a: Vec<f64>, ridge: f64) -> Self {
        for k in 0..m {
            a[k * m + k] += ridge;
        }
        Self { m, a }
    }

    pub(super) fn factor(&self) -> Option<Factor> {
        let m = self.m;
        let mut l = vec![0.0; m * m];
        cholesky_into(&self.a, m, &mut l).then_some(Factor { m, l })
    }
}

/// In-place Cholesky of the lower triangle of `a` (n x n, row-major) into `l`; false if the
/// matrix is not positive definite. Compiled for 256-bit vectors where the CPU has them
/// (the same arithmetic, no fused operations: the factor is bit for bit the same).
fn cholesky_into(a: &[f64], n: usize, l: &mut [f64]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if n > 8 && std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports the feature the function is compiled for.
        return unsafe { cholesky_avx2(a, n, l) };
    }
    cholesky_body(a, n, l)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn cholesky_avx2(a: &[f64], n: usize, l: &mut [f64]) -> bool {
    cholesky_body(a, n, l)
}

#[inline(always)]
fn cholesky_body(a: &[f64], n: usize, l: &mut [f64]) -> bool {
    for i in 0..n {
        for j in 0..=i {
            let s = a[i * n + j] - dot(&l[i * n..i * n + j], &l[j * n..j * n + j]);
            if i == j {
                if !(s > 0.0) {
                    return false;
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    true
}

impl Factor {
    pub(super) fn log_det(&self) -> f64 {
        (0..self.m).map(|i| 2.0 * self.l[i * self.m + i].ln()).sum()
    }

    /// L itself (lower triangular, row-major m x m).
    pub(super) fn lower(&self) -> &[f64] {
        &self.l
    }

    /// The full inverse (row-major), from L^-1.
    pub(super) fn inverse(&self) -> Vec<f64> {
        self.inverse_and_lower().0
    }

    /// The full inverse P = L^-T L^-1 and L^-1 (both row-major m x m; L^-1 lower
    /// triangular, zero above the diagonal).
    pub(super) fn inverse_and_lower(&self) -> (Vec<f64>, Vec<f64>) {
        let m = self.m;
        let (mut li, mut p) = (vec![0.0; m * m], vec![0.0; m * m]);
        inverse_into(&self.l, m, &mut li, &mut p);
        (p, li)
    }
}

/// P = A^-1 = L^-T L^-1 from the Cholesky factor `l` (m x m, row-major) into `p`, with the
/// columns of L^-1 in `li` (both at least m x m).
fn inverse_into(l: &[f64], m: usize, li: &mut [f64], p: &mut [f64]) {
    // Columns of L^-1 by forward substitution, stored row-major in `li`.
    for c in 0..m {
        for i in c..m {
            let mut s = if i == c { 1.0 } else { 0.0 };
            for k in c..i {
                s -= l[i * m + k] * li[k * m + c];
            }
            li[i * m + c] = s / l[i * m + i];
        }
    }
    // P = L^-T L^-1.
    for i in 0..m {
        for j in 0..=i {
            let s: f64 = (i..m).map(|k| li[k * m + i] * li[k * m + j]).sum();
            p[i * m + j] = s;
            p[j * m + i] = s;
        }
    }
}

/// log det(I + sign D) for a symmetric r x r block `d` (row-major), or -inf when the matrix
/// is not positive definite. `scratch` holds at least 2 r^2 values; nothing is allocated.
pub(super) fn log_det_identity_plus(d: &[f64], r: usize, sign: f64, scratch: &mut [f64]) -> f64 {
    if r == 3 {
        // Positive definite by Sylvester's criterion; closed-form determinant.
        let g = |a: usize, b: usize| sign * d[a * 3 + b] + if a == b { 1.0 } else { 0.0 };
        let (a, b, c, e, f, h) = (g(0, 0), g(0, 1), g(0, 2), g(1, 1), g(1, 2), g(2, 2));
        let m2 = a * e - b * b;
        let det = a * (e * h - f * f) - b * (b * h - f * c) + c * (b * f - e * c);
        return if a > 0.0 && m2 > 0.0 && det > 0.0 {
            det.ln()
        } else {
            f64::NEG_INFINITY
        };
    }
    let (s, l) = scratch[..2 * r * r].split_at_mut(r * r);
    for (k, v) in s.iter_mut().enumerate() {
        *v = sign * d[k] + if k % (r + 1) == 0 { 1.0 } else { 0.0 };
    }
    if !cholesky_into(s, r, l) {
        return f64::NEG_INFINITY;
    }
    (0..r).map(|i| 2.0 * l[i * r + i].ln()).sum()
}

/// log det and inverse of a small symmetric positive-definite matrix (r x r, row-major).
pub(super) fn small_inverse(a: &[f64], r: usize) -> Option<(f64, Vec<f64>)> {
    if r <= 6 {
        return small_inverse6(a, r).map(|(ld, p, _)| (ld, p[..r * r].to_vec()));
    }
    let f = Info {
        m: r,
        a: a.to_vec(),
    }
    .factor()?;
    Some((f.log_det(), f.inverse()))
}

/// A matrix operand for [`gemm`]: data with its row and column strides.
#[derive(Clone, Copy)]
pub(super) struct Strided<'a> {
    pub(super) data: &'a [f64],
    pub(super) rs: usize,
    pub(super) cs: usize,
}

/// C (m x n, strides `crs`, `ccs`) = alpha A B + beta C for A m x k and B k x n of any
/// strides, through `matrixmultiply`.
#[allow(clippy::too_many_arguments)]
pub(super) fn gemm(
    (m, k, n): (usize, usize, usize),
    alpha: f64,
    a: Strided<'_>,
    b: Strided<'_>,
    beta: f64,
    c: &mut [f64],
    crs: usize,
    ccs: usize,
) {
    if m == 0 || n == 0 {
        return;
    }
    let last = |rows: usize, cols: usize, rs: usize, cs: usize| {
        if rows == 0 || cols == 0 {
            0
        } else {
            (rows - 1) * rs + (cols - 1) * cs + 1
        }
    };
    assert!(a.data.len() >= last(m, k, a.rs, a.cs), "A out of bounds");
    assert!(b.data.len() >= last(k, n, b.rs, b.cs), "B out of bounds");
    assert!(c.len() >= last(m, n, crs, ccs), "C out of bounds");
    // SAFETY: the asserts above keep every element the strides address inside its slice.
    unsafe {
        matrixmultiply::dgemm(
            m,
            k,
            n,
            alpha,
            a.data.as_ptr(),
            a.rs as isize,
            a.cs as isize,
            b.data.as_ptr(),
            b.rs as isize,
            b.cs as isize,
            beta,
            c.as_mut_ptr(),
            crs as isize,
            ccs as isize,
        );
    }
}

/// a * b + c, fused when the calling kernel is compiled for FMA.
#[inline(always)]
pub(super) fn madd<const FMA: bool>(a: f64, b: f64, c: f64) -> f64 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// a * b + c in single precision, fused when the calling kernel is compiled for FMA.
#[inline(always)]
pub(super) fn madd32<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// Dot product with four independent accumulators, so the compiler can vectorise it.
#[inline(always)]
pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let chunks = n / 4;
    for k in 0..chunks {
        for l in 0..4 {
            acc[l] += a[4 * k + l] * b[4 * k + l];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for k in 4 * chunks..n {
        s += a[k] * b[k];
    }
    s
}

/// [`small_inverse`] for r <= 6 on the stack (the lane design's toggle, 163 times per
/// DETMAX run): the same operations in the same order, nothing allocated. Also answers
/// L^-1 (row-major, lower triangular), L the Cholesky factor of `a`: a^-1 = L^-T L^-1.
pub(super) fn small_inverse6(a: &[f64], r: usize) -> Option<(f64, [f64; 36], [f64; 36])> {
    let (mut l, mut li, mut p) = ([0.0; 36], [0.0; 36], [0.0; 36]);
    if r > 6 || !cholesky_into(&a[..r * r], r, &mut l) {
        return None;
    }
    let ld = (0..r).map(|i| 2.0 * l[i * r + i].ln()).sum();
    inverse_into(&l, r, &mut li, &mut p);
    Some((ld, p, li))
}
