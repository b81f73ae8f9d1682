//! The solver-ready, dimensionless description of a 3-PF robot ([`Setup`]) and of what a
//! solve is given ([`Mode`]): joints for forward kinematics, the platform pose for inverse
//! kinematics. Lengths are in the reference length `L`, forces in `E I_1 / L^2`, moments in
//! `E I_1 / L`.

use super::params::PcrParams;
use super::{Integrator, Load};
use crate::geometry::wrap_angle;

/// Scaled, solver-ready geometry of one limb.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LimbSetup {
    /// Proximal clamp at q = 0 (in L).
    pub(crate) a: [f64; 2],
    /// Unit stage axis.
    pub(crate) u: [f64; 2],
    /// Proximal tangent angle gamma + alpha.
    pub(crate) phi0: f64,
    /// `(cos phi0, sin phi0)`, computed once (the proximal state needs them every solve).
    pub(crate) tangent0: [f64; 2],
    /// Bending flexibility relative to limb 1, (d_1 / d_i)^4.
    pub(crate) flex: f64,
    /// Rod length (in L).
    pub(crate) length: f64,
    /// Distal clamp in {P} (in L).
    pub(crate) b: [f64; 2],
    /// Distal tangent angle in {P}, unwrapped next to `phi0` (the rod makes no loop).
    pub(crate) beta: f64,
}

/// Everything the shooting residual needs apart from the unknowns and the inputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Setup {
    /// The three limbs.
    pub(crate) limbs: [LimbSetup; 3],
    /// Scaled external load: force (E I_1 / L^2) and moment (E I_1 / L).
    pub(crate) load: [f64; 3],
    /// Reference length L (m).
    pub(crate) l_ref: f64,
    /// Bending stiffness E I_1 of limb 1 (N*m^2): the wrench scale.
    pub(crate) ei: f64,
    /// Integration steps per rod.
    pub(crate) steps: usize,
    /// The integration method.
    pub(crate) integrator: Integrator,
    /// Sign of the determinant of the shooting Jacobian (forward, inverse) on the stable
    /// branch connected to the unloaded home configuration; 0 while unknown.
    pub(crate) stable_sign: [f64; 2],
}

impl Setup {
    /// Scaled setup of a parameter set.
    pub(crate) fn new(
        p: &PcrParams,
        load: &Load,
        l_ref: f64,
        steps: usize,
        integrator: Integrator,
    ) -> Self {
        let d1 = p.limbs[0].d;
        let ei = p.e * std::f64::consts::PI * d1.powi(4) / 64.0;
        let limbs = std::array::from_fn(|i| {
            let lp = &p.limbs[i];
            let phi0 = lp.gamma + lp.alpha;
            let r2 = (d1 / lp.d) * (d1 / lp.d);
            LimbSetup {
                a: [lp.ax / l_ref, lp.ay / l_ref],
                u: [lp.gamma.cos(), lp.gamma.sin()],
                phi0,
                tangent0: [phi0.cos(), phi0.sin()],
                flex: r2 * r2,
                length: lp.l / l_ref,
                b: [lp.bx / l_ref, lp.by / l_ref],
                beta: phi0 + wrap_angle(lp.beta - phi0),
            }
        });
        let f = l_ref * l_ref / ei;
        let load = [
            load.force[0] * f,
            load.force[1] * f,
            load.moment * l_ref / ei,
        ];
        Self {
            limbs,
            load,
            l_ref,
            ei,
            steps,
            integrator,
            stable_sign: [0.0; 2],
        }
    }

    /// The same robot with straight unloaded rods at q = 0 and the platform at the origin:
    /// distal clamps moved to the tips of the straight rods. Its solution is known exactly
    /// (all wrenches zero, pose zero), which makes it the start of every continuation.
    pub(crate) fn relaxed(&self) -> Self {
        let mut s = *self;
        for l in &mut s.limbs {
            l.b = [
                l.a[0] + l.length * l.phi0.cos(),
                l.a[1] + l.length * l.phi0.sin(),
            ];
            l.beta = l.phi0;
        }
        s.load = [0.0; 3];
        s
    }

    /// Blend of two setups of the same robot that differ only in distal clamps and load.
    pub(crate) fn blend(&self, other: &Setup, t: f64) -> Setup {
        let mut s = *self;
        let lerp = |a: f64, b: f64| a + t * (b - a);
        for (l, o) in s.limbs.iter_mut().zip(&other.limbs) {
            l.b = [lerp(l.b[0], o.b[0]), lerp(l.b[1], o.b[1])];
            l.beta = lerp(l.beta, o.beta);
        }
        s.load = std::array::from_fn(|k| lerp(self.load[k], other.load[k]));
        s
    }
}

/// What is given: joints (forward kinematics) or the platform pose (inverse kinematics),
/// scaled (lengths in L).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Mode {
    /// Given joints q/L.
    Fk([f64; 3]),
    /// Given pose (x/L, y/L, theta).
    Ik([f64; 3]),
}

impl Mode {
    /// 0 for forward, 1 for inverse kinematics (index into [`Setup::stable_sign`]).
    pub(crate) fn index(&self) -> usize {
        match self {
            Mode::Fk(_) => 0,
            Mode::Ik(_) => 1,
        }
    }

    /// The given inputs, scaled.
    pub(crate) fn input(&self) -> [f64; 3] {
        match self {
            Mode::Fk(q) => *q,
            Mode::Ik(x) => *x,
        }
    }

    /// Straight-line blend between two inputs of the same kind.
    pub(crate) fn blend(&self, other: &Mode, t: f64) -> Mode {
        let lerp = |a: &[f64; 3], b: &[f64; 3]| std::array::from_fn(|k| a[k] + t * (b[k] - a[k]));
        match (self, other) {
            (Mode::Fk(a), Mode::Fk(b)) => Mode::Fk(lerp(a, b)),
            (Mode::Ik(a), Mode::Ik(b)) => Mode::Ik(lerp(a, b)),
            _ => *other,
        }
    }
}
