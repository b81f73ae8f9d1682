//! SmarAct MCS and MCS2 mocks over one simulated set of positioners ([`StageModel`]):
//! closed-loop moves take time, reference searches zero the position, range limits and
//! unknown commands give the controllers' own errors. The MCS2 command set is in `mcs2`.

mod mcs2;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio::time::Instant;
use tokio_util::codec::Framed;

use super::line::LineCodec;
use crate::mock_kit::fault::Fate;
use crate::mock_kit::{BoxIo, Conn, Faults, Handler};
use mcs2::mcs2_reply;

/// Serial number the MCS2 mock reports (`:DEV:SNUM?`).
pub const MCS2_SERIAL: &str = "MCS2-00001234";
/// Device name the MCS2 mock reports (`:DEV:NAME?`).
pub const MCS2_NAME: &str = "MCS2-sim";
/// System id the MCS mock reports (`:GSI`).
pub const MCS_SYSTEM_ID: i64 = 3_118_167_526;

/// The positioners behind a controller: the hook for piezo-stage twins.
pub trait StageModel: Send + 'static {
    /// Number of channels.
    fn channels(&self) -> u8;
    /// Travel range of `ch` (pm).
    fn range_pm(&self, ch: u8) -> (i64, i64);
    /// Closed-loop speed (pm/s).
    fn speed_pm_s(&self, ch: u8) -> f64;
    /// Position reached when commanded to `target_pm` (the closed-loop residual).
    fn settle(&self, ch: u8, target_pm: i64) -> i64;
    /// Whether the channels start referenced (a commissioned cell's stages keep their
    /// reference; a fresh controller's need a reference search).
    fn referenced_at_start(&self) -> bool {
        false
    }
}

/// Default: three SLC-1730 stages, ±10.5 mm, 20 mm/s, settling 2 nm short of the target.
#[derive(Debug, Clone, Default)]
pub struct Slc1730x3;

