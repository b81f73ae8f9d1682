//! ABB IRB 120 kinematics for the RWS mock's default arm model: standard DH forward
//! kinematics (tool0 flange) and a damped Newton inverse for tool-frame relative moves.

/// Homogeneous transform, row-major.
pub type Mat4 = [[f64; 4]; 4];

/// DH table (a mm, alpha rad, d mm, theta offset rad) of the IRB 120 (product spec values).
const DH: [(f64, f64, f64, f64); 6] = [
    (0.0, -std::f64::consts::FRAC_PI_2, 290.0, 0.0),
    (270.0, 0.0, 0.0, -std::f64::consts::FRAC_PI_2),
    (70.0, -std::f64::consts::FRAC_PI_2, 0.0, 0.0),
    (0.0, std::f64::consts::FRAC_PI_2, 302.0, 0.0),
    (0.0, -std::f64::consts::FRAC_PI_2, 0.0, 0.0),
    (0.0, 0.0, 72.0, std::f64::consts::PI),
];

/// Joint limits (deg) from the IRB 120 product specification.
pub const LIMITS_DEG: [(f64, f64); 6] = [
    (-165.0, 165.0),
    (-110.0, 110.0),
    (-110.0, 70.0),
    (-160.0, 160.0),
    (-120.0, 120.0),
    (-400.0, 400.0),
];

