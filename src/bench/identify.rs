//! `calibd bench identify`: one ball-centring identification of the IRB 120 twin (31
//! parameters, seeded twin data) from 90 to 100,000 measurements, with time and peak memory
//! per size. Identification time was linear in the measurements before the large-Jacobian
//! kernels; the target (issue 35) is 100,000 measurements under 0.6 s and 100 MB.

use std::time::{Duration, Instant};

use super::{Figure, time};
use crate::identify::{SolveOptions, solve};
use crate::measure::{PointMeasurement, PointProblem};
use crate::twin::SerialTwin;
use crate::util::NoMonitor;

/// Measurement counts of the sweep.
pub const SIZES: [usize; 5] = [90, 360, 1_440, 10_000, 100_000];

/// `n` centring measurements of the IRB 120 twin (seed 1), spread over the three balls
/// (seeded: the same data on every run).
pub fn centring_data(twin: &SerialTwin, n: usize) -> Vec<PointMeasurement> {
    let per_ball = n.div_ceil(twin.plate.len().max(1));
    let mut meas = twin.centring(per_ball, 2);
    meas.truncate(n);
    meas
}

/// Identify the twin's parameters from `meas` (problem construction included, as a job
/// does it); the final cost.
pub fn identify_once(twin: &SerialTwin, meas: &[PointMeasurement]) -> f64 {
    let ids: Vec<_> = twin
        .file
        .identify
        .iter()
        .filter_map(|n| twin.nominal.param_by_name(n).ok())
        .collect();
    let p = PointProblem::new(twin.nominal.clone(), ids, twin.plate.clone(), meas.to_vec())
        .expect("twin data are consistent");
    let x0 = p.initial();
    // As a `serial.identify` job solves it: a nearly linear fit from the nominal model.
    let o = SolveOptions {
        lm: crate::identify::LmOptions {
            nearly_linear: true,
            ..Default::default()
        },
        ..Default::default()
    };
    let s = solve(&p, &p.unknowns(), &x0, &o, &NoMonitor).expect("twin identification converges");
    s.cost_after
}

/// Runs per size: many for the small ones, few for the large ones.
fn runs_for(n: usize) -> usize {
    match n {
        0..=2_000 => 11,
        2_001..=20_000 => 5,
        _ => 3,
    }
}

/// The sweep over `sizes`: one figure per size (median time of one identification, peak
/// memory of the process during its runs).
pub fn sweep(sizes: &[usize]) -> Vec<Figure> {
    let twin = SerialTwin::irb120(1);
    let mut figs = Vec::new();
    let mut sink = 0.0;
    for &n in sizes {
        let t = Instant::now();
        let meas = centring_data(&twin, n);
        eprintln!(
            "identify bench: {n} measurements generated in {:.1} s",
            t.elapsed().as_secs_f64()
        );
        let target = (n == 100_000).then_some(Duration::from_millis(600));
        figs.push(time(
            &format!("identification, 31 parameters, {n} ball-centring measurements"),
            runs_for(n),
            1,
            target,
            || sink += identify_once(&twin, &meas),
        ));
    }
    std::hint::black_box(sink);
    figs
}

/// Run the identification sweep over [`SIZES`].
pub fn run() -> Vec<Figure> {
    sweep(&SIZES)
}
