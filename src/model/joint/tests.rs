//! Prismatic and mimic joints against independent computations: central differences of the
//! forward kinematics for every parameter column, closed-form gantry positions, the
//! potential-energy gradient for static loads, and the URDF write-back.

use nalgebra::Vector3;

use crate::model::dh::DhFile;
use crate::model::urdf::UrdfModel;
use crate::model::{Chain, JointField, JointKind, ParamId, Quantity};

pub(crate) const SLIDE_URDF: &str = include_str!("../../../tests/data/robots/slide_gripper.urdf");
pub(crate) const SLIDE_DH: &str = include_str!("../../../tests/data/robots/slide_arm.json");

fn slide_urdf() -> Chain {
    UrdfModel::parse(SLIDE_URDF)
        .expect("parses")
        .chain("base_link", "tcp")
        .expect("chain")
}

fn slide_dh() -> Chain {
    DhFile::parse(SLIDE_DH)
        .expect("parses")
        .to_chain()
        .expect("chain")
}

/// Every parameter moved off its nominal value so that every column is exercised.
fn perturbed(mut c: Chain) -> Chain {
    c.base = [0.01, -0.02, 0.03, 0.04, -0.02, 0.01];
    for (k, id) in c.param_ids().into_iter().enumerate() {
        let s = (k as f64 * 1.3).sin();
        let v = c.param(id);
        let dv = match (id, id.quantity()) {
            (ParamId::Joint(_, JointField::Multiplier), _) => 0.05 * s,
            (_, Quantity::Compliance) => 1e-3 * (1.5 + s),
            (_, Quantity::Length) => s * if c.units.mm { 0.5 } else { 2e-3 },
            _ => 0.02 * s,
        };
        c.set_param(id, v + dv);
    }
    c
}

/// Largest |analytic - central difference| over all parameter columns (model length unit
/// per parameter unit), relative to 1 + |central difference|.
fn jacobian_discrepancy(c: &Chain, q: &[f64], local: Vector3<f64>) -> f64 {
    let tau = c.static_torques(q);
    let ids = c.param_ids();
    let mut jac = vec![Vector3::zeros(); ids.len()];
    let p = c.point_jacobian(q, Some(&tau), &local, &mut jac);
    assert!((c.tcp(q, Some(&tau)).apply(&local) - p).norm() < 1e-12);
    let h = 1e-6;
    let mut worst: f64 = 0.0;
    for (k, id) in ids.iter().enumerate() {
        let (mut a, mut b) = (c.clone(), c.clone());
        a.set_param(*id, c.param(*id) + h);
        b.set_param(*id, c.param(*id) - h);
        let fd =
            (a.tcp(q, Some(&tau)).apply(&local) - b.tcp(q, Some(&tau)).apply(&local)) / (2.0 * h);
        let err = (fd - jac[k]).norm() / (1.0 + fd.norm());
        assert!(
            err < 1e-6,
            "{}: analytic {:?} vs central {:?}",
            c.param_name(*id),
            jac[k],
            fd
        );
        worst = worst.max(err);
    }
    worst
}

#[test]
fn urdf_prismatic_and_mimic_jacobian_matches_central_differences() {
    let c = perturbed(slide_urdf());
    // turn, lift, extend, bend, grip: the two mimic joints have no variable.
    assert_eq!(c.dof(), 5);
    let names: Vec<String> = c.param_ids().iter().map(|id| c.param_name(*id)).collect();
    for n in [
        "extend.offset",
        "grip2.offset",
        "bend2.offset",
        "bend2.multiplier",
        "grip2.multiplier",
    ] {
        assert!(names.iter().any(|x| x == n), "{n} missing from {names:?}");
    }
    assert!(!names.iter().any(|x| x == "extend.c" || x == "bend2.c"));
    let id = c.param_by_name("extend.offset").expect("name");
    assert_eq!(id.quantity(), Quantity::Length);
    assert_eq!(c.units.name(id.quantity()), "m");
    let mut worst: f64 = 0.0;
    for q in [[0.3, -0.4, 0.25, 0.7, 0.02], [-1.2, 0.9, 0.05, -1.3, 0.035]] {
        worst = worst.max(jacobian_discrepancy(
            &c,
            &q,
            Vector3::new(0.01, -0.02, 0.03),
        ));
    }
    eprintln!("URDF prismatic + mimic: max relative Jacobian discrepancy {worst:.2e}");
}

#[test]
fn dh_prismatic_and_coupling_rows_jacobian_matches_central_differences() {
    let c = perturbed(slide_dh());
    assert_eq!(c.dof(), 4);
    assert_eq!(c.joints[2].kind, JointKind::Prismatic);
    assert!(c.joints[4].mimic.is_some() && c.joints[5].mimic.is_some());
    let d3 = c.param_by_name("d3").expect("d3");
    assert_eq!(d3.quantity(), Quantity::Length);
    assert!(
        c.param_by_name("c3").is_err(),
        "a prismatic row has no compliance"
    );
    let mut worst: f64 = 0.0;
    for q in [[0.3, -0.4, 80.0, 0.7], [-1.2, 0.9, 150.0, -1.3]] {
        worst = worst.max(jacobian_discrepancy(&c, &q, Vector3::new(1.0, -2.0, 3.0)));
    }
    eprintln!("DH prismatic + coupling rows: max relative Jacobian discrepancy {worst:.2e}");
}

