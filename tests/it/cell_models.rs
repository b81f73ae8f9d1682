//! Every cell kind has a current model and an acceptance rule: a 3-PF and a motion-capture
//! campaign run by the daemon's service against the simulated lab each become their cell's
//! current model when their validation improves on the nominal model, the decision stored
//! with the job's result; `cells()` (behind `GET /v1/cells`) lists all three cells with
//! their history, and the cell runs on the stored model from then on.

use std::sync::Arc;
use std::time::Duration;

use calibd::lab::Lab;
use calibd::service::{Origin, Service, ServiceConfig, Submitter};
use calibd::sim::SimOptions;
use calibd::store::{JobState, Store};
use serde_json::{Value, json};
use tokio_util::sync::CancellationToken;

fn operator() -> Submitter {
    Submitter {
        name: Some("test".into()),
        may_drive_devices: true,
    }
}

async fn until_final(svc: &Service, id: i64) -> calibd::store::JobRecord {
    loop {
        let j = svc.job(id).await.unwrap();
        if j.state.is_final() || j.state == JobState::Paused {
            return j;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn cell<'a>(cells: &'a [Value], name: &str) -> &'a Value {
    cells
        .iter()
        .find(|c| c["name"] == name)
        .unwrap_or_else(|| panic!("no cell {name} in {cells:?}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pcr_and_mocap_campaigns_become_their_cells_current_models() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path()).unwrap();
    let lab = Arc::new(Lab::simulated(&SimOptions::default()).await.unwrap());
    let stop = CancellationToken::new();
    let cfg = ServiceConfig {
        workers: 1,
        ..Default::default()
    };
    let (svc, _w) = Service::start_with_lab(store.clone(), cfg, Some(lab.clone()), stop.clone())
        .await
        .unwrap();
    let before = svc.cells().await.unwrap();
    let kinds: Vec<&str> = before.iter().filter_map(|c| c["kind"].as_str()).collect();
    assert_eq!(kinds, ["ball_centring", "pcr", "mocap"]);
    assert!(before.iter().all(|c| c["current_model_is_nominal"] == true));

    let pcr = json!({
        "kind": "cell.pcr_campaign", "cell": "pcr3pf", "poses": 48, "seed": 1,
        "validation_fraction": 0.25,
    });
    let mocap = json!({
        "kind": "cell.mocap_campaign",
        "cell": "talos",
        "postures": {"nocp": {
            "constraints": {"collision": false},
            "seed": 3,
            "options": {"base_pool": 200, "max_postures": 40}
        }},
        "options": {"settle_s": 0.05, "record_s": 0.5}
    });
    let p = svc
        .submit(pcr, 0, operator(), Origin::default())
        .await
        .unwrap();
    let m = svc
        .submit(mocap, 0, operator(), Origin::default())
        .await
        .unwrap();
    for id in [p, m] {
        let j = until_final(&svc, id).await;
        assert_eq!(j.state, JobState::Succeeded, "job {id}: {:?}", j.error);
    }
    let cells = svc.cells().await.unwrap();
    for (name, job) in [("pcr3pf", p), ("talos", m)] {
        let c = cell(&cells, name);
        let models = c["models"].as_array().unwrap();
        assert_eq!(models.len(), 1, "{c}");
        assert_eq!(models[0]["state"], "current", "{}", models[0]["reason"]);
        assert_eq!(models[0]["job_id"], job);
        assert_eq!(c["current_model"], models[0]["id"]);
        assert_eq!(c["current_model_is_nominal"], false);
        // The rule's own figures: a gain of more than 10 % and the absolute threshold.
        let v = &models[0]["validation"];
        let (b, a) = (
            v["before"]["mean"].as_f64().unwrap(),
            v["after"]["mean"].as_f64().unwrap(),
        );
        let rule = &c["acceptance"];
        assert!(
            b - a
                > (rule["min_relative_gain"].as_f64().unwrap() * b)
                    .max(rule["min_gain"].as_f64().unwrap()),
            "{name}: {b} -> {a} does not pass {rule}"
        );
        // The decision was written with the result: it is in the job's result too.
        let r = store.result(job).unwrap().unwrap();
        assert_eq!(r["cell"], name);
    }
    // The ball-centring cell ran nothing: still nominal.
    assert_eq!(cell(&cells, "irb120")["current_model_is_nominal"], true);
    // The cells now run on the stored models.
    let pcr_model: calibd::model::pcr::PcrFile =
        serde_json::from_value(cell(&cells, "pcr3pf")["models"][0]["model"].clone()).unwrap();
    assert_eq!(lab.pcr("pcr3pf").unwrap().current_model(), pcr_model);
    let urdf = cell(&cells, "talos")["models"][0]["model"]
        .as_str()
        .unwrap()
        .to_string();
    assert_eq!(lab.mocap("talos").unwrap().current_model(), urdf);
    assert_ne!(urdf, calibd::twin::humanoid::TALOS_URDF);
    stop.cancel();
    lab.stop().await;
}
