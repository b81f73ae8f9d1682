//! URDF text of a DH/Hayati serial model (nominal or calibrated): each row's constant part
//! `Rx(alpha) Dx(a) Ry(beta) Rz(theta_offset) Dz(d)` becomes the joint's `<origin>` (the
//! motion `Rz(q)` commutes with `Dz(d)`), the base a fixed joint `world -> base_link`, the
//! tool a fixed joint `flange -> tcp`, the masses point-mass `<inertial>`s. Metres and
//! radians, as URDF wants. Joint compliance has no URDF element and is not written.

use std::fmt::Write as _;

use super::ModelError;
use super::chain::{Chain, Geometry};
use super::joint::JointKind;
use crate::geometry::Frame;

/// The URDF of `chain` (MDH rows only), robot name `name`. The chain `world` -> `tcp` of the
/// result has the forward kinematics of `chain` with compliance off.
pub fn to_urdf(chain: &Chain, name: &str) -> Result<String, ModelError> {
    let m = chain.units.metre();
    let mut out = String::new();
    let _ = writeln!(out, "<?xml version=\"1.0\"?>");
    let _ = writeln!(
        out,
        "<!-- Written by calibd from a DH/Hayati model; joint compliance is not representable in URDF and is omitted. Joint velocity and effort limits are not in the DH model: written as 0 (unknown). -->"
    );
    let _ = writeln!(out, "<robot name=\"{}\">", xml_escape(name));
    link(&mut out, "world", None, m);
    link(&mut out, "base_link", None, m);
    fixed(
        &mut out,
        "base",
        "world",
        "base_link",
        &chain.base_frame(),
        m,
    );
    let mut parent = "base_link".to_string();
    for (i, j) in chain.joints.iter().enumerate() {
        let Geometry::Mdh { alpha, a, beta, d } = j.geometry else {
            return Err(ModelError::Field {
                field: format!("joints[{i}]"),
                reason: "only modified-DH rows can be written as URDF".into(),
            });
        };
        if j.mimic.is_some() {
            return Err(ModelError::Field {
                field: format!("joints[{i}].mimic"),
                reason: "coupled rows are not written as URDF".into(),
            });
        }
        let child = format!("link{}", i + 1);
        let masses: Vec<_> = chain.masses.iter().filter(|p| p.body == i).collect();
        link(&mut out, &child, masses.first().copied(), m);
        // theta = q + offset for revolute and fixed rows; prismatic rows keep theta = offset.
        let origin = Frame::rot_x(alpha)
            .mul(&Frame::trans(a, 0.0, 0.0))
            .mul(&Frame::rot_y(beta))
            .mul(&Frame::rot_z(j.offset))
            .mul(&Frame::trans(0.0, 0.0, d));
        let kind = match (j.kind, j.limits) {
            (JointKind::Revolute, Some(_)) => "revolute",
            (JointKind::Revolute, None) => "continuous",
            (JointKind::Prismatic, _) => "prismatic",
            (JointKind::Fixed, _) => "fixed",
        };
        let _ = writeln!(
            out,
            "  <joint name=\"{}\" type=\"{kind}\">",
            xml_escape(&j.name)
        );
        origin_tag(&mut out, &origin, m);
        let _ = writeln!(
            out,
            "    <parent link=\"{parent}\"/>\n    <child link=\"{child}\"/>"
        );
        if j.kind != JointKind::Fixed {
            let _ = writeln!(out, "    <axis xyz=\"0 0 1\"/>");
        }
        if let (Some([lo, hi]), true) = (j.limits, j.kind != JointKind::Fixed) {
            let k = if j.kind == JointKind::Prismatic {
                m
            } else {
                1.0
            };
            let _ = writeln!(
                out,
                "    <limit lower=\"{}\" upper=\"{}\" effort=\"{}\" velocity=\"0\"/>",
                lo * k,
                hi * k,
                j.effort.unwrap_or(0.0)
            );
        }
        let _ = writeln!(out, "  </joint>");
        // Further masses of the same body (e.g. the payload): fixed child links.
        for (n, p) in masses.iter().enumerate().skip(1) {
            let extra = format!("{child}_{}_{}", xml_name(&p.name), n);
            link(&mut out, &extra, Some(p), m);
            fixed(
                &mut out,
                &format!("{extra}_joint"),
                &child,
                &extra,
                &Frame::identity(),
                m,
            );
        }
        parent = child;
    }
    link(&mut out, "tcp", None, m);
    fixed(&mut out, "tool", &parent, "tcp", &chain.tool_frame(), m);
    let _ = writeln!(out, "</robot>");
    Ok(out)
}

/// Joint offsets of a calibrated URDF chain as ROS 2 parameters for a `ros2_control`
/// hardware interface (`node` names the parameter namespace): `joint_offsets.<joint>` in rad
/// (m for prismatic joints). The calibrated model is `theta = q + offset`, so the interface
/// reports `state = encoder + offset` and commands `encoder = command - offset`.
pub fn ros2_control_offsets(chain: &Chain, node: &str) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# Joint offsets identified by calibd: state = encoder + offset, encoder = command - offset\n# (rad for revolute joints, m for prismatic joints)."
    );
    let _ = writeln!(out, "{node}:\n  ros__parameters:\n    joint_offsets:");
    for &j in chain.actuated() {
        let joint = &chain.joints[j];
        let _ = writeln!(out, "      {}: {}", joint.name, joint.offset);
    }
    out
}

