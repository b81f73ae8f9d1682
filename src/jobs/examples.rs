//! Example jobs over the IRB 120 digital twin with inline data: what the web page offers,
//! `calibd example NAME` prints and the daemon's tests submit. Built from fixed seeds, so
//! each example is the same document every time.

use serde_json::{Map, Value, json};

use crate::measure::{PointMeasurement, Target};
use crate::twin::SerialTwin;

/// Names and one-line descriptions of the examples.
pub const EXAMPLES: &[(&str, &str)] = &[
    (
        "irb120-identify",
        "serial.identify: IRB 120 twin, 3 x 40 ball-centring measurements, 60 tracker validation points",
    ),
    (
        "irb120-fk",
        "serial.fk: IRB 120 nominal model, 20 random configurations",
    ),
    (
        "irb120-dispersion",
        "serial.dispersion: IRB 120 twin, sizes 20/40/60, 10 repetitions each",
    ),
    (
        "irb120-design",
        "serial.design: DETMAX picks 45 of 120 IRB 120 twin ball centrings by observability (O1..O5 of the selection against the pool)",
    ),
    (
        "pcr-identify",
        "pcr.identify: 3-PF twin, 99 calibration and 56 validation poses under the microscope, staged identification (Table 3)",
    ),
    (
        "humanoid-design",
        "humanoid.design: TALOS left arm, up to 20 postures chosen by NOCP for two marker clusters",
    ),
    (
        "trical-campaign",
        "cell.trical_campaign: the IRB 120 cell measures 3 x 15 centrings (designed) and 15 validation centrings, identifies, decides the cell's model",
    ),
    (
        "pcr-campaign",
        "cell.pcr_campaign: the 3-PF cell measures 64 poses under the microscope (25 % held out), identifies, checks accuracy on a 2 mm square",
    ),
    (
        "mocap-campaign",
        "cell.mocap_campaign: the TALOS cell records up to 40 designed postures with motion capture, identifies geometry and elasticity",
    ),
];

/// The campaign examples: the files of `examples/`, embedded.
const CAMPAIGNS: &[(&str, &str)] = &[
    (
        "trical-campaign",
        include_str!("../../examples/trical_campaign.json"),
    ),
    (
        "pcr-campaign",
        include_str!("../../examples/pcr_campaign.json"),
    ),
    (
        "mocap-campaign",
        include_str!("../../examples/mocap_campaign.json"),
    ),
];

/// The example job `name`.
pub fn example(name: &str) -> Option<Value> {
    match name {
        "irb120-identify" => Some(twin_identify(40, 60)),
        "irb120-fk" => Some(twin_fk(20)),
        "irb120-dispersion" => Some(twin_dispersion(&[20, 40, 60], 10)),
        "irb120-design" => Some(twin_design(40, 45)),
        "pcr-identify" => twin_pcr_identify(1),
        "humanoid-design" => Some(talos_design()),
        other => CAMPAIGNS
            .iter()
            .find(|(n, _)| *n == other)
            .and_then(|(_, text)| serde_json::from_str(text).ok()),
    }
}

/// Measurement rows (joints in degrees, then `ball` or `x, y, z`) as a JSON table.
pub fn measurement_rows(ms: &[PointMeasurement]) -> Vec<Value> {
    ms.iter()
        .map(|m| {
            let mut o = Map::new();
            for (k, v) in m.q.iter().enumerate() {
                o.insert(format!("q{}", k + 1), json!(v.to_degrees()));
            }
            match m.target {
                Target::Ball(b) => {
                    o.insert("ball".into(), json!(b + 1));
                }
                Target::Point(p) => {
                    for (n, v) in ["x", "y", "z"].iter().zip(p.iter()) {
                        o.insert(n.to_string(), json!(v));
                    }
                }
            }
            Value::Object(o)
        })
        .collect()
}

/// A `serial.identify` job over the twin: `per_ball` centrings per ball, `validation` points.
pub fn twin_identify(per_ball: usize, validation: usize) -> Value {
    let twin = SerialTwin::irb120(1);
    json!({
        "kind": "serial.identify",
        "model": serde_json::to_value(&twin.file).unwrap_or_default(),
        "measurements": measurement_rows(&twin.centring(per_ball, 2)),
        "ball_plate": {"d12": twin.ballbar[0], "d13": twin.ballbar[1], "d23": twin.ballbar[2]},
        "validation": measurement_rows(&twin.tracker(validation, 3)),
    })
}

