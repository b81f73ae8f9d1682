//! log det(M ± A_i) for eight candidates at once: a Cholesky factorisation run lane-wise
//! (SIMD across candidates, so every operation is a full vector operation with no horizontal
//! reductions), over the envelope (skyline) of the pool's information matrices in an order
//! that keeps the structural zeros (marker parameters of different clusters never meet) out of
//! the envelope. With AVX2 and FMA the kernel is compiled for them and chosen at run time.

use super::kernels::madd;

/// Candidates evaluated together.
pub(super) const LANES: usize = 8;

/// Skyline (envelope) layout of the symmetric m x m matrices of a pool, in a permuted order:
/// row i stores columns `first[i]..=i`; every entry outside is zero in every matrix (and
/// stays zero in the Cholesky factor).
#[derive(Debug, Clone)]
pub(super) struct Envelope {
    /// Matrix size.
    pub(super) m: usize,
    /// Original index of each position.
    pub(super) order: Vec<usize>,
    /// First stored column of each row (positions).
    pub(super) first: Vec<usize>,
    /// Offset of each row's first stored entry.
    pub(super) off: Vec<usize>,
    /// Stored entries.
    pub(super) len: usize,
}

impl Envelope {
    /// The envelope of a symmetric nonzero pattern (`nz`, m x m row-major; the diagonal is
    /// always stored). Columns are ordered by degree (fewest couplings first), ties by their
    /// pattern, so that groups of parameters coupled only among themselves and to the
    /// dense rest come first, each group contiguous.
    pub(super) fn from_pattern(nz: &[bool], m: usize) -> Self {
        let row = |c: usize| &nz[c * m..(c + 1) * m];
        let degree: Vec<usize> = (0..m)
            .map(|c| row(c).iter().filter(|&&v| v).count())
            .collect();
        let mut order: Vec<usize> = (0..m).collect();
        order.sort_by(|&a, &b| {
            degree[a]
                .cmp(&degree[b])
                .then_with(|| row(b).cmp(row(a)))
                .then(a.cmp(&b))
        });
        let first: Vec<usize> = (0..m)
            .map(|i| (0..i).find(|&j| nz[order[i] * m + order[j]]).unwrap_or(i))
            .collect();
        let mut off = Vec::with_capacity(m);
        let mut len = 0;
        for (i, &f) in first.iter().enumerate() {
            off.push(len);
            len += i + 1 - f;
        }
        Self {
            m,
            order,
            first,
            off,
            len,
        }
    }

    /// Storage index of (i, j), positions with j <= i, if inside the envelope.
    #[cfg(test)]
    pub(super) fn index(&self, i: usize, j: usize) -> Option<usize> {
        (j >= self.first[i] && j <= i).then(|| self.off[i] + j - self.first[i])
    }
}

/// Scratch of [`log_dets`], sized for one envelope.
#[derive(Clone)]
pub(super) struct Work {
    buf: Vec<[f64; LANES]>,
    inv: Vec<[f64; LANES]>,
}

impl Work {
    pub(super) fn new(env: &Envelope) -> Self {
        Self {
            buf: vec![[0.0; LANES]; env.len],
            inv: vec![[0.0; LANES]; env.m],
        }
    }
}

