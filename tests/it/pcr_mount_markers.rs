//! `pcr.mount_markers` on a rendered wide-field image of the shipped 3-PF robot whose six
//! clamps sit a few micrometres off nominal: the job finds the six markers and writes their
//! measured positions into the model, which loads, solves and carries the stated
//! uncertainty; a picture without markers fails naming what is missing.

use calibd::jobs::DirResolver;
use calibd::jobs::prepare;
use calibd::measure::fiducial::{DetectSpec, FieldSpec, MarkerPose, detect, render_field};
use calibd::measure::pattern::codec::encode_png;
use calibd::model::pcr::PcrFile;
use calibd::util::NoMonitor;
use serde_json::json;
use std::f64::consts::PI;

/// An angle wrapped into [-pi, pi).
fn angle(a: f64) -> f64 {
    (a + PI).rem_euclid(2.0 * PI) - PI
}

#[test]
fn every_quarter_turn_and_id_decodes_at_its_pose() {
    let markers: Vec<MarkerPose> = (0..10u8)
        .map(|k| MarkerPose {
            id: k,
            x_um: -2000.0 + 1200.0 * k as f64,
            y_um: 1500.0 - 333.3 * k as f64,
            theta_rad: -PI + 0.7 * k as f64,
        })
        .collect();
    let spec = FieldSpec {
        markers: markers.clone(),
        cell_um: 100.0,
        pixel_um: 10.0,
        origin_um: [-3000.0, -2500.0],
        width: 1300,
        height: 500,
        noise_frac: 0.01,
        seed: 4,
    };
    let det = DetectSpec {
        cell_um: 100.0,
        pixel_um: 10.0,
        origin_um: spec.origin_um,
    };
    let found = detect(&render_field(&spec).expect("render"), &det).expect("markers");
    assert_eq!(found.len(), markers.len(), "{found:?}");
    for (f, t) in found.iter().zip(&markers) {
        assert_eq!(f.id, t.id);
        assert!(
            (f.x_um - t.x_um).hypot(f.y_um - t.y_um) < 0.25,
            "{f:?} vs {t:?}"
        );
        assert!(
            angle(f.theta_rad - t.theta_rad).abs() < 0.5e-3,
            "{f:?} vs {t:?}"
        );
    }
    // The ring's corners and the code: an id that does not exist is refused.
    assert!(calibd::measure::fiducial::cells(10).is_err());
}

#[test]
fn the_measured_mounts_become_the_models_nominal_clamp_positions() {
    let dir = tempfile::tempdir().expect("dir");
    let model = PcrFile::parse(calibd::twin::pcr::PCR3PF_JSON).expect("model");
    // The real clamps: nominal plus a few um; the platform at the origin (q = 0).
    let offsets = [
        (3.1, -2.2),
        (-1.7, 4.0),
        (2.5, 2.5),
        (-3.3, 0.8),
        (0.9, -4.1),
        (1.2, 1.9),
    ];
    let mut truth = Vec::new();
    for (i, l) in model.limbs.iter().enumerate() {
        let (dx, dy) = offsets[i];
        truth.push(MarkerPose {
            id: i as u8,
            x_um: l.Ax * 1e6 + dx,
            y_um: l.Ay * 1e6 + dy,
            theta_rad: l.gamma,
        });
    }
    for (i, l) in model.limbs.iter().enumerate() {
        let (dx, dy) = offsets[3 + i];
        truth.push(MarkerPose {
            id: 3 + i as u8,
            x_um: l.Bx * 1e6 + dx,
            y_um: l.By * 1e6 + dy,
            theta_rad: l.beta,
        });
    }
    let origin = [-25_000.0, -32_500.0];
    let img = render_field(&FieldSpec {
        markers: truth.clone(),
        cell_um: 100.0,
        pixel_um: 10.0,
        origin_um: origin,
        width: 5700,
        height: 5500,
        noise_frac: 0.01,
        seed: 12,
    })
    .expect("render");
    std::fs::write(dir.path().join("wide.png"), encode_png(&img).expect("png")).expect("write");
    std::fs::write(
        dir.path().join("pcr3pf.json"),
        calibd::twin::pcr::PCR3PF_JSON,
    )
    .expect("write");
    let doc = json!({
        "kind": "pcr.mount_markers", "image": "wide.png", "model": "pcr3pf.json",
        "camera": {"pixel_um": 10.0, "origin_um": origin}, "cell_um": 100.0,
    });
    let r = DirResolver {
        dir: dir.path().into(),
    };
    let done = prepare(&doc, &r)
        .expect("valid job")
        .run(&NoMonitor)
        .expect("markers found");
    let t = done.main_table.expect("table");
    assert_eq!(t.columns, ["id", "x_um", "y_um", "theta_rad"]);
    assert_eq!(t.rows.len(), 6);
    let measured: PcrFile =
        serde_json::from_value(done.result["measured_model"].clone()).expect("a model file");
    measured.robot().expect("it solves");
    // Each marker's pose (table rows by id) against the truth.
    let mut worst_rad = 0.0f64;
    for (row, m) in t.rows.iter().zip(&truth) {
        assert_eq!(row[0], f64::from(m.id));
        let e = (row[1] - m.x_um).hypot(row[2] - m.y_um);
        let a = angle(row[3] - m.theta_rad);
        eprintln!(
            "mount {}: position error {e:.3} um, angle error {:.3} mrad",
            m.id,
            a * 1e3
        );
        worst_rad = worst_rad.max(a.abs());
    }
    assert!(worst_rad < 0.5e-3, "worst angle error {worst_rad} rad");
    let mut worst = 0.0f64;
    for i in 0..3 {
        let l = &measured.limbs[i];
        for (got, want) in [
            (l.Ax * 1e6, truth[i].x_um),
            (l.Ay * 1e6, truth[i].y_um),
            (l.Bx * 1e6, truth[3 + i].x_um),
            (l.By * 1e6, truth[3 + i].y_um),
        ] {
            worst = worst.max((got - want).abs());
        }
        // Everything else is the file's.
        assert_eq!(l.gamma, model.limbs[i].gamma);
        assert_eq!(l.l, model.limbs[i].l);
    }
    eprintln!("pcr.mount_markers: worst clamp coordinate error {worst:.3} um");
    assert!(worst < 0.25, "worst clamp coordinate error {worst} um");
    assert_eq!(measured.uncertainty.Ay, 0.25e-6);
    assert!(
        done.artefacts
            .iter()
            .any(|a| a.name == "measured_model.json")
    );

    // A picture of the robot without its markers.
    let blank = render_field(&FieldSpec {
        markers: vec![],
        width: 600,
        height: 500,
        ..FieldSpec {
            markers: vec![],
            cell_um: 100.0,
            pixel_um: 10.0,
            origin_um: origin,
            width: 1,
            height: 1,
            noise_frac: 0.01,
            seed: 1,
        }
    })
    .expect("render");
    std::fs::write(
        dir.path().join("blank.png"),
        encode_png(&blank).expect("png"),
    )
    .expect("write");
    let doc = json!({
        "kind": "pcr.mount_markers", "image": "blank.png", "model": "pcr3pf.json",
        "camera": {"pixel_um": 10.0, "origin_um": origin}, "cell_um": 100.0,
    });
    let e = prepare(&doc, &r)
        .expect("valid job")
        .run(&NoMonitor)
        .unwrap_err();
    assert!(e.to_string().contains("no readable marker"), "{e}");
}
