//! RWS driver actor: one keep-alive HTTP connection with Digest auth and session cookies
//! reused; typed requests for joints, RAPID variables, controller state and moves through
//! the calibd RAPID module, refused locally when outside joint limits or step limits
//! (the move logic is in `moves`).

mod identity;
mod modules;
mod moves;

pub use identity::{DEFAULT_CALIB_MODULE, RwsIdentity, TASK, parse_modules};

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio::sync::{mpsc, watch};

use super::digest::Challenge;
use super::http::{Headers, HttpClientCodec, Request, Response, url_encode};

use crate::actor::{Reply, call};
use crate::error::DriverError;
use crate::link::{Backoff, Connect, Link, Once};

const DEVICE: &str = "rws";
const DATA: &str = "/rw/rapid/symbol/data/RAPID/T_ROB1";

/// Driver configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct RwsConfig {
    /// `Host` header value (the controller address).
    pub host: String,
    /// RWS user.
    pub user: String,
    /// RWS password.
    pub password: String,
    /// Timeout of one HTTP exchange.
    pub timeout: Duration,
    /// Timeout of a whole move (write, execute, acknowledge).
    pub move_timeout: Duration,
    /// Poll period while waiting for a move's acknowledgement.
    pub poll: Duration,
    /// Joint limits (deg), min and max per joint; targets outside are refused.
    pub limits_deg: [(f64, f64); 6],
    /// Largest allowed joint change of one `move_abs_j` (deg, any joint).
    pub max_joint_step_deg: f64,
    /// Largest allowed length of one `move_rel_tool` step (mm).
    pub max_tool_step_mm: f64,
    /// Reconnection back-off.
    pub backoff: Backoff,
}

impl Default for RwsConfig {
    fn default() -> Self {
        RwsConfig {
            host: "127.0.0.1".into(),
            user: "Default User".into(),
            password: "robotics".into(),
            timeout: Duration::from_secs(5),
            move_timeout: Duration::from_secs(60),
            poll: Duration::from_millis(50),
            limits_deg: super::irb120::LIMITS_DEG,
            max_joint_step_deg: 15.0,
            max_tool_step_mm: 10.0,
            backoff: Backoff::default(),
        }
    }
}

/// Controller state as read from `/rw/panel` and `/rw/rapid/execution`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ControllerState {
    /// `motoron`, `motoroff`, `guardstop`, `emergencystop`, ...
    pub ctrlstate: String,
    /// `AUTO`, `MANR`, `MANF`, ...
    pub opmode: String,
    /// `running` or `stopped`.
    pub execstate: String,
}

/// Link state on the watch channel; `joints_deg` is the last joint reading.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RwsState {
    /// True while the HTTP connection is open.
    pub connected: bool,
    /// Successful (re)connections.
    pub connects: u64,
    /// Last joint angles read (deg).
    pub joints_deg: Option<[f64; 6]>,
    /// Last error.
    pub last_error: Option<String>,
}

enum Op {
    Joints(Reply<[f64; 6]>),
    Read(String, Reply<String>),
    Write(String, String, Reply<()>),
    State(Reply<ControllerState>),
    MoveAbsJ([f64; 6], Reply<[f64; 6]>),
    MoveRelTool([f64; 3], Reply<[f64; 6]>),
    Identity(String, Reply<RwsIdentity>),
    LoadModule(String, String, bool, Reply<String>),
}

impl std::fmt::Debug for Op {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Op::Joints(_) => write!(f, "Joints"),
            Op::Read(v, _) => write!(f, "Read({v})"),
            Op::Write(v, x, _) => write!(f, "Write({v}, {x})"),
            Op::State(_) => write!(f, "State"),
            Op::MoveAbsJ(q, _) => write!(f, "MoveAbsJ({q:?})"),
            Op::MoveRelTool(d, _) => write!(f, "MoveRelTool({d:?})"),
            Op::Identity(m, _) => write!(f, "Identity({m})"),
            Op::LoadModule(file, _, stop, _) => write!(f, "LoadModule({file}, stop {stop})"),
        }
    }
}

/// Cheap, cloneable handle to the RWS actor.
#[derive(Debug, Clone)]
pub struct RwsHandle {
    tx: mpsc::Sender<Op>,
    state: watch::Receiver<RwsState>,
}

impl RwsHandle {
    /// Starts the actor on an open transport (no reconnection).
    pub fn attach<T>(io: T, cfg: RwsConfig) -> Self
    where
        T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
    {
        Self::connect(Once::new(io), cfg)
    }

