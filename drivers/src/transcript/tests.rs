//! Round trips of the recorder and the parser: masking, connections, cut lines.

use super::*;

#[derive(Debug, Clone, Default)]
struct Shared(Arc<Mutex<Vec<u8>>>);
impl Write for Shared {
    fn write(&mut self, b: &[u8]) -> io::Result<usize> {
        self.0
            .lock()
            .map_err(|_| io::Error::other("poisoned"))?
            .extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

#[test]
fn record_then_parse_round_trips() {
    let buf = Shared::default();
    let r = Recorder::to_writer(buf.clone(), "uwave", "unit test").unwrap();
    r.record(Direction::FromDevice, b"DT10000+00000011.88M\r", false);
    r.record(Direction::ToDevice, &[0, 1, 0xff], true);
    let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
    let t = Transcript::parse(&text).unwrap();
    assert_eq!(t.header.unwrap().device, "uwave");
    assert_eq!(t.chunks.len(), 2);
    assert_eq!(t.chunks[0].bytes().unwrap(), b"DT10000+00000011.88M\r");
    assert_eq!(t.chunks[0].text.as_deref(), Some("DT10000+00000011.88M\\r"));
    assert!(t.chunks[1].udp);
    assert_eq!(t.chunks[1].bytes().unwrap(), vec![0, 1, 0xff]);
    assert!(t.chunks[1].t_us >= t.chunks[0].t_us);
}

#[test]
fn authorization_values_are_masked_and_connections_numbered() {
    let buf = Shared::default();
    let r = Recorder::to_writer(buf.clone(), "abb", "unit test").unwrap();
    let secret = "Digest username=\"calibd\", response=\"0123456789abcdef\"";
    let req = format!("GET /rw/system HTTP/1.1\r\nHost: rc\r\nAuthorization: {secret}\r\n\r\n");
    r.connection()
        .record(Direction::ToDevice, req.as_bytes(), false);
    let second = r.connection();
    second.record(Direction::FromDevice, b"HTTP/1.1 200 OK\r\n\r\n", false);
    second.record(Direction::ToDevice, req.as_bytes(), false);
    let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
    assert!(!text.contains("0123456789abcdef"), "{text}");
    let t = Transcript::parse(&text).unwrap();
    assert_eq!(
        t.chunks.iter().map(|c| c.conn).collect::<Vec<_>>(),
        [Some(0), Some(1), Some(1)]
    );
    let c = &t.chunks[0];
    let masked = c.bytes().unwrap();
    assert_eq!(masked.len(), req.len());
    let from = req.find("Digest").unwrap();
    assert_eq!(c.redacted, vec![[from, from + secret.len()]]);
    assert!(masked[from..from + secret.len()].iter().all(|b| *b == b'*'));
    // Replay compares everything but the masked value.
    assert_eq!(c.first_difference(&masked, req.as_bytes()), None);
    let other = req.replace("/rw/system", "/rw/panel!");
    assert_eq!(c.first_difference(&masked, other.as_bytes()), Some(8));
}

#[test]
fn a_line_cut_by_a_crash_is_dropped() {
    let buf = Shared::default();
    let r = Recorder::to_writer(buf.clone(), "uwave", "unit test").unwrap();
    r.record(Direction::FromDevice, b"DT10000+00000011.88M\r", false);
    r.record(Direction::FromDevice, b"DT10100+00000012.01M\r", false);
    let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
    let cut = &text[..text.len() - 10];
    let t = Transcript::parse(cut).unwrap();
    assert_eq!(t.chunks.len(), 1);
    assert_eq!(t.chunks[0].bytes().unwrap(), b"DT10000+00000011.88M\r");
    assert_eq!(t.chunks[0].line, 2);
    // The same bad line with its newline is an error, not a crash's cut.
    assert!(Transcript::parse(&format!("{cut}\n")).is_err());
}

#[test]
fn bad_lines_are_reported_with_line_number() {
    let e = Transcript::parse("# c\n{\"t_us\":0,\"dir\":\"c2d\",\"hex\":\"abc\"}\n").unwrap_err();
    assert!(e.to_string().contains("line 2"), "{e}");
    let e = Transcript::parse("{\"t_us\":0,\"dir\":\"up\",\"hex\":\"00\"}").unwrap_err();
    assert!(e.to_string().contains("line 1"), "{e}");
    assert_eq!(from_hex("0a 0B"), Some(vec![10, 11]));
    assert_eq!(from_hex("0g"), None);
}
