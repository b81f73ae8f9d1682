//! Daemon settings: a TOML file (`deny_unknown_fields`) under environment variables (each
//! setting has one), under the command line's `--listen` / `--data`. With no file and no
//! variables the embedded defaults need nothing installed: loopback, a data folder in the
//! working directory, one worker per core, an operator token created on first start.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::api::auth::Role;

/// Why the settings could not be loaded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The file could not be read.
    #[error("config: cannot read {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file is not valid.
    #[error("config: {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong, with line and column.
        message: String,
    },
    /// An environment variable has an invalid value.
    #[error("config: environment variable {name}={value:?}: {message}")]
    Env {
        /// Variable.
        name: &'static str,
        /// Its value.
        value: String,
        /// What is wrong.
        message: String,
    },
}

/// Log line format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    /// Human-readable lines.
    #[default]
    Text,
    /// One JSON object per line (for log collectors).
    Json,
}

/// A bearer token allowed to use the API: only its SHA-256 is stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TokenConfig {
    /// Name recorded with what the token does (never the token itself).
    pub name: String,
    /// What the token may do.
    pub role: Role,
    /// Hex SHA-256 of the token (`calibd token` prints both).
    pub sha256: String,
}

/// Authentication settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[derive(Default)]
pub struct AuthConfig {
    /// Allow reads (GET) without a token (default false: results and datasets are the lab's).
    pub anonymous_read: bool,
    /// Tokens. Empty: an operator token is created in `DATA/operator.token`.
    pub tokens: Vec<TokenConfig>,
}

/// Every daemon setting.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Address to listen on.
    pub listen: String,
    /// Data folder (database, operator token).
    pub data: PathBuf,
    /// Jobs run at once; 0 means one per core.
    pub workers: usize,
    /// Most jobs waiting in the queue.
    pub max_queued: usize,
    /// Largest request body in bytes (job documents with inline tables, dataset uploads).
    pub max_body_bytes: usize,
    /// Bytes of request bodies in flight at once, over all clients; a request beyond it is
    /// refused with 503 and `Retry-After` (bounds the memory parallel uploads take).
    pub max_body_bytes_in_flight: u64,
    /// Time limit for producing a response, in seconds (event streams are not limited).
    pub request_timeout_s: u64,
    /// Most open client connections; one more is closed at once (idle and half-sent
    /// connections cannot exhaust the daemon's memory).
    pub max_connections: usize,
    /// Most open connections from one peer address (its fair share of
    /// `max_connections`); one more is closed at once.
    pub max_connections_per_address: usize,
    /// Connections of `max_connections` kept for operators: once the others are taken, a
    /// request without an operator token is answered 503 and its connection closed.
    pub operator_reserved_connections: usize,
    /// Most event streams (`GET /v1/events`, `/v1/jobs/{id}/events`) open at once per
    /// token (per address without a token); one more is answered 429.
    pub max_event_streams_per_token: usize,
    /// Time a client may take none of the bytes the daemon sends it (an event stream
    /// nobody reads), in seconds; then it is disconnected and its slot freed.
    pub send_timeout_s: u64,
    /// Time a client has to send a request's headers, in seconds; also closes idle
    /// keep-alive connections.
    pub header_read_timeout_s: u64,
    /// Host names the API answers to (the `Host` header, port ignored; `*` allows any).
    /// Loopback names by default: a DNS-rebinding page cannot reach the API through a
    /// browser. Add the reverse proxy's public name or the lab PC's name here.
    pub allowed_hosts: Vec<String>,
    /// Shortest interval between two occurrences of a schedule, in seconds.
    pub min_schedule_interval_s: u64,
    /// Log line format.
    pub log_format: LogFormat,
    /// Devices of the lab, shown by the device panel.
    pub devices: Vec<String>,
    /// Authentication.
    pub auth: AuthConfig,
    /// The lab the campaign kinds drive: `sim` (the simulated lab on loopback: digital
    /// twins behind the mock device servers, driven over the real protocols), `none`, or
    /// the path of a lab file describing real cells (`deploy/lab.example.toml`).
    pub lab: String,
    /// Seed of the simulated lab's twins.
    pub lab_seed: u64,
    /// Seconds between two background checks of the lab's devices (`GET /v1/lab`) while all
    /// answer (a failing device is checked again after 2 s).
    pub lab_check_interval_s: u64,
    /// Folder to record every device's traffic to (`calibd-transcript/1`, one file per cell
    /// and device in a subfolder per start; `calibd serve --record`). Unset: no recording.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub record: Option<PathBuf>,
    /// Where jobs and results are stored: unset (the SQLite file in `data`, the default),
    /// `sqlite:FOLDER`, or a `postgres://USER@HOST:PORT/DB` URL (several daemons on one
    /// database). The URL carries no password: see `password_file`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub store: Option<String>,
    /// File holding the PostgreSQL password (first line). `CALIBD_STORE_PASSWORD` gives it
    /// instead; neither is ever logged.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub password_file: Option<PathBuf>,
    /// This daemon's name in a fleet (PostgreSQL store): unique, stable across restarts.
    /// Default: the host name.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// In a fleet, whether this daemon runs the schedules (exactly one daemon should).
    pub fleet_scheduler: bool,
    /// In a fleet, how long a claimed job stays with this daemon without a heartbeat (s);
    /// after that another daemon re-queues it.
    pub fleet_lease_s: u64,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            listen: "127.0.0.1:8750".into(),
            data: PathBuf::from("calibd-data"),
            workers: 0,
            max_queued: 10_000,
            max_body_bytes: 16 * 1024 * 1024,
            max_body_bytes_in_flight: 64 * 1024 * 1024,
            request_timeout_s: 30,
            max_connections: 512,
            max_connections_per_address: 64,
            operator_reserved_connections: 32,
            max_event_streams_per_token: 16,
            send_timeout_s: 60,
            header_read_timeout_s: 10,
            allowed_hosts: vec!["localhost".into(), "127.0.0.1".into(), "::1".into()],
            min_schedule_interval_s: 60,
            log_format: LogFormat::Text,
            devices: Vec::new(),
            auth: AuthConfig::default(),
            lab: "sim".into(),
            lab_seed: 7,
            lab_check_interval_s: 30,
            record: None,
            store: None,
            password_file: None,
            name: None,
            fleet_scheduler: false,
            fleet_lease_s: 15,
        }
    }
}