    /// Starts the actor with a connector (reconnects with back-off).
    pub fn connect<C: Connect>(connector: C, cfg: RwsConfig) -> Self {
        let (tx, rx) = mpsc::channel(16);
        let (stx, srx) = watch::channel(RwsState::default());
        let actor = Actor {
            link: Link::new(DEVICE, connector, HttpClientCodec, cfg.backoff),
            cfg,
            rx,
            state: stx,
            challenge: None,
            nc: 0,
            cookies: Vec::new(),
            seq: None,
        };
        tokio::spawn(actor.run());
        RwsHandle { tx, state: srx }
    }

    /// Current joint angles of ROB_1 (deg).
    pub async fn joints_deg(&self) -> Result<[f64; 6], DriverError> {
        call(&self.tx, DEVICE, Op::Joints).await
    }

    /// Reads a RAPID variable of task T_ROB1 as its RAPID literal.
    pub async fn read_rapid(&self, var: &str) -> Result<String, DriverError> {
        call(&self.tx, DEVICE, |r| Op::Read(var.to_string(), r)).await
    }

    /// Writes a RAPID variable of task T_ROB1 (value as a RAPID literal).
    pub async fn write_rapid(&self, var: &str, value: &str) -> Result<(), DriverError> {
        call(&self.tx, DEVICE, |r| {
            Op::Write(var.to_string(), value.to_string(), r)
        })
        .await
    }

    /// Motors, operating mode and RAPID execution state.
    pub async fn controller_state(&self) -> Result<ControllerState, DriverError> {
        call(&self.tx, DEVICE, Op::State).await
    }

    /// Moves to a joint target (deg) with MoveAbsJ; returns the joints reached.
    pub async fn move_abs_j(&self, q_deg: [f64; 6]) -> Result<[f64; 6], DriverError> {
        call(&self.tx, DEVICE, |r| Op::MoveAbsJ(q_deg, r)).await
    }

    /// Moves the TCP by `dp_mm` along the tool axes (MoveL RelTool); returns the joints reached.
    pub async fn move_rel_tool(&self, dp_mm: [f64; 3]) -> Result<[f64; 6], DriverError> {
        call(&self.tx, DEVICE, |r| Op::MoveRelTool(dp_mm, r)).await
    }

    /// Controller name, RobotWare version, whether the calibd RAPID module `calib_module`
    /// ([`DEFAULT_CALIB_MODULE`] unless the lab renamed it) is loaded in T_ROB1, and the
    /// controller state. A missing module is reported in the identity (see
    /// [`RwsIdentity::module_error`]), not as an error.
    pub async fn identity(&self, calib_module: &str) -> Result<RwsIdentity, DriverError> {
        call(&self.tx, DEVICE, |r| {
            Op::Identity(calib_module.to_string(), r)
        })
        .await
    }

    /// Upload `text` as `$HOME/<file>` (file service), then load it into T_ROB1 under RAPID
    /// mastership, replacing a module of the same name; with `stop`, stop the RAPID
    /// execution first (a controller does not load into a running task). The file's path;
    /// a refusal is a [`DriverError::Device`] with the controller's message.
    pub async fn load_module(
        &self,
        file: &str,
        text: &str,
        stop: bool,
    ) -> Result<String, DriverError> {
        call(&self.tx, DEVICE, |r| {
            Op::LoadModule(file.to_string(), text.to_string(), stop, r)
        })
        .await
    }

    /// Watch channel with link state and the last joints read.
    pub fn state(&self) -> watch::Receiver<RwsState> {
        self.state.clone()
    }
}

struct Actor<C: Connect> {
    link: Link<C, HttpClientCodec>,
    cfg: RwsConfig,
    rx: mpsc::Receiver<Op>,
    state: watch::Sender<RwsState>,
    challenge: Option<Challenge>,
    nc: u32,
    cookies: Vec<(String, String)>,
    /// Last command sequence number written to `calib_seq`.
    seq: Option<i64>,
}

fn protocol(detail: String) -> DriverError {
    DriverError::Protocol {
        device: DEVICE,
        detail,
    }
}

fn device(code: i64, message: String) -> DriverError {
    DriverError::Device {
        device: DEVICE,
        code,
        message,
    }
}

/// `_embedded._state[0]` of a JSON reply.
fn state0(r: &Response) -> Result<serde_json::Value, DriverError> {
    let v: serde_json::Value =
        serde_json::from_slice(&r.body).map_err(|e| protocol(format!("reply is not JSON: {e}")))?;
    v.pointer("/_embedded/_state/0")
        .cloned()
        .ok_or_else(|| protocol("reply has no _embedded._state[0]".into()))
}

