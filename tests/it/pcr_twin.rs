//! The 3-PF twin: after the three-step identification on 99 Poisson-disc poses the model
//! error on 56 validation poses is at the microscope's noise level, against micrometres for
//! the nominal model; the gauge freedoms are found and named; gauge-free parameters come
//! back to their true values.

use calibd::design::poisson_disc_n;
use calibd::measure::pcr::{CalibrationOptions, identify_steps};
use calibd::twin::PcrTwin;
use calibd::util::NoMonitor;

#[test]
fn three_step_identification_reaches_the_noise_level() {
    let twin = PcrTwin::nominal(3).expect("twin");
    let lim = twin.file.limits();
    let (lo, hi) = (
        [lim[0][0], lim[1][0], lim[2][0]],
        [lim[0][1], lim[1][1], lim[2][1]],
    );
    let (cal_q, _) = poisson_disc_n(lo, hi, 99, 1).expect("calibration joints");
    let (val_q, _) = poisson_disc_n(lo, hi, 56, 2).expect("validation joints");
    let cal = twin.measure(&cal_q, 10).expect("calibration readings");
    let val = twin.measure(&val_q, 11).expect("validation readings");
    let base = twin.file.robot().expect("nominal robot");
    let res = identify_steps(
        &base,
        &twin.file,
        &cal,
        Some(&val),
        &CalibrationOptions::default(),
        &NoMonitor,
    )
    .expect("identification");
    let v = res.table3.validation.as_ref().expect("validation set");
    // Noise: 9.13 nm per coordinate, so |error| has mean 11.4 nm (Rayleigh); 1.2 urad.
    assert!(
        v.e_p.identified.mean < 0.03,
        "validation e_P mean {} um",
        v.e_p.identified.mean
    );
    assert!(
        v.e_p.identified.max < 0.1,
        "validation e_P max {} um",
        v.e_p.identified.max
    );
    assert!(
        v.e_theta.identified.max < 0.01,
        "validation e_theta max {} mrad",
        v.e_theta.identified.max
    );
    assert!(
        v.e_p.nominal.mean > 2.0,
        "nominal model error {} um",
        v.e_p.nominal.mean
    );
    assert!(v.e_p.nominal.mean > 100.0 * v.e_p.identified.mean);
    // Every step converged; the last one is the full set.
    assert_eq!(res.steps.len(), 3);
    assert!(
        res.steps.iter().all(|s| s.stop_reason.converged()),
        "{:?}",
        res.steps
    );
    // Gauges: E (no load), a common scale of the diameters, the rigid motion of {W} with the
    // clamps A and the sensor (3), the rigid motion of {P} with the clamps B and the pattern
    // (3).
    assert_eq!(res.unidentifiable.len(), 8, "{:?}", res.unidentifiable);
    assert!(res.unidentifiable.contains(&"E".to_string()));
    assert_eq!(
        res.unidentifiable
            .iter()
            .filter(|n| n.starts_with("d_"))
            .count(),
        1
    );
    assert!(res.unidentifiable.iter().any(|n| n.starts_with("beta_")));
    let e = res.params.iter().find(|p| p.name == "E").expect("E");
    assert_eq!(e.value, e.nominal, "E is held at nominal");
    // Gauge-free parameters come back to the truth: rod lengths, mount angles alpha, and the
    // diameter ratios (within a few standard deviations).
    let value = |n: &str| res.params.iter().find(|p| p.name == n).expect("parameter");
    let t = &twin.true_params;
    for i in 0..3 {
        let l = value(&format!("l_{}", i + 1));
        let err = (l.value - t.limbs[i].l).abs();
        assert!(
            err < 4.0 * l.std.unwrap_or(0.0) && err < 2e-6,
            "l_{}: off by {err:e}",
            i + 1
        );
        let a = value(&format!("alpha_{}", i + 1));
        let err = (a.value - t.limbs[i].alpha).abs();
        assert!(
            err < 4.0 * a.std.unwrap_or(0.0),
            "alpha_{}: off by {err:e}",
            i + 1
        );
    }
    let ratio = value("d_2").value / value("d_1").value;
    let true_ratio = t.limbs[1].d / t.limbs[0].d;
    assert!(
        (ratio / true_ratio - 1.0).abs() < 0.02,
        "d_2/d_1 {ratio} vs {true_ratio}"
    );
    // No bound was hit.
    assert!(res.params.iter().all(|p| p.at_bound.is_none()));
}

#[test]
fn hold_mode_keeps_the_dropped_parameters_at_nominal() {
    let twin = PcrTwin::nominal(1).expect("twin");
    let lim = twin.file.limits();
    let (lo, hi) = (
        [lim[0][0], lim[1][0], lim[2][0]],
        [lim[0][1], lim[1][1], lim[2][1]],
    );
    let (cal_q, _) = poisson_disc_n(lo, hi, 99, 1).expect("calibration joints");
    let (val_q, _) = poisson_disc_n(lo, hi, 56, 101).expect("validation joints");
    let cal = twin.measure(&cal_q, 10).expect("readings");
    let val = twin.measure(&val_q, 11).expect("readings");
    let base = twin.file.robot().expect("nominal robot");
    let opts = CalibrationOptions {
        hold_unidentifiable: true,
        ..Default::default()
    };
    let res = identify_steps(&base, &twin.file, &cal, Some(&val), &opts, &NoMonitor)
        .expect("identification");
    assert_eq!(res.unidentifiable.len(), 8);
    for name in &res.unidentifiable {
        let p = res
            .params
            .iter()
            .find(|p| &p.name == name)
            .expect("parameter");
        assert_eq!(p.value, p.nominal, "{name} held");
        assert!(p.std.is_none() && !p.identifiable);
    }
    // This twin's errors happen to fit inside the bounds in that gauge too.
    let v = res.table3.validation.as_ref().expect("validation");
    assert!(v.e_p.identified.max < 0.1, "{}", v.e_p.identified.max);
}
