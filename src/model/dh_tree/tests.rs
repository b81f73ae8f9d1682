//! DH tree files against independent expectations: the classic rows multiplied out by hand,
//! the same robot in modified DH, and each chain written as a separate serial DH file.

use serde_json::{Value, json};

use super::*;
use crate::model::dh::DhFile;

const CLASSIC: &str = include_str!("../../../tests/data/robots/two_arm_tree.json");
const MODIFIED: &str = include_str!("../../../tests/data/robots/two_arm_tree_modified.json");

fn load(text: &str, name: &str) -> DhTreeFile {
    DhTreeFile::parse(text, name).expect("tree file parses")
}

/// Joint values (deg or mm per row with its own variable) exercising every joint.
fn qs(c: &Chain) -> Vec<Vec<f64>> {
    let deg = std::f64::consts::PI / 180.0;
    (0..3)
        .map(|s| {
            c.actuated()
                .iter()
                .enumerate()
                .map(|(k, &j)| {
                    let v = ((k + 1) as f64 * (s as f64 + 0.7)).sin();
                    match c.joints[j].kind {
                        crate::model::JointKind::Prismatic => 50.0 + 40.0 * v,
                        _ => 60.0 * v * deg,
                    }
                })
                .collect()
        })
        .collect()
}

/// The classic rows of a chain multiplied out: base * prod Rz(theta) Dz(d) Dx(a) Rx(alpha)
/// * tool, with theta/d from the variable (or the coupling), written without the loader.
fn classic_by_hand(f: &DhTreeFile, end: &str, tool: [f64; 3], q: &[f64]) -> Vector3<f64> {
    let deg = std::f64::consts::PI / 180.0;
    let mut names = vec![end.to_string()];
    while let Some(r) = f
        .rows
        .iter()
        .find(|r| &r.name == names.last().expect("non-empty"))
    {
        if r.parent == f.root {
            break;
        }
        names.push(r.parent.clone());
    }
    names.reverse();
    let b = f.base;
    let mut t = Frame::from_xyzabc(&[b.x, b.y, b.z, b.a * deg, b.b * deg, b.c * deg]);
    let mut k = 0;
    let mut vals: Vec<(String, f64)> = Vec::new();
    for n in &names {
        let r = f.rows.iter().find(|r| &r.name == n).expect("row");
        let v = match (&r.mimic, r.row_type) {
            (Some(m), _) => {
                let lead = vals.iter().find(|(n, _)| *n == m.joint).expect("leader").1;
                m.multiplier * lead + m.offset
            }
            (None, RowType::Fixed) => 0.0,
            (None, _) => {
                let raw = q[k];
                k += 1;
                if r.row_type == RowType::Prismatic {
                    raw
                } else {
                    raw / deg
                }
            }
        };
        vals.push((n.clone(), v));
        let (theta, d) = match r.row_type {
            RowType::Prismatic => (r.theta_offset, r.d + v),
            _ => (r.theta_offset + v, r.d),
        };
        t = t
            .mul(&Frame::rot_z(theta * deg))
            .mul(&Frame::trans(0.0, 0.0, d))
            .mul(&Frame::trans(r.a, 0.0, 0.0))
            .mul(&Frame::rot_x(r.alpha * deg));
    }
    t.apply(&Vector3::from(tool))
}

#[test]
fn classic_chains_match_the_rows_multiplied_by_hand() {
    let f = load(CLASSIC, "two_arm_tree.json");
    assert_eq!(f.chain_names(), ["torso", "left_arm", "right_arm"]);
    for (name, end, tool) in [
        ("left_arm", "l_hand", [0.0, 0.0, 20.0]),
        ("right_arm", "r_wrist2", [5.0, 0.0, 30.0]),
    ] {
        let c = f.chain(name, "two_arm_tree.json").expect("chain");
        // Left: torso, lift, 4 arm joints (the fixed hand has no column); right: torso, lift,
        // 4 arm joints and the slide (the coupled wrist has no column).
        assert_eq!(c.dof(), if name == "left_arm" { 6 } else { 7 }, "{name}");
        for q in qs(&c) {
            let want = classic_by_hand(&f, end, tool, &q);
            let got = c.tcp(&q, None).p;
            assert!(
                (got - want).norm() < 1e-9,
                "{name} {q:?}: {got:?} vs {want:?}"
            );
        }
    }
}

#[test]
fn classic_and_modified_files_of_one_robot_agree() {
    let (fc, fm) = (load(CLASSIC, "classic"), load(MODIFIED, "modified"));
    for name in ["torso", "left_arm", "right_arm"] {
        let (a, b) = (
            fc.chain(name, "classic").expect("c"),
            fm.chain(name, "modified").expect("m"),
        );
        for q in qs(&a) {
            let (ta, tb) = (a.tcp(&q, None), b.tcp(&q, None));
            assert!(
                (ta.p - tb.p).norm() < 1e-9 && (ta.r - tb.r).norm() < 1e-12,
                "{name} {q:?}"
            );
        }
    }
}