fn field(v: &serde_json::Value, k: &str) -> Result<String, DriverError> {
    v.get(k)
        .and_then(|x| x.as_str())
        .map(str::to_string)
        .ok_or_else(|| protocol(format!("reply has no string field {k:?}")))
}

impl<C: Connect> Actor<C> {
    async fn run(mut self) {
        while let Some(req) = self.rx.recv().await {
            match req {
                Op::Joints(r) => drop(r.send(self.joints().await)),
                Op::Read(v, r) => drop(r.send(self.read(&v).await)),
                Op::Write(v, x, r) => drop(r.send(self.write(&v, &x).await)),
                Op::State(r) => drop(r.send(self.ctrl_state().await)),
                Op::MoveAbsJ(q, r) => {
                    let res = self.move_abs_j(q).await;
                    drop(r.send(res))
                }
                Op::MoveRelTool(d, r) => {
                    let res = self.move_rel_tool(d).await;
                    drop(r.send(res))
                }
                Op::Identity(m, r) => {
                    let res = self.identity(m).await;
                    drop(r.send(res))
                }
                Op::LoadModule(file, text, stop, r) => {
                    let res = self.load_module(&file, &text, stop).await;
                    drop(r.send(res))
                }
            }
        }
    }

    fn build(&mut self, method: &str, target: &str, body: Option<(&[u8], &str)>) -> Request {
        let mut headers = vec![
            ("Host".to_string(), self.cfg.host.clone()),
            ("Accept".to_string(), "application/json".to_string()),
        ];
        if !self.cookies.is_empty() {
            let c: Vec<String> = self
                .cookies
                .iter()
                .map(|(k, v)| format!("{k}={v}"))
                .collect();
            headers.push(("Cookie".into(), c.join("; ")));
        }
        if let Some(ch) = &self.challenge {
            self.nc += 1;
            let cnonce = format!(
                "{:016x}",
                u64::from(self.nc).wrapping_mul(0x2545_f491_4f6c_dd1d)
            );
            let a = ch.authorization(
                &self.cfg.user,
                &self.cfg.password,
                method,
                target,
                self.nc,
                &cnonce,
            );
            headers.push(("Authorization".into(), a));
        }
        if let Some((_, ty)) = body {
            headers.push(("Content-Type".into(), ty.into()));
        }
        let body = body.map(|b| b.0.to_vec()).unwrap_or_default();
        Request {
            method: method.into(),
            target: target.into(),
            headers,
            body,
        }
    }

    /// One request/response on the current connection.
    async fn once(&mut self, req: Request) -> Result<Response, DriverError> {
        let timeout = self.cfg.timeout;
        let (f, _) = self.link.ensure().await?;
        let exchange = async {
            f.send(req)
                .await
                .map_err(|e| DriverError::from_codec(DEVICE, e))?;
            match f.next().await {
                Some(Ok(r)) => Ok(r),
                Some(Err(e)) => Err(DriverError::from_codec(DEVICE, e)),
                None => Err(DriverError::Closed { device: DEVICE }),
            }
        };
        let r =
            tokio::time::timeout(timeout, exchange)
                .await
                .unwrap_or(Err(DriverError::Timeout {
                    device: DEVICE,
                    what: "an HTTP reply".into(),
                    after_ms: timeout.as_millis() as u64,
                }));
        let connects = self.link.connects;
        match &r {
            Ok(resp) => {
                if resp
                    .header("connection")
                    .is_some_and(|c| c.eq_ignore_ascii_case("close"))
                {
                    self.link.reset();
                }
                self.state.send_modify(|s| {
                    s.connected = true;
                    s.connects = connects;
                });
            }
            Err(e) => {
                self.link.reset();
                let msg = e.to_string();
                self.state.send_modify(|s| {
                    s.connected = false;
                    s.last_error = Some(msg);
                });
            }
        }
        r
    }

    /// Request with auth handling and one retry on a fresh connection if a kept-alive
    /// connection turned out closed. Non-2xx replies become device errors.
    async fn exchange(
        &mut self,
        method: &str,
        target: &str,
        form: Option<&str>,
    ) -> Result<Response, DriverError> {
        let body = form.map(|f| (f.as_bytes(), "application/x-www-form-urlencoded"));
        self.exchange_body(method, target, body).await
    }

