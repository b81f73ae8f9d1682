//! Joint-interface mock speaking `calibd-joints/1` in simulate mode: a [`JointModel`] (the
//! hook for a digital twin) is the robot; a `move` is played on it tick by tick ([`TICK`])
//! over its duration and answered once the posture is reached, while `read` (from any
//! connection) sees the joints on their way. One move at a time across connections (`busy`
//! otherwise); `stop` from any connection halts it. Planned faults (drop, stall, garbage,
//! truncate, device error, delay) replace replies. `calibd mock joints` serves [`Linear`].

use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::StreamExt;
use tokio_util::codec::Framed;

use super::PROTOCOL;
use super::codec::{ErrorCode, Identity, Incoming, Reply, Request, ServerCodec};
use crate::mock_kit::{BoxIo, Conn, Faults, Handler};

/// How often a running move updates the model's joints.
pub const TICK: Duration = Duration::from_millis(5);

/// The robot behind the mock: the hook for a digital twin.
pub trait JointModel: Send + 'static {
    /// Robot name sent in `hello`.
    fn robot(&self) -> String;
    /// Joint names, in the robot's order.
    fn names(&self) -> Vec<String>;
    /// Limits `[lo, hi]` (rad) of each joint, same order.
    fn limits(&self) -> Vec<[f64; 2]>;
    /// Current positions (rad), same order.
    fn positions(&mut self) -> Vec<f64>;
    /// Put the joints at `q` (rad): called every [`TICK`] of a move.
    fn set_positions(&mut self, q: &[f64]);
    /// A move from the current positions to `target` in `duration_s` is about to start;
    /// an error is a controller fault (the move does not start), its text the message.
    fn begin_move(&mut self, _target: &[f64], _duration_s: f64) -> Result<(), String> {
        Ok(())
    }
    /// Where the joints are `t_s` into a move from `start` to `target` of `duration_s`
    /// (`0 <= t_s < duration_s`). Linear by default.
    fn profile(&self, start: &[f64], target: &[f64], duration_s: f64, t_s: f64) -> Vec<f64> {
        let u = if duration_s > 0.0 {
            (t_s / duration_s).clamp(0.0, 1.0)
        } else {
            1.0
        };
        start
            .iter()
            .zip(target)
            .map(|(a, b)| a + u * (b - a))
            .collect()
    }
}

/// Default model: named joints with limits that move linearly, starting at rest.
#[derive(Debug, Clone, PartialEq)]
pub struct Linear {
    /// Robot name.
    pub robot: String,
    /// Joint names.
    pub names: Vec<String>,
    /// Joint limits (rad).
    pub limits: Vec<[f64; 2]>,
    /// Current positions (rad).
    pub q: Vec<f64>,
}

impl Linear {
    /// Joints `names` with `limits`, each at 0 clamped into its limits.
    pub fn new(robot: impl Into<String>, names: Vec<String>, limits: Vec<[f64; 2]>) -> Self {
        let q = limits.iter().map(|[lo, hi]| 0f64.clamp(*lo, *hi)).collect();
        Linear {
            robot: robot.into(),
            names,
            limits,
            q,
        }
    }

    /// The `calibd mock joints` robot: a four-joint arm (`joint_1` .. `joint_4`, limits
    /// ±2 rad, ±1.5 rad, 0..2.5 rad and ±3 rad).
    pub fn demo() -> Self {
        Linear::new(
            "calibd simulated arm",
            (1..=4).map(|k| format!("joint_{k}")).collect(),
            vec![[-2.0, 2.0], [-1.5, 1.5], [0.0, 2.5], [-3.0, 3.0]],
        )
    }
}

impl JointModel for Linear {
    fn robot(&self) -> String {
        self.robot.clone()
    }
    fn names(&self) -> Vec<String> {
        self.names.clone()
    }
    fn limits(&self) -> Vec<[f64; 2]> {
        self.limits.clone()
    }
    fn positions(&mut self) -> Vec<f64> {
        self.q.clone()
    }
    fn set_positions(&mut self, q: &[f64]) {
        self.q = q.to_vec();
    }
}

/// The robot shared by every connection of one mock.
struct Controller {
    model: Arc<Mutex<dyn JointModel>>,
    moving: AtomicBool,
    /// Incremented by every `stop`: a move ends when it changes.
    stops: AtomicU64,
}

fn error(code: ErrorCode, message: impl Into<String>) -> Reply {
    Reply::Error {
        code,
        message: message.into(),
    }
}

fn internal() -> Reply {
    error(
        ErrorCode::Fault,
        "internal error: the robot model is unusable",
    )
}

/// A move accepted and started.
struct Plan {
    names: Vec<String>,
    start: Vec<f64>,
    target: Vec<f64>,
    duration_s: f64,
    stops: u64,
}

impl Controller {
    fn with<R>(&self, f: impl FnOnce(&mut dyn JointModel) -> R) -> Result<R, Reply> {
        match self.model.lock() {
            Ok(mut m) => Ok(f(&mut *m)),
            Err(_) => Err(internal()),
        }
    }

