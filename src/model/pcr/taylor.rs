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
//! The residual's integration runs on x86-64 as a kernel of vector intrinsics
//! (`taylor_x86`) with the same operations in the same order as the portable code here.
//! Sums are ordered for short dependency chains: each new coefficient waits for a product
//! and two additions after the previous one (see `products_outward`), not for a whole sum.
//!
//! The variational columns are the exact derivatives of the coefficient recursion (each
//! product `a b` differentiates to `da b + a db`), so they are exact derivatives of the
//! discrete map, as the RK4 ones are: Newton converges quadratically to the discrete
//! solution.

use super::rod::{C, DIM, M, PHI, Rod, S, Seed, State, X, Y, forcing, seed_start};

/// Order of the Taylor series: terms `0..=ORDER` of `c`, `s` and `m` per step.
pub(crate) const ORDER: usize = 13;
/// Number of Taylor coefficients per component.
pub(super) const TERMS: usize = ORDER + 1;
/// Largest number of terms supported by the generic functions.
const MAX_TERMS: usize = 32;
/// Rods integrated side by side: four lanes of every arithmetic operation, which the
/// compiler turns into vector instructions, and independent dependency chains that keep the
/// processor's pipelines full.
pub(super) const L: usize = 4;
/// One value per lane.
pub(super) type Lanes = [f64; L];

