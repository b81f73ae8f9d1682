//! RWS 1.0 mock of an IRC5 with an IRB 120: HTTP Digest auth (realm
//! `validusers@robapi.abb`), session cookies, JSON (`Content-Type: application/json`) for
//! joint/robtarget, RAPID PERS variables, execution, controller state and op mode; the calibd
//! RAPID module (`drivers/rapid/CalibServer.mod`) is simulated on an [`ArmModel`]. System
//! info and the module list of T_ROB1 come from [`ControllerInfo`]. The resources are in
//! `route`.

mod files;
mod route;
use route::route;

use std::collections::{HashMap, HashSet};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use serde_json::json;
use tokio::time::Instant;
use tokio_util::codec::Framed;

use super::digest;
use super::http::{Headers, HttpServerCodec, Request, Response};
use super::irb120;
use super::rapid::{format_jointtarget, parse_jointtarget, parse_pos};
use crate::mock_kit::fault::Fate;
use crate::mock_kit::{BoxIo, Conn, Faults, Handler};

/// Realm of IRC5 RobotWare 6.
pub const REALM: &str = "validusers@robapi.abb";

/// The arm behind the controller: the hook for a digital twin of the IRB 120.
pub trait ArmModel: Send + 'static {
    /// Joint angles at power-up (deg).
    fn home_deg(&self) -> [f64; 6];
    /// Flange position (mm) and orientation quaternion (w, x, y, z) at `q_deg`.
    fn tool_pose(&self, q_deg: &[f64; 6]) -> ([f64; 3], [f64; 4]);
    /// Joint angles after a `RelTool` move by `dp_mm` in the tool frame (None: unreachable).
    fn rel_tool(&self, q_deg: &[f64; 6], dp_mm: [f64; 3]) -> Option<[f64; 6]>;
    /// Joint speed used to time simulated moves, deg/s.
    fn speed_deg_s(&self) -> f64 {
        90.0
    }
    /// Called whenever the simulated joints change (during and at the end of a move), so a
    /// twin can keep the physical arm, and the sensors that see it, in step.
    fn moved(&mut self, _q_deg: &[f64; 6]) {}
}

/// Default model: an IRB 120 at rest in its calibration-friendly pose.
#[derive(Debug, Clone, Default)]
pub struct Irb120;

impl ArmModel for Irb120 {
    fn home_deg(&self) -> [f64; 6] {
        [0.0, 0.0, 0.0, 0.0, 30.0, 0.0]
    }
    fn tool_pose(&self, q: &[f64; 6]) -> ([f64; 3], [f64; 4]) {
        let t = irb120::fk(q);
        ([t[0][3], t[1][3], t[2][3]], irb120::quaternion(&t))
    }
    fn rel_tool(&self, q: &[f64; 6], dp: [f64; 3]) -> Option<[f64; 6]> {
        irb120::rel_tool(q, dp)
    }
}

struct Motion {
    from: [f64; 6],
    to: [f64; 6],
    start: Instant,
    duration: Duration,
}

/// What the mock controller says about itself (`GET /rw/system`) and which RAPID modules
/// T_ROB1 holds (`GET /rw/rapid/modules?task=T_ROB1`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControllerInfo {
    /// System name (`sys-system.name`).
    pub name: String,
    /// RobotWare version (`rwversion`).
    pub rwversion: String,
    /// RobotWare version name (`rwversionname`).
    pub rwversionname: String,
    /// Program modules loaded in T_ROB1 (the system modules `BASE` and `user` are always
    /// listed too).
    pub program_modules: Vec<String>,
}

impl Default for ControllerInfo {
    /// A virtual IRC5 named `IRB120-sim` on RobotWare 6.15 with the calibd module loaded.
    fn default() -> Self {
        ControllerInfo {
            name: "IRB120-sim".into(),
            rwversion: "6.15.1013".into(),
            rwversionname: "6.15.01.00".into(),
            program_modules: vec!["CalibServer".into()],
        }
    }
}

/// Everything the RWS mock is configured with: the accepted account and the controller's
/// identity.
#[derive(Debug, Clone)]
pub struct RwsMockOptions {
    /// The account Digest authentication accepts.
    pub credentials: Credentials,
    /// System info and RAPID modules.
    pub controller: ControllerInfo,
}

impl From<Credentials> for RwsMockOptions {
    fn from(credentials: Credentials) -> Self {
        RwsMockOptions {
            credentials,
            controller: ControllerInfo::default(),
        }
    }
}