    fn hello(&self) -> Reply {
        self.with(|m| {
            Reply::Hello(Identity {
                protocol: PROTOCOL.into(),
                robot: m.robot(),
                joints: m.names(),
                limits_rad: m.limits(),
            })
        })
        .unwrap_or_else(|e| e)
    }

    fn read(&self) -> Reply {
        self.with(|m| Reply::State {
            positions_rad: m.names().into_iter().zip(m.positions()).collect(),
            moving: self.moving.load(Ordering::SeqCst),
        })
        .unwrap_or_else(|e| e)
    }

    fn stop(&self) -> Reply {
        self.stops.fetch_add(1, Ordering::SeqCst);
        Reply::Done
    }

    /// Check a move and start it (or say why not).
    fn plan(&self, positions: &BTreeMap<String, f64>, duration_s: f64) -> Result<Plan, Reply> {
        self.with(|m| {
            let names = m.names();
            let limits = m.limits();
            let start = m.positions();
            let mut target = start.clone();
            for (name, v) in positions {
                let Some(k) = names.iter().position(|n| n == name) else {
                    return Err(error(
                        ErrorCode::UnknownJoint,
                        format!(
                            "no joint {:?} (joints: {})",
                            name.chars().take(64).collect::<String>(),
                            names.join(", ")
                        ),
                    ));
                };
                let [lo, hi] = limits.get(k).copied().unwrap_or([f64::NAN; 2]);
                if !(*v >= lo && *v <= hi) {
                    return Err(error(
                        ErrorCode::OutOfLimits,
                        format!("{name} = {v} rad is outside [{lo}, {hi}]"),
                    ));
                }
                target[k] = *v;
            }
            if self
                .moving
                .compare_exchange(false, true, Ordering::SeqCst, Ordering::SeqCst)
                .is_err()
            {
                return Err(error(ErrorCode::Busy, "another move is running"));
            }
            if let Err(message) = m.begin_move(&target, duration_s) {
                self.moving.store(false, Ordering::SeqCst);
                return Err(error(ErrorCode::Fault, message));
            }
            Ok(Plan {
                names,
                start,
                target,
                duration_s,
                stops: self.stops.load(Ordering::SeqCst),
            })
        })
        .and_then(|r| r)
    }
}

/// A simulate-mode handler around any joint model; every connection drives the same robot.
pub fn handler_with(model: Arc<Mutex<dyn JointModel>>, faults: Faults) -> Handler {
    let ctl = Arc::new(Controller {
        model,
        moving: AtomicBool::new(false),
        stops: AtomicU64::new(0),
    });
    Arc::new(move |io, conn| Box::pin(session(io, conn, ctl.clone(), faults.clone())))
}

/// Clears the moving flag when a move ends, however it ends.
struct Moving<'a>(&'a Controller);

impl Drop for Moving<'_> {
    fn drop(&mut self) {
        self.0.moving.store(false, Ordering::SeqCst);
    }
}

/// Play `plan` on the model; requests arriving meanwhile wait in `pending` (a `stop` acts at
/// once). `None` when the client left (the robot stays where it got to).
async fn run_move(
    f: &mut Framed<BoxIo, ServerCodec>,
    conn: &Conn,
    ctl: &Controller,
    plan: Plan,
    pending: &mut VecDeque<Incoming>,
) -> Option<Reply> {
    let _moving = Moving(ctl);
    let t0 = tokio::time::Instant::now();
    loop {
        if ctl.stops.load(Ordering::SeqCst) != plan.stops {
            let here = ctl.with(|m| m.positions()).ok()?;
            tracing::info!(device = "joints", "move stopped");
            return Some(error(
                ErrorCode::Fault,
                format!(
                    "stopped before the posture was reached, at {}",
                    fmt_positions(&plan.names, &here)
                ),
            ));
        }
        let t = t0.elapsed().as_secs_f64();
        if t >= plan.duration_s {
            let r = ctl.with(|m| {
                m.set_positions(&plan.target);
                Reply::Reached {
                    positions_rad: plan.names.iter().cloned().zip(m.positions()).collect(),
                }
            });
            return Some(r.unwrap_or_else(|e| e));
        }
        if let Err(e) = ctl.with(|m| {
            let q = m.profile(&plan.start, &plan.target, plan.duration_s, t);
            m.set_positions(&q)
        }) {
            return Some(e);
        }
        tokio::select! {
            _ = tokio::time::sleep(TICK) => {}
            _ = conn.token.cancelled() => return None,
            l = f.next() => match l {
                Some(Ok(Incoming::Request(Request::Stop))) => {
                    ctl.stop();
                    // Its reply (`ok`) follows the move's.
                    pending.push_back(Incoming::Request(Request::Stop));
                }
                Some(Ok(other)) => pending.push_back(other),
                Some(Err(_)) | None => return None,
            },
        }
    }
}

