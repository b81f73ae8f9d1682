//! The exchange state of DETMAX: membership, P = M^-1 and D_i = B_i P B_i^T of every
//! candidate, updated in place (Woodbury) when a candidate enters or leaves. Every buffer is
//! allocated once per design; a toggle allocates only the r x r inverse of its candidate.

use super::kernels::{Strided, dot, gemm, log_det_identity_plus, small_inverse};
use super::pool::Pool;

/// Buffers of one toggle, sized for the largest block.
#[derive(Clone)]
struct Workspace {
    /// U = P B_a^T (m x r, row-major).
    u: Vec<f64>,
    /// U S^-1 (m x r, row-major).
    us: Vec<f64>,
    /// E = B_all U (rows x r, row-major: each candidate's rows contiguous).
    e: Vec<f64>,
    /// E S^-1 (rows x r, row-major), for blocks of mixed sizes.
    es: Vec<f64>,
}

/// Exchange state of a design.
#[derive(Clone)]
pub(super) struct Design<'a> {
    pool: &'a Pool,
    pub(super) member: Vec<bool>,
    pub(super) log_det: f64,
    /// P = M^-1 (m x m, symmetric).
    p: Vec<f64>,
    /// Offsets of each candidate's D_i in `d`.
    off: Vec<usize>,
    d: Vec<f64>,
    pub(super) updates: usize,
    ws: Workspace,
}

impl<'a> Design<'a> {
    pub(super) fn new(pool: &'a Pool, start: &[usize], ridge: f64) -> Option<Self> {
        let mut off = Vec::with_capacity(pool.len());
        let mut total = 0;
        for &r in &pool.rows {
            off.push(total);
            total += r * r;
        }
        let mut member = vec![false; pool.len()];
        for &i in start {
            member[i] = true;
        }
        let (m, rows) = (pool.m, pool.stacked.nrows());
        let rmax = pool.rows.iter().copied().max().unwrap_or(0);
        let mut d = Self {
            pool,
            member,
            log_det: 0.0,
            p: vec![0.0; m * m],
            off,
            d: vec![0.0; total],
            updates: 0,
            ws: Workspace {
                u: vec![0.0; m * rmax],
                us: vec![0.0; m * rmax],
                e: vec![0.0; rows * rmax],
                es: vec![0.0; rows * rmax],
            },
        };
        d.rebuild(ridge)?;
        Some(d)
    }

