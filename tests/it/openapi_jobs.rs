//! `openapi.yaml` describes the job documents as the server parses them: its generated
//! region (`JobDocument`, one `job.KIND` schema per kind, `TimeZone`) is exactly what
//! `calibd::jobs::schema::openapi_schemas` generates from the kinds' specs, the example
//! jobs validate against it, documents the server refuses for their shape are refused by
//! it, and the schedules' `cron` pattern agrees with the daemon's parser.
//!
//! After changing a spec or adding a kind, rewrite the region with
//! `CALIBD_UPDATE_OPENAPI=1 cargo test --test it openapi_jobs::` and commit `openapi.yaml`.

use crate::server::schema;

use std::str::FromStr;
use std::sync::Once;

use calibd::jobs::schema::{openapi_schemas, schema_name, splice_openapi};
use calibd::jobs::{KINDS, NoReferences};
use calibd::schedule::Rule;
use calibd::store::NewSchedule;
use serde_json::{Value, json};

const PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/openapi.yaml");

/// With `CALIBD_UPDATE_OPENAPI=1`, the file's generated region rewritten (once, before any
/// test of this file reads it).
static UPDATE: Once = Once::new();

fn update_if_asked() {
    UPDATE.call_once(|| {
        if std::env::var("CALIBD_UPDATE_OPENAPI").as_deref() != Ok("1") {
            return;
        }
        let text = std::fs::read_to_string(PATH).unwrap();
        let want = splice_openapi(&text, &openapi_schemas().unwrap()).unwrap();
        if want != text {
            std::fs::write(PATH, &want).unwrap();
            eprintln!("rewrote the generated region of {PATH}");
        }
    });
}

/// The contract as JSON (after the update, if asked).
fn contract() -> Value {
    update_if_asked();
    schema::contract()
}

#[test]
fn openapi_yaml_holds_the_schemas_generated_from_the_kinds() {
    update_if_asked();
    let text = std::fs::read_to_string(PATH).unwrap();
    let schemas = openapi_schemas().unwrap();
    let want = splice_openapi(&text, &schemas).unwrap();
    if want != text {
        let line = want
            .lines()
            .zip(text.lines())
            .position(|(a, b)| a != b)
            .map_or(want.lines().count().min(text.lines().count()), |i| i + 1);
        panic!(
            "openapi.yaml's generated job documents differ from the kinds' specs (first at line \
             {line}); run `CALIBD_UPDATE_OPENAPI=1 cargo test --test it openapi_jobs::` and commit \
             openapi.yaml"
        );
    }
    // The YAML written reads back as the JSON generated.
    let doc = contract();
    let in_file = doc["components"]["schemas"].as_object().unwrap();
    for (name, s) in &schemas {
        assert_eq!(in_file.get(name), Some(s), "components.schemas.{name}");
    }
    // No schema of a kind that is no longer registered.
    for name in in_file.keys().filter(|n| n.starts_with("job.")) {
        assert!(schemas.contains_key(name), "{name} has no registered kind");
    }
    assert_eq!(
        doc["components"]["schemas"]["JobDocument"]["oneOf"]
            .as_array()
            .unwrap()
            .len(),
        KINDS.len()
    );
}

/// Errors of `v` against `components.schemas.NAME`.
fn errors(doc: &Value, name: &str, v: &Value) -> Vec<String> {
    let s = json!({"$ref": format!("#/components/schemas/{name}")});
    schema::check(doc, &s, v, "$")
}

#[test]
fn every_example_job_validates_against_the_job_document_schema() {
    let doc = contract();
    for (name, _) in calibd::jobs::examples::EXAMPLES {
        let job = calibd::jobs::examples::example(name).unwrap();
        let errs = errors(&doc, "JobDocument", &job);
        assert!(errs.is_empty(), "example {name}: {errs:#?}");
    }
}

