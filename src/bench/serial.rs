//! `calibd bench serial`: FK + gravity torques, one 31-parameter identification from 360
//! measurements, DETMAX 75 of 360, and a 2,000-identification dispersion study, all on the
//! IRB 120 twin.

use std::time::Duration;

use super::{Figure, time};
use crate::design::{DetmaxOptions, detmax};
use crate::identify::{SolveOptions, solve};
use crate::jobs::serial::design::DesignPool;
use crate::jobs::{NoReferences, prepare};
use crate::measure::PointProblem;
use crate::twin::SerialTwin;
use crate::util::{NoMonitor, Rng};

/// A dispersion job over twin data as inline JSON.
pub fn dispersion_job(sizes: &[usize], repetitions: usize) -> serde_json::Value {
    crate::jobs::examples::twin_dispersion(sizes, repetitions)
}

/// Run the serial benchmarks.
pub fn run() -> Vec<Figure> {
    let twin = SerialTwin::irb120(1);
    let mut rng = Rng::new(9);
    let qs: Vec<Vec<f64>> = (0..10_000).map(|_| twin.random_q(&mut rng)).collect();
    let mut figs = Vec::new();
    let c = twin.nominal.clone();
    let mut sink = 0.0;
    figs.push(time(
        "FK + gravity torques per configuration (IRB 120)",
        15,
        qs.len(),
        Some(Duration::from_micros(1)),
        || {
            for q in &qs {
                let tau = c.static_torques(q);
                sink += c.tcp(q, Some(&tau)).p.x;
            }
        },
    ));
    let meas = twin.centring(120, 2);
    let ids: Vec<_> = twin
        .file
        .identify
        .iter()
        .filter_map(|n| twin.nominal.param_by_name(n).ok())
        .collect();
    figs.push(time(
        "identification, 31 parameters, 360 measurements",
        11,
        1,
        Some(Duration::from_millis(20)),
        || {
            let p = PointProblem::new(
                twin.nominal.clone(),
                ids.clone(),
                twin.plate.clone(),
                meas.clone(),
            )
            .expect("twin data are consistent");
            let x0 = p.initial();
            let s = solve(&p, &p.unknowns(), &x0, &SolveOptions::default(), &NoMonitor)
                .expect("twin identification converges");
            sink += s.cost_after;
        },
    ));
    let job = dispersion_job(&[75], 1);
    let prepared = crate::jobs::serial::identify::parse_inputs(
        &crate::jobs::Inputs::new(&NoReferences),
        &job["model"],
        None,
        &job["measurements"],
        serde_json::from_value(job["ball_plate"].clone())
            .ok()
            .as_ref(),
        None,
        Default::default(),
    )
    .expect("twin inputs are valid");
    let dp = DesignPool::new(&prepared).expect("pool builds");
    let mut seed = 0;
    figs.push(time(
        "DETMAX, 75 of 360 configurations",
        11,
        1,
        Some(Duration::from_millis(100)),
        || {
            seed += 1;
            let s = detmax(
                &dp.pool,
                &DetmaxOptions {
                    n: 75,
                    seed,
                    max_excursion: 6,
                },
                &NoMonitor,
            )
            .expect("not cancelled");
            sink += s.log_det;
        },
    ));
    let sizes: Vec<usize> = (2..=10).map(|k| 10 * k).collect();
    let study = prepare(&dispersion_job(&sizes, 223), &NoReferences).expect("valid dispersion job");
    figs.push(time(
        "dispersion study, 9 sizes x 223 = 2,007 identifications (all cores)",
        1,
        1,
        Some(Duration::from_secs(10)),
        || {
            let r = study.run(&NoMonitor).expect("study runs");
            sink += r.result["identifications"].as_f64().unwrap_or(0.0);
        },
    ));
    std::hint::black_box(sink);
    figs
}