    /// As [`Actor::exchange`] with any body and content type.
    async fn exchange_body(
        &mut self,
        method: &str,
        target: &str,
        body: Option<(&[u8], &str)>,
    ) -> Result<Response, DriverError> {
        let mut tries = 0;
        loop {
            tries += 1;
            let was_up = self.link.is_up();
            let req = self.build(method, target, body);
            let resp = match self.once(req).await {
                Ok(r) => r,
                // A stale keep-alive connection: retry once on a new one.
                Err(DriverError::Closed { .. }) if was_up && tries == 1 => continue,
                Err(e) => return Err(e),
            };
            for c in resp.header_all("set-cookie") {
                if let Some((k, v)) = c.split(';').next().and_then(|kv| kv.split_once('=')) {
                    let (k, v) = (k.trim().to_string(), v.trim().to_string());
                    self.cookies.retain(|(a, _)| *a != k);
                    self.cookies.push((k, v));
                }
            }
            if resp.status == 401 && tries <= 2 {
                let ch = resp.header("www-authenticate").and_then(Challenge::parse);
                if ch.is_none() {
                    return Err(protocol("401 without a Digest challenge".into()));
                }
                self.challenge = ch;
                self.nc = 0;
                self.cookies.clear();
                continue;
            }
            if (200..300).contains(&resp.status) {
                return Ok(resp);
            }
            let v: Option<serde_json::Value> = serde_json::from_slice(&resp.body).ok();
            let st = v.as_ref().and_then(|v| v.pointer("/_embedded/status"));
            let code = st
                .and_then(|s| s.get("code"))
                .and_then(|c| {
                    c.as_i64()
                        .or_else(|| c.as_str().and_then(|s| s.parse().ok()))
                })
                .unwrap_or(i64::from(resp.status));
            let msg = st
                .and_then(|s| s.get("msg"))
                .and_then(|m| m.as_str())
                .map_or_else(
                    || format!("HTTP {} {}", resp.status, resp.reason),
                    str::to_string,
                );
            return Err(device(code, format!("HTTP {}: {msg}", resp.status)));
        }
    }

    async fn get_state(&mut self, path: &str) -> Result<serde_json::Value, DriverError> {
        let sep = if path.contains('?') { '&' } else { '?' };
        let r = self
            .exchange("GET", &format!("{path}{sep}json=1"), None)
            .await?;
        state0(&r)
    }

    async fn joints(&mut self) -> Result<[f64; 6], DriverError> {
        let s = self
            .get_state("/rw/motionsystem/mechunits/ROB_1/jointtarget")
            .await?;
        let mut q = [0.0; 6];
        for (i, v) in q.iter_mut().enumerate() {
            let k = format!("rax_{}", i + 1);
            let t = field(&s, &k)?;
            *v = t
                .trim()
                .parse()
                .map_err(|_| protocol(format!("{k} = {t:?} is not a number")))?;
        }
        self.state.send_modify(|st| st.joints_deg = Some(q));
        Ok(q)
    }

    async fn read(&mut self, var: &str) -> Result<String, DriverError> {
        check_name(var)?;
        let s = self.get_state(&format!("{DATA}/{var}")).await?;
        field(&s, "value")
    }

    async fn write(&mut self, var: &str, value: &str) -> Result<(), DriverError> {
        check_name(var)?;
        let form = format!("value={}", url_encode(value));
        self.exchange(
            "POST",
            &format!("{DATA}/{var}?action=set&json=1"),
            Some(&form),
        )
        .await?;
        Ok(())
    }

    async fn ctrl_state(&mut self) -> Result<ControllerState, DriverError> {
        let c = self.get_state("/rw/panel/ctrlstate").await?;
        let o = self.get_state("/rw/panel/opmode").await?;
        let e = self.get_state("/rw/rapid/execution").await?;
        Ok(ControllerState {
            ctrlstate: field(&c, "ctrlstate")?,
            opmode: field(&o, "opmode")?,
            execstate: field(&e, "ctrlexecstate")?,
        })
    }
}

fn parse_num(s: &str) -> Result<i64, DriverError> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.fract() == 0.0)
        .map(|v| v as i64)
        .ok_or_else(|| protocol(format!("RAPID num {s:?} is not an integer")))
}

fn check_name(var: &str) -> Result<(), DriverError> {
    if var.is_empty() || !var.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(DriverError::InvalidRequest {
            device: DEVICE,
            detail: format!("RAPID variable name {var:?}"),
        });
    }
    Ok(())
}
