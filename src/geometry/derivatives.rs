//! Exact derivatives of a transformed point with respect to the six numbers of the two
//! parameterised transforms the models use (`xyzabc` frames and URDF placement errors), and
//! the rigid fit of two point sets (Kabsch), used to measure a body pose from its markers.

use nalgebra::{Matrix3, Vector3};

use super::Frame;

/// Derivatives of `from_xyzabc(v).apply(p)` with respect to x, y, z, a, b, c
/// (`Dx Dy Dz Rz(a) Ry(b) Rx(c)`), in the parent frame.
pub fn xyzabc_point_derivatives(v: &[f64; 6], p: &Vector3<f64>) -> [Vector3<f64>; 6] {
    let rz = Frame::rot_z(v[3]).r;
    let rzy = rz * Frame::rot_y(v[4]).r;
    let q = rzy * Frame::rot_x(v[5]).r * p;
    [
        Vector3::x(),
        Vector3::y(),
        Vector3::z(),
        Vector3::z().cross(&q),
        (rz * Vector3::y()).cross(&q),
        (rzy * Vector3::x()).cross(&q),
    ]
}

/// Derivatives of `from_urdf_errors(e).apply(p)` with respect to dx, dy, dz, rx, ry, rz
/// (`Dx Dy Dz Rx Ry Rz`), in the parent frame.
pub fn urdf_errors_point_derivatives(e: &[f64; 6], p: &Vector3<f64>) -> [Vector3<f64>; 6] {
    let rx = Frame::rot_x(e[3]).r;
    let rxy = rx * Frame::rot_y(e[4]).r;
    let q = rxy * Frame::rot_z(e[5]).r * p;
    [
        Vector3::x(),
        Vector3::y(),
        Vector3::z(),
        Vector3::x().cross(&q),
        (rx * Vector3::y()).cross(&q),
        (rxy * Vector3::z()).cross(&q),
    ]
}

/// The rigid transform `T` minimising `sum |T * local_k - world_k|^2` (Kabsch with the
/// reflection guard), or `None` with fewer than three points or collinear points.
pub fn kabsch(local: &[Vector3<f64>], world: &[Vector3<f64>]) -> Option<Frame> {
    let n = local.len();
    if n < 3 || world.len() != n {
        return None;
    }
    let cl = local.iter().sum::<Vector3<f64>>() / n as f64;
    let cw = world.iter().sum::<Vector3<f64>>() / n as f64;
    let mut h = Matrix3::zeros();
    for (a, b) in local.iter().zip(world) {
        h += (a - cl) * (b - cw).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let s = svd.singular_values;
    // Rank < 2: the points are collinear (or coincide) and the rotation is not determined.
    let mut sorted = [s[0], s[1], s[2]];
    sorted.sort_by(|a, b| b.total_cmp(a));
    if !(sorted[1] > 1e-12 * sorted[0].max(f64::MIN_POSITIVE)) {
        return None;
    }
    let v = vt.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let r = v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    Some(Frame { r, p: cw - r * cl })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::Rng;

    fn fd(f: impl Fn(&[f64; 6]) -> Vector3<f64>, v: &[f64; 6], k: usize) -> Vector3<f64> {
        let h = 1e-6;
        let (mut a, mut b) = (*v, *v);
        a[k] += h;
        b[k] -= h;
        (f(&a) - f(&b)) / (2.0 * h)
    }

    #[test]
    fn derivatives_match_central_differences() {
        let v = [0.1, -0.2, 0.3, 0.7, -0.4, 1.1];
        let p = Vector3::new(0.3, -0.5, 0.9);
        let dx = xyzabc_point_derivatives(&v, &p);
        let du = urdf_errors_point_derivatives(&v, &p);
        for k in 0..6 {
            let a = fd(|w| Frame::from_xyzabc(w).apply(&p), &v, k);
            let b = fd(|w| Frame::from_urdf_errors(w).apply(&p), &v, k);
            assert!((a - dx[k]).norm() < 1e-9, "xyzabc {k}");
            assert!((b - du[k]).norm() < 1e-9, "urdf {k}");
        }
    }

    #[test]
    fn kabsch_recovers_a_rigid_transform_and_refuses_collinear_points() {
        let mut rng = Rng::new(3);
        let t = Frame::from_xyzabc(&[0.2, -1.0, 0.5, 2.5, -0.9, 0.4]);
        let local: Vec<Vector3<f64>> = (0..4).map(|_| Vector3::from(rng.in_ball(0.1))).collect();
        let world: Vec<Vector3<f64>> = local.iter().map(|p| t.apply(p)).collect();
        let f = kabsch(&local, &world).unwrap();
        assert!((f.r - t.r).norm() < 1e-12 && (f.p - t.p).norm() < 1e-12);
        let line: Vec<Vector3<f64>> = (0..3).map(|k| Vector3::x() * k as f64).collect();
        assert!(kabsch(&line, &line).is_none());
        assert!(kabsch(&local[..2], &world[..2]).is_none());
    }
}
