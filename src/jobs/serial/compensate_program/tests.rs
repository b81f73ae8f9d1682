use serde_json::{Value, json};

use super::*;
use crate::geometry::Frame;
use crate::jobs::prepare as prepare_job;
use crate::model::compensate::rotation_vector;
use crate::model::rapid::conf::Controller;
use crate::model::rapid::data::{Held, RobTarget, tooldata, wobjdata};
use crate::run::NoReferences;
use crate::twin::SerialTwin;
use crate::util::NoMonitor;

const MODULE: &str = include_str!("../../../../tests/data/rapid/PickPlace.mod");

fn job(model: Value, nominal: Value, module: &str) -> Value {
    json!({"kind": "serial.compensate_program", "model": model, "nominal": nominal,
           "module": module})
}

fn run(doc: &Value) -> crate::jobs::Completed {
    prepare_job(doc, &NoReferences)
        .expect("valid job")
        .run(&NoMonitor)
        .expect("job runs")
}

/// The frame of a tooldata or wobjdata declared in `src` (`tool0`, `wobj0`: identity).
fn frame_of(src: &str, name: &str) -> Frame {
    if name == "tool0" || name == "wobj0" {
        return Frame::identity();
    }
    let m = parse(src).unwrap();
    let v = m
        .decls
        .iter()
        .find(|d| d.name == name)
        .unwrap()
        .value
        .clone()
        .unwrap();
    match tooldata(&v).or_else(|| wobjdata(&v)) {
        Some(Held::Frame(f)) => f,
        other => panic!("{other:?}"),
    }
}

/// Literal robtargets of a module in order (array elements row-major).
fn robtargets(src: &str) -> Vec<RobTarget> {
    fn go(v: &crate::model::rapid::Value, out: &mut Vec<RobTarget>) {
        match RobTarget::of(v) {
            Some(rt) => out.push(rt),
            None => v.items().into_iter().flatten().for_each(|i| go(i, out)),
        }
    }
    let mut out = Vec::new();
    for d in parse(src)
        .unwrap()
        .decls
        .iter()
        .filter(|d| d.ty == "robtarget")
    {
        if let Some(v) = &d.value {
            go(v, &mut out);
        }
    }
    out
}

#[test]
fn on_the_twin_the_filtered_program_puts_the_true_robot_on_the_original_targets() {
    let twin = SerialTwin::irb120(1);
    let truth = serde_json::to_value(twin.file.with_chain(&twin.truth)).unwrap();
    let nominal = serde_json::to_value(&twin.file).unwrap();
    let done = run(&job(truth, nominal, MODULE));
    let r = &done.result;
    assert_eq!(r["module"], "PickPlace");
    assert_eq!(r["file"], "PickPlace.mod");
    assert_eq!(r["summary"]["targets"], 12);
    assert_eq!(r["summary"]["corrected"], 12, "{}", r["targets"]);
    let out = done
        .artefacts
        .iter()
        .find(|a| a.name == "PickPlace.mod")
        .unwrap();
    let text = String::from_utf8(out.content.clone()).unwrap();
    let table = done.main_table.unwrap();
    assert_eq!(table.rows.len(), 12);
    let controller = Controller::new(&twin.nominal).unwrap();
    let mut truth = twin.truth.clone();
    (truth.base, truth.tool) = ([0.0; 6], [0.0; 6]);
    let (before, after) = (robtargets(MODULE), robtargets(&text));
    let reports = r["targets"].as_array().unwrap();
    let (mut worst_mm, mut worst_rad, mut nominal_mm) = (0.0f64, 0.0f64, 0.0f64);
    for ((b, a), rep) in before.iter().zip(&after).zip(reports) {
        let tool = frame_of(MODULE, rep["tool"].as_str().unwrap());
        let wobj = frame_of(MODULE, rep["wobj"].as_str().unwrap());
        let want = wobj.mul(&b.frame().unwrap());
        // The controller moves to the new target: nominal IK, branch by its cf data.
        let cf = a.confdata().unwrap();
        let q = controller
            .joints(&wobj.mul(&a.frame().unwrap()).mul(&tool.inverse()), cf)
            .expect("the new cf data are the joints' quadrants and branch");
        assert_eq!(controller.confdata(&q), cf);
        let tau = truth.static_torques(&q);
        let got = truth.tcp(&q, Some(&tau)).mul(&tool);
        worst_mm = worst_mm.max((got.p - want.p).norm());
        worst_rad = worst_rad.max(rotation_vector(&(want.r.transpose() * got.r)).norm());
        // The unfiltered program on the same robot, for comparison.
        let q0 = controller
            .joints(&want.mul(&tool.inverse()), b.confdata().unwrap())
            .unwrap();
        let tau0 = truth.static_torques(&q0);
        nominal_mm = nominal_mm.max((truth.tcp(&q0, Some(&tau0)).mul(&tool).p - want.p).norm());
    }
    println!(
        "true TCP vs the program's targets: filtered max {worst_mm:.2e} mm {worst_rad:.2e} rad; \
         unfiltered max {nominal_mm:.3} mm; mean correction {} mm",
        r["summary"]["mean_correction_mm"]
    );
    assert!(
        worst_mm < 1e-3 && worst_rad < 1e-6,
        "{worst_mm} mm {worst_rad} rad"
    );
    assert!(nominal_mm > 0.5, "{nominal_mm}");
    let csv = String::from_utf8(done.artefacts[1].content.clone()).unwrap();
    assert!(
        csv.lines().nth(3).unwrap().starts_with("pGlue{1},"),
        "{csv}"
    );
}

