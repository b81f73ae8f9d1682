//! The planar Kirchhoff rod of one limb, integrated by hand-written fixed-step RK4 on stack
//! arrays, with optional variational equations for exact Jacobians.
//!
//! Everything here is dimensionless: arc length and positions in units of the solver's
//! reference length `L`, forces in `E I_ref / L^2`, moments in `E I_ref / L`, where `I_ref` is
//! the second moment of area of limb 1. The rod's bending flexibility relative to limb 1 is
//! `flex = I_ref / I_i = (d_1 / d_i)^4` (exactly 1 when all diameters are equal), so the
//! Young's modulus never enters the integration: with no external load the kinematics are
//! independent of `E` bit for bit.
//!
//! The tangent is carried as `(cos phi, sin phi)` and the angle `phi` itself, so no
//! trigonometric function is evaluated inside the integration loop:
//!
//! ```text
//! x' = c   y' = s   c' = -s k   s' = c k   phi' = k   m' = nx s - ny c     (k = flex m)
//! ```
//!
//! `n = (nx, ny)` is constant along the rod (no distributed load).
//!
//! Two methods integrate these equations: classical RK4 here (the straightforward reference)
//! and the Taylor-series method of `taylor` (the fast default, [`Integrator`]).

pub(crate) use super::Integrator;

/// Number of state components: x, y, c = cos(phi), s = sin(phi), phi, m.
pub(crate) const DIM: usize = 6;

/// Index of each state component.
pub(crate) const X: usize = 0;
/// y.
pub(crate) const Y: usize = 1;
/// cos(phi).
pub(crate) const C: usize = 2;
/// sin(phi).
pub(crate) const S: usize = 3;
/// phi (unwrapped).
pub(crate) const PHI: usize = 4;
/// Bending moment m.
pub(crate) const M: usize = 5;

/// A rod state.
pub(crate) type State = [f64; DIM];

/// Which quantity a variational column differentiates with respect to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Seed {
    /// The constant internal force component nx.
    Nx,
    /// The constant internal force component ny.
    Ny,
    /// The proximal moment m(0).
    M0,
    /// The proximal tangent angle phi(0).
    Phi0,
    /// The flexibility ratio `flex`.
    Flex,
}

/// Fixed data of one rod integration.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Rod {
    /// Internal force (constant along the rod), scaled.
    pub(crate) n: [f64; 2],
    /// Flexibility ratio I_ref / I_i.
    pub(crate) flex: f64,
    /// Scaled rod length l_i / L.
    pub(crate) length: f64,
    /// Number of integration steps.
    pub(crate) steps: usize,
    /// The integration method.
    pub(crate) integrator: Integrator,
}

/// Proximal state: position `(x, y)`, angle `phi`, moment `m` (scaled).
#[cfg(test)]
pub(crate) fn start_state(x: f64, y: f64, phi: f64, m: f64) -> State {
    let (s, c) = phi.sin_cos();
    [x, y, c, s, phi, m]
}

/// Proximal state with the tangent `(cos phi, sin phi)` given (computed once per robot).
pub(crate) fn start_state_tangent(x: f64, y: f64, phi: f64, tangent: [f64; 2], m: f64) -> State {
    [x, y, tangent[0], tangent[1], phi, m]
}

#[inline(always)]
fn rhs(y: &State, nx: f64, ny: f64, flex: f64) -> State {
    let k = flex * y[M];
    [y[C], y[S], -y[S] * k, y[C] * k, k, nx * y[S] - ny * y[C]]
}

/// Right-hand side of the ODE at a state: `d(state)/ds` (used for the length derivative).
pub(crate) fn derivative(rod: &Rod, y: &State) -> State {
    rhs(y, rod.n[0], rod.n[1], rod.flex)
}

/// Forcing coefficients of a seed's variational equation: (d nx, d ny, d flex).
pub(crate) fn forcing(seed: Seed) -> [f64; 3] {
    match seed {
        Seed::Nx => [1.0, 0.0, 0.0],
        Seed::Ny => [0.0, 1.0, 0.0],
        Seed::Flex => [0.0, 0.0, 1.0],
        Seed::M0 | Seed::Phi0 => [0.0; 3],
    }
}

#[inline(always)]
fn rhs_var(y: &State, v: &State, fc: &[f64; 3], nx: f64, ny: f64, flex: f64) -> State {
    let k = flex * y[M];
    let dk = flex * v[M] + fc[2] * y[M];
    let (dnx, dny) = (fc[0], fc[1]);
    [
        v[C],
        v[S],
        -v[S] * k - y[S] * dk,
        v[C] * k + y[C] * dk,
        dk,
        dnx * y[S] + nx * v[S] - dny * y[C] - ny * v[C],
    ]
}

/// Stage state `y + h k`. Only c, s and m are advanced: the right-hand side does not read
/// x, y or phi (they are quadratures), so their stage values are never needed.
#[inline(always)]
fn axpy(y: &State, h: f64, k: &State) -> State {
    let mut o = *y;
    o[C] += h * k[C];
    o[S] += h * k[S];
    o[M] += h * k[M];
    o
}

/// Initial value of the variational column for `seed` at the proximal state `y0`.
pub(crate) fn seed_start(seed: Seed, y0: &State) -> State {
    let mut v = [0.0; DIM];
    match seed {
        Seed::M0 => v[M] = 1.0,
        Seed::Phi0 => {
            v[C] = -y0[S];
            v[S] = y0[C];
            v[PHI] = 1.0;
        }
        Seed::Nx | Seed::Ny | Seed::Flex => {}
    }
    v
}

