use super::conf::Controller;
use super::correct::Filter;
use super::data::{Held, RobTarget, tooldata, wobjdata};
use super::program::{Options, Outcome, filter_module};
use super::*;
use crate::geometry::Frame;
use crate::model::Chain;
use crate::model::compensate::{Tolerances, rotation_vector};
use crate::twin::SerialTwin;
use crate::util::Rng;

const MODULE: &str = include_str!("../../../tests/data/rapid/PickPlace.mod");

fn tolerances() -> Tolerances {
    Tolerances {
        position: 1e-4,
        angle: 1e-5f64.to_radians(),
        singular_sin: 1e-3,
        singular_shoulder: 1.0,
    }
}

fn filter(cal: &Chain, nominal: &Chain) -> Filter {
    Filter::new(cal, nominal, false, tolerances(), 5.0).expect("OPW arm")
}

/// The module text with every robtarget's pose and configuration numbers replaced by `#`.
fn masked(src: &str) -> String {
    let m = parse(src).expect("parses");
    let mut spans = Vec::new();
    for d in m.decls.iter().filter(|d| d.ty == "robtarget") {
        let Some(v) = &d.value else { continue };
        let mut stack = vec![v];
        while let Some(v) = stack.pop() {
            if let Some(rt) = RobTarget::of(v) {
                spans.extend(
                    rt.pos
                        .iter()
                        .chain(&rt.rot)
                        .chain(&rt.conf)
                        .map(|n| (n.1, n.2)),
                );
            } else if let Some(items) = v.items() {
                stack.extend(items);
            }
        }
    }
    spans.sort();
    let mut out = String::new();
    let mut at = 0;
    for (s, e) in spans {
        out.push_str(&src[at..s]);
        out.push('#');
        at = e;
    }
    out + &src[at..]
}

/// Every literal robtarget of a module: label, pose, configuration, tool and wobj names.
fn targets(src: &str) -> Vec<(String, Frame, [i64; 4])> {
    let m = parse(src).unwrap();
    let mut out = Vec::new();
    for d in m.decls.iter().filter(|d| d.ty == "robtarget") {
        let Some(v) = &d.value else { continue };
        let mut flat = Vec::new();
        collect(v, d.dims.len(), &mut flat);
        for (k, rt) in flat.into_iter().enumerate() {
            out.push((
                format!("{}#{k}", d.name),
                rt.frame().unwrap(),
                rt.confdata().unwrap(),
            ));
        }
    }
    out
}

fn collect(v: &Value, depth: usize, out: &mut Vec<RobTarget>) {
    if depth == 0 {
        out.extend(RobTarget::of(v));
    } else {
        for it in v.items().unwrap() {
            collect(it, depth - 1, out);
        }
    }
}

/// Frames of the module's tools and work objects by name.
fn data_frame(src: &str, name: &str) -> Frame {
    if name == "tool0" || name == "wobj0" {
        return Frame::identity();
    }
    let m = parse(src).unwrap();
    let d = m.decls.iter().find(|d| d.name == name).unwrap();
    let v = d.value.as_ref().unwrap();
    match tooldata(v).or_else(|| wobjdata(v)) {
        Some(Held::Frame(f)) => f,
        other => panic!("{name}: {other:?}"),
    }
}

#[test]
fn the_module_parses_with_its_declarations_and_moves() {
    let m = parse(MODULE).unwrap();
    assert_eq!(m.name, "PickPlace");
    let of = |ty: &str| -> Vec<&str> {
        m.decls
            .iter()
            .filter(|d| d.ty == ty)
            .map(|d| d.name.as_str())
            .collect()
    };
    assert_eq!(
        of("robtarget"),
        ["pHome", "pPick", "pGlue", "pTray", "pCurrent"]
    );
    assert_eq!(of("tooldata"), ["tGripper", "tGlue"]);
    assert_eq!(of("wobjdata"), ["wInfeed", "wTray"]);
    let tray = m.decls.iter().find(|d| d.name == "pTray").unwrap();
    assert_eq!(tray.dims, [Some(2), Some(3)]);
    assert_eq!(tray.storage, "PERS");
    assert_eq!(tray.line, 38);
    // Uses: tool and work object of each move, through Offs and RelTool too.
    let uses = |t: &str| -> Vec<(String, String, bool)> {
        m.moves
            .iter()
            .flat_map(|mv| {
                mv.targets.iter().filter(|x| x.0 == t).map(|x| {
                    (
                        mv.tool.clone().unwrap(),
                        mv.wobj.clone().unwrap_or_default(),
                        x.1,
                    )
                })
            })
            .collect()
    };
    let pick = uses("pPick");
    assert_eq!(pick.len(), 3);
    assert!(pick.iter().all(|u| u.0 == "tGripper" && u.1 == "wInfeed"));
    assert_eq!(pick.iter().filter(|u| u.2).count(), 2);
    let glue = uses("pGlue");
    assert_eq!(glue.len(), 7, "{glue:?}");
    assert!(glue.iter().all(|u| u.0 == "tGlue" && u.1.is_empty()));
    assert_eq!(uses("pTray").len(), 3);
    // The tool's frame: TCP 142.7 mm out, tilted 30 deg about y.
    let g = data_frame(MODULE, "tGlue");
    assert!((g.p.z - 142.7).abs() < 1e-12);
    assert!((g.r[(0, 2)] - 0.5).abs() < 1e-8, "{}", g.r);
    // The tray's object frame: uframe * oframe.
    let w = data_frame(MODULE, "wTray");
    let expect = 260.0 + 10f64.to_radians().cos() * 5.0 + 10f64.to_radians().sin() * 3.0;
    assert!((w.p.x - expect).abs() < 1e-6, "{} vs {expect}", w.p.x);
}

