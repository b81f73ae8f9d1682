//! Lumped elasticity: the deflection of a joint from the gravity direction seen in its frame,
//! and the lumped coefficients that known compliances and mass moments would give.
//!
//! For a joint carrying a first mass moment `M` (kg*m, about the joint frame's origin, in
//! joint axes) under gravity `g = |g| u` (`u` the unit direction in joint axes), the moment
//! about axis `a` is `|g| M . (u x a)`, and a compliance `c_a` (rad/(N*m)) turns it into a
//! deflection. Expanded in the components of `u`, each axis has two coefficients:
//!
//! | deflection | = |
//! |---|---|
//! | `dz` (joint) | `kz_gx ux + kz_gy uy`, `kz_gx = -c_z g M_y`, `kz_gy = c_z g M_x` |
//! | `dx` (lateral) | `kx_gy uy + kx_gz uz`, `kx_gy = -c_x g M_z`, `kx_gz = c_x g M_y` |
//! | `dy` (lateral) | `ky_gx ux + ky_gz uz`, `ky_gx = c_y g M_z`, `ky_gz = -c_y g M_x` |
//!
//! The six coefficients are what the data determine without masses (products of compliance
//! and mass moment); the identification decides which of them are identifiable.

use nalgebra::Vector3;

/// Standard gravity (m/s^2).
pub const STANDARD_GRAVITY_M_S2: f64 = 9.80665;

/// Names of the six lumped coefficients of a row, in storage order.
pub const COEFFICIENTS: [&str; 6] = ["kz_gx", "kz_gy", "kx_gy", "kx_gz", "ky_gx", "ky_gz"];

/// Deflection axis of each coefficient: 0 = about z (joint), 1 = about x, 2 = about y.
pub const AXIS: [usize; 6] = [0, 0, 1, 1, 2, 2];

/// Gravity component (in joint axes) each coefficient multiplies.
pub const COMPONENT: [usize; 6] = [0, 1, 1, 2, 0, 2];

/// Deflection `[dz, dx, dy]` (rad) of a joint with coefficients `k` when the unit gravity
/// direction in its frame is `u`.
pub fn deflection(k: &[f64; 6], u: &Vector3<f64>) -> [f64; 3] {
    let mut d = [0.0; 3];
    for (c, kc) in k.iter().enumerate() {
        d[AXIS[c]] += kc * u[COMPONENT[c]];
    }
    d
}

/// The lumped coefficients of a joint with compliances `c = [c_z, c_x, c_y]` (rad/(N*m))
/// carrying the first mass moment `moment` (kg*m, joint axes, constant in the joint frame).
pub fn lumped(c: [f64; 3], moment: &Vector3<f64>) -> [f64; 6] {
    let g = STANDARD_GRAVITY_M_S2;
    let (mx, my, mz) = (moment.x, moment.y, moment.z);
    [
        -c[0] * g * my,
        c[0] * g * mx,
        -c[1] * g * mz,
        c[1] * g * my,
        c[2] * g * mz,
        -c[2] * g * mx,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The expansion equals compliance x (r x m g) . axis for a point mass.
    #[test]
    fn lumped_coefficients_equal_the_gravity_moment_times_compliance() {
        let c = [2e-4, 5e-5, 3e-5];
        let (m, r) = (3.0, Vector3::new(0.2, -0.1, 0.35));
        let u = Vector3::new(0.3, -0.5, -0.8).normalize();
        let f = u * (m * STANDARD_GRAVITY_M_S2);
        let tau = r.cross(&f);
        let d = deflection(&lumped(c, &(r * m)), &u);
        let want = [c[0] * tau.z, c[1] * tau.x, c[2] * tau.y];
        for (a, (x, y)) in d.iter().zip(want).enumerate() {
            assert!((x - y).abs() < 1e-15, "axis {a}: {x} vs {y}");
        }
    }
}