fn fmt_positions(names: &[String], q: &[f64]) -> String {
    names
        .iter()
        .zip(q)
        .map(|(n, v)| format!("{n} = {v:.4}"))
        .collect::<Vec<_>>()
        .join(", ")
}

async fn session(io: BoxIo, conn: Conn, ctl: Arc<Controller>, faults: Faults) {
    let mut f = Framed::new(io, ServerCodec::default());
    let mut pending: VecDeque<Incoming> = VecDeque::new();
    loop {
        let incoming = match pending.pop_front() {
            Some(i) => i,
            None => tokio::select! {
                _ = conn.token.cancelled() => return,
                l = f.next() => match l {
                    Some(Ok(i)) => i,
                    Some(Err(_)) | None => return,
                },
            },
        };
        let reply = match incoming {
            Incoming::Bad(m) => error(ErrorCode::BadRequest, m),
            Incoming::Request(Request::Hello) => ctl.hello(),
            Incoming::Request(Request::Read) => ctl.read(),
            // A stop queued during a move already took effect.
            Incoming::Request(Request::Stop) => ctl.stop(),
            Incoming::Request(Request::Move {
                positions_rad,
                duration_s,
            }) => match ctl.plan(&positions_rad, duration_s) {
                Err(r) => r,
                Ok(plan) => match run_move(&mut f, &conn, &ctl, plan, &mut pending).await {
                    Some(r) => r,
                    None => return,
                },
            },
        };
        let injected = |_| error(ErrorCode::Fault, "joint controller fault (injected)");
        let wire = |r: &Reply| r.text().into_bytes();
        if !faults
            .send(&mut f, &conn.token, reply, wire, injected)
            .await
        {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::joints::{JointsConfig, JointsHandle};
    use crate::link::TcpConnector;
    use crate::mock_kit::start_with;

    fn demo() -> (Arc<Mutex<Linear>>, Handler) {
        let m = Arc::new(Mutex::new(Linear::demo()));
        let model: Arc<Mutex<dyn JointModel>> = m.clone();
        (m, handler_with(model, Faults::default()))
    }

    #[tokio::test]
    async fn a_move_passes_through_the_profile_and_a_stop_from_another_client_halts_it() {
        let (model, h) = demo();
        let m = start_with("127.0.0.1:0", h).await.expect("mock");
        let a = JointsHandle::connect(TcpConnector::new(m.addr.clone()), JointsConfig::default());
        let b = JointsHandle::connect(TcpConnector::new(m.addr.clone()), JointsConfig::default());
        let target = BTreeMap::from([("joint_1".to_string(), 1.0)]);
        let mv = tokio::spawn({
            let a = a.clone();
            async move { a.move_to(target, Duration::from_secs(5)).await }
        });
        // Wait (by state, not time) until the joint is on its way, then stop it from `b`.
        let seen = loop {
            let r = b.read().await.expect("read");
            if r.moving && r.positions_rad["joint_1"] > 0.0 {
                break r.positions_rad["joint_1"];
            }
            tokio::task::yield_now().await;
        };
        assert!(seen < 1.0);
        let e = b
            .move_to(BTreeMap::from([("joint_2".into(), 0.1)]), Duration::ZERO)
            .await
            .expect_err("busy");
        assert!(
            matches!(e, crate::DriverError::Device { code: 3, .. }),
            "{e}"
        );
        b.stop().await.expect("stop");
        let e = mv.await.expect("task").expect_err("stopped");
        assert!(
            matches!(&e, crate::DriverError::Device { code: 4, message, .. } if message.contains("stopped")),
            "{e}"
        );
        let q = model.lock().expect("model").q[0];
        assert!(q > 0.0 && q < 1.0, "{q}");
        assert!(!b.read().await.expect("read").moving);
        m.stop().await;
    }

    #[tokio::test]
    async fn a_stop_on_the_moving_connection_is_sent_at_once_and_answered_after_the_move() {
        let (model, h) = demo();
        let m = start_with("127.0.0.1:0", h).await.expect("mock");
        let a = JointsHandle::connect(TcpConnector::new(m.addr.clone()), JointsConfig::default());
        let mut state = a.state();
        let mv = tokio::spawn({
            let a = a.clone();
            async move {
                a.move_to(
                    BTreeMap::from([("joint_3".to_string(), 2.0)]),
                    Duration::from_secs(10),
                )
                .await
            }
        });
        state.wait_for(|s| s.moving).await.expect("moving");
        // Wait until the mock has the move running (the joint left 0).
        while model.lock().expect("model").q[2] == 0.0 {
            tokio::time::sleep(TICK).await;
        }
        a.stop().await.expect("stop");
        let e = mv.await.expect("task").expect_err("stopped");
        assert!(
            matches!(e, crate::DriverError::Device { code: 4, .. }),
            "{e}"
        );
        let r = a.read().await.expect("read after the stop");
        assert!(!r.moving && r.positions_rad["joint_3"] < 2.0, "{r:?}");
        m.stop().await;
    }
}
