use super::*;
use crate::model::urdf::UrdfModel;

/// A fixed mount, then two revolute joints and a tool point.
const URDF: &str = r#"<robot name="two">
  <link name="world"/><link name="mount"/><link name="l1"/><link name="l2"/><link name="tip"/>
  <joint name="m" type="fixed"><parent link="world"/><child link="mount"/>
    <origin xyz="0.1 0.2 0.05" rpy="0 0 0.3"/></joint>
  <joint name="j1" type="revolute"><parent link="mount"/><child link="l1"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.05 0 0.2" rpy="1.5708 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="t" type="fixed"><parent link="l2"/><child link="tip"/>
    <origin xyz="0.4 0.01 0" rpy="0 0 0"/></joint>
</robot>"#;

fn chain() -> Chain {
    UrdfModel::parse(URDF)
        .expect("parses")
        .chain("world", "tip")
        .expect("chain")
}

fn names(c: &Chain, ids: &[ParamId], idx: &[usize]) -> Vec<String> {
    idx.iter().map(|&k| c.param_name(ids[k])).collect()
}

/// The mount's and joint 1's placement errors and joint 1's offset, nothing of joint 2;
/// nothing without the whole base.
#[test]
fn lists_the_placements_up_to_joint_1_and_its_offset() {
    let c = chain();
    let ids = c.param_ids();
    let got = names(&c, &ids, &base_duplicates(&c, &ids));
    let mut want: Vec<String> = ["m", "j1"]
        .iter()
        .flat_map(|j| crate::model::params::URDF_ERRORS.map(|e| format!("{j}.{e}")))
        .collect();
    want.push("j1.offset".into());
    assert_eq!(got, want);
    let without_c: Vec<ParamId> = ids
        .iter()
        .copied()
        .filter(|id| *id != ParamId::Base(5))
        .collect();
    assert!(base_duplicates(&c, &without_c).is_empty());
}

/// Any change of the listed parameters is reproduced exactly by a change of the base frame
/// alone (`base' = base * F' * F^-1`, F the first moving joint's frame at q = 0): the TCP
/// agrees to rounding at every configuration tried.
#[test]
fn every_listed_change_is_a_base_change() {
    let nominal = chain();
    let ids = nominal.param_ids();
    let listed = base_duplicates(&nominal, &ids);
    let mut moved = nominal.clone();
    for (n, &k) in listed.iter().enumerate() {
        let v = moved.param(ids[k]) + 0.01 * (n as f64 + 1.0) * if n % 2 == 0 { 1.0 } else { -1.0 };
        moved.set_param(ids[k], v);
    }
    let first_frame = |c: &Chain| {
        let mut out = Vec::new();
        c.joint_frames(&[0.0, 0.0], None, &mut out);
        out[1]
    };
    let base = moved
        .base_frame()
        .mul(&first_frame(&moved))
        .mul(&first_frame(&nominal).inverse());
    let mut rebased = nominal.clone();
    rebased.base = base.to_xyzabc();
    let mut worst: f64 = 0.0;
    for q in [[0.0, 0.0], [0.7, -1.2], [-2.5, 0.4], [1.9, 2.8]] {
        let (a, b) = (moved.tcp(&q, None), rebased.tcp(&q, None));
        worst = worst.max((a.p - b.p).norm()).max((a.r - b.r).norm());
    }
    assert!(worst < 1e-12, "{worst}");
    // Joint 2's placement is not a base change: the same construction misses it.
    let mut j2 = nominal.clone();
    let dx = nominal.param_by_name("j2.dx").expect("name");
    j2.set_param(dx, 0.01);
    let mut rebased = nominal.clone();
    rebased.base = j2
        .base_frame()
        .mul(&first_frame(&j2))
        .mul(&first_frame(&nominal).inverse())
        .to_xyzabc();
    let q = [0.7, -1.2];
    assert!((j2.tcp(&q, None).p - rebased.tcp(&q, None).p).norm() > 1e-3);
}
