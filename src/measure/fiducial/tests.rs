use super::*;
use crate::measure::pattern::GrayImage;

/// The six mounts of the shipped 3-PF model at q = 0 (platform at the origin): A_i and B_i
/// in um, each marker turned by its rod's angle.
fn mounts() -> (PcrFile, Vec<MarkerPose>) {
    let file = PcrFile::parse(crate::twin::pcr::PCR3PF_JSON).expect("model");
    let mut m = Vec::new();
    for (i, l) in file.limbs.iter().enumerate() {
        m.push(MarkerPose {
            id: i as u8,
            x_um: l.Ax * 1e6 + 3.7,
            y_um: l.Ay * 1e6 - 2.1,
            theta_rad: l.gamma + 0.013,
        });
    }
    for (i, l) in file.limbs.iter().enumerate() {
        m.push(MarkerPose {
            id: 3 + i as u8,
            x_um: l.Bx * 1e6 - 1.3,
            y_um: l.By * 1e6 + 4.4,
            theta_rad: l.beta - 0.021,
        });
    }
    (file, m)
}

/// A wide-field view of the whole robot: 10 um pixels, 100 um cells (0.5 mm markers).
const PIXEL_UM: f64 = 10.0;
const CELL_UM: f64 = 100.0;
const ORIGIN_UM: [f64; 2] = [-25_000.0, -32_500.0];

fn field(markers: Vec<MarkerPose>, noise: f64, seed: u64) -> GrayImage {
    render_field(&FieldSpec {
        markers,
        cell_um: CELL_UM,
        pixel_um: PIXEL_UM,
        origin_um: ORIGIN_UM,
        width: 5700,
        height: 5500,
        noise_frac: noise,
        seed,
    })
    .expect("render")
}

fn spec() -> DetectSpec {
    DetectSpec {
        cell_um: CELL_UM,
        pixel_um: PIXEL_UM,
        origin_um: ORIGIN_UM,
    }
}

#[test]
fn the_six_mounts_are_found_within_a_quarter_micrometre() {
    let (mut file, truth) = mounts();
    let img = field(truth.clone(), 0.01, 3);
    let t0 = std::time::Instant::now();
    let found = detect(&img, &spec()).expect("markers");
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    assert_eq!(found.len(), MOUNTS, "{found:?}");
    let (mut worst_um, mut worst_rad) = (0.0f64, 0.0f64);
    for (f, t) in found.iter().zip(&truth) {
        assert_eq!(f.id, t.id);
        let e = (f.x_um - t.x_um).hypot(f.y_um - t.y_um);
        let a = (f.theta_rad - t.theta_rad + PI).rem_euclid(2.0 * PI) - PI;
        eprintln!(
            "mount {}: position error {e:.3} um, angle error {:.3} mrad",
            f.id,
            a * 1e3
        );
        worst_um = worst_um.max(e);
        worst_rad = worst_rad.max(a.abs());
    }
    eprintln!(
        "5700 x 5500 px at {PIXEL_UM} um/px, 1 % noise: worst {worst_um:.3} um, {:.3} mrad, detection {ms:.0} ms",
        worst_rad * 1e3
    );
    assert!(worst_um < 0.25, "worst position error {worst_um} um");
    assert!(worst_rad < 0.5e-3, "worst angle error {worst_rad} rad");
    // Into the model file: A in the world frame, B in the platform's (here at the origin).
    into_model(&mut file, &found, [0.0, 0.0, 0.0], 0.25e-6).expect("model");
    for i in 0..3 {
        assert!((file.limbs[i].Ax * 1e6 - truth[i].x_um).abs() < 0.25);
        assert!((file.limbs[i].By * 1e6 - truth[3 + i].y_um).abs() < 0.25);
    }
    assert_eq!(file.uncertainty.Bx, 0.25e-6);
    file.robot().expect("a valid model");
}

use std::f64::consts::PI;

#[test]
fn every_quarter_turn_and_id_decodes_and_a_blank_image_has_no_marker() {
    let markers: Vec<MarkerPose> = (0..8u8)
        .map(|k| MarkerPose {
            id: k % 10,
            x_um: -20_000.0 + 5000.0 * k as f64,
            y_um: -25_000.0 + 1234.5 * k as f64,
            theta_rad: -PI + 0.9 * k as f64,
        })
        .collect();
    let found = detect(&field(markers.clone(), 0.01, 4), &spec()).expect("markers");
    assert_eq!(found.len(), markers.len());
    for t in &markers {
        let f = found.iter().find(|f| f.id == t.id).expect("id found");
        assert!(
            (f.x_um - t.x_um).hypot(f.y_um - t.y_um) < 0.5,
            "{f:?} vs {t:?}"
        );
        let a = (f.theta_rad - t.theta_rad + PI).rem_euclid(2.0 * PI) - PI;
        assert!(a.abs() < 1e-3, "{f:?} vs {t:?}");
    }
    let e = detect(&field(vec![], 0.01, 5), &spec()).unwrap_err();
    assert!(e.to_string().contains("no readable marker"), "{e}");
    assert!(cells(10).is_err());
}
