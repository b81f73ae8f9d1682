//! Benchmarks printed by `calibd bench <area>`: wall-clock figures of the hot paths, measured
//! as the median of repeated runs (speed targets are checked here, never by timed tests).

pub mod api;
pub mod compare;
pub mod fleet;
pub mod humanoid;
pub mod identify;
pub mod kernels;
pub mod pcr;
pub mod serial;

use std::time::{Duration, Instant};

use serde::Serialize;

/// One printed figure.
#[derive(Debug, Clone, Serialize)]
pub struct Figure {
    /// What was measured.
    pub name: String,
    /// Median time per operation.
    #[serde(rename = "median_per_op_s", serialize_with = "secs")]
    pub per_op: Duration,
    /// Fastest run, per operation.
    #[serde(rename = "min_per_op_s", serialize_with = "secs")]
    pub min: Duration,
    /// Slowest run, per operation.
    #[serde(rename = "max_per_op_s", serialize_with = "secs")]
    pub max: Duration,
    /// Timed runs.
    pub runs: usize,
    /// Operations per timed run.
    pub ops: usize,
    /// The target, for the printout.
    #[serde(rename = "target_per_op_s", serialize_with = "opt_secs")]
    pub target: Option<Duration>,
    /// Peak resident memory of the process during the runs (bytes; Linux only: the
    /// high-water mark is reset before the first run).
    pub peak_rss_bytes: Option<u64>,
    /// CPU time (user + system, every thread of the process) of the median run, per
    /// operation: beside the wall time it shows what a figure costs on a shared machine.
    #[serde(rename = "cpu_per_op_s", serialize_with = "opt_secs")]
    pub cpu: Option<Duration>,
    /// A target on the CPU time (for work spread over every core, where the wall time
    /// depends on what else runs).
    #[serde(rename = "cpu_target_per_op_s", serialize_with = "opt_secs")]
    pub cpu_target: Option<Duration>,
}

impl Figure {
    /// The figure with a target on its CPU time.
    pub fn with_cpu_target(mut self, t: Duration) -> Self {
        self.cpu_target = Some(t);
        self
    }
}

fn secs<S: serde::Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(d.as_secs_f64())
}

fn opt_secs<S: serde::Serializer>(d: &Option<Duration>, s: S) -> Result<S::Ok, S::Error> {
    match d {
        Some(d) => s.serialize_f64(d.as_secs_f64()),
        None => s.serialize_none(),
    }
}

/// Resets the process's resident-memory high-water mark (Linux `clear_refs`); false when
/// the platform cannot.
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// The process's resident-memory high-water mark (bytes), from `/proc/self/status`.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// CPU time (user + system) the process has used so far, from getrusage; None where it is
/// not available.
pub fn cpu_time() -> Option<Duration> {
    #[cfg(unix)]
    {
        rusage_cpu(libc::RUSAGE_SELF)
    }
    #[cfg(not(unix))]
    None
}

/// CPU time (user + system) the calling thread has used so far (Linux); None elsewhere.
pub fn thread_cpu_time() -> Option<Duration> {
    #[cfg(target_os = "linux")]
    {
        rusage_cpu(libc::RUSAGE_THREAD)
    }
    #[cfg(not(target_os = "linux"))]
    None
}

/// Context switches of the process so far, voluntary (it waited) and involuntary (it was
/// preempted), from getrusage (Linux); None elsewhere.
pub fn context_switches() -> Option<Switches> {
    #[cfg(target_os = "linux")]
    {
        rusage(libc::RUSAGE_SELF).map(Switches::of)
    }
    #[cfg(not(target_os = "linux"))]
    None
}

/// Context switches of the calling thread so far (Linux); None elsewhere.
pub fn thread_context_switches() -> Option<Switches> {
    #[cfg(target_os = "linux")]
    {
        rusage(libc::RUSAGE_THREAD).map(Switches::of)
    }
    #[cfg(not(target_os = "linux"))]
    None
}

/// Context switch counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
pub struct Switches {
    /// The thread gave up the CPU to wait (for a socket, a lock, a timer).
    pub voluntary: u64,
    /// The thread was preempted (another thread's turn: a loaded machine).
    pub involuntary: u64,
}

impl Switches {
    #[cfg(target_os = "linux")]
    fn of(u: libc::rusage) -> Switches {
        Switches {
            voluntary: u.ru_nvcsw.max(0) as u64,
            involuntary: u.ru_nivcsw.max(0) as u64,
        }
    }

