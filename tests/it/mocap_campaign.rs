//! `cell.mocap_campaign` against the simulated lab: TALOS twin behind a joint interface and
//! the QTM RT mock, driven over the real protocol. The identified model must reach the
//! twin's mocap noise level; an interrupted campaign resumed from its journal measures the
//! same postures as an uninterrupted one, none twice.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use calibd::campaigns::engine::{Retry, recorded};
use calibd::campaigns::mocap::{self, PostureSample, RecordOptions};
use calibd::jobs::NoReferences;
use calibd::lab::Lab;
use calibd::procedures::{Journal, MemoryJournal};
use calibd::sim::{SimMocapOptions, SimOptions};
use calibd::twin::humanoid::left_arm_spec;
use calibd::util::NoMonitor;
use serde_json::json;

const RATE_HZ: f64 = 200.0;
const RECORD_S: f64 = 0.5;

/// The simulated lab, and the count of robot moves to fail from now on.
fn lab(rt: &tokio::runtime::Runtime) -> (Lab, Arc<AtomicUsize>) {
    let faults = Arc::new(AtomicUsize::new(0));
    let opts = SimOptions {
        seed: 11,
        mocap: SimMocapOptions {
            rate_hz: RATE_HZ,
            joint_speed_rad_s: 8.0,
            failing_moves: faults.clone(),
        },
        ..SimOptions::default()
    };
    (
        rt.block_on(Lab::simulated(&opts)).expect("simulated lab"),
        faults,
    )
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}

#[test]
fn nocp_campaign_identifies_to_the_mocap_noise_level() {
    let rt = runtime();
    let (lab, _) = lab(&rt);
    let doc = json!({
        "kind": "cell.mocap_campaign",
        "cell": "talos",
        "postures": {"nocp": {
            "constraints": {"collision": false},
            "seed": 3,
            "options": {"base_pool": 200, "max_postures": 40}
        }},
        "options": {"settle_s": 0.05, "record_s": RECORD_S, "tolerance_mm": 5.0}
    });
    let job = calibd::jobs::prepare(&doc, &NoReferences).expect("valid job");
    assert_eq!(job.devices(), vec!["talos.joints", "talos.qtm"]);
    let lab = Arc::new(lab);
    let t0 = Instant::now();
    let done = calibd::offline::run_on(
        rt.handle(),
        &job,
        lab.clone(),
        Arc::new(MemoryJournal::default()),
        &NoMonitor,
    )
    .expect("campaign");
    let wall = t0.elapsed().as_secs_f64();
    let r = &done.result;
    let c = &r["campaign"];
    let planned = c["planned"].as_u64().unwrap();
    assert!(planned >= 8, "{c}");
    assert_eq!(c["recorded"].as_u64(), Some(planned), "{c}");
    let before = r["rmse_before_mm"].as_f64().unwrap();
    let after = r["rmse_after_mm"].as_f64().unwrap();
    let p = r["base_parameter_count"].as_f64().unwrap();
    // Who measured; no held-out postures without cross-validation: the tolerance is not
    // checked, and says how to check it.
    let names = crate::common::instrument_names(r);
    assert_eq!(names, ["talos.joints", "talos.qtm"], "{}", r["instruments"]);
    let t = &r["tolerance"];
    assert!(t["held_out_max"].is_null(), "{t}");
    assert!(
        t["outcome"]
            .as_str()
            .unwrap_or("")
            .starts_with("not checked")
            && t["compared"]
                .as_str()
                .unwrap_or("")
                .contains("cross_validation"),
        "{t}"
    );
    // Independent expectation from the twin's noise: each marker coordinate of a frame has
    // sigma; a posture's position is a mean of low-pass filtered samples, whose variance
    // lies between sigma^2 / W (all W frames of the window averaged) and sigma^2 (unity-gain
    // filter); a least-squares fit of p parameters to m coordinates leaves a 3-D RMSE of
    // sqrt(3 (1 - p / m)) times that.
    let sigma_mm = left_arm_spec(false).noise * 1e3;
    let markers = left_arm_spec(false).markers.len() as f64;
    let m = 3.0 * markers * planned as f64;
    let dof = (3.0 * (1.0 - p / m)).sqrt();
    let w = RECORD_S * RATE_HZ;
    let (lo, hi) = (0.7 * dof * sigma_mm / w.sqrt(), 3f64.sqrt() * sigma_mm);
    eprintln!(
        "postures {planned}, base parameters {p}, rmse {before:.3} -> {after:.3} mm (noise bounds {lo:.3}..{hi:.3}), campaign {c}, wall {wall:.1} s"
    );
    assert!(after > lo && after < hi, "{after} mm outside [{lo}, {hi}]");
    assert!(
        before > 10.0 * after,
        "nominal {before} mm vs calibrated {after} mm"
    );
    rt.block_on(lab.stop());
}

