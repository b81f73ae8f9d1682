//! Taylor-series integration of the planar Kirchhoff rod (the fast integrator), with exact
//! variational equations.
//!
//! The rod's equations (`rod`) are polynomial of degree two in `(c, s, m)`:
//!
//! ```text
//! c' = -s k   s' = c k   m' = nx s - ny c   k = flex m   (x' = c, y' = s, phi' = k)
//! ```
//!
//! so the Taylor coefficients of the solution about a point follow from the state there by
//! Cauchy products, to any order, without evaluating a trigonometric function. A step of
//! length `h` sums the series with its coefficients pre-scaled by `h^j`. With [`ORDER`] 13
//! and four steps per rod the tip error on the 3-PF workspace is about 1e-11 m (RK4 needs
//! 48 steps for 6e-10 m), with less than half of the arithmetic, done four rods at a time.
//!
//! The variational columns are the exact derivatives of the coefficient recursion (each
//! product `a b` differentiates to `da b + a db`), so they are exact derivatives of the
//! discrete map, as the RK4 ones are: Newton converges quadratically to the discrete
//! solution.

use super::rod::{C, DIM, M, PHI, Rod, S, Seed, State, X, Y, forcing, seed_start};

/// Order of the Taylor series: terms `0..=ORDER` of `c`, `s` and `m` per step.
pub(crate) const ORDER: usize = 13;
/// Number of Taylor coefficients per component.
const TERMS: usize = ORDER + 1;
/// Largest number of terms supported by the generic functions.
const MAX_TERMS: usize = 32;
/// Rods integrated side by side: four lanes of every arithmetic operation, which the
/// compiler turns into vector instructions, and independent dependency chains that keep the
/// processor's pipelines full.
const L: usize = 4;
/// One value per lane.
type Lanes = [f64; L];

/// `1 / j` for `j = 0..=MAX_TERMS` (entry 0 unused).
const INV: [f64; MAX_TERMS + 1] = {
    let mut a = [0.0; MAX_TERMS + 1];
    let mut j = 1;
    while j <= MAX_TERMS {
        a[j] = 1.0 / j as f64;
        j += 1;
    }
    a
};

/// Per lane: the rod's force, flexibility and step length.
#[derive(Clone, Copy)]
struct Coeffs {
    nx: Lanes,
    ny: Lanes,
    flex: Lanes,
    h: Lanes,
}

/// Taylor coefficients of one step for every lane, scaled by `h^j`: `c`, `s`, `m` and
/// `k = flex m`.
struct Series<const T: usize> {
    c: [Lanes; T],
    s: [Lanes; T],
    m: [Lanes; T],
    k: [Lanes; T],
}

/// Cauchy products `sum_i a_i b_(j-i)` and `sum_i c_i b_(j-i)` for `i = 0..=j`, with two
/// partial sums each (shorter dependency chains).
#[inline(always)]
fn products<const T: usize>(
    a: &[Lanes; T],
    c: &[Lanes; T],
    b: &[Lanes; T],
    j: usize,
) -> [Lanes; 2] {
    let (mut p0, mut p1, mut q0, mut q1) = ([0.0; L], [0.0; L], [0.0; L], [0.0; L]);
    let mut i = 0;
    while i < j {
        for l in 0..L {
            p0[l] += a[i][l] * b[j - i][l];
            q0[l] += c[i][l] * b[j - i][l];
            p1[l] += a[i + 1][l] * b[j - i - 1][l];
            q1[l] += c[i + 1][l] * b[j - i - 1][l];
        }
        i += 2;
    }
    if i == j {
        for l in 0..L {
            p0[l] += a[j][l] * b[0][l];
            q0[l] += c[j][l] * b[0][l];
        }
    }
    [
        std::array::from_fn(|l| p0[l] + p1[l]),
        std::array::from_fn(|l| q0[l] + q1[l]),
    ]
}

impl<const T: usize> Series<T> {
    fn zero() -> Self {
        Self {
            c: [[0.0; L]; T],
            s: [[0.0; L]; T],
            m: [[0.0; L]; T],
            k: [[0.0; L]; T],
        }
    }
}