#[test]
fn an_identity_calibration_returns_the_module_byte_for_byte() {
    let twin = SerialTwin::irb120(1);
    let nominal = serde_json::to_value(&twin.file).unwrap();
    let done = run(&job(nominal.clone(), nominal, MODULE));
    assert_eq!(done.result["summary"]["unchanged"], 12);
    assert_eq!(done.artefacts[0].content, MODULE.as_bytes());
}

#[test]
fn a_module_that_does_not_parse_is_refused_naming_the_line() {
    let twin = SerialTwin::irb120(1);
    let nominal = serde_json::to_value(&twin.file).unwrap();
    let broken = MODULE.replace(
        "WaitTime 0.2;   ! gripper closes",
        "WaitTime 0.2   ! gripper closes",
    );
    let e = prepare_job(
        &job(nominal.clone(), nominal.clone(), &broken),
        &NoReferences,
    )
    .unwrap_err();
    assert!(e.is_invalid_input(), "{e:?}");
    let line = MODULE
        .lines()
        .position(|l| l.contains("gripper closes"))
        .unwrap()
        + 1;
    assert!(
        e.to_string().contains(&format!("`module`: line {line}:")),
        "{e}"
    );
    // A tool given by the job that is not a tooldata literal.
    let mut doc = job(nominal.clone(), nominal, MODULE);
    doc["options"] = json!({"tooldata": {"tX": "[TRUE,[[0,0,1]]]"}});
    let e = prepare_job(&doc, &NoReferences).unwrap_err().to_string();
    assert!(e.contains("options.tooldata.tX"), "{e}");
}

#[test]
fn a_target_without_its_tool_is_reported_and_a_given_tool_fixes_it() {
    let twin = SerialTwin::irb120(1);
    let truth = serde_json::to_value(twin.file.with_chain(&twin.truth)).unwrap();
    let nominal = serde_json::to_value(&twin.file).unwrap();
    // The tools live in another module: without them the targets are reported, not guessed.
    let start = MODULE.find("    PERS tooldata tGripper").unwrap();
    let end = MODULE.find("    ! --- Work objects").unwrap();
    let no_tools = format!("{}{}", &MODULE[..start], &MODULE[end..]);
    let done = run(&job(truth.clone(), nominal.clone(), &no_tools));
    let t = &done.result["targets"][1];
    assert_eq!(t["outcome"], "data");
    assert!(
        t["reason"]
            .as_str()
            .unwrap()
            .contains("tooldata `tGripper` is not declared"),
        "{t}"
    );
    let mut doc = job(truth, nominal, &no_tools);
    doc["options"] = json!({"tooldata": {
        "tGripper": "[TRUE,[[0,0,115.5],[1,0,0,0]],[0.85,[0,0,48],[1,0,0,0],0,0,0]]",
        "tGlue": "[TRUE,[[32.1,0,142.7],[0.965925826,0,0.258819045,0]],[0.6,[10,0,60],[1,0,0,0],0,0,0]]"}});
    let full = run(&job(
        serde_json::to_value(twin.file.with_chain(&twin.truth)).unwrap(),
        serde_json::to_value(&twin.file).unwrap(),
        MODULE,
    ));
    let given = run(&doc);
    assert_eq!(given.result["summary"]["corrected"], 12);
    // The same corrections (the lines moved up by the tools' four lines).
    let without_lines = |v: &Value| -> Vec<Value> {
        let mut rows = v.as_array().unwrap().clone();
        for r in &mut rows {
            r.as_object_mut().unwrap().remove("line");
        }
        rows
    };
    assert_eq!(
        without_lines(&given.result["targets"]),
        without_lines(&full.result["targets"])
    );
}