/// Controller state shared by all connections.
struct Robot {
    model: Box<dyn ArmModel>,
    info: ControllerInfo,
    vars: HashMap<String, String>,
    joints: [f64; 6],
    motion: Option<Motion>,
    last_seq: String,
    running: bool,
    motors_on: bool,
    nonces: HashSet<String>,
    sessions: HashSet<String>,
    counter: u64,
    /// Files of the file service by path (`$HOME/x.mod`).
    files: HashMap<String, Vec<u8>>,
    /// Whether a client holds RAPID mastership.
    mastership: bool,
}

impl Robot {
    fn new(model: Box<dyn ArmModel>, info: ControllerInfo) -> Self {
        let home = model.home_deg();
        let mut vars = HashMap::new();
        vars.insert("calib_q".into(), format_jointtarget(&home));
        vars.insert("calib_dp".into(), "[0,0,0]".into());
        for v in ["calib_cmd", "calib_seq", "calib_ack", "calib_err"] {
            vars.insert(v.into(), "0".into());
        }
        Robot {
            model,
            info,
            vars,
            joints: home,
            motion: None,
            last_seq: "0".into(),
            running: true,
            motors_on: true,
            nonces: HashSet::new(),
            sessions: HashSet::new(),
            counter: 0,
            files: HashMap::new(),
            mastership: false,
        }
    }

    /// Advances the simulated RAPID task (CalibServer.mod) to `now`.
    fn update(&mut self, now: Instant) {
        if let Some(m) = &self.motion {
            let s = if m.duration.is_zero() {
                1.0
            } else {
                ((now - m.start).as_secs_f64() / m.duration.as_secs_f64()).min(1.0)
            };
            for i in 0..6 {
                // The end of a move is the target exactly, whatever the path to it.
                self.joints[i] = if s >= 1.0 {
                    m.to[i]
                } else {
                    m.from[i] + s * (m.to[i] - m.from[i])
                };
            }
            self.model.moved(&self.joints);
            if s >= 1.0 {
                self.motion = None;
                self.vars.insert("calib_ack".into(), self.last_seq.clone());
            }
            return;
        }
        if !self.running || !self.motors_on {
            return;
        }
        let seq = self.vars.get("calib_seq").cloned().unwrap_or_default();
        if seq == self.last_seq {
            return;
        }
        self.last_seq = seq.clone();
        let cmd = self.vars.get("calib_cmd").map(|s| s.trim().to_string());
        let target = match cmd.as_deref() {
            Some("1") => self.vars.get("calib_q").and_then(|v| parse_jointtarget(v)),
            Some("2") => self
                .vars
                .get("calib_dp")
                .and_then(|v| parse_pos(v))
                .and_then(|dp| self.model.rel_tool(&self.joints, dp)),
            _ => None,
        };
        let inside = |q: &[f64; 6]| {
            q.iter()
                .zip(irb120::LIMITS_DEG)
                .all(|(v, (lo, hi))| *v >= lo && *v <= hi)
        };
        match target {
            Some(to) if inside(&to) => {
                let dmax = (0..6)
                    .map(|i| (to[i] - self.joints[i]).abs())
                    .fold(0.0, f64::max);
                self.vars.insert("calib_err".into(), "0".into());
                self.motion = Some(Motion {
                    from: self.joints,
                    to,
                    start: now,
                    duration: Duration::from_secs_f64(dmax / self.model.speed_deg_s()),
                });
            }
            _ => {
                let code = if matches!(cmd.as_deref(), Some("1") | Some("2")) {
                    "2"
                } else {
                    "1"
                };
                self.vars.insert("calib_err".into(), code.into());
                self.vars.insert("calib_ack".into(), seq);
            }
        }
    }
}

/// The account the mock's Digest authentication accepts (`calibd mock abb --user
/// --password`).
#[derive(Debug, Clone)]
pub struct Credentials {
    /// RWS user name.
    pub user: String,
    /// RWS password.
    pub password: String,
}

/// Builds the simulate-mode handler with the default IRB 120.
pub(crate) fn handler(opts: impl Into<RwsMockOptions>, faults: Faults) -> Handler {
    handler_with(Box::new(Irb120), opts, faults)
}

/// Builds a simulate-mode handler around any arm model (`opts`: [`RwsMockOptions`],
/// [`Credentials`] with the default controller identity, or the `calibd mock` arguments).
pub fn handler_with(
    model: Box<dyn ArmModel>,
    opts: impl Into<RwsMockOptions>,
    faults: Faults,
) -> Handler {
    let RwsMockOptions {
        credentials,
        controller,
    } = opts.into();
    let robot = Arc::new(Mutex::new(Robot::new(model, controller)));
    let Credentials { user, password } = credentials;
    Arc::new(move |io, conn| {
        let s = Server {
            robot: robot.clone(),
            faults: faults.clone(),
            user: user.clone(),
            password: password.clone(),
        };
        Box::pin(s.run(io, conn))
    })
}