#[test]
fn a_module_that_does_not_parse_names_the_line() {
    let cases: [(&str, usize, &str); 9] = [
        (
            "MODULE m\n  VAR num a := 1\n  VAR num b := 2;\nENDMODULE",
            2,
            "not ended by `;`",
        ),
        (
            "MODULE m\nCONST robtarget p := [[1,2,3],[1,0,0,0],\n  [0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9];\nENDMODULE",
            2,
            "not closed",
        ),
        (
            "MODULE m\nPROC a()\n  x := 1;\nPROC b()\nENDPROC\nENDMODULE",
            4,
            "missing ENDPROC",
        ),
        (
            "MODULE m\nPROC a()\n  IF x THEN\n    y := 1;\nENDPROC\nENDMODULE",
            5,
            "IF opened on line 3",
        ),
        ("MODULE m\n  x := (1 + 2];\nENDMODULE", 2, "closes the `(`"),
        ("PROC a()\nENDPROC", 1, "expected MODULE"),
        (
            "MODULE m\n  TASK PERS num a := 1\n  LOCAL VAR num b := 2;\nENDMODULE",
            2,
            "before LOCAL",
        ),
        (
            "MODULE m\nPROC a()\n  x := 1\n  y := 2;\nENDPROC\nENDMODULE",
            3,
            "missing between `1` and `y`",
        ),
        ("MODULE m\nPROC a()\nENDPROC\n", 1, "MODULE is not closed"),
    ];
    for (src, line, text) in cases {
        let e = parse(src).unwrap_err();
        assert_eq!(e.line, line, "{src:?}: {e}");
        assert!(e.message.contains(text), "{src:?}: {e}");
    }
    // A robtarget with a wrong number of components is refused when filtered, not parsed.
    let twin = SerialTwin::irb120(1);
    let f = filter(&twin.nominal, &twin.nominal);
    let src = "MODULE m\nCONST robtarget p := [[1,2,3],[1,0,0,0],[0,0,0,0]];\nENDMODULE\n";
    let out = filter_module(src, &f, &Options::default()).unwrap();
    assert_eq!(out.targets[0].outcome, Outcome::NotLiteral);
    assert_eq!(out.text, src);
}

#[test]
fn an_identity_calibration_leaves_every_byte() {
    let twin = SerialTwin::irb120(1);
    let f = filter(&twin.nominal, &twin.nominal);
    let out = filter_module(MODULE, &f, &Options::default()).unwrap();
    assert_eq!(out.module, "PickPlace");
    assert_eq!(out.targets.len(), 12);
    for t in &out.targets {
        assert_eq!(t.outcome, Outcome::Unchanged, "{t:?}");
        assert!(t.correction_mm < 1e-6 && t.correction_deg < 1e-7, "{t:?}");
        assert_eq!(t.conf_before, t.conf_after, "{t:?}");
    }
    assert_eq!(out.text, MODULE);
}