/// RK4 integration of `R` rods in lockstep from `y0`; returns the distal states.
/// Lockstep integration of independent rods keeps the processor's pipelines full: a single
/// RK4 chain is bound by the latency of its dependent operations.
pub(crate) fn rk4<const R: usize>(rods: &[Rod; R], y0: &[State; R]) -> [State; R] {
    let steps = rods.iter().map(|r| r.steps).max().unwrap_or(0);
    let h: [f64; R] = std::array::from_fn(|r| rods[r].length / steps as f64);
    let mut y = *y0;
    for _ in 0..steps {
        for r in 0..R {
            let (nx, ny, f) = (rods[r].n[0], rods[r].n[1], rods[r].flex);
            let hr = h[r];
            let yr = y[r];
            let k1 = rhs(&yr, nx, ny, f);
            let k2 = rhs(&axpy(&yr, 0.5 * hr, &k1), nx, ny, f);
            let k3 = rhs(&axpy(&yr, 0.5 * hr, &k2), nx, ny, f);
            let k4 = rhs(&axpy(&yr, hr, &k3), nx, ny, f);
            for i in 0..DIM {
                y[r][i] += hr / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
            }
        }
    }
    y
}

/// RK4 integration of `R` rods in lockstep together with the variational equations of the
/// `K` seeds.
///
/// The variational equations are integrated with the same RK4 stages as the state, so the
/// derivatives are exact derivatives of the discrete map (not an approximation of it): Newton
/// then converges quadratically to the discrete solution.
pub(crate) fn rk4_var<const R: usize, const K: usize>(
    rods: &[Rod; R],
    y0: &[State; R],
    seeds: [Seed; K],
) -> ([State; R], [[State; K]; R]) {
    let steps = rods.iter().map(|r| r.steps).max().unwrap_or(0);
    let h: [f64; R] = std::array::from_fn(|r| rods[r].length / steps as f64);
    let mut y = *y0;
    let mut v: [[State; K]; R] =
        std::array::from_fn(|r| std::array::from_fn(|j| seed_start(seeds[j], &y0[r])));
    let fc: [[f64; 3]; K] = std::array::from_fn(|j| forcing(seeds[j]));
    for _ in 0..steps {
        for r in 0..R {
            let (nx, ny, f) = (rods[r].n[0], rods[r].n[1], rods[r].flex);
            let hr = h[r];
            let yr = y[r];
            let k1 = rhs(&yr, nx, ny, f);
            let y2 = axpy(&yr, 0.5 * hr, &k1);
            let k2 = rhs(&y2, nx, ny, f);
            let y3 = axpy(&yr, 0.5 * hr, &k2);
            let k3 = rhs(&y3, nx, ny, f);
            let y4 = axpy(&yr, hr, &k3);
            let k4 = rhs(&y4, nx, ny, f);
            for j in 0..K {
                let vj = v[r][j];
                let c = &fc[j];
                let l1 = rhs_var(&yr, &vj, c, nx, ny, f);
                let l2 = rhs_var(&y2, &axpy(&vj, 0.5 * hr, &l1), c, nx, ny, f);
                let l3 = rhs_var(&y3, &axpy(&vj, 0.5 * hr, &l2), c, nx, ny, f);
                let l4 = rhs_var(&y4, &axpy(&vj, hr, &l3), c, nx, ny, f);
                for i in 0..DIM {
                    v[r][j][i] += hr / 6.0 * (l1[i] + 2.0 * (l2[i] + l3[i]) + l4[i]);
                }
            }
            for i in 0..DIM {
                y[r][i] += hr / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
            }
        }
    }
    (y, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rod(steps: usize) -> Rod {
        Rod {
            n: [0.7, -1.3],
            flex: 1.1,
            length: 1.0,
            steps,
            integrator: Integrator::Rk4,
        }
    }

    /// A uniform moment and no force bends the rod into a circular arc: closed form.
    #[test]
    fn pure_moment_gives_a_circular_arc() {
        let r = Rod {
            n: [0.0, 0.0],
            flex: 2.0,
            length: 1.0,
            steps: 400,
            integrator: Integrator::Rk4,
        };
        let m = 0.8;
        let [y] = crate::model::pcr::shooting::integrate(&[r], &[start_state(0.1, 0.2, 0.3, m)]);
        let k = 2.0 * m;
        let (p0, p1) = (0.3_f64, 0.3 + k);
        let xe = 0.1 + (p1.sin() - p0.sin()) / k;
        let ye = 0.2 - (p1.cos() - p0.cos()) / k;
        assert!((y[X] - xe).abs() < 1e-10, "{} vs {xe}", y[X]);
        assert!((y[Y] - ye).abs() < 1e-10, "{} vs {ye}", y[Y]);
        assert!((y[PHI] - p1).abs() < 1e-14);
        assert!((y[M] - m).abs() < 1e-15);
    }

    /// The variational columns equal central finite differences of the discrete map.
    #[test]
    fn variational_columns_match_finite_differences() {
        let y0 = start_state(0.0, 0.0, 0.4, 0.5);
        let seeds = [Seed::Nx, Seed::Ny, Seed::M0, Seed::Phi0, Seed::Flex];
        let (_, [v]) = crate::model::pcr::shooting::integrate_var(&[rod(30)], &[y0], seeds);
        let h = 1e-6;
        for (j, seed) in seeds.iter().enumerate() {
            let eval = |e: f64| {
                let mut r = rod(30);
                let (mut phi, mut m) = (0.4, 0.5);
                match seed {
                    Seed::Nx => r.n[0] += e,
                    Seed::Ny => r.n[1] += e,
                    Seed::M0 => m += e,
                    Seed::Phi0 => phi += e,
                    Seed::Flex => r.flex += e,
                }
                crate::model::pcr::shooting::integrate(&[r], &[start_state(0.0, 0.0, phi, m)])[0]
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