#[test]
fn documents_the_server_refuses_for_their_shape_are_outside_the_schema() {
    let doc = contract();
    let fk = calibd::jobs::examples::example("irb120-fk").unwrap();
    assert!(errors(&doc, "JobDocument", &fk).is_empty());
    let mut refused = vec![
        // The case: no model.
        json!({"kind": "pcr.fk"}),
        json!({"kind": "no.such_kind"}),
        json!({"kind": "cell.jog", "q_deg": "0"}),
        json!({"kind": "pcr.accuracy", "model": {}, "trajectory": {"square": 0.002}, "twin": {"model": {}}}),
        json!({"kind": "serial.fk", "model": {}, "joints": "not-a-dataset"}),
        // serde reads a struct from an array of its fields; the server refuses that form.
        json!({"kind": "cell.zero_check", "options": [0.1]}),
        json!({"kind": "cell.mocap_campaign", "postures": {"nocp": {"options": [null, null]}}}),
        // A campaign designs its postures when it runs: its SRDF is inline or refused now.
        json!({"kind": "cell.mocap_campaign", "postures": {"nocp": {"constraints": {"srdf": "AAA"}}}}),
    ];
    for (k, v) in [
        ("extra", json!(1)),
        ("joints", json!(3)),
        ("model", json!(null)),
    ] {
        let mut d = fk.clone();
        d[k] = v;
        refused.push(d);
    }
    for d in refused {
        assert!(
            !errors(&doc, "JobDocument", &d).is_empty(),
            "the schema accepts {d}"
        );
        let e = calibd::jobs::prepare(&d, &NoReferences).unwrap_err();
        assert!(e.is_invalid_input(), "{d}: {e}");
    }
    let e = calibd::jobs::prepare(
        &json!({"kind": "cell.mocap_campaign", "postures": {"nocp": {"options": [null]}}}),
        &NoReferences,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("postures.nocp.options") && e.contains("not an array"),
        "{e}"
    );
    // Every kind's document refuses a property its spec does not know, as the server does.
    for k in KINDS {
        let s = &doc["components"]["schemas"][schema_name(k.name)];
        assert_eq!(s["additionalProperties"], json!(false), "{}", k.name);
        assert_eq!(s["properties"]["kind"]["const"], json!(k.name));
    }
}

/// Whether the daemon takes `cron` (the defaults: UTC, at least 60 s between occurrences).
fn server_accepts(cron: &str) -> bool {
    let s = NewSchedule {
        name: "n".into(),
        cron: cron.into(),
        timezone: "UTC".into(),
        job: json!({"kind": "serial.fk"}),
        priority: 0,
        missed: Default::default(),
        enabled: true,
    };
    Rule::parse(&s).is_ok_and(|r| {
        r.shortest_interval(chrono::Utc::now(), 1000)
            .is_none_or(|gap| gap.as_secs() >= 60)
    })
}

#[test]
fn the_cron_pattern_agrees_with_the_daemon() {
    let doc = contract();
    let cron = &doc["components"]["schemas"]["ScheduleInput"]["properties"]["cron"];
    let pattern = regex::Regex::new(cron["pattern"].as_str().unwrap()).unwrap();
    let min = cron["minLength"].as_u64().unwrap() as usize;
    let documented = |c: &str| c.chars().count() >= min && pattern.is_match(c);
    for c in [
        "0 2 * * *",
        "* * * * *",
        "*/5 9-17 * * MON-FRI",
        "0,30 * * * *",
        "15 2 1,15 * *",
        "0 0 1 jan,jul *",
        "0 0 L * ?",
        "0 0 15W * *",
        "0 12 * * 5#3",
        "0 12 * * 5L",
        "30 0 2 * * *",
        "0 */10 * * * *",
        "@daily",
        "@hourly",
        "  0 2 * * *  ",
        "59 23 31 12 7",
    ] {
        assert!(server_accepts(c), "the daemon refuses {c:?}");
        assert!(documented(c), "the pattern refuses {c:?}");
    }
    for c in [
        "",
        " ",
        "0 2 * *",
        "0 2 * * * * * *",
        "* * * * * *",
        "*/30 * * * * *",
        "0,30 * * * * *",
        "60 * * * *",
        "0 24 * * *",
        "0 0 32 * *",
        "0 0 * 13 *",
        "0 0 * * 8",
        "0 0 * * FUNDAY",
        "@every_minute",
        "x y z",
    ] {
        assert!(!server_accepts(c), "the daemon takes {c:?}");
        assert!(!documented(c), "the pattern takes {c:?}");
    }
    // The schema's time zones are the ones the daemon knows.
    let zones = doc["components"]["schemas"]["TimeZone"]["enum"]
        .as_array()
        .unwrap();
    assert!(zones.contains(&json!("Europe/Berlin")) && zones.contains(&json!("UTC")));
    for z in zones {
        assert!(chrono_tz::Tz::from_str(z.as_str().unwrap()).is_ok(), "{z}");
    }
}