    /// `self - earlier`, counter by counter (0 where a counter did not grow).
    pub fn since(self, earlier: Switches) -> Switches {
        Switches {
            voluntary: self.voluntary.saturating_sub(earlier.voluntary),
            involuntary: self.involuntary.saturating_sub(earlier.involuntary),
        }
    }
}

/// getrusage's figures for `who`.
#[cfg(unix)]
fn rusage(who: libc::c_int) -> Option<libc::rusage> {
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the rusage it is given a pointer to; it was zeroed, and is
    // read only if the call succeeded.
    unsafe {
        if libc::getrusage(who, usage.as_mut_ptr()) != 0 {
            return None;
        }
        Some(usage.assume_init())
    }
}

/// getrusage's user + system time for `who`.
#[cfg(unix)]
fn rusage_cpu(who: libc::c_int) -> Option<Duration> {
    let usage = rusage(who)?;
    let tv = |t: libc::timeval| {
        Duration::from_secs(t.tv_sec.max(0) as u64) + Duration::from_micros(t.tv_usec.max(0) as u64)
    };
    Some(tv(usage.ru_utime) + tv(usage.ru_stime))
}

/// Median, min and max over `runs` of the time of `f`, divided by `ops` operations per
/// call, with the peak resident memory of the runs and the CPU time of the median run.
pub fn time<F: FnMut()>(
    name: &str,
    runs: usize,
    ops: usize,
    target: Option<Duration>,
    mut f: F,
) -> Figure {
    let reset = reset_peak_rss();
    let mut times: Vec<(Duration, Option<Duration>)> = (0..runs.max(1))
        .map(|_| {
            let (t, c) = (Instant::now(), cpu_time());
            f();
            let cpu = c.zip(cpu_time()).map(|(a, b)| b.saturating_sub(a));
            (t.elapsed(), cpu)
        })
        .collect();
    times.sort();
    let cpu = times[times.len() / 2].1;
    let times: Vec<Duration> = times.into_iter().map(|t| t.0).collect();
    let per = |d: Duration| d / ops.max(1) as u32;
    Figure {
        name: name.into(),
        per_op: per(times[times.len() / 2]),
        min: per(times[0]),
        max: per(times[times.len() - 1]),
        runs: times.len(),
        ops,
        target,
        peak_rss_bytes: if reset { peak_rss_bytes() } else { None },
        cpu: cpu.map(per),
        cpu_target: None,
    }
}

/// Every figure of a benchmark run, as written by `calibd bench ... --json FILE` so a run
/// can be compared with an earlier one.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// calibd version.
    pub version: &'static str,
    /// When the run ended (UTC, RFC 3339).
    pub finished_at: String,
    /// Logical CPUs of the machine.
    pub cpus: usize,
    /// Figures per area (`serial`, `pcr`, `humanoid`).
    pub areas: Vec<Area>,
}

/// The figures of one benchmark area.
#[derive(Debug, Clone, Serialize)]
pub struct Area {
    /// `serial`, `pcr` or `humanoid`.
    pub area: String,
    /// Its figures, in the printed order.
    pub figures: Vec<Figure>,
}

impl Report {
    /// A report of `areas` finished now.
    pub fn new(areas: Vec<Area>) -> Self {
        Self {
            version: env!("CARGO_PKG_VERSION"),
            finished_at: chrono::Utc::now().to_rfc3339(),
            cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
            areas,
        }
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
        let mut target = f
            .target
            .map(|t| format!("(target < {})", fmt(t)))
            .unwrap_or_default();
        if let Some(t) = f.cpu_target {
            target = format!("(target cpu < {})", fmt(t));
        }
        let verdict = match (f.cpu_target.zip(f.cpu), f.target) {
            (Some((t, c)), _) if c <= t => "ok",
            (Some(_), _) => "SLOWER THAN TARGET",
            (None, Some(t)) if f.per_op <= t => "ok",
            (None, Some(_)) => "SLOWER THAN TARGET",
            (None, None) => "",
        };
        let mem = f
            .peak_rss_bytes
            .map(|b| format!("{:.0} MB", b as f64 / 1e6))
            .unwrap_or_default();
        let cpu = f.cpu.map(|c| format!("cpu {}", fmt(c))).unwrap_or_default();
        writeln!(
            out,
            "{:<58} {:>12} {:>14} {:>8} {:<22} {}",
            f.name,
            fmt(f.per_op),
            cpu,
            mem,
            target,
            verdict
        )?;
    }
    Ok(())
}
