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
