//! Checks of the chain against independent computations: central differences for the
//! parameter Jacobian, and the derivative of the potential energy for the static torques.

use nalgebra::Vector3;

use super::*;
use crate::model::dh::DhFile;
use crate::model::urdf::UrdfModel;

fn irb120() -> Chain {
    let mut c = DhFile::parse(include_str!("../../../tests/data/robots/irb120.json"))
        .unwrap()
        .to_chain()
        .unwrap();
    // Non-zero betas, compliances and tool angles so every column is exercised.
    for (k, id) in c.param_ids().into_iter().enumerate() {
        let v = c.param(id);
        let bump = match id.quantity() {
            Quantity::Angle => 0.01 * ((k as f64).sin()),
            Quantity::Compliance => 1e-4 * (1.0 + (k as f64).cos()),
            _ => 0.5 * (k as f64).cos(),
        };
        c.set_param(id, v + bump);
    }
    c
}

fn check_jacobian(c: &Chain, q: &[f64], tau: &[f64], local: Vector3<f64>) {
    let ids = c.param_ids();
    let mut jac = vec![Vector3::zeros(); ids.len()];
    let p = c.point_jacobian(q, Some(tau), &local, &mut jac);
    let tcp = c.tcp(q, Some(tau));
    assert!((tcp.apply(&local) - p).norm() < 1e-12);
    for (k, id) in ids.iter().enumerate() {
        let h = match id.quantity() {
            Quantity::Length => 1e-4,
            _ => 1e-7,
        };
        let mut a = c.clone();
        a.set_param(*id, c.param(*id) + h);
        let mut b = c.clone();
        b.set_param(*id, c.param(*id) - h);
        let fd =
            (a.tcp(q, Some(tau)).apply(&local) - b.tcp(q, Some(tau)).apply(&local)) / (2.0 * h);
        let err = (fd - jac[k]).norm();
        let scale = 1.0 + fd.norm();
        assert!(
            err < 1e-6 * scale,
            "{}: analytic {:?} vs central {:?}",
            c.param_name(*id),
            jac[k],
            fd
        );
    }
}

#[test]
fn dh_jacobian_matches_central_differences() {
    let c = irb120();
    let q = [0.3, -0.4, 0.5, 1.1, -0.7, 2.0];
    let tau = c.static_torques(&q);
    check_jacobian(&c, &q, &tau, Vector3::new(1.0, -2.0, 3.0));
}

#[test]
fn urdf_jacobian_matches_central_differences() {
    let m = UrdfModel::parse(include_str!("../../../tests/data/mukca/panda_nominal.urdf")).unwrap();
    let mut c = m.chain("panda_link0", "ball_link").unwrap();
    c.base = [0.1, -0.2, 0.3, 0.4, -0.2, 0.1];
    for (k, id) in c.param_ids().into_iter().enumerate() {
        if let ParamId::Joint(_, _) = id {
            c.set_param(id, 2e-3 * (k as f64).sin());
        }
    }
    let q = [0.3, -0.5, 0.2, -2.0, 0.4, 1.7, 0.8];
    let tau = c.static_torques(&q);
    check_jacobian(&c, &q, &tau, Vector3::zeros());
}

/// The static motor torque is the gradient of the potential energy V(q) = -sum m g . c(q).
#[test]
fn static_torques_are_the_potential_gradient() {
    let c = irb120();
    let q = [0.3, -0.4, 0.5, 1.1, -0.7, 2.0];
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
    for k in 0..6 {
        let h = 1e-6;
        let (mut a, mut b) = (q, q);
        a[k] += h;
        b[k] -= h;
        let fd = (energy(&a) - energy(&b)) / (2.0 * h);
        assert!(
            (fd - tau[k]).abs() < 1e-6 * (1.0 + fd.abs()),
            "joint {}: {} vs {}",
            k + 1,
            tau[k],
            fd
        );
    }
    // Joint 1 of the nominal arm is vertical: gravity gives it no torque.
    let nominal = DhFile::parse(include_str!("../../../tests/data/robots/irb120.json"))
        .unwrap()
        .to_chain()
        .unwrap();
    assert!(nominal.static_torques(&q)[0].abs() < 1e-9);
    // Joint 2 carries the arm stretched forward: several N*m.
    assert!(tau[1].abs() > 1.0, "{}", tau[1]);
}
