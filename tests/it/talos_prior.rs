//! TALOS F1/F2 with a prior (issue 13, item 2): MAP identification on the 61 real F1 rows
//! (Apache-2.0, in the repository) with the prior's weight chosen by K-fold on F1 alone,
//! against FIGAROH's regularised fit of the same data: at most 0.564 mm on the F1 training
//! rows and at most 0.899 mm on the held-out crane session F2 (base frame and marker refit,
//! joints held). F2 has no licence file: it is read from `../shared/data/real/` when it
//! exists, and the test says when it skipped that half.

use std::path::{Path, PathBuf};

use calibd::jobs::{DirResolver, prepare};
use calibd::util::NoMonitor;
use serde_json::{Value, json};

fn examples() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples"))
}

fn run(doc: &Value, dir: &Path) -> Value {
    let resolver = DirResolver {
        dir: dir.to_path_buf(),
    };
    prepare(doc, &resolver)
        .expect("the job is valid")
        .run(&NoMonitor)
        .expect("the job runs")
        .result
}

fn f1(with_prior: bool) -> Value {
    let name = if with_prior {
        "humanoid_identify_f1_map.json"
    } else {
        "humanoid_identify_f1.json"
    };
    let text = std::fs::read_to_string(examples().join(name)).expect("example");
    let mut doc: Value = serde_json::from_str(&text).expect("json");
    if let Some(o) = doc["options"].as_object_mut() {
        o.remove("cross_validation");
    }
    run(&doc, &examples())
}

/// `../shared` (the team's data outside the repository), or `CALIBD_SHARED_DIR`.
fn shared() -> PathBuf {
    std::env::var_os("CALIBD_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared"))
}

/// The crane session validated with `calibrated` (F1's result); `None` without `../shared`.
fn crane(calibrated: &Value) -> Option<f64> {
    session(calibrated, "talos_feb_arm_02_07_crane.csv", false)
}

