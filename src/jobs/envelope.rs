//! The result envelope every result carries: kind, times, version and input hashes.

use std::collections::BTreeMap;

use chrono::{DateTime, SecondsFormat, Utc};
use serde_json::{Map, Value, json};

/// The calibd version that produces results.
pub use crate::run::VERSION;

/// Envelope fields first, then the kind's fields.
pub fn wrap(
    kind: &str,
    started: DateTime<Utc>,
    finished: DateTime<Utc>,
    hashes: &BTreeMap<String, String>,
    fields: Map<String, Value>,
) -> Value {
    let mut m = Map::new();
    m.insert("kind".into(), json!(kind));
    m.insert(
        "started_at".into(),
        json!(started.to_rfc3339_opts(SecondsFormat::Millis, true)),
    );
    m.insert(
        "finished_at".into(),
        json!(finished.to_rfc3339_opts(SecondsFormat::Millis, true)),
    );
    m.insert(
        "duration_s".into(),
        json!((finished - started).num_microseconds().unwrap_or(0) as f64 * 1e-6),
    );
    m.insert("calibd_version".into(), json!(VERSION));
    m.insert("inputs_sha256".into(), json!(hashes));
    m.extend(fields);
    Value::Object(m)
}