fn plan(lab: &Lab) -> Vec<Vec<(String, f64)>> {
    let cell = lab.mocap("talos").expect("mocap cell");
    (0..5)
        .map(|k| {
            cell.joints
                .iter()
                .zip(&cell.limits)
                .enumerate()
                .map(|(j, (n, [lo, hi]))| {
                    let u = ((k * 7 + j * 3) % 10) as f64 / 10.0;
                    (n.clone(), lo + (0.2 + 0.6 * u) * (hi - lo))
                })
                .collect()
        })
        .collect()
}

fn record(lab: &Lab, rt: &tokio::runtime::Runtime, j: &dyn Journal) -> Result<usize, String> {
    let cell = lab.mocap("talos").expect("mocap cell");
    let opts = RecordOptions {
        settle: Duration::from_millis(50),
        window: Duration::from_secs_f64(RECORD_S),
        preprocess: Default::default(),
    };
    let retry = Retry {
        attempts: 2,
        backoff: Duration::from_millis(10),
    };
    rt.block_on(mocap::run(
        &*cell.robot,
        &*cell.stream,
        &plan(lab),
        j,
        &opts,
        &retry,
        &NoMonitor,
    ))
    .map(|s| s.recorded)
    .map_err(|e| e.to_string())
}

#[test]
fn interrupted_campaign_resumes_to_the_same_measurement_set() {
    let rt = runtime();
    let (lab, faults) = lab(&rt);
    let full = MemoryJournal::default();
    assert_eq!(record(&lab, &rt, &full), Ok(5));
    let crashed = MemoryJournal::failing_after(2);
    let e = record(&lab, &rt, &crashed).unwrap_err();
    assert!(e.contains("journal"), "{e}");
    let kept = crashed.entries().unwrap();
    assert_eq!(kept.len(), 2);
    let resumed = MemoryJournal::with(kept.clone());
    assert_eq!(record(&lab, &rt, &resumed), Ok(5));
    let a: Vec<PostureSample> = recorded(&full, 0, 5).unwrap();
    let b: Vec<PostureSample> = recorded(&resumed, 0, 5).unwrap();
    // The first two survive unchanged; nothing measured twice; same postures.
    assert_eq!(
        &b[..2],
        &recorded::<PostureSample>(&MemoryJournal::with(kept), 0, 5).unwrap()[..]
    );
    assert_eq!(
        a.iter().map(|s| s.index).collect::<Vec<_>>(),
        vec![0, 1, 2, 3, 4]
    );
    assert_eq!(
        b.iter().map(|s| s.index).collect::<Vec<_>>(),
        vec![0, 1, 2, 3, 4]
    );
    for (x, y) in a.iter().zip(&b) {
        for (qa, qb) in x.q.iter().zip(&y.q) {
            assert!((qa - qb).abs() < 1e-9, "posture {}: {qa} vs {qb}", x.index);
        }
        // The same marker positions up to the mocap noise of two independent recordings
        // (each a mean of many frames of 0.5 mm noise: far below 1 mm apart).
        assert_eq!(x.markers.len(), 9);
        for (name, pa) in &x.markers {
            let (pa, pb) = (pa.unwrap(), y.markers[name].unwrap());
            let d = ((pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2) + (pa[2] - pb[2]).powi(2))
                .sqrt();
            assert!(d < 1e-3, "posture {} marker {name}: {d} m apart", x.index);
        }
    }
    // A device fault that persists pauses the campaign at the posture, with the reason.
    // Two attempts per posture: two faults in a row pause at the first posture, one is
    // retried; resuming the paused journal measures everything once.
    let j = MemoryJournal::default();
    faults.store(2, Ordering::SeqCst);
    let e = record(&lab, &rt, &j).unwrap_err();
    assert!(
        e.contains("paused at configuration 0") && e.contains("injected"),
        "{e}"
    );
    assert!(j.entries().unwrap().is_empty());
    faults.store(1, Ordering::SeqCst);
    assert_eq!(record(&lab, &rt, &j), Ok(5));
    rt.block_on(lab.stop());
}