/// A held-out left-arm session (F2 columns; `headerless`: F3b, which has no header line)
/// validated with `calibrated`: base frame and marker refit, joints held.
fn session(calibrated: &Value, file: &str, headerless: bool) -> Option<f64> {
    let path = shared().join("data/real/talos_arm_mocap").join(file);
    if !path.exists() {
        println!("skipped: session {} not found", path.display());
        return None;
    }
    let dir =
        std::env::temp_dir().join(format!("calibd-talos-prior-{}-{file}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    std::fs::write(dir.join("calibrated.json"), calibrated.to_string()).expect("write");
    let samples = if headerless {
        let mut text = String::from("t,x1,y1,z1,torso1,torso2");
        for k in 1..=7 {
            text += &format!(",armL{k}");
        }
        text += "\n";
        text += &std::fs::read_to_string(&path).expect("session");
        std::fs::write(dir.join("samples.csv"), text).expect("write");
        dir.join("samples.csv")
    } else {
        path
    };
    let f1: Value = serde_json::from_str(
        &std::fs::read_to_string(examples().join("humanoid_identify_f1.json")).expect("example"),
    )
    .expect("json");
    let mut map = json!({"x1": "hand_x", "y1": "hand_y", "z1": "hand_z",
        "torso1": "torso_1_joint", "torso2": "torso_2_joint"});
    for k in 1..=7 {
        map[format!("armL{k}")] = json!(format!("arm_left_{k}_joint"));
    }
    let doc = json!({
        "kind": "humanoid.validate",
        "urdf": examples().join(f1["urdf"].as_str().expect("urdf")),
        "samples": samples,
        "column_map": map,
        "root_link": "base_link",
        "joints": f1["joints"],
        "markers": f1["markers"],
        "base": {"mode": "identify"},
        "calibrated": "calibrated.json",
        "options": {"elastic": {"joints": [], "base": false}},
    });
    let r = run(&doc, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    Some(r["rmse_fcm_mm"].as_f64().expect("rmse_fcm_mm"))
}

/// Issue 30, item 8: no user-given std. `"prior": {"scale": "auto"}` chooses the length and
/// angle stds by 5-fold over a self-extending grid on F1 alone; the choice is the grid's
/// smallest held-out RMS and not on its edge, and the calibration beats FIGAROH on the
/// held-out crane session F2 (0.899 mm) and least squares there (1.254 mm); on F1 training
/// it stays within 0.011 mm of FIGAROH's 0.564 mm (measured 0.572 mm).
#[test]
fn an_automatic_prior_beats_figaroh_without_a_user_std() {
    let text = std::fs::read_to_string(examples().join("humanoid_identify_f1_auto.json"))
        .expect("example");
    let doc: Value = serde_json::from_str(&text).expect("json");
    assert!(doc["options"]["prior"].get("default_std").is_none());
    assert!(doc["options"].get("prior_weight").is_none());
    let r = run(&doc, &examples());
    assert_eq!(r["prior"]["mode"], "map_auto");
    let auto = &r["prior"]["auto"];
    assert_eq!(auto["at_edge"], false, "{auto}");
    let (len, ang) = (
        auto["length_mm"].as_f64().expect("length"),
        auto["angle_deg"].as_f64().expect("angle"),
    );
    let grid = auto["grid"].as_array().expect("grid");
    let col = |c: &Value, k: &str| c[k].as_f64().unwrap_or(f64::NAN);
    let rms: Vec<f64> = grid
        .iter()
        .map(|c| c["rms_mm"].as_f64().unwrap_or(f64::INFINITY))
        .collect();
    let best = rms.iter().copied().fold(f64::INFINITY, f64::min);
    assert_eq!(auto["held_out_rms_mm"].as_f64(), Some(best));
    // Interior: smaller and larger values of both stds were tried.
    for (v, k) in [(len, "length_mm"), (ang, "angle_deg")] {
        assert!(
            grid.iter().any(|c| col(c, k) < v),
            "{k} {v} at the low edge"
        );
        assert!(
            grid.iter().any(|c| col(c, k) > v),
            "{k} {v} at the high edge"
        );
    }
    let worst = rms
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    assert_eq!(auto["sensitivity_mm"], json!([best, worst]));
    assert_eq!(r["convergence"]["converged"], true, "{}", r["convergence"]);
    let train = r["rmse_after_mm"].as_f64().expect("rmse");
    println!(
        "auto prior: {len} mm / {ang} deg (weight 1), {} cells, 5-fold held-out {best:.3} mm \
         (grid {best:.3}..{worst:.3} mm); F1 training {train:.3} mm",
        grid.len()
    );
    // FIGAROH's 0.564 mm on the training rows is not reached: the K-fold choice (about
    // 5.7 mm / 0.35 deg) trades 0.008 mm of training fit for the held-out error; the
    // least-squares fit of the same rows gives 0.568 mm.
    let Some(f2) = crane(&r) else {
        assert!(train < 0.575, "F1 training {train} mm (FIGAROH 0.564)");
        return;
    };
    let f3b = session(&r, "talos_feb_arm_2_contact.csv", true);
    let ls = f1(false);
    let (f2_ls, f3b_ls) = (
        crane(&ls),
        session(&ls, "talos_feb_arm_2_contact.csv", true),
    );
    println!(
        "held out: F2 auto {f2:.3} mm (least squares {f2_ls:?}, FIGAROH 0.899); \
         F3b auto {f3b:?} mm (least squares {f3b_ls:?})"
    );
    assert!(train < 0.575, "F1 training {train} mm (FIGAROH 0.564)");
    assert!(f2 < 0.899, "F2 held out {f2} mm (FIGAROH 0.899)");
    assert!(
        f2 < f2_ls.unwrap_or(f64::INFINITY),
        "F2 auto {f2} vs least squares {f2_ls:?}"
    );
}