    /// The stacked blocks (column-major, rows x m) as a strided operand.
    fn all(&self) -> Strided<'a> {
        let st = &self.pool.stacked;
        Strided {
            data: st.as_slice(),
            rs: 1,
            cs: st.nrows(),
        }
    }

    /// Recompute P and every D_i from scratch (start, and to stop drift).
    pub(super) fn rebuild(&mut self, ridge: f64) -> Option<()> {
        let pool = self.pool;
        let (m, rows) = (pool.m, pool.stacked.nrows());
        let all = pool.stacked.as_slice();
        let members = self.selected();
        let f = pool.information_factor(&members, ridge)?;
        self.log_det = f.log_det();
        self.p = f.inverse();
        // W = B_all P (rows x m, row-major); D_i[x][y] = W_(r0+x) . B_(r0+y).
        let mut w = vec![0.0; rows * m];
        let p = Strided {
            data: &self.p,
            rs: m,
            cs: 1,
        };
        gemm((rows, m, m), 1.0, self.all(), p, 0.0, &mut w, m, 1);
        for (i, &r) in pool.rows.iter().enumerate() {
            let (r0, o) = (pool.row0[i], self.off[i]);
            for x in 0..r {
                let wx = &w[(r0 + x) * m..(r0 + x + 1) * m];
                for y in 0..r {
                    let s: f64 = (0..m).map(|c| wx[c] * all[r0 + y + c * rows]).sum();
                    self.d[o + x * r + y] = s;
                }
            }
        }
        self.updates = 0;
        Some(())
    }

    /// Change of log det if candidate i were added (sign +1) or removed (sign -1):
    /// log det(I + sign D_i). `scratch` holds at least 2 r^2 values.
    pub(super) fn change(&self, i: usize, sign: f64, scratch: &mut [f64]) -> f64 {
        let r = self.pool.rows[i];
        if r == 0 {
            return 0.0;
        }
        log_det_identity_plus(&self.d[self.off[i]..self.off[i] + r * r], r, sign, scratch)
    }

    /// Add (sign +1) or remove (sign -1) candidate `a`, updating P and every D_i (Woodbury),
    /// with the large products done as matrix multiplications into the workspace.
    pub(super) fn toggle(&mut self, a: usize, sign: f64) -> Option<()> {
        let pool = self.pool;
        let r = pool.rows[a];
        if r > 0 {
            let (m, rows) = (pool.m, pool.stacked.nrows());
            let da = &self.d[self.off[a]..self.off[a] + r * r];
            let s: Vec<f64> = (0..r * r)
                .map(|k| sign * da[k] + if k % (r + 1) == 0 { 1.0 } else { 0.0 })
                .collect();
            let (ld, sinv) = small_inverse(&s, r)?;
            let all = pool.stacked.as_slice();
            let Workspace { u, us, e, es } = &mut self.ws;
            // U = P B_a^T (m x r); E = B_all U (rows x r).
            let bat = op(&all[pool.row0[a]..], rows, 1);
            gemm((m, m, r), 1.0, op(&self.p, m, 1), bat, 0.0, u, r, 1);
            match r {
                2 => narrow::<2>(all, rows, &u[..m * 2], e),
                3 => narrow::<3>(all, rows, &u[..m * 3], e),
                6 => narrow::<6>(all, rows, &u[..m * 6], e),
                _ => gemm(
                    (rows, m, r),
                    1.0,
                    op(all, 1, rows),
                    op(u, r, 1),
                    0.0,
                    e,
                    r,
                    1,
                ),
            }
            // P' = P - sign (U S^-1) U^T.
            let sv = op(&sinv, r, 1);
            gemm((m, r, r), 1.0, op(u, r, 1), sv, 0.0, us, r, 1);
            gemm(
                (m, r, m),
                -sign,
                op(us, r, 1),
                op(u, 1, r),
                1.0,
                &mut self.p,
                m,
                1,
            );
            // D_i' = D_i - sign E_i S^-1 E_i^T.
            gemm((rows, r, r), 1.0, op(e, r, 1), sv, 0.0, es, r, 1);
            for (i, &ri) in pool.rows.iter().enumerate() {
                let (r0, o) = (pool.row0[i], self.off[i]);
                for x in 0..ri {
                    let ex = &es[(r0 + x) * r..(r0 + x + 1) * r];
                    for y in 0..=x {
                        let v = dot(ex, &e[(r0 + y) * r..(r0 + y + 1) * r]);
                        self.d[o + x * ri + y] -= sign * v;
                        if y != x {
                            self.d[o + y * ri + x] = self.d[o + x * ri + y];
                        }
                    }
                }
            }
            self.log_det += ld;
        }
        self.member[a] = sign > 0.0;
        self.updates += 1;
        Some(())
    }

    /// Greedy step: add the outside candidate raising log det most, or remove the inside one
    /// lowering it least.
    pub(super) fn greedy(&mut self, add: bool) -> Option<usize> {
        let sign = if add { 1.0 } else { -1.0 };
        let rmax = self.pool.rows.iter().copied().max().unwrap_or(0);
        let mut scratch = vec![0.0; 2 * rmax * rmax];
        let mut best: Option<(usize, f64)> = None;
        for i in 0..self.pool.len() {
            if self.member[i] == add {
                continue;
            }
            let c = self.change(i, sign, &mut scratch);
            if best.is_none_or(|b| c > b.1) {
                best = Some((i, c));
            }
        }
        let (best, _) = best?;
        self.toggle(best, sign)?;
        Some(best)
    }

    pub(super) fn selected(&self) -> Vec<usize> {
        (0..self.member.len()).filter(|&i| self.member[i]).collect()
    }
}

/// E = B_all U for a narrow U (m x R, row-major) and B_all column-major (rows x m), E
/// row-major: one pass over B per column, no packing (the general GEMM packs both operands,
/// which costs more than the product itself when R is 2 to 6).
fn narrow<const R: usize>(all: &[f64], rows: usize, u: &[f64], e: &mut [f64]) {
    let e = &mut e[..rows * R];
    e.fill(0.0);
    for (c, uc) in u.chunks_exact(R).enumerate() {
        let mut w = [0.0; R];
        w.copy_from_slice(uc);
        let bc = &all[c * rows..(c + 1) * rows];
        for (er, &b) in e.chunks_exact_mut(R).zip(bc) {
            for x in 0..R {
                er[x] += b * w[x];
            }
        }
    }
}

/// A strided operand.
fn op(data: &[f64], rs: usize, cs: usize) -> Strided<'_> {
    Strided { data, rs, cs }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::Rng;

    /// The unpacked narrow product equals the general GEMM to rounding.
    #[test]
    fn narrow_product_equals_the_general_one() {
        let mut rng = Rng::new(4);
        let (rows, m) = (37, 11);
        let all: Vec<f64> = (0..rows * m).map(|_| rng.normal()).collect();
        let u: Vec<f64> = (0..m * 3).map(|_| rng.normal()).collect();
        let (mut a, mut b) = (vec![1.0; rows * 3], vec![0.0; rows * 3]);
        narrow::<3>(&all, rows, &u, &mut a);
        gemm(
            (rows, m, 3),
            1.0,
            op(&all, 1, rows),
            op(&u, 3, 1),
            0.0,
            &mut b,
            3,
            1,
        );
        let err = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-12, "{err:e}");
    }
}