/// A `serial.fk` job over the twin's nominal model and `n` random configurations.
pub fn twin_fk(n: usize) -> Value {
    let twin = SerialTwin::irb120(1);
    let mut rng = crate::util::Rng::new(5);
    let rows: Vec<Value> = (0..n)
        .map(|_| {
            let q = twin.random_q(&mut rng);
            let o: Map<String, Value> = q
                .iter()
                .enumerate()
                .map(|(k, v)| (format!("q{}", k + 1), json!(v.to_degrees())))
                .collect();
            Value::Object(o)
        })
        .collect();
    json!({
        "kind": "serial.fk",
        "model": serde_json::to_value(&twin.file).unwrap_or_default(),
        "joints": rows,
    })
}

/// A `serial.dispersion` job over the twin.
pub fn twin_dispersion(sizes: &[usize], repetitions: usize) -> Value {
    let twin = SerialTwin::irb120(1);
    json!({
        "kind": "serial.dispersion",
        "model": serde_json::to_value(&twin.file).unwrap_or_default(),
        "measurements": measurement_rows(&twin.centring(120, 2)),
        "ball_plate": {"d12": twin.ballbar[0], "d13": twin.ballbar[1], "d23": twin.ballbar[2]},
        "validation": measurement_rows(&twin.tracker(100, 3)),
        "sizes": sizes,
        "repetitions": repetitions,
        "options": {"seed": 7}
    })
}

/// A `serial.design` job: DETMAX chooses `n` of the twin's `3 * per_ball` centrings.
pub fn twin_design(per_ball: usize, n: usize) -> Value {
    let twin = SerialTwin::irb120(1);
    json!({
        "kind": "serial.design",
        "model": serde_json::to_value(&twin.file).unwrap_or_default(),
        "pool": measurement_rows(&twin.centring(per_ball, 2)),
        "ball_plate": {"d12": twin.ballbar[0], "d13": twin.ballbar[1], "d23": twin.ballbar[2]},
        "n": n,
        "options": {"seed": 1}
    })
}

/// A `pcr.identify` job over the 3-PF twin's data set (`calibd twin pcr`), inline, with
/// the staged identification of `examples/pcr_identify.json`; none if the twin fails.
pub fn twin_pcr_identify(seed: u64) -> Option<Value> {
    let files = crate::jobs::pcr::twin_files(seed).ok()?;
    let file = |name: &str| {
        files
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, text)| text.as_str())
    };
    let rows = |name: &str| {
        crate::run::Table::from_csv(name, file(name)?)
            .ok()
            .map(|t| t.to_json_rows())
    };
    Some(json!({
        "kind": "pcr.identify",
        "model": serde_json::from_str::<Value>(file("pcr3pf.json")?).ok()?,
        "measurements": rows("calibration.csv")?,
        "validation": rows("validation.csv")?,
        "options": {"steps": [
            ["extrinsics"],
            ["extrinsics", "l", "gamma", "alpha", "Ax", "Ay", "Bx", "By"],
            ["all"]
        ]}
    }))
}

/// A `humanoid.design` job: NOCP postures of TALOS's left arm for two marker clusters.
pub fn talos_design() -> Value {
    json!({
        "kind": "humanoid.design",
        "urdf": crate::twin::humanoid::TALOS_URDF,
        "root_link": "torso_2_link",
        "joints": (1..=7).map(|k| format!("arm_left_{k}_joint")).collect::<Vec<_>>(),
        "clusters": [
            {"link": "arm_left_4_link", "centre": [0.05, 0.0, -0.12]},
            {"link": "arm_left_7_link", "centre": [0.04, 0.0, -0.10]}
        ],
        "seed": 3,
        "options": {"base_pool": 150, "max_postures": 20}
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_example_is_a_valid_job() {
        for (name, _) in EXAMPLES {
            let doc = example(name).unwrap();
            let job = crate::jobs::prepare(&doc, &crate::run::NoReferences)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(Some(job.kind.as_str()), doc["kind"].as_str());
            // Only the campaigns drive devices.
            assert_eq!(
                job.devices().is_empty(),
                !name.ends_with("-campaign"),
                "{name}"
            );
        }
    }
}