/// The environment variable of each setting, and its form.
pub const ENV_VARS: &[(&str, &str)] = &[
    ("CALIBD_LISTEN", "listen: address, e.g. 127.0.0.1:8750"),
    ("CALIBD_DATA", "data: folder"),
    ("CALIBD_WORKERS", "workers: integer, 0 = one per core"),
    ("CALIBD_MAX_QUEUED", "max_queued: integer"),
    ("CALIBD_MAX_BODY_BYTES", "max_body_bytes: integer"),
    (
        "CALIBD_MAX_BODY_BYTES_IN_FLIGHT",
        "max_body_bytes_in_flight: integer",
    ),
    ("CALIBD_REQUEST_TIMEOUT_S", "request_timeout_s: integer"),
    ("CALIBD_MAX_CONNECTIONS", "max_connections: integer"),
    (
        "CALIBD_MAX_CONNECTIONS_PER_ADDRESS",
        "max_connections_per_address: integer",
    ),
    (
        "CALIBD_OPERATOR_RESERVED_CONNECTIONS",
        "operator_reserved_connections: integer",
    ),
    (
        "CALIBD_MAX_EVENT_STREAMS_PER_TOKEN",
        "max_event_streams_per_token: integer",
    ),
    ("CALIBD_SEND_TIMEOUT_S", "send_timeout_s: integer"),
    (
        "CALIBD_HEADER_READ_TIMEOUT_S",
        "header_read_timeout_s: integer",
    ),
    (
        "CALIBD_ALLOWED_HOSTS",
        "allowed_hosts: comma-separated host names, * = any",
    ),
    (
        "CALIBD_MIN_SCHEDULE_INTERVAL_S",
        "min_schedule_interval_s: integer",
    ),
    ("CALIBD_LOG_FORMAT", "log_format: text or json"),
    ("CALIBD_DEVICES", "devices: comma-separated names"),
    ("CALIBD_LAB", "lab: sim, none or a lab file path"),
    ("CALIBD_LAB_SEED", "lab_seed: integer"),
    (
        "CALIBD_LAB_CHECK_INTERVAL_S",
        "lab_check_interval_s: integer",
    ),
    ("CALIBD_RECORD", "record: folder for device transcripts"),
    (
        "CALIBD_STORE",
        "store: sqlite:FOLDER or postgres://USER@HOST:PORT/DB",
    ),
    ("CALIBD_NAME", "name: this daemon's name in a fleet"),
    ("CALIBD_FLEET_LEASE_S", "fleet_lease_s: integer"),
    ("CALIBD_FLEET_SCHEDULER", "fleet_scheduler: true or false"),
    (
        "CALIBD_STORE_PASSWORD_FILE",
        "password_file: file with the PostgreSQL password",
    ),
    (
        "CALIBD_ANONYMOUS_READ",
        "auth.anonymous_read: true or false",
    ),
    (
        "CALIBD_TOKENS",
        "auth.tokens: comma-separated name:role:sha256 (replaces the file's tokens)",
    ),
];

