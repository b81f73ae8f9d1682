#![allow(dead_code, unreachable_pub)]
//! The real `calibd serve` binary as a child process, for tests that kill it with SIGKILL
//! and start it again on the same data folder (single daemons and fleets alike).

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};

use serde_json::Value;

/// A running `calibd serve`; killed when dropped.
pub struct Daemon {
    /// The process.
    pub child: Child,
    /// Its base URL (`http://127.0.0.1:PORT`).
    pub url: String,
}

impl Daemon {
    /// Start `calibd serve` on a free loopback port with data folder `data` and the extra
    /// environment `env`; returns once it listens. `quiet` sends its stderr to /dev/null.
    pub fn start(data: &Path, env: &[(&str, &str)], quiet: bool) -> Daemon {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_calibd"));
        cmd.args(["serve", "--listen", "127.0.0.1:0", "--data"])
            .arg(data)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(if quiet {
                Stdio::null()
            } else {
                Stdio::inherit()
            });
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd.spawn().expect("calibd starts");
        let out = child.stdout.take().expect("piped stdout");
        let mut line = String::new();
        BufReader::new(out)
            .read_line(&mut line)
            .expect("calibd prints its address");
        let url = line
            .trim()
            .strip_prefix("calibd listening on ")
            .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
            .to_string();
        Daemon { child, url }
    }

    /// Kill the process with SIGKILL and reap it.
    pub fn kill9(&mut self) {
        self.child.kill().expect("SIGKILL"); // std's kill is SIGKILL on Unix
        self.child.wait().expect("reaped");
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// GET `url` as JSON.
pub async fn get(c: &reqwest::Client, url: &str) -> Value {
    c.get(url).send().await.unwrap().json().await.unwrap()
}

/// POST `doc` to `d`'s `/v1/jobs` with bearer `token`; returns the new job's id.
pub async fn submit(c: &reqwest::Client, d: &Daemon, token: &str, doc: &Value) -> i64 {
    let r = c
        .post(format!("{}/v1/jobs", d.url))
        .bearer_auth(token)
        .json(doc)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    r.json::<Value>().await.unwrap()["id"].as_i64().unwrap()
}

/// A campaign's measurement journal, from `d`'s API.
pub async fn journal(c: &reqwest::Client, d: &Daemon, id: i64) -> Vec<Value> {
    get(c, &format!("{}/v1/jobs/{id}/measurements", d.url)).await["entries"]
        .as_array()
        .unwrap()
        .clone()
}
