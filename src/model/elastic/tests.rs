use nalgebra::Vector3;

use super::*;
use crate::twin::elastic::{nominal, revolute_rows};
use crate::util::Rng;

fn options(joint: bool, lateral: bool) -> ElasticOptions {
    with_lumping(joint, lateral, Lumping::Subtree)
}

fn with_lumping(joint: bool, lateral: bool, lumping: Lumping) -> ElasticOptions {
    ElasticOptions {
        lumping,
        joint: if joint { revolute_rows() } else { Vec::new() },
        lateral: if lateral { revolute_rows() } else { Vec::new() },
    }
}

/// A twin tree with every parameter moved off nominal (elastic coefficients of a few mrad)
/// and a sample whose gravity features come from the perturbed model.
fn perturbed(opts: &ElasticOptions, seed: u64) -> (ElasticTree, TreeSample) {
    let mut m = nominal(opts);
    let mut rng = Rng::new(seed);
    for p in m.params.clone() {
        let scale = match p {
            TParam::Compliance(..) => 1e-4,
            TParam::Weight(..) => 5.0,
            p if p.is_length() => 0.01,
            _ => 0.05,
        };
        let v = m.value(p) + rng.normal() * scale;
        m.set(p, v);
    }
    let q: Vec<f64> = (0..m.variables).map(|_| rng.range(-2.5, 2.5)).collect();
    let s = m.sample(q);
    (m, s)
}

/// Every column of the analytic marker Jacobian against central differences of
/// `marker_positions` (the features are data, held fixed).
fn check_jacobian(opts: &ElasticOptions) -> usize {
    let mut checked_elastic = 0;
    for seed in 0..4 {
        let (m, s) = perturbed(opts, seed);
        let mut analytic = Vec::new();
        m.marker_jacobians(&s, |_, _, j| analytic.push(j.to_vec()));
        for (g, p) in m.params.iter().enumerate() {
            let h = 1e-6;
            let (mut mp, mut mm) = (m.clone(), m.clone());
            mp.set(*p, m.value(*p) + h);
            mm.set(*p, m.value(*p) - h);
            let (pp, pm) = (mp.marker_positions(&s), mm.marker_positions(&s));
            for k in 0..m.markers.len() {
                let numeric: Vector3<f64> = (pp[k] - pm[k]) / (2.0 * h);
                let err = (numeric - analytic[k][g]).norm();
                assert!(
                    err < 1e-7 * (1.0 + numeric.norm()),
                    "seed {seed} marker {k} {}: analytic {:?} numeric {:?}",
                    m.param_name(*p),
                    analytic[k][g],
                    numeric
                );
            }
            if matches!(
                p,
                TParam::Elastic(..) | TParam::Compliance(..) | TParam::Weight(..)
            ) {
                checked_elastic += 1;
            }
        }
    }
    checked_elastic
}

#[test]
fn lumped_joint_compliance_jacobian_matches_central_differences() {
    // 11 revolute rows x 2 coefficients x 4 seeds.
    assert_eq!(check_jacobian(&options(true, false)), 88);
}

#[test]
fn bodies_compliance_and_weight_jacobian_matches_central_differences() {
    // 11 rows x (3 compliances + 4 weights) x 4 seeds.
    assert_eq!(
        check_jacobian(&with_lumping(true, true, Lumping::Bodies)),
        308
    );
}

#[test]
fn lateral_compliance_jacobian_matches_central_differences() {
    assert_eq!(check_jacobian(&options(false, true)), 176);
    assert_eq!(check_jacobian(&options(true, true)), 264);
}

/// The deflection is a rotation of the joint output: a point on the hand of a one-joint
/// deflection moves by `delta x (p - o_joint)` to first order, whatever the coefficients.
#[test]
fn a_lateral_coefficient_bends_about_the_joint_x_axis() {
    let mut m = nominal(&options(false, true));
    let i = m.row("r1").unwrap_or(0);
    let q = vec![0.3, 0.2, -0.4, 0.7, 1.1, -0.5, 0.2, 0.1, 0.4, -0.3];
    let s = m.sample(q);
    let rigid = m.marker_positions(&s)[0];
    let frames = m.row_frames(&s);
    m.elastic[i][3] = 1e-6; // kx_gz: dx = 1e-6 * gz
    let bent = m.marker_positions(&s)[0];
    // Joint frame of r1 (variable 3): its parent's output, Rx Dx Ry Rz(theta + q).
    let parent = frames[i - 1];
    let geo = match &m.rows[i].kind {
        RowKind::Revolute { geometry, .. } => *geometry,
        RowKind::Fixed { .. } => [0.0; 5],
    };
    let joint = parent
        .mul(&crate::geometry::Frame::rot_x(geo[0]))
        .mul(&crate::geometry::Frame::trans(geo[1], 0.0, 0.0))
        .mul(&crate::geometry::Frame::rot_y(geo[2]))
        .mul(&crate::geometry::Frame::rot_z(geo[3] + s.q[3]));
    let base = crate::geometry::Frame::from_xyzabc(&m.base);
    let axis = base.r * joint.r * Vector3::x();
    let origin = base.apply(&joint.p);
    let want = axis.cross(&(rigid - origin)) * (1e-6 * s.gravity[i].z);
    assert!(
        ((bent - rigid) - want).norm() < 1e-11,
        "{:?} vs {want:?}",
        bent - rigid
    );
    assert!(want.norm() > 1e-8, "the check must move the point");
}

#[test]
fn bad_trees_are_refused_with_the_field_named() {
    let m = nominal(&ElasticOptions::default());
    let mut rows = m.rows.clone();
    rows[1].parent = Some(5);
    let e = ElasticTree::new(
        rows,
        m.markers.clone(),
        m.variables,
        &ElasticOptions::default(),
    );
    assert!(e.is_err_and(|e| e.to_string().contains("rows.t0.parent")));
    let e = ElasticTree::new(
        m.rows.clone(),
        m.markers.clone(),
        m.variables,
        &ElasticOptions {
            joint: vec!["r_mount".into()],
            ..Default::default()
        },
    );
    assert!(e.is_err_and(|e| e.to_string().contains("not a revolute row")));
}