fn parse<T: std::str::FromStr>(name: &'static str, value: &str) -> Result<T, ConfigError>
where
    T::Err: std::fmt::Display,
{
    value.trim().parse().map_err(|e: T::Err| ConfigError::Env {
        name,
        value: value.into(),
        message: e.to_string(),
    })
}

/// A comma-separated list, items trimmed, empty items dropped.
fn list(v: &str) -> Vec<String> {
    v.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(String::from)
        .collect()
}

impl Config {
    /// Parse a TOML document.
    pub fn from_toml(path: &Path, text: &str) -> Result<Config, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.into(),
            message: e.to_string(),
        })
    }

    /// Defaults, then the file (if any), then environment variables read through `env`.
    pub fn load(
        file: Option<&Path>,
        env: &dyn Fn(&str) -> Option<String>,
    ) -> Result<Config, ConfigError> {
        let mut c = match file {
            Some(p) => {
                let text = std::fs::read_to_string(p).map_err(|source| ConfigError::Read {
                    path: p.into(),
                    source,
                })?;
                let mut c = Config::from_toml(p, &text)?;
                // A lab file named in the settings file is relative to it.
                if let Some(dir) = p.parent()
                    && !matches!(c.lab.as_str(), "sim" | "none")
                    && Path::new(&c.lab).is_relative()
                {
                    c.lab = dir.join(&c.lab).display().to_string();
                }
                c
            }
            None => Config::default(),
        };
        c.apply_env(env)?;
        Ok(c)
    }

    /// Where the store is: `store`, or the SQLite file in `data` when unset. The password
    /// comes from `password_file`, else from `CALIBD_STORE_PASSWORD` read through `env`.
    pub fn store_location(
        &self,
        env: &dyn Fn(&str) -> Option<String>,
    ) -> Result<crate::store::Location, ConfigError> {
        let Some(store) = &self.store else {
            return Ok(crate::store::Location::Sqlite(self.data.clone()));
        };
        let password = match &self.password_file {
            Some(p) => {
                let text = std::fs::read_to_string(p).map_err(|source| ConfigError::Read {
                    path: p.clone(),
                    source,
                })?;
                Some(text.lines().next().unwrap_or("").to_string())
            }
            None => env("CALIBD_STORE_PASSWORD"),
        };
        crate::store::Location::parse(store, password).map_err(|e| ConfigError::Env {
            name: "CALIBD_STORE",
            value: String::from("(the store setting)"),
            message: e.to_string(),
        })
    }

    /// This daemon's name in a fleet: `name`, else the host name.
    pub fn daemon_name(&self) -> String {
        self.name.clone().unwrap_or_else(|| {
            std::fs::read_to_string("/proc/sys/kernel/hostname")
                .map(|h| h.trim().to_string())
                .ok()
                .filter(|h| !h.is_empty())
                .unwrap_or_else(|| "calibd".into())
        })
    }

    /// Override settings from environment variables.
    pub fn apply_env(&mut self, env: &dyn Fn(&str) -> Option<String>) -> Result<(), ConfigError> {
        for (name, _) in ENV_VARS {
            let Some(v) = env(name) else { continue };
            match *name {
                "CALIBD_LISTEN" => self.listen = v,
                "CALIBD_DATA" => self.data = PathBuf::from(v),
                "CALIBD_WORKERS" => self.workers = parse(name, &v)?,
                "CALIBD_MAX_QUEUED" => self.max_queued = parse(name, &v)?,
                "CALIBD_MAX_BODY_BYTES" => self.max_body_bytes = parse(name, &v)?,
                "CALIBD_MAX_BODY_BYTES_IN_FLIGHT" => {
                    self.max_body_bytes_in_flight = parse(name, &v)?
                }
                "CALIBD_REQUEST_TIMEOUT_S" => self.request_timeout_s = parse(name, &v)?,
                "CALIBD_MAX_CONNECTIONS" => self.max_connections = parse(name, &v)?,
                "CALIBD_MAX_CONNECTIONS_PER_ADDRESS" => {
                    self.max_connections_per_address = parse(name, &v)?
                }
                "CALIBD_OPERATOR_RESERVED_CONNECTIONS" => {
                    self.operator_reserved_connections = parse(name, &v)?
                }
                "CALIBD_MAX_EVENT_STREAMS_PER_TOKEN" => {
                    self.max_event_streams_per_token = parse(name, &v)?
                }
                "CALIBD_SEND_TIMEOUT_S" => self.send_timeout_s = parse(name, &v)?,
                "CALIBD_HEADER_READ_TIMEOUT_S" => self.header_read_timeout_s = parse(name, &v)?,
                "CALIBD_MIN_SCHEDULE_INTERVAL_S" => self.min_schedule_interval_s = parse(name, &v)?,
                "CALIBD_ALLOWED_HOSTS" => self.allowed_hosts = list(&v),
                "CALIBD_LOG_FORMAT" => {
                    self.log_format = match v.trim() {
                        "text" => LogFormat::Text,
                        "json" => LogFormat::Json,
                        _ => {
                            return Err(ConfigError::Env {
                                name,
                                value: v,
                                message: "expected text or json".into(),
                            });
                        }
                    }
                }
                "CALIBD_DEVICES" => self.devices = list(&v),
                "CALIBD_LAB" => {
                    if v.trim().is_empty() {
                        return Err(ConfigError::Env {
                            name,
                            value: v,
                            message: "expected sim, none or a lab file path".into(),
                        });
                    }
                    self.lab = v.trim().into();
                }
                "CALIBD_LAB_SEED" => self.lab_seed = parse(name, &v)?,
                "CALIBD_LAB_CHECK_INTERVAL_S" => self.lab_check_interval_s = parse(name, &v)?,
                "CALIBD_RECORD" => self.record = Some(PathBuf::from(v.trim())),
                "CALIBD_NAME" => self.name = Some(v.trim().to_string()),
                "CALIBD_FLEET_LEASE_S" => self.fleet_lease_s = parse(name, &v)?,
                "CALIBD_FLEET_SCHEDULER" => self.fleet_scheduler = parse(name, &v)?,
                "CALIBD_STORE" => self.store = Some(v.trim().to_string()),
                "CALIBD_STORE_PASSWORD_FILE" => self.password_file = Some(PathBuf::from(v)),
                "CALIBD_ANONYMOUS_READ" => self.auth.anonymous_read = parse(name, &v)?,
                "CALIBD_TOKENS" => {
                    let mut tokens = Vec::new();
                    for item in v.split(',').map(str::trim).filter(|s| !s.is_empty()) {
                        let parts: Vec<&str> = item.split(':').collect();
                        let [n, r, h] = parts[..] else {
                            return Err(ConfigError::Env {
                                name,
                                value: v.clone(),
                                message: format!("`{item}` is not name:role:sha256"),
                            });
                        };
                        let role = Role::parse(r).ok_or_else(|| ConfigError::Env {
                            name,
                            value: v.clone(),
                            message: format!("unknown role `{r}` (viewer, submitter, operator)"),
                        })?;
                        tokens.push(TokenConfig {
                            name: n.into(),
                            role,
                            sha256: h.into(),
                        });
                    }
                    self.auth.tokens = tokens;
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// Workers to start (resolving 0 to the number of cores).
    pub fn worker_count(&self) -> usize {
        if self.workers == 0 {
            std::thread::available_parallelism().map_or(2, |n| n.get())
        } else {
            self.workers
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn environment_overrides_the_file() {
        let c = Config::from_toml(
            Path::new("t.toml"),
            "workers = 3\n[auth]\nanonymous_read = false\n",
        )
        .unwrap();
        assert_eq!((c.workers, c.auth.anonymous_read), (3, false));
        let mut c2 = c.clone();
        let env = |k: &str| match k {
            "CALIBD_WORKERS" => Some("5".to_string()),
            "CALIBD_TOKENS" => Some("ci:viewer:abcd, op:operator:ef01".to_string()),
            "CALIBD_DEVICES" => Some("irb120, uwave".to_string()),
            _ => None,
        };
        c2.apply_env(&env).unwrap();
        assert_eq!(c2.workers, 5);
        assert_eq!(c2.devices, ["irb120", "uwave"]);
        assert_eq!(c2.auth.tokens[1].role, Role::Operator);
        let bad = |k: &str| (k == "CALIBD_WORKERS").then(|| "many".to_string());
        let e = c.clone().apply_env(&bad).unwrap_err().to_string();
        assert!(e.contains("CALIBD_WORKERS") && e.contains("many"), "{e}");
    }

    #[test]
    fn unknown_settings_are_refused_with_their_name() {
        let e = Config::from_toml(Path::new("x.toml"), "listen = \"a\"\nworkrs = 2\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("workrs"), "{e}");
    }

    #[test]
    fn every_setting_has_an_environment_variable() {
        // The serialised default names every top-level and auth setting once.
        let v = toml::Value::try_from(Config::default()).unwrap();
        let mut keys: Vec<String> = v.as_table().unwrap().keys().cloned().collect();
        keys.retain(|k| k != "auth");
        keys.extend(["anonymous_read".to_string(), "tokens".to_string()]);
        for k in keys {
            assert!(
                ENV_VARS.iter().any(|(_, d)| d.starts_with(&format!("{k}:"))
                    || d.starts_with(&format!("auth.{k}:"))),
                "setting {k} has no environment variable"
            );
        }
    }
}