/// Fills `t` (every entry is written) with the coefficients of a step from `(c0, s0, m0)`.
#[inline(always)]
fn series<const T: usize>(t: &mut Series<T>, c0: Lanes, s0: Lanes, m0: Lanes, co: &Coeffs) {
    t.c[0] = c0;
    t.s[0] = s0;
    t.m[0] = m0;
    t.k[0] = std::array::from_fn(|l| co.flex[l] * m0[l]);
    for j in 0..T - 1 {
        let [a, b] = products(&t.s, &t.c, &t.k, j);
        for l in 0..L {
            let f = co.h[l] * INV[j + 1];
            t.c[j + 1][l] = -f * a[l];
            t.s[j + 1][l] = f * b[l];
            t.m[j + 1][l] = f * (co.nx[l] * t.s[j][l] - co.ny[l] * t.c[j][l]);
            t.k[j + 1][l] = co.flex[l] * t.m[j + 1][l];
        }
    }
}

/// Lane states: x, y, c, s, phi, m.
type LaneState = [Lanes; DIM];

/// Adds a step of length `h` with coefficients `t` to the lane states `y`.
#[inline(always)]
fn advance<const T: usize>(y: &mut LaneState, h: &Lanes, t: &Series<T>) {
    let mut o = [[0.0; L]; DIM];
    // Smallest terms first.
    for j in (0..T).rev() {
        for l in 0..L {
            o[X][l] += t.c[j][l] * INV[j + 1];
            o[Y][l] += t.s[j][l] * INV[j + 1];
            o[PHI][l] += t.k[j][l] * INV[j + 1];
            o[C][l] += t.c[j][l];
            o[S][l] += t.s[j][l];
            o[M][l] += t.m[j][l];
        }
    }
    for l in 0..L {
        y[X][l] += h[l] * o[X][l];
        y[Y][l] += h[l] * o[Y][l];
        y[PHI][l] += h[l] * o[PHI][l];
        y[C][l] = o[C][l];
        y[S][l] = o[S][l];
        y[M][l] = o[M][l];
    }
}

/// Step count, per-lane coefficients and lane states of the rods `first..first + L` (lanes
/// past the last rod repeat it).
#[inline(always)]
fn pack<const R: usize>(
    rods: &[Rod; R],
    y0: &[State; R],
    first: usize,
) -> (usize, Coeffs, LaneState) {
    let steps = rods.iter().map(|r| r.steps).max().unwrap_or(0);
    let idx = |l: usize| (first + l).min(R - 1);
    let co = Coeffs {
        nx: std::array::from_fn(|l| rods[idx(l)].n[0]),
        ny: std::array::from_fn(|l| rods[idx(l)].n[1]),
        flex: std::array::from_fn(|l| rods[idx(l)].flex),
        h: std::array::from_fn(|l| rods[idx(l)].length / steps as f64),
    };
    let y = std::array::from_fn(|i| std::array::from_fn(|l| y0[idx(l)][i]));
    (steps, co, y)
}

/// Whether the processor has AVX2: the lanes then run in one 256-bit register instead of
/// two 128-bit ones. Only vector width changes (no fused multiply-add), so the results are
/// bit for bit those of the portable code.
#[cfg(target_arch = "x86_64")]
fn avx2() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
}

/// Integrates `R` rods from `y0` (Taylor steps of [`ORDER`]); returns the distal states.
pub(crate) fn integrate<const R: usize>(rods: &[Rod; R], y0: &[State; R]) -> [State; R] {
    #[cfg(target_arch = "x86_64")]
    if avx2() {
        // SAFETY: the processor supports AVX2, the only feature the function is compiled for.
        return unsafe { integrate_avx2(rods, y0) };
    }
    integrate_terms::<R, TERMS>(rods, y0)
}

/// [`integrate`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn integrate_avx2<const R: usize>(rods: &[Rod; R], y0: &[State; R]) -> [State; R] {
    integrate_terms::<R, TERMS>(rods, y0)
}

/// Integrates `R` rods from `y0` with Taylor series of `T` terms.
#[inline(always)]
fn integrate_terms<const R: usize, const T: usize>(rods: &[Rod; R], y0: &[State; R]) -> [State; R] {
    let mut out = *y0;
    for first in (0..R).step_by(L) {
        let (steps, co, mut y) = pack(rods, y0, first);
        let mut t = Series::<T>::zero();
        for _ in 0..steps {
            series(&mut t, y[C], y[S], y[M], &co);
            advance(&mut y, &co.h, &t);
        }
        for (l, o) in out.iter_mut().skip(first).take(L).enumerate() {
            *o = std::array::from_fn(|i| y[i][l]);
        }
    }
    out
}