impl StageModel for Slc1730x3 {
    fn channels(&self) -> u8 {
        3
    }
    fn range_pm(&self, _: u8) -> (i64, i64) {
        (-10_500_000_000, 10_500_000_000)
    }
    fn speed_pm_s(&self, _: u8) -> f64 {
        20e9
    }
    fn settle(&self, _: u8, t: i64) -> i64 {
        t - 2000
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Activity {
    Idle,
    Moving {
        from: i64,
        to: i64,
        start: Instant,
        dur: Duration,
    },
    Referencing {
        until: Instant,
    },
}

#[derive(Debug, Clone, Copy)]
struct Axis {
    pos: i64,
    activity: Activity,
    referenced: bool,
    fault: bool,
}

/// Simulated controller state shared by all connections.
pub(crate) struct Sim {
    model: Box<dyn StageModel>,
    axes: Vec<Axis>,
    errors: Vec<(i64, String)>,
}

impl Sim {
    fn new(model: Box<dyn StageModel>) -> Self {
        let n = model.channels() as usize;
        let axis = Axis {
            pos: 0,
            activity: Activity::Idle,
            referenced: model.referenced_at_start(),
            fault: false,
        };
        Sim {
            model,
            axes: vec![axis; n],
            errors: Vec::new(),
        }
    }

    fn update(&mut self, now: Instant) {
        for a in &mut self.axes {
            match a.activity {
                Activity::Moving {
                    from,
                    to,
                    start,
                    dur,
                } => {
                    let s = if dur.is_zero() {
                        1.0
                    } else {
                        ((now - start).as_secs_f64() / dur.as_secs_f64()).min(1.0)
                    };
                    a.pos = from + ((to - from) as f64 * s) as i64;
                    if s >= 1.0 {
                        a.pos = to;
                        a.activity = Activity::Idle;
                    }
                }
                Activity::Referencing { until } if now >= until => {
                    a.pos = 0;
                    a.referenced = true;
                    a.activity = Activity::Idle;
                }
                _ => {}
            }
        }
    }

    /// Starts a move; Err(()) when the target is outside the range.
    fn start_move(&mut self, ch: usize, target: i64) -> Result<(), ()> {
        let (lo, hi) = self.model.range_pm(ch as u8);
        if target < lo || target > hi {
            return Err(());
        }
        let to = self.model.settle(ch as u8, target);
        let speed = self.model.speed_pm_s(ch as u8).max(1.0);
        let a = &mut self.axes[ch];
        let dur = Duration::from_secs_f64((to - a.pos).abs() as f64 / speed);
        a.activity = Activity::Moving {
            from: a.pos,
            to,
            start: Instant::now(),
            dur,
        };
        Ok(())
    }

    fn start_reference(&mut self, ch: usize) {
        self.axes[ch].activity = Activity::Referencing {
            until: Instant::now() + Duration::from_millis(100),
        };
    }

    fn stop(&mut self, ch: usize) {
        self.axes[ch].activity = Activity::Idle;
    }

    fn channel(&self, s: &str) -> Option<usize> {
        s.parse::<usize>().ok().filter(|c| *c < self.axes.len())
    }
}

fn sim(model: Box<dyn StageModel>) -> Arc<Mutex<Sim>> {
    Arc::new(Mutex::new(Sim::new(model)))
}

/// Simulate-mode handler for the MCS (ASCII) controller.
pub(crate) fn mcs_handler(faults: Faults) -> Handler {
    mcs_handler_with_model(Box::new(Slc1730x3), faults)
}

/// Simulate-mode handler for the MCS2 (SCPI) controller.
pub(crate) fn mcs2_handler(faults: Faults) -> Handler {
    mcs2_handler_with_model(Box::new(Slc1730x3), faults)
}

/// MCS handler around any stage model.
pub fn mcs_handler_with_model(model: Box<dyn StageModel>, faults: Faults) -> Handler {
    handler_with(sim(model), faults, Dialect::Mcs)
}

/// MCS2 handler around any stage model.
pub fn mcs2_handler_with_model(model: Box<dyn StageModel>, faults: Faults) -> Handler {
    handler_with(sim(model), faults, Dialect::Mcs2)
}

/// The error queue of a simulated MCS2 controller, shared by all its connections: tests use
/// it to play another client that left errors behind, and to look at what is queued.
#[derive(Clone)]
pub struct Mcs2ErrorQueue(Arc<Mutex<Sim>>);

impl std::fmt::Debug for Mcs2ErrorQueue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Mcs2ErrorQueue({:?})", self.pending())
    }
}

impl Mcs2ErrorQueue {
    /// Appends an error as `:SYST:ERR?` will report it (`<code>,"<text>"`).
    pub fn push(&self, code: i64, text: &str) {
        if let Ok(mut s) = self.0.lock() {
            s.errors.push((code, text.to_string()));
        }
    }

    /// The queued errors, oldest first.
    pub fn pending(&self) -> Vec<(i64, String)> {
        self.0.lock().map(|s| s.errors.clone()).unwrap_or_default()
    }
}

/// MCS2 handler around any stage model, with a handle on its error queue.
pub fn mcs2_handler_with_queue(
    model: Box<dyn StageModel>,
    faults: Faults,
) -> (Handler, Mcs2ErrorQueue) {
    let sim = sim(model);
    (
        handler_with(sim.clone(), faults, Dialect::Mcs2),
        Mcs2ErrorQueue(sim),
    )
}