struct Server {
    robot: Arc<Mutex<Robot>>,
    faults: Faults,
    user: String,
    password: String,
}

fn json_response(status: u16, v: serde_json::Value) -> Response {
    Response {
        status,
        reason: reason(status).into(),
        headers: vec![("Content-Type".into(), "application/json".into())],
        body: v.to_string().into_bytes(),
    }
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        204 => "No Content",
        201 => "Created",
        400 => "Bad Request",
        403 => "Forbidden",
        401 => "Unauthorized",
        404 => "Not Found",
        503 => "Service Unavailable",
        _ => "Error",
    }
}

fn state(items: serde_json::Value) -> Response {
    json_response(200, json!({"_links": {}, "_embedded": {"_state": [items]}}))
}

fn error(status: u16, code: i64, msg: &str) -> Response {
    json_response(
        status,
        json!({"_embedded": {"status": {"code": code, "msg": msg}}}),
    )
}

fn no_content() -> Response {
    Response {
        status: 204,
        reason: "No Content".into(),
        headers: Vec::new(),
        body: Vec::new(),
    }
}

impl Server {
    async fn run(self, io: BoxIo, conn: Conn) {
        let mut f = Framed::new(io, HttpServerCodec);
        loop {
            let req = tokio::select! {
                _ = conn.token.cancelled() => return,
                r = f.next() => match r { Some(Ok(r)) => r, _ => return },
            };
            let close = req
                .header("connection")
                .is_some_and(|c| c.eq_ignore_ascii_case("close"));
            let mut resp = self.respond(&req);
            if resp.status != 401 {
                let wire = |r: &Response| {
                    let mut b = bytes::BytesMut::new();
                    let _ =
                        tokio_util::codec::Encoder::encode(&mut HttpServerCodec, r.clone(), &mut b);
                    b.to_vec()
                };
                let busy = |_| error(503, -1073414144, "Too many active sessions");
                resp = match self
                    .faults
                    .apply(f.get_mut(), &conn.token, resp, wire, busy)
                    .await
                {
                    Fate::Send(r) => r,
                    // Garbage in an HTTP stream: the client cannot resynchronise.
                    Fate::Skipped | Fate::Close => return,
                };
            }
            if f.send(resp).await.is_err() || close {
                return;
            }
        }
    }

    fn respond(&self, req: &Request) -> Response {
        let Ok(mut r) = self.robot.lock() else {
            return error(500, -1, "internal error");
        };
        // Authentication: a known session cookie, or a valid Digest header.
        let cookie_ok = req.header_all("cookie").any(|c| {
            c.split(';').any(|kv| {
                kv.trim()
                    .strip_prefix("-http-session-=")
                    .is_some_and(|v| r.sessions.contains(v))
            })
        });
        let mut set_cookie = None;
        if !cookie_ok {
            let ok = req
                .header("authorization")
                .and_then(|h| digest::verify(h, &req.method, REALM, &self.user, &self.password))
                .is_some_and(|n| r.nonces.contains(&n));
            if !ok {
                r.counter += 1;
                let nonce = digest::md5_hex(&format!("nonce-{}-{:?}", r.counter, Instant::now()));
                r.nonces.insert(nonce.clone());
                let mut resp = error(401, -1073479669, "Unauthorized");
                resp.headers.push((
                    "WWW-Authenticate".into(),
                    format!(
                        "Digest realm=\"{REALM}\", domain=\"/\", qop=\"auth\", nonce=\"{nonce}\", opaque=\"799d5\", algorithm=\"MD5\", stale=\"FALSE\""
                    ),
                ));
                return resp;
            }
            r.counter += 1;
            let sid = format!("{:016x}", r.counter.wrapping_mul(0x9e37_79b9_7f4a_7c15));
            r.sessions.insert(sid.clone());
            set_cookie = Some(sid);
        }
        r.update(Instant::now());
        let mut resp = route(&mut r, req);
        if let Some(sid) = set_cookie {
            resp.headers.push((
                "Set-Cookie".into(),
                format!("-http-session-={sid}; Path=/; httponly"),
            ));
            resp.headers.push((
                "Set-Cookie".into(),
                format!("ABBCX={}; Path=/; httponly", r.counter),
            ));
        }
        resp
    }
}