/// Fills `d` (every entry is written) with the coefficients of one variational column
/// (every lane) over a step, given the state's coefficients `t` and the seed's forcing `fc`
/// = (d nx, d ny, d flex).
#[inline(always)]
fn series_var<const T: usize>(
    d: &mut Series<T>,
    v: &LaneState,
    t: &Series<T>,
    fc: &[f64; 3],
    co: &Coeffs,
) {
    let (dnx, dny, dflex) = (fc[0], fc[1], fc[2]);
    d.c[0] = v[C];
    d.s[0] = v[S];
    d.m[0] = v[M];
    d.k[0] = std::array::from_fn(|l| co.flex[l] * v[M][l] + dflex * t.m[0][l]);
    for j in 0..T - 1 {
        // d(s k) = ds k + s dk, d(c k) = dc k + c dk.
        let [a1, b1] = products(&d.s, &d.c, &t.k, j);
        let [a2, b2] = products(&t.s, &t.c, &d.k, j);
        for l in 0..L {
            let f = co.h[l] * INV[j + 1];
            d.c[j + 1][l] = -f * (a1[l] + a2[l]);
            d.s[j + 1][l] = f * (b1[l] + b2[l]);
            d.m[j + 1][l] = f
                * (dnx * t.s[j][l] + co.nx[l] * d.s[j][l] - dny * t.c[j][l] - co.ny[l] * d.c[j][l]);
            d.k[j + 1][l] = co.flex[l] * d.m[j + 1][l] + dflex * t.m[j + 1][l];
        }
    }
}

/// Integrates `R` rods in lockstep together with the variational equations of the `K`
/// seeds; returns the distal states and, per rod, the derivative of its distal state with
/// respect to each seed (exact derivatives of the discrete map).
pub(crate) fn integrate_var<const R: usize, const K: usize>(
    rods: &[Rod; R],
    y0: &[State; R],
    seeds: [Seed; K],
) -> ([State; R], [[State; K]; R]) {
    #[cfg(target_arch = "x86_64")]
    if avx2() {
        // SAFETY: the processor supports AVX2, the only feature the function is compiled for.
        return unsafe { integrate_var_avx2(rods, y0, seeds) };
    }
    integrate_var_body(rods, y0, seeds)
}

/// [`integrate_var`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn integrate_var_avx2<const R: usize, const K: usize>(
    rods: &[Rod; R],
    y0: &[State; R],
    seeds: [Seed; K],
) -> ([State; R], [[State; K]; R]) {
    integrate_var_body(rods, y0, seeds)
}