fn handler_with(sim: Arc<Mutex<Sim>>, faults: Faults, d: Dialect) -> Handler {
    Arc::new(move |io, conn| Box::pin(session(io, conn, sim.clone(), faults.clone(), d)))
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Dialect {
    Mcs,
    Mcs2,
}

async fn session(io: BoxIo, conn: Conn, sim: Arc<Mutex<Sim>>, faults: Faults, d: Dialect) {
    let mut f = Framed::new(io, LineCodec::default());
    loop {
        let line = tokio::select! {
            _ = conn.token.cancelled() => return,
            l = f.next() => match l { Some(Ok(l)) => l, _ => return },
        };
        let replies = match sim.lock() {
            Ok(mut s) => {
                s.update(Instant::now());
                match d {
                    Dialect::Mcs => vec![mcs_reply(&mut s, line.trim())],
                    // A line's commands run under one lock: no other client's command
                    // runs between them (the driver's error attribution relies on it), and
                    // every client shares the one error queue.
                    Dialect::Mcs2 => line
                        .split(';')
                        .filter_map(|c| mcs2_reply(&mut s, c.trim()))
                        .collect(),
                }
            }
            Err(_) => return,
        };
        let eol = if d == Dialect::Mcs { "" } else { "\r" };
        for r in replies {
            // The device's own error: MCS answers with one, MCS2 faults positioner 0 and
            // queues an error, the reply itself unchanged.
            let error = |r: String| match d {
                Dialect::Mcs => ":E0,129".to_string(),
                Dialect::Mcs2 => {
                    if let Ok(mut s) = sim.lock() {
                        s.axes[0].fault = true;
                        s.errors
                            .push((-300, "Device-specific error: positioner fault".into()));
                    }
                    r
                }
            };
            let wire = |r: &String| r.clone().into_bytes();
            match faults.apply(f.get_mut(), &conn.token, r, wire, error).await {
                Fate::Send(r) => {
                    if f.send(format!("{r}{eol}")).await.is_err() {
                        return;
                    }
                }
                Fate::Skipped => continue,
                Fate::Close => return,
            }
        }
    }
}

fn mcs_reply(s: &mut Sim, cmd: &str) -> String {
    let Some(body) = cmd.strip_prefix(':') else {
        return ":E-1,1".into();
    };
    let split = body
        .find(|c: char| !c.is_ascii_uppercase())
        .unwrap_or(body.len());
    let (m, rest) = body.split_at(split);
    let args: Vec<&str> = if rest.is_empty() {
        Vec::new()
    } else {
        rest.split(',').collect()
    };
    let ch_txt = args.first().copied().unwrap_or("-1");
    let nums: Option<Vec<i64>> = args.iter().skip(1).map(|a| a.trim().parse().ok()).collect();
    let Some(nums) = nums else {
        return format!(":E{ch_txt},4");
    };
    if m == "SCM" {
        return ":E-1,0".into();
    }
    if m == "GSI" && args.is_empty() {
        return format!(":ID{MCS_SYSTEM_ID}");
    }
    if m == "GNC" && args.is_empty() {
        return format!(":N{}", s.axes.len());
    }
    let Some(ch) = s.channel(ch_txt) else {
        return if matches!(
            m,
            "GP" | "GS" | "GPPK" | "MPA" | "MPR" | "FRM" | "S" | "SP" | "CS"
        ) {
            format!(":E{ch_txt},7")
        } else {
            ":E-1,2".into()
        };
    };
    let a = s.axes[ch];
    let status = match a.activity {
        Activity::Idle => 3,
        Activity::Moving { .. } => 4,
        Activity::Referencing { .. } => 7,
    };
    match (m, nums.as_slice()) {
        ("GP", []) => format!(":P{ch},{}", a.pos / 1000),
        ("GS", []) => format!(":S{ch},{}", if a.fault { 8 } else { status }),
        ("GPPK", []) => format!(":PPK{ch},{}", u8::from(a.referenced)),
        ("MPA", [nm, _hold]) | ("MPR", [nm, _hold]) => {
            let target = if m == "MPA" {
                nm.saturating_mul(1000)
            } else {
                a.pos.saturating_add(nm.saturating_mul(1000))
            };
            match s.start_move(ch, target) {
                Ok(()) => format!(":E{ch},0"),
                Err(()) => format!(":E{ch},147"),
            }
        }
        ("FRM", [_dir, _hold, _autozero]) => {
            s.start_reference(ch);
            format!(":E{ch},0")
        }
        ("S", []) => {
            s.stop(ch);
            format!(":E{ch},0")
        }
        ("SP", [nm]) => {
            s.axes[ch].pos = nm.saturating_mul(1000);
            format!(":E{ch},0")
        }
        ("GP" | "GS" | "GPPK" | "S", _) => format!(":E{ch},6"),
        ("MPA" | "MPR" | "SP" | "FRM", _) => format!(":E{ch},5"),
        _ => ":E-1,2".into(),
    }
}