fn mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut c = [[0.0; 4]; 4];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn dh(a: f64, alpha: f64, d: f64, theta: f64) -> Mat4 {
    let (st, ct) = theta.sin_cos();
    let (sa, ca) = alpha.sin_cos();
    [
        [ct, -st * ca, st * sa, a * ct],
        [st, ct * ca, -ct * sa, a * st],
        [0.0, sa, ca, d],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// Flange pose for joint angles in degrees.
pub fn fk(q_deg: &[f64; 6]) -> Mat4 {
    let mut t: Mat4 = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    for (i, (a, al, d, off)) in DH.iter().enumerate() {
        t = mul(&t, &dh(*a, *al, *d, q_deg[i].to_radians() + off));
    }
    t
}

/// Unit quaternion (w, x, y, z) of a rotation matrix.
pub fn quaternion(t: &Mat4) -> [f64; 4] {
    let tr = t[0][0] + t[1][1] + t[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (t[2][1] - t[1][2]) / s,
            (t[0][2] - t[2][0]) / s,
            (t[1][0] - t[0][1]) / s,
        ]
    } else if t[0][0] > t[1][1] && t[0][0] > t[2][2] {
        let s = (1.0 + t[0][0] - t[1][1] - t[2][2]).sqrt() * 2.0;
        [
            (t[2][1] - t[1][2]) / s,
            0.25 * s,
            (t[0][1] + t[1][0]) / s,
            (t[0][2] + t[2][0]) / s,
        ]
    } else if t[1][1] > t[2][2] {
        let s = (1.0 + t[1][1] - t[0][0] - t[2][2]).sqrt() * 2.0;
        [
            (t[0][2] - t[2][0]) / s,
            (t[0][1] + t[1][0]) / s,
            0.25 * s,
            (t[1][2] + t[2][1]) / s,
        ]
    } else {
        let s = (1.0 + t[2][2] - t[0][0] - t[1][1]).sqrt() * 2.0;
        [
            (t[1][0] - t[0][1]) / s,
            (t[0][2] + t[2][0]) / s,
            (t[1][2] + t[2][1]) / s,
            0.25 * s,
        ]
    };
    if q[0] < 0.0 { q.map(|v| -v) } else { q }
}

/// Pose error (mm, and rad scaled by 100 mm) from `t` to `goal`, in the base frame.
fn pose_error(t: &Mat4, goal: &Mat4) -> [f64; 6] {
    let mut e = [0.0; 6];
    for i in 0..3 {
        e[i] = goal[i][3] - t[i][3];
    }
    // Small-angle orientation error: 0.5 * sum(n x n_goal).
    for c in 0..3 {
        let a = [t[0][c], t[1][c], t[2][c]];
        let b = [goal[0][c], goal[1][c], goal[2][c]];
        e[3] += 0.5 * (a[1] * b[2] - a[2] * b[1]) * 100.0;
        e[4] += 0.5 * (a[2] * b[0] - a[0] * b[2]) * 100.0;
        e[5] += 0.5 * (a[0] * b[1] - a[1] * b[0]) * 100.0;
    }
    e
}

/// Solves `a x = b` by Gaussian elimination with partial pivoting (None if singular).
fn solve6(mut a: [[f64; 6]; 6], mut b: [f64; 6]) -> Option<[f64; 6]> {
    for c in 0..6 {
        let p = (c..6).max_by(|i, j| a[*i][c].abs().total_cmp(&a[*j][c].abs()))?;
        if a[p][c].abs() < 1e-9 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        for r in c + 1..6 {
            let f = a[r][c] / a[c][c];
            for k in c..6 {
                a[r][k] -= f * a[c][k];
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; 6];
    for r in (0..6).rev() {
        x[r] = (b[r] - (r + 1..6).map(|k| a[r][k] * x[k]).sum::<f64>()) / a[r][r];
    }
    Some(x)
}

/// Joint angles (deg) that move the flange by `dp_mm` along its own axes, keeping its
/// orientation (RAPID `RelTool`). None when unreachable, singular or outside the limits.
pub fn rel_tool(q_deg: &[f64; 6], dp_mm: [f64; 3]) -> Option<[f64; 6]> {
    let t0 = fk(q_deg);
    let mut goal = t0;
    for i in 0..3 {
        goal[i][3] += (0..3).map(|k| t0[i][k] * dp_mm[k]).sum::<f64>();
    }
    let mut q = *q_deg;
    for _ in 0..50 {
        let t = fk(&q);
        let e = pose_error(&t, &goal);
        if e.iter().map(|v| v * v).sum::<f64>().sqrt() < 1e-7 {
            let inside = q
                .iter()
                .zip(LIMITS_DEG)
                .all(|(v, (lo, hi))| *v >= lo && *v <= hi);
            return inside.then_some(q);
        }
        let mut j = [[0.0; 6]; 6];
        let h = 1e-6;
        for c in 0..6 {
            let mut qp = q;
            qp[c] += h;
            let ep = pose_error(&fk(&qp), &goal);
            for r in 0..6 {
                j[r][c] = (e[r] - ep[r]) / h;
            }
        }
        let dq = solve6(j, e)?;
        for c in 0..6 {
            q[c] += dq[c];
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn home_pose_matches_the_datasheet() {
        // IRB 120 at all-zero joints: tool0 at x = 302 + 72, z = 290 + 270 + 70, pointing down x.
        let t = fk(&[0.0; 6]);
        assert!((t[0][3] - 374.0).abs() < 1e-9, "{t:?}");
        assert!(t[1][3].abs() < 1e-9);
        assert!((t[2][3] - 630.0).abs() < 1e-9);
        // Flange z axis along base x.
        assert!((t[0][2] - 1.0).abs() < 1e-12);
        let q = quaternion(&t);
        assert!((q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn rel_tool_moves_along_the_tool_axes() {
        let q0 = [10.0, 5.0, 10.0, 0.0, 40.0, 0.0];
        let q1 = rel_tool(&q0, [1.0, -2.0, 3.0]).unwrap();
        let (t0, t1) = (fk(&q0), fk(&q1));
        for i in 0..3 {
            let want = t0[i][3] + t0[i][0] - 2.0 * t0[i][1] + 3.0 * t0[i][2];
            assert!((t1[i][3] - want).abs() < 1e-6);
            for k in 0..3 {
                assert!((t1[i][k] - t0[i][k]).abs() < 1e-8);
            }
        }
        assert!(rel_tool(&q0, [5000.0, 0.0, 0.0]).is_none());
    }
}
