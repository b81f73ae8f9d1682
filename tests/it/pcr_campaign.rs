//! `cell.pcr_campaign` against the simulated lab: the 3-PF twin behind the MCS2 and
//! microscope mocks, driven over their protocols. The identified model predicts held-out
//! readings at the twin's microscope noise (9.13 nm per coordinate, from the model file),
//! and a campaign whose journal fails part-way resumes to the same measurement set as an
//! uninterrupted run, never measuring a joint set twice.

use std::sync::Arc;

use calibd::jobs::{NoReferences, prepare};
use calibd::lab::Lab;
use calibd::procedures::{EntryStatus, Journal, JournalEntry, MemoryJournal};
use calibd::sim::SimOptions;
use calibd::util::NoMonitor;
use serde_json::{Value, json};

const NOISE_M: f64 = 9.13e-9;

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}

fn run(
    rt: &tokio::runtime::Runtime,
    lab: &Arc<Lab>,
    doc: &Value,
    journal: &Arc<MemoryJournal>,
) -> Result<Value, calibd::jobs::JobError> {
    let job = prepare(doc, &NoReferences).expect("valid job");
    assert_eq!(job.devices(), vec!["pcr3pf.stages", "pcr3pf.microscope"]);
    let journal: Arc<dyn Journal> = journal.clone();
    calibd::offline::run_on(rt.handle(), &job, lab.clone(), journal, &NoMonitor).map(|c| c.result)
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn campaign_identifies_the_twin_to_its_noise_level_and_measures_accuracy() {
    let rt = runtime();
    let lab = rt
        .block_on(Lab::simulated(&SimOptions::default()))
        .map(Arc::new)
        .expect("lab");
    let doc = json!({
        "kind": "cell.pcr_campaign", "poses": 48, "seed": 1, "validation_fraction": 0.25,
        "accuracy": {"trajectory": {"square": 0.002, "points_per_side": 3}, "repetitions": 3},
        "options": {"tolerance_um": 0.05},
    });
    let journal = Arc::new(MemoryJournal::default());
    let t0 = std::time::Instant::now();
    let r = run(&rt, &lab, &doc, &journal).expect("campaign");
    eprintln!("campaign wall time {:.2} s", t0.elapsed().as_secs_f64());
    eprintln!("campaign {}", r["campaign"]);
    eprintln!("validation {}", r["validation"]);
    eprintln!("residual_std {}", r["residual_std"]);
    eprintln!("accuracy {}", r["accuracy"]["summary"]);
    let c = &r["campaign"];
    assert_eq!(c["calibration"], 36);
    assert_eq!(c["validation"], 12);
    // 8 poses of the square, 3 cycles.
    assert_eq!(c["accuracy_measurements"], 24);
    assert_eq!(c["journal_entries"], 48 + 24);
    // Held-out readings: the nominal model is micrometres off; the identified one predicts
    // them at the noise (|e| of 2-D noise of 9.13 nm per coordinate has mean 11.4 nm).
    let v = &r["validation"];
    assert_eq!(v["after"]["unit"], "m");
    assert!(num(&v["before"]["mean"]) > 1e-6, "{v}");
    let after = num(&v["after"]["mean"]);
    assert!(after > 5e-9 && after < 30e-9, "validation mean {after:e} m");
    // The residual standard deviation estimates the twin's noise.
    let sigma = num(&r["residual_std"]["value"]);
    assert!(
        (sigma / NOISE_M - 1.0).abs() < 0.35,
        "residual std {sigma:e} m against {NOISE_M:e} m"
    );
    // Who measured, and the declared tolerance against the held-out maximum (um).
    let names = crate::common::instrument_names(&r);
    assert_eq!(
        names,
        ["pcr3pf.stages", "pcr3pf.microscope"],
        "{}",
        r["instruments"]
    );
    let t = &r["tolerance"];
    let max_um = num(&v["after"]["max"]) * 1e6;
    assert!(
        (num(&t["held_out_max"]) - max_um).abs() <= 1e-12 * max_um,
        "{t}"
    );
    assert_eq!(t["unit"], "um");
    let expected = if max_um <= 0.05 { "pass" } else { "fail" };
    assert_eq!(t["outcome"], expected, "{t}");
    // ISO 9283 on the robot with the identified model: AP_P at the tens-of-nm level.
    let ap = num(&r["accuracy"]["summary"]["ap_p_um"]["mean"]);
    assert!(ap < 0.05, "AP_P mean {ap} um");
    rt.block_on(lab.stop());
}

fn measured(j: &Arc<MemoryJournal>) -> Vec<JournalEntry> {
    j.entries().expect("entries")
}

#[test]
fn a_failed_journal_resumes_to_the_same_measurement_set() {
    let doc =
        json!({"kind": "cell.pcr_campaign", "poses": 20, "seed": 4, "validation_fraction": 0.2});
    let rt = runtime();
    // Uninterrupted.
    let lab = rt
        .block_on(Lab::simulated(&SimOptions::default()))
        .map(Arc::new)
        .expect("lab");
    let whole = Arc::new(MemoryJournal::default());
    let r_whole = run(&rt, &lab, &doc, &whole).expect("uninterrupted");
    rt.block_on(lab.stop());
    // Interrupted after 7 measurements, then resumed (a fresh lab: a restart).
    let lab = rt
        .block_on(Lab::simulated(&SimOptions::default()))
        .map(Arc::new)
        .expect("lab");
    let broken = Arc::new(MemoryJournal::failing_after(7));
    let e = run(&rt, &lab, &doc, &broken).expect_err("the journal fails");
    assert!(e.to_string().contains("journal"), "{e}");
    let first = measured(&broken);
    assert_eq!(first.len(), 7);
    let resumed = Arc::new(MemoryJournal::with(first.clone()));
    let r_resumed = run(&rt, &lab, &doc, &resumed).expect("resumed");
    rt.block_on(lab.stop());
    let (a, b) = (measured(&whole), measured(&resumed));
    assert_eq!(a.len(), 20);
    assert_eq!(b.len(), 20);
    // What was journalled before the failure is kept as it was, never measured again.
    assert_eq!(&b[..7], &first[..]);
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.index, y.index);
        assert_eq!(x.status, EntryStatus::Measured);
        assert_eq!(y.status, EntryStatus::Measured);
        // Same commanded joint set; the settled joints and readings differ only by the
        // stage residual (2 nm) and the microscope noise.
        assert_eq!(x.data["q_cmd"], y.data["q_cmd"]);
        for k in 0..3 {
            let dq = num(&x.data["q"][k]) - num(&y.data["q"][k]);
            assert!(dq.abs() <= 4.1e-9, "index {} q{k}: {dq:e}", x.index);
        }
        for k in 0..2 {
            let dz = num(&x.data["z"][k]) - num(&y.data["z"][k]);
            assert!(dz.abs() < 12.0 * NOISE_M, "index {} z{k}: {dz:e}", x.index);
        }
    }
    assert_eq!(r_whole["campaign"]["recorded"], 20);
    assert_eq!(r_resumed["campaign"]["recorded"], 20);
    assert_eq!(r_resumed["campaign"]["journal_entries"], 20);
}