/// A Cartesian gantry (three prismatic rows, modified DH): the TCP is `(d3 + q3, d2 + q2,
/// d1 + q1)` in closed form (z1 = base z, z2 = base y, z3 = base x).
#[test]
fn dh_gantry_positions_in_closed_form() {
    let text = SLIDE_DH.to_string();
    let mut f = DhFile::parse(&text).expect("parses");
    f.joints.truncate(3);
    for (j, (alpha, theta, d)) in
        f.joints
            .iter_mut()
            .zip([(0.0, 0.0, 100.0), (-90.0, -90.0, 50.0), (-90.0, 0.0, 20.0)])
    {
        j.row_type = crate::model::dh::RowType::Prismatic;
        j.mimic = None;
        (j.alpha, j.a, j.beta, j.theta_offset, j.d) = (alpha, 0.0, 0.0, theta, d);
        j.limits = [-500.0, 500.0];
    }
    f.tool = crate::model::dh::Xyzabc {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        a: 0.0,
        b: 0.0,
        c: 0.0,
    };
    f.identify.clear();
    let c = f.to_chain().expect("gantry");
    for q in [[0.0, 0.0, 0.0], [12.5, -40.0, 310.0], [-200.0, 75.0, 3.0]] {
        let p = c.tcp(&q, None).p;
        let want = Vector3::new(20.0 + q[2], 50.0 + q[1], 100.0 + q[0]);
        assert!((p - want).norm() < 1e-9, "q {q:?}: {p:?} vs {want:?}");
    }
}

/// A URDF gantry: axes x, y, -z with offset origins; the offset of a prismatic joint is a
/// length that moves the TCP by exactly that much along the axis.
#[test]
fn urdf_gantry_positions_in_closed_form() {
    let urdf = r#"<robot name="gantry">
      <link name="frame"/><link name="bridge"/><link name="carriage"/><link name="quill"/>
      <link name="tcp"/>
      <joint name="x" type="prismatic"><parent link="frame"/><child link="bridge"/>
        <origin xyz="0 0 1" rpy="0 0 0"/><axis xyz="1 0 0"/>
        <limit lower="0" upper="2" effort="1" velocity="1"/></joint>
      <joint name="y" type="prismatic"><parent link="bridge"/><child link="carriage"/>
        <origin xyz="0.1 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/>
        <limit lower="0" upper="1" effort="1" velocity="1"/></joint>
      <joint name="z" type="prismatic"><parent link="carriage"/><child link="quill"/>
        <origin xyz="0 0.2 0" rpy="0 0 0"/><axis xyz="0 0 -1"/>
        <limit lower="0" upper="0.5" effort="1" velocity="1"/></joint>
      <joint name="t" type="fixed"><parent link="quill"/><child link="tcp"/>
        <origin xyz="0 0 -0.05" rpy="0 0 0"/></joint>
    </robot>"#;
    let mut c = UrdfModel::parse(urdf)
        .expect("parses")
        .chain("frame", "tcp")
        .expect("chain");
    assert_eq!(c.dof(), 3);
    for q in [[0.0, 0.0, 0.0], [1.25, 0.5, 0.3], [0.01, 0.99, 0.45]] {
        let p = c.tcp(&q, None).p;
        let want = Vector3::new(0.1 + q[0], 0.2 + q[1], 1.0 - q[2] - 0.05);
        assert!((p - want).norm() < 1e-12, "q {q:?}: {p:?} vs {want:?}");
    }
    let id = c.param_by_name("z.offset").expect("name");
    c.set_param(id, 0.003);
    let p = c.tcp(&[0.5, 0.5, 0.2], None).p;
    assert!(
        (p - Vector3::new(0.6, 0.7, 1.0 - 0.203 - 0.05)).norm() < 1e-12,
        "{p:?}"
    );
    assert_eq!(c.variable_quantity(2), Quantity::Length);
}

