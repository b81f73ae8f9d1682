//! Replay over TCP: each connection gets its recorded part; strict mode stops at the first
//! departure and refuses later connections; lax mode logs and serves on.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use super::{ReplayOptions, handler};
use crate::mock_kit::start_with;
use crate::transcript::Transcript;

/// Two recorded connections: `A` answered `one`, then `B` answered `two`.
const TWO_CONNECTIONS: &str = r#"{"format":"calibd-transcript/1","device":"test"}
{"t_us":0,"dir":"c2d","hex":"410a","conn":0}
{"t_us":10,"dir":"d2c","hex":"6f6e650a","conn":0}
{"t_us":20,"dir":"c2d","hex":"420a","conn":1}
{"t_us":30,"dir":"d2c","hex":"74776f0a","conn":1}
"#;

async fn serve(strict: bool) -> crate::mock_kit::RunningMock {
    let t = Transcript::parse(TWO_CONNECTIONS).expect("transcript");
    let opts = ReplayOptions {
        label: "test.jsonl".into(),
        strict,
    };
    start_with("127.0.0.1:0", handler(t, opts))
        .await
        .expect("replay mock")
}

/// Sends `request` on a new connection and reads until the mock closes it or `want` bytes
/// came (bounded by a generous timeout, a failure guard rather than a wait).
async fn exchange(addr: &str, request: &[u8], want: usize) -> Vec<u8> {
    let mut s = TcpStream::connect(addr).await.expect("connect");
    s.write_all(request).await.expect("write");
    let mut got = Vec::new();
    let mut buf = [0u8; 64];
    while got.len() < want {
        let n = tokio::time::timeout(Duration::from_secs(10), s.read(&mut buf))
            .await
            .expect("the mock answers or closes")
            .unwrap_or(0);
        if n == 0 {
            break;
        }
        got.extend_from_slice(&buf[..n]);
    }
    got
}

#[tokio::test]
async fn each_connection_gets_its_recorded_part() {
    let m = serve(true).await;
    assert_eq!(exchange(&m.addr, b"A\n", 4).await, b"one\n");
    assert_eq!(exchange(&m.addr, b"B\n", 4).await, b"two\n");
    m.stop().await;
}

#[tokio::test]
async fn strict_replay_stops_at_a_mismatch_and_refuses_later_connections() {
    let m = serve(true).await;
    // Another command: no recorded reply, the connection is closed.
    assert_eq!(exchange(&m.addr, b"X\n", 4).await, b"");
    // The second connection's recorded request, but the replay has stopped.
    assert_eq!(exchange(&m.addr, b"B\n", 4).await, b"");
    m.stop().await;
}

#[tokio::test]
async fn lax_replay_logs_a_mismatch_and_serves_on() {
    let m = serve(false).await;
    assert_eq!(exchange(&m.addr, b"X\n", 4).await, b"one\n");
    assert_eq!(exchange(&m.addr, b"B\n", 4).await, b"two\n");
    m.stop().await;
}
