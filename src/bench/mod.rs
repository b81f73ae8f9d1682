//! Benchmarks printed by `calibd bench <area>`: wall-clock figures of the hot paths, measured
//! as the median of repeated runs (speed targets are checked here, never by timed tests).

pub mod api;
pub mod humanoid;
pub mod pcr;
pub mod serial;

use std::time::{Duration, Instant};

/// One printed figure.
#[derive(Debug, Clone)]
pub struct Figure {
    /// What was measured.
    pub name: String,
    /// Median time per operation.
    pub per_op: Duration,
    /// Operations per timed run.
    pub ops: usize,
    /// The target, for the printout.
    pub target: Option<Duration>,
}

/// Median over `runs` of the time of `f`, divided by `ops` operations per call.
pub fn time<F: FnMut()>(
    name: &str,
    runs: usize,
    ops: usize,
    target: Option<Duration>,
    mut f: F,
) -> Figure {
    let mut times: Vec<Duration> = (0..runs.max(1))
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed()
        })
        .collect();
    times.sort();
    Figure {
        name: name.into(),
        per_op: times[times.len() / 2] / ops.max(1) as u32,
        ops,
        target,
    }
}

/// Human-readable duration.
pub fn fmt(d: Duration) -> String {
    let s = d.as_secs_f64();
    if s < 1e-6 {
        format!("{:.1} ns", s * 1e9)
    } else if s < 1e-3 {
        format!("{:.2} us", s * 1e6)
    } else if s < 1.0 {
        format!("{:.2} ms", s * 1e3)
    } else {
        format!("{:.3} s", s)
    }
}

/// Print figures as a table.
pub fn print(out: &mut dyn std::io::Write, figures: &[Figure]) -> std::io::Result<()> {
    for f in figures {
        let target = f
            .target
            .map(|t| format!("(target < {})", fmt(t)))
            .unwrap_or_default();
        let verdict = match f.target {
            Some(t) if f.per_op <= t => "ok",
            Some(_) => "SLOWER THAN TARGET",
            None => "",
        };
        writeln!(
            out,
            "{:<58} {:>12} {:<22} {}",
            f.name,
            fmt(f.per_op),
            target,
            verdict
        )?;
    }
    Ok(())
}