/// Static loads are the gradient of the potential energy V(q) = -sum m g . c(q); a mimic
/// joint's load reaches its leader through the multiplier, a slide's load is a force (N).
#[test]
fn static_loads_with_prismatic_and_mimic_are_the_potential_gradient() {
    let c = perturbed(slide_urdf());
    let q = [0.3, -0.4, 0.25, 0.7, 0.02];
    let energy = |q: &[f64]| {
        let mut frames = Vec::new();
        c.joint_frames(q, None, &mut frames);
        c.masses
            .iter()
            .map(|m| {
                -m.mass
                    * c.gravity
                        .dot(&(frames[m.body].apply(&m.com) * c.units.metre()))
            })
            .sum::<f64>()
    };
    let tau = c.static_torques(&q);
    for k in 0..q.len() {
        let h = 1e-6;
        let (mut a, mut b) = (q, q);
        a[k] += h;
        b[k] -= h;
        let fd = (energy(&a) - energy(&b)) / (2.0 * h);
        assert!(
            (fd - tau[k]).abs() < 1e-6 * (1.0 + fd.abs()),
            "variable {k}: {} vs {fd}",
            tau[k]
        );
    }
    // The lift carries everything: several N*m; the slide holds a few N.
    assert!(tau[1].abs() > 1.0 && tau[2].abs() > 0.1, "{tau:?}");
}

#[test]
fn urdf_write_back_keeps_prismatic_offsets_and_mimic_multipliers() {
    let m = UrdfModel::parse(SLIDE_URDF).expect("parses");
    let c = perturbed(m.chain("base_link", "tcp").expect("chain"));
    let text = m.write_calibrated(&c).expect("written");
    let back = UrdfModel::parse(&text)
        .expect("reparses")
        .chain("base_link", "tcp")
        .expect("chain");
    let q = [0.3, -0.4, 0.25, 0.7, 0.02];
    let (a, b) = (c.flange(&q, None), back.flange(&q, None));
    assert!(
        (a.p - b.p).norm() < 1e-12 && (a.r - b.r).norm() < 1e-12,
        "{:?} vs {:?}",
        a.p,
        b.p
    );
}

#[test]
fn dh_write_back_keeps_coupling_multipliers() {
    let f = DhFile::parse(SLIDE_DH).expect("parses");
    let c = perturbed(f.to_chain().expect("chain"));
    let back = f.with_chain(&c).to_chain().expect("rebuilt");
    let q = [0.3, -0.4, 80.0, 0.7];
    assert!((back.tcp(&q, None).p - c.tcp(&q, None).p).norm() < 1e-9);
}

#[test]
fn bad_mimic_leaders_and_prismatic_compliance_are_named() {
    let bad = SLIDE_URDF.replace(r#"<mimic joint="bend""#, r#"<mimic joint="nope""#);
    let e = UrdfModel::parse(&bad)
        .expect("parses")
        .chain("base_link", "tcp")
        .unwrap_err();
    let e = e.to_string();
    assert!(e.contains("bend2") && e.contains("nope"), "{e}");
    // A mimic of a mimic has no variable to follow.
    let bad = SLIDE_URDF.replace(r#"<mimic joint="grip""#, r#"<mimic joint="bend2""#);
    let e = UrdfModel::parse(&bad)
        .expect("parses")
        .chain("base_link", "tcp")
        .unwrap_err();
    assert!(e.to_string().contains("grip2"), "{e}");
    let bad = SLIDE_DH.replace(r#""joint": "j4""#, r#""joint": "j9""#);
    let e = DhFile::parse(&bad)
        .expect("parses")
        .to_chain()
        .unwrap_err()
        .to_string();
    assert!(e.contains("joints[4].mimic") && e.contains("j9"), "{e}");
    let bad = SLIDE_DH.replace(
        r#""d": 100, "theta_offset": 0,"#,
        r#""d": 100, "theta_offset": 0, "compliance": 0.01,"#,
    );
    let e = DhFile::parse(&bad)
        .expect("parses")
        .to_chain()
        .unwrap_err()
        .to_string();
    assert!(e.contains("joints[2].compliance"), "{e}");
    let bad = SLIDE_DH.replace(
        r#""type": "prismatic", "alpha": -90"#,
        r#""type": "telescopic", "alpha": -90"#,
    );
    let e = DhFile::parse(&bad).unwrap_err().to_string();
    assert!(e.contains("joints[2]") && e.contains("telescopic"), "{e}");
}

/// The identification sees a prismatic offset as a length (m / mm), never as an angle that
/// the half-turn rule would judge modulo a turn; a multiplier is dimensionless.
#[test]
fn prismatic_offsets_are_lengths_for_the_identification() {
    let c = slide_urdf();
    let ids = [
        c.param_by_name("extend.offset").expect("name"),
        c.param_by_name("bend2.multiplier").expect("name"),
        c.param_by_name("bend2.offset").expect("name"),
    ];
    let u = crate::measure::point::chain_unknowns(&c, &ids);
    assert_eq!(
        (u[0].unit.as_str(), u[1].unit.as_str(), u[2].unit.as_str()),
        ("m", "1", "rad")
    );
    assert!(!crate::identify::trust::is_angle(&u[0]) && !crate::identify::trust::is_angle(&u[1]));
    assert!(crate::identify::trust::is_angle(&u[2]));
    let d = slide_dh();
    let u = crate::measure::point::chain_unknowns(&d, &[d.param_by_name("d3").expect("d3")]);
    assert_eq!(u[0].unit, "mm");
}
