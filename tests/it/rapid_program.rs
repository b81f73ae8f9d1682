//! `serial.compensate_program` through the daemon's HTTP API with the simulated lab: a RAPID
//! module that does not parse is a 422 naming its line; uploading the filtered module to the
//! cell's controller (the RWS mock, over a real socket) needs the operator role; a refusal
//! of the controller fails the job with its message; stopped first, the module is uploaded
//! and loaded into T_ROB1, and the controller lists it.

use calibd_drivers::TcpConnector;
use calibd_drivers::rws::{RwsConfig, RwsHandle};
use reqwest::Method;
use serde_json::{Value, json};

use crate::server::{self, OPERATOR, SUBMITTER};

const MODULE: &str = include_str!("../data/rapid/PickPlace.mod");

fn doc(module: &str, upload: Option<Value>) -> Value {
    let twin = calibd::twin::SerialTwin::irb120(7);
    let mut d = json!({
        "kind": "serial.compensate_program",
        "model": serde_json::to_value(twin.file.with_chain(&twin.truth)).unwrap(),
        "nominal": serde_json::to_value(&twin.file).unwrap(),
        "module": module,
    });
    if let Some(u) = upload {
        d["upload"] = u;
    }
    d
}

async fn post(s: &server::TestServer, token: &str, body: &Value) -> (u16, Value) {
    let r = s
        .req(Method::POST, "/v1/jobs", Some(token))
        .json(body)
        .send()
        .await
        .unwrap();
    let st = r.status().as_u16();
    (st, r.json().await.unwrap_or(Value::Null))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_filtered_module_is_uploaded_and_loaded_by_an_operator_only() {
    let s = server::start(|_| {}).await;
    // Not RAPID: 422 naming the line.
    let broken = MODULE.replace(
        "MoveL pPick, v100, fine, tGripper\\WObj:=wInfeed;",
        "MoveL pPick, v100, fine, tGripper\\WObj:=wInfeed",
    );
    let line = MODULE
        .lines()
        .position(|l| l.contains("MoveL pPick, v100"))
        .unwrap()
        + 1;
    let (st, e) = post(&s, OPERATOR, &doc(&broken, None)).await;
    assert_eq!(st, 422, "{e}");
    let msg = e["error"]["message"].as_str().unwrap();
    assert!(msg.contains(&format!("line {line}:")), "{msg}");
    // Without upload any submitter may filter; with it the job drives the controller.
    let upload = json!({"cell": "irb120"});
    let (st, e) = post(&s, SUBMITTER, &doc(MODULE, Some(upload.clone()))).await;
    assert_eq!(st, 403, "{e}");
    assert!(
        e["error"]["message"].as_str().unwrap().contains("operator"),
        "{e}"
    );
    // The controller runs the calibd module: it refuses to load, and says why.
    let (st, j) = post(&s, OPERATOR, &doc(MODULE, Some(upload))).await;
    assert_eq!(st, 201, "{j}");
    let j = s.wait(j["id"].as_i64().unwrap()).await;
    assert_eq!(j["state"], "failed", "{j}");
    let err = j["error"].as_str().unwrap_or_default();
    assert!(
        err.contains("upload to cell irb120") && err.contains("RAPID program is executing"),
        "{err}"
    );
    // Stopped first: uploaded, loaded, listed by the controller.
    let (st, j) = post(
        &s,
        OPERATOR,
        &doc(
            MODULE,
            Some(json!({"cell": "irb120", "stop_program": true})),
        ),
    )
    .await;
    assert_eq!(st, 201, "{j}");
    let id = j["id"].as_i64().unwrap();
    let j = s.wait(id).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let (_, r) = s.get(&format!("/v1/jobs/{id}/result")).await;
    assert_eq!(r["upload"]["path"], "$HOME/PickPlace.mod", "{r}");
    assert_eq!(r["upload"]["module"], "PickPlace");
    assert_eq!(r["summary"]["corrected"], 12);
    // The controller (the cell's RWS mock, over its socket) lists the module, stopped.
    let (st, lab) = s.get("/v1/lab").await;
    assert_eq!(st, 200);
    assert_eq!(lab["simulated"], true, "the page's banner: {lab}");
    let addr = lab["devices"]
        .as_array()
        .and_then(|d| {
            d.iter().find(|d| {
                d["cell"] == "irb120" && d["device"].as_str().is_some_and(|n| n.ends_with("rws"))
            })
        })
        .and_then(|d| d["address"].as_str())
        .unwrap_or_else(|| panic!("{lab}"))
        .to_string();
    let h = RwsHandle::connect(TcpConnector::new(addr), RwsConfig::default());
    let id = h.identity("CalibServer").await.unwrap();
    assert!(id.rapid_modules.iter().any(|m| m == "PickPlace"), "{id:?}");
    assert_eq!(id.execstate, "stopped");
}