/// A link, with a point-mass inertial (its centre of mass as the inertial origin) if any.
fn link(out: &mut String, name: &str, mass: Option<&super::PointMass>, m: f64) {
    match mass {
        None => {
            let _ = writeln!(out, "  <link name=\"{name}\"/>");
        }
        Some(p) => {
            let _ = writeln!(
                out,
                "  <link name=\"{name}\">\n    <inertial>\n      <origin xyz=\"{} {} {}\" rpy=\"0 0 0\"/>\n      <mass value=\"{}\"/>\n      <inertia ixx=\"0\" ixy=\"0\" ixz=\"0\" iyy=\"0\" iyz=\"0\" izz=\"0\"/>\n    </inertial>\n  </link>",
                p.com.x * m,
                p.com.y * m,
                p.com.z * m,
                p.mass
            );
        }
    }
}

/// A fixed joint from `parent` to `child` at `f`.
fn fixed(out: &mut String, name: &str, parent: &str, child: &str, f: &Frame, m: f64) {
    let _ = writeln!(out, "  <joint name=\"{name}\" type=\"fixed\">");
    origin_tag(out, f, m);
    let _ = writeln!(
        out,
        "    <parent link=\"{parent}\"/>\n    <child link=\"{child}\"/>\n  </joint>"
    );
}

/// `<origin xyz rpy>` of a frame (lengths times `m` to metres; rpy = roll c, pitch b, yaw a).
fn origin_tag(out: &mut String, f: &Frame, m: f64) {
    let r = &f.r;
    // R = Rz(yaw) Ry(pitch) Rx(roll); pitch from atan2 stays accurate near +-90 deg.
    let h = r[(0, 0)].hypot(r[(1, 0)]);
    let pitch = (-r[(2, 0)]).atan2(h);
    let (yaw, roll) = if h > 1e-9 {
        (r[(1, 0)].atan2(r[(0, 0)]), r[(2, 1)].atan2(r[(2, 2)]))
    } else {
        ((-r[(0, 1)]).atan2(r[(1, 1)]), 0.0)
    };
    let _ = writeln!(
        out,
        "    <origin xyz=\"{} {} {}\" rpy=\"{roll} {pitch} {yaw}\"/>",
        f.p.x * m,
        f.p.y * m,
        f.p.z * m,
    );
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A name usable in a link name (letters, digits, `_`).
fn xml_name(s: &str) -> String {
    s.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::urdf::UrdfModel;
    use crate::twin::SerialTwin;
    use crate::util::Rng;

    #[test]
    fn ros2_offsets_list_every_joint_with_its_offset() {
        let text = include_str!("../../tests/data/robots/irb120.json");
        let mut c = crate::model::dh::DhFile::parse(text)
            .unwrap()
            .to_chain()
            .unwrap();
        c.joints[2].offset = 0.0125;
        let y = ros2_control_offsets(&c, "calibration");
        let v: serde_json::Value = yaml_serde::from_str(&y).expect("valid YAML");
        let o = &v["calibration"]["ros__parameters"]["joint_offsets"];
        assert_eq!(o["j3"].as_f64(), Some(0.0125));
        assert_eq!(o.as_object().map(|m| m.len()), Some(6));
    }

    /// FK of the written URDF (parsed back, chain world -> tcp) equals the DH model's, for
    /// the nominal and the twin's true (calibrated-like: beta, offsets) IRB 120.
    #[test]
    fn urdf_round_trip_has_the_fk_of_the_dh_model() {
        let twin = SerialTwin::irb120(3);
        for chain in [&twin.nominal, &twin.truth] {
            let text = to_urdf(chain, "irb120").expect("MDH rows write");
            let urdf = UrdfModel::parse(&text).expect("the URDF parses");
            let back = urdf.chain("world", "tcp").expect("chain world -> tcp");
            assert_eq!(back.dof(), 6);
            let mut rng = Rng::new(8);
            let mut worst = 0.0f64;
            for _ in 0..200 {
                let q = twin.random_q(&mut rng);
                let a = chain.tcp(&q, None);
                let b = back.tcp(&q, None);
                worst = worst.max((a.p - b.p * 1e3).norm());
                assert!((a.r - b.r).norm() < 1e-12);
            }
            assert!(worst < 1e-9, "worst {worst} mm");
            // Limits and the masses (links and payload) made it across.
            let l = back.joints.iter().filter_map(|j| j.limits).count();
            assert_eq!(l, 6);
            let total: f64 = back.masses.iter().map(|p| p.mass).sum();
            let want: f64 = chain.masses.iter().map(|p| p.mass).sum();
            assert!((total - want).abs() < 1e-12, "{total} vs {want}");
            // The same gravity torques in {0} once the base is set aside (URDF gravity is
            // along -z of the root; here the robot frame).
            let base = urdf.chain("base_link", "tcp").unwrap();
            let q = twin.random_q(&mut rng);
            let (t1, t2) = (chain.static_torques(&q), base.static_torques(&q));
            for k in 0..6 {
                assert!(
                    (t1[k] - t2[k]).abs() < 1e-9,
                    "tau{}: {} vs {}",
                    k + 1,
                    t1[k],
                    t2[k]
                );
            }
        }
    }
}