#[test]
fn on_the_twin_the_controller_reaches_with_the_rewritten_targets_what_the_true_robot_was_asked() {
    // The "calibrated model" is the twin's truth: what the IRC5 moves to with the rewritten
    // targets (its nominal inverse kinematics, branch by the new cf data) must put the true
    // robot's TCP where the original targets meant.
    let twin = SerialTwin::irb120(1);
    let f = filter(&twin.truth, &twin.nominal);
    let out = filter_module(MODULE, &f, &Options::default()).unwrap();
    assert_eq!(
        masked(&out.text),
        masked(MODULE),
        "bytes outside the targets changed"
    );
    let before = targets(MODULE);
    let after = targets(&out.text);
    assert_eq!(before.len(), 12);
    let controller = Controller::new(&twin.nominal).unwrap();
    let mut truth = twin.truth.clone();
    truth.base = [0.0; 6];
    truth.tool = [0.0; 6];
    let (mut worst_mm, mut worst_rad, mut mean_corr) = (0.0f64, 0.0f64, 0.0);
    for (((label, t, _), (_, t2, cf2)), r) in before.iter().zip(&after).zip(&out.targets) {
        assert_eq!(r.outcome, Outcome::Corrected, "{label}: {r:?}");
        mean_corr += r.correction_mm / 12.0;
        let (tool, wobj) = (data_frame(MODULE, &r.tool), data_frame(MODULE, &r.wobj));
        // The controller: nominal IK of the new target with its cf.
        let flange = wobj.mul(t2).mul(&tool.inverse());
        let q = controller
            .joints(&flange, *cf2)
            .unwrap_or_else(|| panic!("{label}: cf {cf2:?} not reachable"));
        assert_eq!(controller.confdata(&q), *cf2, "{label}");
        for k in [0, 3, 5] {
            assert_eq!(
                conf::quadrant(q[k]),
                cf2[[0, 0, 0, 1, 0, 2][k]],
                "{label} axis {}",
                k + 1
            );
        }
        // The true robot at those joints (with its deflection) vs the original target.
        let tau = truth.static_torques(&q);
        let tcp = truth.tcp(&q, Some(&tau)).mul(&tool);
        let want = wobj.mul(t);
        let dp = (tcp.p - want.p).norm();
        let da = rotation_vector(&(want.r.transpose() * tcp.r)).norm();
        worst_mm = worst_mm.max(dp);
        worst_rad = worst_rad.max(da);
        // Against the nominal joints of the original (what the controller does today).
        assert!(r.correction_mm > 0.05, "{label}: {r:?}");
    }
    println!(
        "12 targets: mean correction {mean_corr:.3} mm; true pose of the filtered program \
         vs the original targets: max {:.2e} mm, {:.2e} rad",
        worst_mm, worst_rad
    );
    assert!(worst_mm < 1e-3, "{worst_mm} mm");
    assert!(worst_rad < 1e-6, "{worst_rad} rad");
}

#[test]
fn jointtargets_are_declared_after_their_robtargets() {
    let twin = SerialTwin::irb120(1);
    let f = filter(&twin.truth, &twin.nominal);
    let o = Options {
        jointtargets: true,
        ..Default::default()
    };
    let out = filter_module(MODULE, &f, &o).unwrap();
    let m = parse(&out.text).expect("the output parses");
    let jt: Vec<&Decl> = m.decls.iter().filter(|d| d.ty == "jointtarget").collect();
    let names: Vec<&str> = jt.iter().map(|d| d.name.as_str()).collect();
    assert_eq!(names, ["pHome_jt", "pPick_jt", "pGlue_jt", "pTray_jt"]);
    assert_eq!(jt[3].dims, [Some(2), Some(3)]);
    assert_eq!(jt[3].storage, "PERS");
    // pTray{2,1} is the 4th element: its joints are the report's.
    let v = jt[3].value.as_ref().unwrap();
    let e = &v.items().unwrap()[1].items().unwrap()[0];
    let q: Vec<f64> = e.items().unwrap()[0]
        .numbers(6)
        .unwrap()
        .iter()
        .map(|n| n.0)
        .collect();
    let r = out
        .targets
        .iter()
        .find(|r| r.target == "pTray{2,1}")
        .unwrap();
    for k in 0..6 {
        assert!((q[k] - r.q_deg.unwrap()[k]).abs() < 1e-6, "{q:?} {r:?}");
    }
}

#[test]
fn controller_configuration_matches_the_closed_form_branches() {
    // cf data of random joints, and the controller's joints for the pose with that cf,
    // are the joints themselves.
    let twin = SerialTwin::irb120(1);
    let c = Controller::new(&twin.nominal).unwrap();
    let mut rng = Rng::new(9);
    let mut seen = std::collections::BTreeSet::new();
    for _ in 0..300 {
        let mut q: [f64; 6] = twin.random_q(&mut rng).try_into().unwrap();
        q[0] = rng.range(-160.0, 160.0).to_radians();
        let cf = c.confdata(&q);
        seen.insert(cf[3]);
        let f = twin.nominal.flange(&q, None);
        let back = c.joints(&f, cf).expect("own configuration");
        for k in 0..6 {
            assert!((back[k] - q[k]).abs() < 1e-9, "{q:?} {back:?}");
        }
    }
    // The home pose is cfx 0; all joints 0 but q5 = -30 deg is cfx 1.
    assert_eq!(c.confdata(&[0.0, 0.0, 0.0, 0.0, 0.5, 0.0]), [0, 0, 0, 0]);
    assert_eq!(c.confdata(&[0.0, 0.0, 0.0, 0.0, -0.5, 0.0])[3], 1);
    assert!(seen.len() >= 4, "{seen:?}");
}