/// The body of [`integrate_var`].
#[inline(always)]
fn integrate_var_body<const R: usize, const K: usize>(
    rods: &[Rod; R],
    y0: &[State; R],
    seeds: [Seed; K],
) -> ([State; R], [[State; K]; R]) {
    let fc: [[f64; 3]; K] = std::array::from_fn(|j| forcing(seeds[j]));
    let mut out = *y0;
    let mut dout: [[State; K]; R] = [[[0.0; DIM]; K]; R];
    for first in (0..R).step_by(L) {
        let (steps, co, mut y) = pack(rods, y0, first);
        let idx = |l: usize| (first + l).min(R - 1);
        let mut v: [LaneState; K] = std::array::from_fn(|j| {
            let cols: [State; L] = std::array::from_fn(|l| seed_start(seeds[j], &y0[idx(l)]));
            std::array::from_fn(|i| std::array::from_fn(|l| cols[l][i]))
        });
        let (mut t, mut d) = (Series::<TERMS>::zero(), Series::<TERMS>::zero());
        for _ in 0..steps {
            series(&mut t, y[C], y[S], y[M], &co);
            for (vj, fcj) in v.iter_mut().zip(&fc) {
                series_var(&mut d, vj, &t, fcj, &co);
                advance(vj, &co.h, &d);
            }
            advance(&mut y, &co.h, &t);
        }
        for l in 0..L.min(R - first) {
            out[first + l] = std::array::from_fn(|i| y[i][l]);
            for (j, vj) in v.iter().enumerate() {
                dout[first + l][j] = std::array::from_fn(|i| vj[i][l]);
            }
        }
    }
    (out, dout)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::pcr::Integrator;
    use crate::model::pcr::rod::{self, start_state};

    fn rod(n: [f64; 2], m: f64, steps: usize, integrator: Integrator) -> (Rod, State) {
        let r = Rod {
            n,
            flex: 1.1,
            length: 1.0,
            steps,
            integrator,
        };
        (r, start_state(0.1, -0.2, 0.4, m))
    }

    /// With short steps the Taylor integration of strongly loaded rods (beyond the 3-PF
    /// workspace's scaled forces and moments of about 5) equals 2,048 RK4 steps to rounding:
    /// the coefficient recursion is right. (Its accuracy with the default steps is checked
    /// on the kinematics in `tests`.)
    #[test]
    fn taylor_tips_equal_fine_rk4_tips() {
        let mut worst = 0.0_f64;
        for (n, m) in [([0.7, -1.3], 0.5), ([-3.0, 2.0], -1.5), ([8.0, 0.5], 2.0)] {
            let (r, y0) = rod(n, m, 16, Integrator::Taylor);
            let (rr, _) = rod(n, m, 2048, Integrator::Rk4);
            let a = integrate(&[r], &[y0])[0];
            let b = rod::integrate(&[rr], &[y0])[0];
            for i in 0..DIM {
                worst = worst.max((a[i] - b[i]).abs());
            }
        }
        println!("Taylor vs RK4 tips: {worst:e}");
        assert!(worst < 1e-11, "Taylor vs RK4: {worst:e}");
    }

    /// The dispatched integration (AVX2 where the processor has it) equals the portable
    /// code bit for bit: only the vector width differs.
    #[test]
    fn dispatched_integration_equals_portable_code_bit_for_bit() {
        let seeds = [Seed::Nx, Seed::Ny, Seed::M0, Seed::Phi0, Seed::Flex];
        let rods: [(Rod, State); 3] = [
            rod([0.7, -1.3], 0.5, 4, Integrator::Taylor),
            rod([-3.0, 2.0], -1.5, 4, Integrator::Taylor),
            rod([8.0, 0.5], 2.0, 4, Integrator::Taylor),
        ];
        let (r, y0) = (rods.map(|p| p.0), rods.map(|p| p.1));
        let bits = |a: &[State]| -> Vec<u64> { a.iter().flatten().map(|v| v.to_bits()).collect() };
        assert_eq!(
            bits(&integrate(&r, &y0)),
            bits(&integrate_terms::<3, TERMS>(&r, &y0))
        );
        let (a, da) = integrate_var(&r, &y0, seeds);
        let (b, db) = integrate_var_body(&r, &y0, seeds);
        assert_eq!(bits(&a), bits(&b));
        assert_eq!(bits(&da.concat()), bits(&db.concat()));
    }

    /// The variational columns equal central finite differences of the discrete map.
    #[test]
    fn variational_columns_match_finite_differences() {
        let seeds = [Seed::Nx, Seed::Ny, Seed::M0, Seed::Phi0, Seed::Flex];
        let (r0, y0) = rod([0.7, -1.3], 0.5, 2, Integrator::Taylor);
        let (_, [v]) = integrate_var(&[r0], &[y0], seeds);
        let h = 1e-6;
        for (j, seed) in seeds.iter().enumerate() {
            let eval = |e: f64| {
                let mut r = r0;
                let (mut phi, mut m) = (0.4, 0.5);
                match seed {
                    Seed::Nx => r.n[0] += e,
                    Seed::Ny => r.n[1] += e,
                    Seed::M0 => m += e,
                    Seed::Phi0 => phi += e,
                    Seed::Flex => r.flex += e,
                }
                integrate(&[r], &[start_state(0.1, -0.2, phi, m)])[0]
            };
            let (p, q) = (eval(h), eval(-h));
            for i in 0..DIM {
                let fd = (p[i] - q[i]) / (2.0 * h);
                assert!(
                    (fd - v[j][i]).abs() < 1e-8,
                    "seed {seed:?} comp {i}: {fd} vs {}",
                    v[j][i]
                );
            }
        }
    }
}