#[test]
fn microscope_faults_are_retried_and_a_dead_microscope_pauses_the_campaign() {
    use calibd_drivers::mock::{FaultKind, FaultSpec};
    let rt = runtime();
    let mut opts = SimOptions::default();
    opts.pcr.microscope_faults = vec![
        FaultSpec {
            kind: FaultKind::Garbage,
            at: 5,
        },
        FaultSpec {
            kind: FaultKind::DeviceError,
            at: 9,
        },
        FaultSpec {
            kind: FaultKind::Drop,
            at: 12,
        },
    ];
    let lab = rt
        .block_on(Lab::simulated(&opts))
        .map(Arc::new)
        .expect("lab");
    let doc = json!({"kind": "cell.pcr_campaign", "poses": 16, "seed": 2, "validation_fraction": 0.0,
                     "options": {"retry": {"attempts": 3, "backoff_ms": 5}}});
    let j = Arc::new(MemoryJournal::default());
    let r = run(&rt, &lab, &doc, &j).expect("campaign survives three faults");
    assert_eq!(r["campaign"]["recorded"], 16);
    // Each joint set is journalled once despite the retries.
    assert_eq!(j.entries().expect("entries").len(), 16);
    rt.block_on(lab.stop());
    // Every reply from reply 5 on is a device error: replies 1 and 2 answer the campaign's
    // instrument check at its start (the identity and one pose), 3 and 4 measure indices 0
    // and 1; the campaign pauses at the first unmeasured index.
    let mut opts = SimOptions::default();
    opts.pcr.microscope_faults = (5..40)
        .map(|at| FaultSpec {
            kind: FaultKind::DeviceError,
            at,
        })
        .collect();
    let lab = rt
        .block_on(Lab::simulated(&opts))
        .map(Arc::new)
        .expect("lab");
    let j = Arc::new(MemoryJournal::default());
    let e = run(&rt, &lab, &doc, &j).expect_err("paused");
    match e {
        calibd::jobs::JobError::Paused { index, reason } => {
            assert_eq!(index, 2);
            assert!(reason.contains("microscope"), "{reason}");
        }
        other => panic!("expected a pause, got {other}"),
    }
    assert_eq!(j.entries().expect("entries").len(), 2);
    rt.block_on(lab.stop());
}
