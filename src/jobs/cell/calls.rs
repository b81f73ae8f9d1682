//! Typed calls from the campaigns into the numerical kinds: DETMAX selection and
//! identification of a serial arm, identification and accuracy of a 3-PF robot, NOCP
//! design and identification of a humanoid.

use serde::Deserialize;
use serde_json::{Map, Value, json};

use crate::campaigns::engine::{Identified, ValidationMeans};
use crate::jobs::{Inputs, JobError, NoReferences, Output, Table};
use crate::model::dh::DhFile;
use crate::util::Monitor;

fn ballbar(d: [f64; 3]) -> Value {
    json!({"d12": d[0], "d13": d[1], "d23": d[2]})
}

fn rows_deg(q: &[Vec<f64>], extra: impl Fn(usize, &mut Map<String, Value>)) -> Value {
    Value::Array(
        q.iter()
            .enumerate()
            .map(|(i, q)| {
                let mut m = Map::new();
                for (k, v) in q.iter().enumerate() {
                    m.insert(format!("q{}", k + 1), json!(v.to_degrees()));
                }
                extra(i, &mut m);
                Value::Object(m)
            })
            .collect(),
    )
}

/// DETMAX selection of `n` of `pool` (joints in rad, 0-based ball) for the ballbar plate
/// (d12, d13, d23 in mm).
pub fn select_for_plate(
    file: &DhFile,
    pool: &[(Vec<f64>, usize)],
    plate: [f64; 3],
    n: usize,
    seed: u64,
    monitor: &dyn Monitor,
) -> Result<Vec<usize>, JobError> {
    let q: Vec<Vec<f64>> = pool.iter().map(|p| p.0.clone()).collect();
    let doc = json!({
        "kind": "serial.design",
        "model": serde_json::to_value(file).unwrap_or(Value::Null),
        "pool": rows_deg(&q, |i, m| { m.insert("ball".into(), json!(pool[i].1 + 1)); }),
        "n": n,
        "ball_plate": ballbar(plate),
        "options": {"seed": seed},
    });
    let out = crate::jobs::serial::design::prepare(&doc, &Inputs::new(&NoReferences))?
        .execute(monitor)?;
    #[derive(Deserialize)]
    struct Selected {
        selected: Vec<usize>,
    }
    let s: Selected = serde_json::from_value(Value::Object(out.fields))
        .map_err(|e| JobError::Failed(format!("the DETMAX selection: {e}")))?;
    Ok(s.selected)
}

/// The calibrated model and validation of an identification's output.
pub fn identified<M: serde::de::DeserializeOwned>(out: Output) -> Result<Identified<M>, JobError> {
    #[derive(Deserialize)]
    struct View<M> {
        calibrated_model: M,
        #[serde(default)]
        validation: Option<ValidationMeans>,
    }
    let v: View<M> = serde_json::from_value(Value::Object(out.fields.clone()))
        .map_err(|e| JobError::Failed(format!("the identification's result: {e}")))?;
    Ok(Identified {
        fields: out.fields,
        model: v.calibrated_model,
        validation: v.validation,
        artefacts: out.artefacts,
    })
}

/// `serial.identify` on ball-centring measurements (joints in rad, 0-based ball), validated
/// on configurations whose TCP positions (mm, world) are known.
pub fn identify_balls(
    file: &DhFile,
    meas: &[(Vec<f64>, usize)],
    plate: [f64; 3],
    validation: &[(Vec<f64>, [f64; 3])],
    options: Option<&Value>,
    monitor: &dyn Monitor,
) -> Result<Identified<DhFile>, JobError> {
    let q: Vec<Vec<f64>> = meas.iter().map(|p| p.0.clone()).collect();
    let mut doc = json!({
        "kind": "serial.identify",
        "model": serde_json::to_value(file).unwrap_or(Value::Null),
        "measurements": rows_deg(&q, |i, m| { m.insert("ball".into(), json!(meas[i].1 + 1)); }),
        "ball_plate": ballbar(plate),
    });
    if let Some(o) = options {
        doc["options"] = o.clone();
    }
    if !validation.is_empty() {
        let vq: Vec<Vec<f64>> = validation.iter().map(|p| p.0.clone()).collect();
        doc["validation"] = rows_deg(&vq, |i, m| {
            let p = validation[i].1;
            m.insert("x".into(), json!(p[0]));
            m.insert("y".into(), json!(p[1]));
            m.insert("z".into(), json!(p[2]));
        });
    }
    let out = crate::jobs::serial::identify::prepare(&doc, &Inputs::new(&NoReferences))?
        .execute(monitor)?;
    identified(out)
}

/// A table's rows as JSON objects without `drop` (a samples table for a kind's input).
pub fn rows_without(t: &Table, drop: &str) -> Value {
    let mut v = t.to_json_rows();
    if let Some(rows) = v.as_array_mut() {
        for r in rows.iter_mut().filter_map(Value::as_object_mut) {
            r.remove(drop);
        }
    }
    v
}