/// The modified tree's rows on the path of `end`, as a serial DH file.
fn serial_file(f: &DhTreeFile, path: &[&str], tool: Value) -> DhFile {
    let rows: Vec<Value> = path
        .iter()
        .map(|n| {
            let r = f.rows.iter().find(|r| r.name == *n).expect("row");
            let mut v = json!({"name": r.name, "alpha": r.alpha, "a": r.a, "d": r.d,
                "theta_offset": r.theta_offset, "limits": r.limits.unwrap_or([-1.0, 1.0]),
                "type": r.row_type});
            if let Some(m) = &r.mimic {
                v["mimic"] =
                    json!({"joint": m.joint, "multiplier": m.multiplier, "offset": m.offset});
            }
            v
        })
        .collect();
    DhFile::from_value(json!({
        "kind": "serial", "name": "one arm",
        "units": {"length": "mm", "angle": "deg", "mass": "kg", "compliance": "deg/(N*m)"},
        "joints": rows,
        "base": {"x": 1000, "y": -50, "z": 0, "a": 90, "b": 0, "c": 0},
        "tool": tool,
        "gravity": {"magnitude": 9.80665, "direction_in_base": [0, 0, -1]}
    }))
    .expect("serial file")
}

#[test]
fn tree_chains_equal_the_arms_as_serial_files() {
    let f = load(MODIFIED, "modified");
    let arms = [
        (
            "left_arm",
            vec![
                "torso",
                "torso_lift",
                "l_shoulder",
                "l_upper",
                "l_elbow",
                "l_wrist",
                "l_hand",
            ],
            json!({"x": 10, "y": 0, "z": 20, "a": 0, "b": 0, "c": 0}),
        ),
        (
            "right_arm",
            vec![
                "torso",
                "torso_lift",
                "r_shoulder",
                "r_upper",
                "r_elbow",
                "r_forearm",
                "r_wrist",
                "r_wrist2",
            ],
            json!({"x": 20, "y": 0, "z": 30, "a": 0, "b": 0, "c": 0}),
        ),
    ];
    for (name, path, tool) in arms {
        let tree = f.chain(name, "modified").expect("tree chain");
        let serial = serial_file(&f, &path, tool)
            .to_chain()
            .expect("serial chain");
        assert_eq!(tree.param_ids().len(), serial.param_ids().len());
        for q in qs(&tree) {
            let (a, b) = (tree.tcp(&q, None), serial.tcp(&q, None));
            assert!(
                (a.p - b.p).norm() < 1e-9 && (a.r - b.r).norm() < 1e-12,
                "{name} {q:?}"
            );
        }
    }
}

/// Replace the first occurrence of `from` (which must exist) in the classic file.
fn edited(from: &str, to: &str) -> String {
    assert!(CLASSIC.contains(from), "{from}");
    CLASSIC.replacen(from, to, 1)
}

#[test]
fn bad_tree_files_name_file_row_and_field() {
    let cases = [
        // Unknown parent.
        (
            edited(r#""parent": "l_upper""#, r#""parent": "l_uper""#),
            vec!["t.json", "rows[4]", "l_elbow", "parent", "l_uper"],
        ),
        // A cycle: torso hangs below its own descendant.
        (
            edited(
                r#""name": "torso", "parent": "base""#,
                r#""name": "torso", "parent": "l_wrist""#,
            ),
            vec!["t.json", "torso", "parent", "cycle"],
        ),
        // Missing convention.
        (
            edited(r#""convention": "classic","#, ""),
            vec!["t.json", "convention"],
        ),
        // An unknown convention.
        (
            edited(r#""convention": "classic""#, r#""convention": "craig""#),
            vec!["t.json", "convention", "craig"],
        ),
        // Unknown chain end.
        (
            edited(r#""end": "l_hand""#, r#""end": "l_fist""#),
            vec!["t.json", "chains[1]", "left_arm", "end", "l_fist"],
        ),
        // Duplicate row name.
        (
            edited(r#""name": "r_upper""#, r#""name": "l_upper""#),
            vec!["t.json", "rows[8]", "l_upper", "twice"],
        ),
    ];
    for (text, want) in cases {
        let e = DhTreeFile::parse(&text, "t.json").unwrap_err().to_string();
        for w in want {
            assert!(e.contains(w), "`{w}` not in: {e}");
        }
    }
    let f = load(CLASSIC, "t.json");
    let e = f.chain("left_leg", "t.json").unwrap_err().to_string();
    assert!(e.contains("left_leg") && e.contains("right_arm"), "{e}");
    // A row with its own variable and no limits, found when its chain is built.
    let text = edited(r#", "limits": [-170, 170]}"#, "}");
    let e = load(&text, "t.json")
        .chain("left_arm", "t.json")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("t.json") && e.contains("l_shoulder") && e.contains("limits"),
        "{e}"
    );
}

/// A chain written as a serial DH file (what a serial job writes back) keeps its FK and its
/// parameter names, for both conventions.
#[test]
fn serial_files_of_tree_chains_keep_the_fk() {
    for (text, file) in [(CLASSIC, "classic.json"), (MODIFIED, "modified.json")] {
        let f = load(text, file);
        for name in ["torso", "left_arm", "right_arm"] {
            let tree = f.chain(name, file).expect("tree chain");
            let serial = f.serial_file(name, file).expect("serial file");
            let back = DhFile::parse(&serde_json::to_string(&serial).expect("json"))
                .expect("reparses")
                .to_chain()
                .expect("serial chain");
            for q in qs(&tree) {
                let (a, b) = (tree.tcp(&q, None), back.tcp(&q, None));
                assert!(
                    (a.p - b.p).norm() < 1e-9 && (a.r - b.r).norm() < 1e-12,
                    "{file} {name}"
                );
            }
            for n in &serial.identify {
                assert!(
                    tree.param_by_name(n).is_ok() && back.param_by_name(n).is_ok(),
                    "{n}"
                );
            }
        }
    }
}