/// `1 / j` for `j = 0..=MAX_TERMS` (entry 0 unused).
pub(super) const INV: [f64; MAX_TERMS + 1] = {
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
pub(super) struct Coeffs {
    pub(super) nx: Lanes,
    pub(super) ny: Lanes,
    pub(super) flex: Lanes,
    pub(super) h: Lanes,
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

/// Per order `j`, the factors of the recursion for every lane: `h / (j + 1)` and the same
/// times `flex nx` and `flex ny` (computed once per integration).
pub(super) struct Factors<const T: usize> {
    pub(super) f: [Lanes; T],
    pub(super) kx: [Lanes; T],
    pub(super) ky: [Lanes; T],
}

impl<const T: usize> Factors<T> {
    #[inline(always)]
    pub(super) fn new(co: &Coeffs) -> Self {
        let f: [Lanes; T] = std::array::from_fn(|j| std::array::from_fn(|l| co.h[l] * INV[j + 1]));
        Self {
            f,
            kx: std::array::from_fn(|j| std::array::from_fn(|l| co.flex[l] * co.nx[l] * f[j][l])),
            ky: std::array::from_fn(|j| std::array::from_fn(|l| co.flex[l] * co.ny[l] * f[j][l])),
        }
    }
}

/// Cauchy products `sum_i a_i b_(j-i)` and `sum_i c_i b_(j-i)` for `i = 0..=j`, summed in
/// the order the terms are ready while the series is built: the middle terms first, from
/// the middle outwards in two partial sums, then the end terms `i = 0` (with `b_j`, the
/// newest `b`) and `i = j` (with `a_j` and `c_j`, the newest of all). The chain of dependent
/// operations from one order to the next is then a product and two additions long.
#[inline(always)]
fn products_outward<const T: usize>(
    a: &[Lanes; T],
    c: &[Lanes; T],
    b: &[Lanes; T],
    j: usize,
) -> [Lanes; 2] {
    let (mut p0, mut p1, mut q0, mut q1) = ([0.0; L], [0.0; L], [0.0; L], [0.0; L]);
    let half = j / 2;
    for i in (1..=half).rev() {
        for l in 0..L {
            p0[l] += a[i][l] * b[j - i][l];
            q0[l] += c[i][l] * b[j - i][l];
        }
    }
    for i in half + 1..j {
        for l in 0..L {
            p1[l] += a[i][l] * b[j - i][l];
            q1[l] += c[i][l] * b[j - i][l];
        }
    }
    if j == 0 {
        return [
            std::array::from_fn(|l| a[0][l] * b[0][l]),
            std::array::from_fn(|l| c[0][l] * b[0][l]),
        ];
    }
    [
        std::array::from_fn(|l| ((p0[l] + p1[l]) + a[0][l] * b[j][l]) + a[j][l] * b[0][l]),
        std::array::from_fn(|l| ((q0[l] + q1[l]) + c[0][l] * b[j][l]) + c[j][l] * b[0][l]),
    ]
}

/// Fills `t` (every entry is written) with the coefficients of a step from `(c0, s0, m0)`.
/// `k = flex m` is computed from `(c, s)` directly (`fa.kx`, `fa.ky`), not from `m`, so it
/// is ready one multiplication earlier for the next order.
#[inline(always)]
fn series<const T: usize>(
    t: &mut Series<T>,
    c0: Lanes,
    s0: Lanes,
    m0: Lanes,
    co: &Coeffs,
    fa: &Factors<T>,
) {
    t.c[0] = c0;
    t.s[0] = s0;
    t.m[0] = m0;
    t.k[0] = std::array::from_fn(|l| co.flex[l] * m0[l]);
    // Unrolled: every index is a constant, so the coefficients can stay in registers.
    macro_rules! orders {
        ($($j:literal)*) => { $( if $j + 1 < T { order::<T, $j>(t, co, fa); } )* };
    }
    const { assert!(T <= MAX_TERMS) };
    orders!(0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24 25 26 27 28 29 30);
}

/// Order `J + 1` of the series from the orders up to `J`.
#[inline(always)]
fn order<const T: usize, const J: usize>(t: &mut Series<T>, co: &Coeffs, fa: &Factors<T>) {
    let [a, b] = products_outward(&t.s, &t.c, &t.k, J);
    for l in 0..L {
        let f = fa.f[J][l];
        let (s, c) = (t.s[J][l], t.c[J][l]);
        t.c[J + 1][l] = -f * a[l];
        t.s[J + 1][l] = f * b[l];
        t.m[J + 1][l] = f * (co.nx[l] * s - co.ny[l] * c);
        t.k[J + 1][l] = fa.kx[J][l] * s - fa.ky[J][l] * c;
    }
}

/// Lane states: x, y, c, s, phi, m.
type LaneState = [Lanes; DIM];

/// Adds a step of length `h` with coefficients `t` to the lane states `y`. The new `c`,
/// `s`, `m` (which the next step's series needs first) are summed in the order their terms
/// are made, so only the last addition waits for the last term; `x`, `y`, `phi` smallest
/// terms first.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one lane index across several arrays
fn advance<const T: usize>(y: &mut LaneState, h: &Lanes, t: &Series<T>) {
    let mut o = [[0.0; L]; DIM];
    o[C] = t.c[0];
    o[S] = t.s[0];
    o[M] = t.m[0];
    for j in 1..T {
        for l in 0..L {
            o[C][l] += t.c[j][l];
            o[S][l] += t.s[j][l];
            o[M][l] += t.m[j][l];
        }
    }
    for j in (0..T).rev() {
        for l in 0..L {
            o[X][l] += t.c[j][l] * INV[j + 1];
            o[Y][l] += t.s[j][l] * INV[j + 1];
            o[PHI][l] += t.k[j][l] * INV[j + 1];
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
pub(super) fn pack<const R: usize>(
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

/// Integrates `R` rods from `y0` (Taylor steps of [`ORDER`]); returns the distal states.
pub(crate) fn integrate<const R: usize>(rods: &[Rod; R], y0: &[State; R]) -> [State; R] {
    #[cfg(target_arch = "x86_64")]
    {
        use super::taylor_x86::{avx2, avx512, integrate_avx2, integrate_avx512};
        if avx512() {
            // SAFETY: the processor has the features the function is compiled for.
            return unsafe { integrate_avx512(rods, y0) };
        }
        if avx2() {
            // SAFETY: the processor has AVX2, the feature the function is compiled for.
            return unsafe { integrate_avx2(rods, y0) };
        }
    }
    integrate_terms::<R, TERMS>(rods, y0)
}

/// Integrates `R` rods from `y0` with Taylor series of `T` terms.
#[inline(always)]
fn integrate_terms<const R: usize, const T: usize>(rods: &[Rod; R], y0: &[State; R]) -> [State; R] {
    let mut out = *y0;
    for first in (0..R).step_by(L) {
        let (steps, co, mut y) = pack(rods, y0, first);
        let fa = Factors::<T>::new(&co);
        let mut t = Series::<T>::zero();
        for _ in 0..steps {
            series(&mut t, y[C], y[S], y[M], &co, &fa);
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
    if super::taylor_x86::avx2() {
        // SAFETY: the processor has AVX2, the feature the function is compiled for.
        return unsafe { super::taylor_x86::integrate_var_avx2(rods, y0, seeds) };
    }
    integrate_var_body(rods, y0, seeds)
}

/// The body of [`integrate_var`].
#[inline(always)]
pub(super) fn integrate_var_body<const R: usize, const K: usize>(
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
        let fa = Factors::<TERMS>::new(&co);
        let (mut t, mut d) = (Series::<TERMS>::zero(), Series::<TERMS>::zero());
        for _ in 0..steps {
            series(&mut t, y[C], y[S], y[M], &co, &fa);
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
    use crate::model::pcr::rod::start_state;

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
            let b = crate::model::pcr::shooting::integrate(&[rr], &[y0])[0];
            for i in 0..DIM {
                worst = worst.max((a[i] - b[i]).abs());
            }
        }
        println!("Taylor vs RK4 tips: {worst:e}");
        assert!(worst < 1e-11, "Taylor vs RK4: {worst:e}");
    }

    /// The dispatched integration (the intrinsics kernel for AVX-512 VL or AVX2 where the
    /// processor has them) equals the portable code bit for bit: the same operations in the
    /// same order, only the vector width and the registers differ.
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
        let portable = bits(&integrate_terms::<3, TERMS>(&r, &y0));
        assert_eq!(bits(&integrate(&r, &y0)), portable);
        #[cfg(target_arch = "x86_64")]
        {
            use crate::model::pcr::taylor_x86::{avx2, avx512, integrate_avx2, integrate_avx512};
            if avx2() {
                // SAFETY: the processor has AVX2.
                assert_eq!(bits(&unsafe { integrate_avx2(&r, &y0) }), portable);
                // Five rods: a full group of four lanes and a partial one.
                let (r5, y5) = (
                    [r[0], r[1], r[2], r[1], r[0]],
                    [y0[2], y0[0], y0[1], y0[0], y0[2]],
                );
                let p5 = bits(&integrate_terms::<5, TERMS>(&r5, &y5));
                // SAFETY: as above.
                assert_eq!(bits(&unsafe { integrate_avx2(&r5, &y5) }), p5);
                if avx512() {
                    // SAFETY: the processor has AVX-512 F and VL.
                    assert_eq!(bits(&unsafe { integrate_avx512(&r, &y0) }), portable);
                    // SAFETY: as above.
                    assert_eq!(bits(&unsafe { integrate_avx512(&r5, &y5) }), p5);
                }
            }
        }
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
