//! A throw-away PostgreSQL cluster for tests: `initdb` + `postgres` on a temporary folder,
//! loopback TCP on a free port, trust authentication, run as `nobody` when the tests run
//! as root (initdb refuses root). The binaries come from `CALIBD_PG_BIN` or the newest
//! `/usr/lib/postgresql/*/bin`; when there are none, [`Cluster::shared`] gives `None` and
//! the tests say "skipped: PostgreSQL not installed". The server runs under a
//! watchdog, so it stops with the test process even when that is killed.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

/// `sh -c WATCHDOG sh PID ROOT SERVER ARGS…`: run the server until process PID ends or
/// the shell gets SIGTERM, then stop it and remove ROOT.
const WATCHDOG: &str = r#"P=$1; R=$2; shift 2
"$@" & C=$!
trap 'kill -INT $C 2>/dev/null' TERM INT
while kill -0 $P 2>/dev/null && kill -0 $C 2>/dev/null; do sleep 0.2; done
kill -INT $C 2>/dev/null; wait $C; rm -rf "$R""#;

/// A running throw-away cluster.
#[derive(Debug)]
pub struct Cluster {
    root: PathBuf,
    port: u16,
    child: Mutex<Option<Child>>,
    next_db: std::sync::atomic::AtomicUsize,
}

/// The folder holding `initdb` and `postgres`, if PostgreSQL is installed.
pub fn bin_dir() -> Option<PathBuf> {
    if let Some(d) = std::env::var_os("CALIBD_PG_BIN") {
        let d = PathBuf::from(d);
        return d.join("initdb").exists().then_some(d);
    }
    let mut found: Vec<(u32, PathBuf)> = std::fs::read_dir("/usr/lib/postgresql")
        .ok()?
        .flatten()
        .filter_map(|e| {
            let v = e.file_name().to_str()?.parse::<u32>().ok()?;
            let bin = e.path().join("bin");
            bin.join("initdb").exists().then_some((v, bin))
        })
        .collect();
    found.sort();
    found.pop().map(|(_, b)| b)
}

fn is_root() -> bool {
    std::fs::metadata("/proc/self")
        .map(|m| std::os::unix::fs::MetadataExt::uid(&m) == 0)
        .unwrap_or(false)
}

/// `program` under `nobody` when running as root.
fn command(bin: &Path, program: &str) -> Command {
    if is_root() {
        let mut c = Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups"]);
        c.arg(bin.join(program));
        c
    } else {
        Command::new(bin.join(program))
    }
}

/// Remove the folders of earlier test processes that are gone (a process-wide cluster is
/// never dropped: its server stops with the process, its folder stays until here).
fn sweep() {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix("calibd-pg-")) else {
            continue;
        };
        let pid = rest.split('-').next().unwrap_or("");
        if !pid.is_empty() && !Path::new("/proc").join(pid).exists() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

fn free_port() -> Result<u16, String> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
    Ok(l.local_addr().map_err(|e| e.to_string())?.port())
}

impl Cluster {
    /// Start a new cluster (None when PostgreSQL is not installed).
    pub fn start() -> Result<Option<Cluster>, String> {
        let Some(bin) = bin_dir() else {
            if std::env::var_os("CALIBD_REQUIRE_PG").is_some() {
                return Err(
                    "CALIBD_REQUIRE_PG is set but no PostgreSQL binaries were found".into(),
                );
            }
            return Ok(None);
        };
        sweep();
        let root =
            std::env::temp_dir().join(format!("calibd-pg-{}-{}", std::process::id(), free_port()?));
        let data = root.join("data");
        std::fs::create_dir_all(&root).map_err(|e| e.to_string())?;
        if is_root() {
            std::os::unix::fs::chown(&root, Some(65534), Some(65534)).map_err(|e| e.to_string())?;
        }
        let out = command(&bin, "initdb")
            .args(["-D"])
            .arg(&data)
            .args([
                "-U",
                "calibd",
                "--auth=trust",
                "-E",
                "UTF8",
                "--no-sync",
                "--no-instructions",
            ])
            .current_dir(&root)
            .output()
            .map_err(|e| format!("initdb: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "initdb failed: {}",
                String::from_utf8_lossy(&out.stderr)
            ));
        }
        let port = free_port()?;
        let log = std::fs::File::create(root.join("server.log")).map_err(|e| e.to_string())?;
        // A watchdog shell runs the server: it stops it (fast shutdown) and removes the
        // folder when the test process is gone, even after a SIGKILL, or on SIGTERM.
        let server = command(&bin, "postgres");
        let child = Command::new("sh")
            .arg("-c")
            .arg(WATCHDOG)
            .arg("sh")
            .arg(std::process::id().to_string())
            .arg(&root)
            .arg(server.get_program())
            .args(server.get_args())
            .arg("-D")
            .arg(&data)
            .args(["-p", &port.to_string(), "-c", "listen_addresses=127.0.0.1"])
            .args([
                "-c",
                "unix_socket_directories=",
                "-c",
                "fsync=off",
                "-c",
                "max_connections=300",
            ])
            .current_dir(&root)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(|e| format!("postgres: {e}"))?;
        let c = Cluster {
            root,
            port,
            child: Mutex::new(Some(child)),
            next_db: std::sync::atomic::AtomicUsize::new(0),
        };
        let t0 = Instant::now();
        loop {
            match postgres::Client::connect(&c.url("postgres"), postgres::NoTls) {
                Ok(_) => break,
                Err(e) if t0.elapsed() > Duration::from_secs(30) => {
                    let log =
                        std::fs::read_to_string(c.root.join("server.log")).unwrap_or_default();
                    return Err(format!("postgres did not start: {e}\n{log}"));
                }
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
        Ok(Some(c))
    }

    /// One cluster for the whole test process, started on first use (never dropped: its
    /// watchdog stops it when the process ends).
    pub fn shared() -> Option<&'static Cluster> {
        static SHARED: OnceLock<Option<Cluster>> = OnceLock::new();
        SHARED
            .get_or_init(|| match Cluster::start() {
                Ok(c) => c,
                Err(e) => panic!("throw-away PostgreSQL cluster: {e}"),
            })
            .as_ref()
    }

    /// The URL of database `db` on this cluster.
    pub fn url(&self, db: &str) -> String {
        format!("postgres://calibd@127.0.0.1:{}/{db}", self.port)
    }

    /// Create a fresh, empty database; returns its URL.
    pub fn fresh_db(&self) -> Result<String, String> {
        let n = self
            .next_db
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let name = format!("t{}_{n}", std::process::id());
        let mut c = postgres::Client::connect(&self.url("postgres"), postgres::NoTls)
            .map_err(|e| e.to_string())?;
        c.batch_execute(&format!("CREATE DATABASE {name}"))
            .map_err(|e| e.to_string())?;
        Ok(self.url(&name))
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.lock().unwrap_or_else(|p| p.into_inner()).take() {
            let _ = Command::new("kill")
                .args(["-TERM", &c.id().to_string()])
                .status();
            let _ = c.wait();
        }
        let _ = std::fs::remove_dir_all(&self.root);
    }
}