/// Rows q1..q3 (m), x, y (m), theta (rad) of 3-PF measurements.
fn pcr_rows(set: &[([f64; 3], [f64; 3])]) -> Value {
    Value::Array(
        set.iter()
            .map(|(q, z)| {
                json!({"q1": q[0], "q2": q[1], "q3": q[2], "x": z[0], "y": z[1], "theta": z[2]})
            })
            .collect(),
    )
}

/// `pcr.identify` of `file` on joint sets (m) and microscope poses (m, rad), validated on
/// `val` if it is not empty.
pub fn identify_pcr(
    file: &crate::model::pcr::PcrFile,
    cal: &[([f64; 3], [f64; 3])],
    val: &[([f64; 3], [f64; 3])],
    options: Option<&Value>,
    monitor: &dyn Monitor,
) -> Result<Identified<crate::model::pcr::PcrFile>, JobError> {
    let mut doc = json!({
        "kind": "pcr.identify",
        "model": serde_json::to_value(file).map_err(|e| JobError::Failed(e.to_string()))?,
        "measurements": pcr_rows(cal),
    });
    if !val.is_empty() {
        doc["validation"] = pcr_rows(val);
    }
    if let Some(o) = options {
        doc["options"] = o.clone();
    }
    let out =
        crate::jobs::pcr::identify::prepare(&doc, &Inputs::new(&NoReferences))?.execute(monitor)?;
    identified(out)
}

/// `pcr.accuracy` of `model` on a trajectory and what the robot reached (grouped by pose,
/// `repetitions` per pose).
pub fn accuracy_pcr(
    model: &crate::model::pcr::PcrFile,
    trajectory: &Value,
    repetitions: usize,
    reached: &[([f64; 3], [f64; 3])],
    monitor: &dyn Monitor,
) -> Result<Map<String, Value>, JobError> {
    let doc = json!({
        "kind": "pcr.accuracy",
        "model": serde_json::to_value(model).map_err(|e| JobError::Failed(e.to_string()))?,
        "trajectory": trajectory,
        "repetitions": repetitions,
        "reached": pcr_rows(reached),
    });
    Ok(
        crate::jobs::pcr::accuracy::prepare(&doc, &Inputs::new(&NoReferences))?
            .execute(monitor)?
            .fields,
    )
}

fn markers_json(cell: &super::mocap::MocapSetup) -> Value {
    Value::Array(
        cell.markers
            .iter()
            .map(|m| json!({"name": m.name, "link": m.link, "initial": [m.initial.x, m.initial.y, m.initial.z]}))
            .collect(),
    )
}

/// `humanoid.design` (NOCP) for the cell's marker layout: the postures table.
pub fn design_nocp(
    cell: &super::mocap::MocapSetup,
    constraints: Option<&Value>,
    seed: u64,
    n: Option<usize>,
    options: Option<&Value>,
    monitor: &dyn Monitor,
) -> Result<Table, JobError> {
    let mut doc = json!({
        "kind": "humanoid.design",
        "urdf": cell.urdf,
        "root_link": cell.root_link,
        "joints": cell.joints,
        "markers": markers_json(cell),
        "base": {"mode": "identify"},
        "seed": seed,
    });
    if let Some(c) = constraints {
        doc["constraints"] = c.clone();
    }
    if let Some(k) = n {
        doc["n"] = json!(k);
    }
    if let Some(o) = options {
        doc["options"] = o.clone();
    }
    crate::jobs::humanoid::design::prepare(&doc, &Inputs::new(&NoReferences))?
        .execute(monitor)?
        .main_table
        .ok_or_else(|| JobError::Failed("the NOCP design returned no postures".into()))
}

/// `humanoid.identify` of the cell's model on a samples table (joints, then markers); the
/// evidence is the marker RMSE (mm) of the starting and the calibrated model.
pub fn identify_humanoid(
    cell: &super::mocap::MocapSetup,
    samples: &Table,
    options: Option<&Value>,
    monitor: &dyn Monitor,
) -> Result<Identified<String>, JobError> {
    let mut doc = json!({
        "kind": "humanoid.identify",
        "urdf": cell.urdf,
        "samples": rows_without(samples, "posture"),
        "root_link": cell.root_link,
        "joints": cell.joints,
        "markers": markers_json(cell),
        "base": {"mode": "identify"},
    });
    if let Some(o) = options {
        doc["options"] = o.clone();
    }
    let out = crate::jobs::humanoid::identify::prepare(&doc, &Inputs::new(&NoReferences))?
        .execute(monitor)?;
    #[derive(Deserialize)]
    struct View {
        calibrated_model: String,
        rmse_before_mm: f64,
        rmse_after_mm: f64,
    }
    let v: View = serde_json::from_value(Value::Object(out.fields.clone()))
        .map_err(|e| JobError::Failed(format!("the identification's result: {e}")))?;
    let mean = |m: f64| crate::campaigns::engine::Mean {
        mean: m,
        rest: Map::new(),
    };
    Ok(Identified {
        fields: out.fields,
        model: v.calibrated_model,
        validation: Some(ValidationMeans {
            before: mean(v.rmse_before_mm),
            after: mean(v.rmse_after_mm),
        }),
        artefacts: out.artefacts,
    })
}