/// log det(M + sign A_l) for the eight matrices of `a` (envelope storage, lane-interleaved:
/// entry k of lane l at `a[k * LANES + l]`), M in envelope storage; -inf for a lane whose
/// matrix is not positive definite.
pub(super) fn log_dets(
    env: &Envelope,
    mk: &[f64],
    a: &[f64],
    sign: f64,
    work: &mut Work,
    out: &mut [f64; LANES],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports the features the function is compiled for.
        unsafe { log_dets_fma(env, mk, a, sign, work, out) };
        return;
    }
    body::<false>(env, mk, a, sign, work, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn log_dets_fma(
    env: &Envelope,
    mk: &[f64],
    a: &[f64],
    sign: f64,
    work: &mut Work,
    out: &mut [f64; LANES],
) {
    body::<true>(env, mk, a, sign, work, out);
}

/// Left-looking Cholesky over the envelope, lane-wise; log det from the product of the
/// pivots with the binary exponent split off every eight pivots (no logarithm per pivot).
#[inline(always)]
fn body<const FMA: bool>(
    env: &Envelope,
    mk: &[f64],
    a: &[f64],
    sign: f64,
    work: &mut Work,
    out: &mut [f64; LANES],
) {
    let Work { buf, inv } = work;
    for ((b, &mv), av) in buf.iter_mut().zip(mk).zip(a.chunks_exact(LANES)) {
        for l in 0..LANES {
            b[l] = madd::<FMA>(sign, av[l], mv);
        }
    }
    let mut ok = [true; LANES];
    let mut prod = [1.0f64; LANES];
    let mut exponent = [0i64; LANES];
    for i in 0..env.m {
        let (fi, oi) = (env.first[i], env.off[i]);
        for j in fi..=i {
            let (fj, oj) = (env.first[j], env.off[j]);
            let k0 = fi.max(fj);
            let n = j - k0;
            let (xi, xj) = (oi + k0 - fi, oj + k0 - fj);
            let mut acc = [[0.0f64; LANES]; 4];
            let mut k = 0;
            while k + 4 <= n {
                for (u, au) in acc.iter_mut().enumerate() {
                    let (x, y) = (buf[xi + k + u], buf[xj + k + u]);
                    for l in 0..LANES {
                        au[l] = madd::<FMA>(x[l], y[l], au[l]);
                    }
                }
                k += 4;
            }
            while k < n {
                let (x, y) = (buf[xi + k], buf[xj + k]);
                for l in 0..LANES {
                    acc[0][l] = madd::<FMA>(x[l], y[l], acc[0][l]);
                }
                k += 1;
            }
            let at = oi + j - fi;
            let mut s = buf[at];
            for l in 0..LANES {
                s[l] -= (acc[0][l] + acc[1][l]) + (acc[2][l] + acc[3][l]);
            }
            if i == j {
                for l in 0..LANES {
                    let v = if s[l] > 0.0 {
                        s[l]
                    } else {
                        ok[l] = false;
                        1.0
                    };
                    let d = v.sqrt();
                    buf[at][l] = d;
                    inv[i][l] = 1.0 / d;
                    prod[l] *= v;
                }
                if i % 8 == 7 {
                    split_exponent(&mut prod, &mut exponent);
                }
            } else {
                for l in 0..LANES {
                    buf[at][l] = s[l] * inv[j][l];
                }
            }
        }
    }
    split_exponent(&mut prod, &mut exponent);
    for l in 0..LANES {
        out[l] = if ok[l] {
            prod[l].ln() + exponent[l] as f64 * std::f64::consts::LN_2
        } else {
            f64::NEG_INFINITY
        };
    }
}

/// Move the binary exponent of each (positive, normal) product into `exponent`.
#[inline(always)]
fn split_exponent(prod: &mut [f64; LANES], exponent: &mut [i64; LANES]) {
    const MASK: u64 = 0x7ff << 52;
    for l in 0..LANES {
        let b = prod[l].to_bits();
        exponent[l] += ((b & MASK) >> 52) as i64 - 1023;
        prod[l] = f64::from_bits((b & !MASK) | (1023 << 52));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::Rng;
    use nalgebra::DMatrix;

    /// An arrow pattern (three groups coupled only to a dense tail) in a shuffled order: the
    /// envelope puts the groups first and contiguous, and the lane-wise log determinants
    /// equal nalgebra's Cholesky to rounding, with -inf where M - A is not positive definite.
    #[test]
    fn lane_log_dets_equal_a_dense_cholesky() {
        let mut rng = Rng::new(21);
        let m = 17;
        // Column c belongs to group c % 4 (group 3: the dense tail, coupled to everything).
        let group = |c: usize| c % 4;
        let coupled = |a: usize, b: usize| group(a) == 3 || group(b) == 3 || group(a) == group(b);
        let block = |rng: &mut Rng| {
            DMatrix::from_fn(12, m, |r, c| {
                if group(c) == 3 || group(c) == r % 3 {
                    rng.normal()
                } else {
                    0.0
                }
            })
        };
        let mut nz = vec![false; m * m];
        for a in 0..m {
            for b in 0..m {
                nz[a * m + b] = coupled(a, b);
            }
        }
        let env = Envelope::from_pattern(&nz, m);
        assert!(env.len < m * (m + 1) / 2, "{} entries", env.len);
        assert!(env.order[m - 4..].iter().all(|&c| group(c) == 3));
        let base = block(&mut rng);
        let mbig = base.tr_mul(&base) * 3.0 + DMatrix::identity(m, m);
        // Lane 0 holds twice the base block: M - A_0 = I - base^T base is indefinite.
        let mut blocks: Vec<DMatrix<f64>> = (0..LANES).map(|_| block(&mut rng)).collect();
        blocks[0] = &base * 2.0;
        let pack = |a: &DMatrix<f64>| {
            let mut v = vec![0.0; env.len];
            for i in 0..m {
                for j in env.first[i]..=i {
                    v[env.index(i, j).unwrap()] = a[(env.order[i], env.order[j])];
                }
                // Outside the envelope the matrix is zero.
                for j in 0..env.first[i] {
                    assert_eq!(a[(env.order[i], env.order[j])], 0.0);
                }
            }
            v
        };
        let mk = pack(&mbig);
        let mut a = vec![0.0; env.len * LANES];
        for (l, b) in blocks.iter().enumerate() {
            for (k, v) in pack(&b.tr_mul(b)).into_iter().enumerate() {
                a[k * LANES + l] = v;
            }
        }
        let mut work = Work::new(&env);
        let mut out = [0.0; LANES];
        for sign in [1.0, -1.0] {
            log_dets(&env, &mk, &a, sign, &mut work, &mut out);
            for (l, b) in blocks.iter().enumerate() {
                let dense = &mbig + b.tr_mul(b) * sign;
                match dense.cholesky() {
                    Some(c) => {
                        let want: f64 = c.l_dirty().diagonal().iter().map(|v| 2.0 * v.ln()).sum();
                        assert!((out[l] - want).abs() < 1e-12 * want.abs().max(1.0));
                    }
                    None => assert_eq!(out[l], f64::NEG_INFINITY),
                }
            }
        }
        assert_eq!(out[0], f64::NEG_INFINITY);
    }
}
