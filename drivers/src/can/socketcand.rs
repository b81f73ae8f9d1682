//! socketcand wire format (linux-can/socketcand `doc/protocol.md`, `state_raw.c`): ASCII
//! messages `< ... >` with no newline; in raw mode frames arrive as
//! `< frame 123 1700000000.000001 11223344 >` and are sent as `< send 123 4 11 22 33 44 >`.

use bytes::{Buf, BufMut, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

use super::frame::CanFrame;
use crate::error::{CodecError, quote};

/// Longest message accepted.
const MAX_MSG: usize = 512;

/// Splits the stream into messages, each returned as its whitespace-separated words.
#[derive(Debug, Clone, Copy, Default)]
pub struct SocketcandCodec;

impl Decoder for SocketcandCodec {
    type Item = Vec<String>;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Vec<String>>, CodecError> {
        let skip = src.iter().take_while(|b| b.is_ascii_whitespace()).count();
        src.advance(skip);
        if src.is_empty() {
            return Ok(None);
        }
        if src[0] != b'<' {
            return Err(CodecError::malformed(format!(
                "socketcand message does not start with '<': {}",
                quote(src)
            )));
        }
        let Some(end) = src.iter().position(|b| *b == b'>') else {
            if src.len() > MAX_MSG {
                return Err(CodecError::malformed(format!(
                    "no '>' within {MAX_MSG} bytes"
                )));
            }
            return Ok(None);
        };
        let msg = src.split_to(end + 1);
        let body = &msg[1..end];
        if body.contains(&b'<') || !body.iter().all(|b| b.is_ascii_graphic() || *b == b' ') {
            return Err(CodecError::malformed(format!(
                "bad socketcand message {}",
                quote(&msg)
            )));
        }
        let text = String::from_utf8_lossy(body);
        Ok(Some(text.split_whitespace().map(str::to_string).collect()))
    }
}

impl Encoder<String> for SocketcandCodec {
    type Error = CodecError;
    fn encode(&mut self, body: String, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(format!("< {body} >").as_bytes());
        Ok(())
    }
}

fn id_of(s: &str) -> Result<(u32, bool), CodecError> {
    let id = u32::from_str_radix(s, 16)
        .map_err(|_| CodecError::malformed(format!("CAN id {s:?} is not hex")))?;
    let ext = s.len() > 3 || id > 0x7ff;
    if id > 0x1fff_ffff {
        return Err(CodecError::malformed(format!("CAN id {s:?} out of range")));
    }
    Ok((id, ext))
}

/// Parses `frame <id> <sec.usec> <HEX>` (the words after `<`).
pub fn parse_frame(words: &[String]) -> Result<CanFrame, CodecError> {
    let bad = || CodecError::malformed(format!("bad frame message {:?}", words.join(" ")));
    let [kind, id, _ts, rest @ ..] = words else {
        return Err(bad());
    };
    if kind != "frame" || rest.len() > 1 {
        return Err(bad());
    }
    let (id, extended) = id_of(id)?;
    let hex = rest.first().map(String::as_str).unwrap_or("");
    let data = crate::transcript::from_hex(hex)
        .filter(|d| d.len() <= 8)
        .ok_or_else(bad)?;
    Ok(CanFrame { id, extended, data })
}

/// Parses `send <id> <dlc> <b>...` (bytes as unpadded hex, as python-can sends them).
pub fn parse_send(words: &[String]) -> Result<CanFrame, CodecError> {
    let bad = || CodecError::malformed(format!("bad send message {:?}", words.join(" ")));
    let [kind, id, dlc, bytes @ ..] = words else {
        return Err(bad());
    };
    if kind != "send" {
        return Err(bad());
    }
    let (id, extended) = id_of(id)?;
    let dlc: usize = dlc.parse().map_err(|_| bad())?;
    if dlc > 8 || bytes.len() != dlc {
        return Err(bad());
    }
    let data = bytes
        .iter()
        .map(|b| u8::from_str_radix(b, 16).map_err(|_| bad()))
        .collect::<Result<_, _>>()?;
    Ok(CanFrame { id, extended, data })
}

fn id_text(f: &CanFrame) -> String {
    if f.extended {
        format!("{:08X}", f.id)
    } else {
        format!("{:03X}", f.id)
    }
}

/// Body of a `send` message for `f`.
pub fn send_body(f: &CanFrame) -> String {
    let mut s = format!("send {} {}", id_text(f), f.data.len());
    for b in &f.data {
        s.push_str(&format!(" {b:02X}"));
    }
    s
}

/// Body of a `frame` message for `f` at `t` (seconds since the epoch).
pub fn frame_body(f: &CanFrame, t: std::time::Duration) -> String {
    let hex: String = f.data.iter().map(|b| format!("{b:02X}")).collect();
    format!(
        "frame {} {}.{:06} {hex}",
        id_text(f),
        t.as_secs(),
        t.subsec_micros()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(s: &str) -> Vec<String> {
        let mut b = BytesMut::from(s.as_bytes());
        SocketcandCodec.decode(&mut b).unwrap().unwrap()
    }

    #[test]
    fn documented_messages() {
        let mut b =
            BytesMut::from(&b"< hi >< ok >  < frame 581 1700000000.000001 4B41600037020000 >"[..]);
        assert_eq!(SocketcandCodec.decode(&mut b).unwrap().unwrap(), vec!["hi"]);
        assert_eq!(SocketcandCodec.decode(&mut b).unwrap().unwrap(), vec!["ok"]);
        let f = parse_frame(&SocketcandCodec.decode(&mut b).unwrap().unwrap()).unwrap();
        assert_eq!(
            f,
            CanFrame {
                id: 0x581,
                extended: false,
                data: vec![0x4b, 0x41, 0x60, 0, 0x37, 0x02, 0, 0]
            }
        );
        // python-can sends unpadded lower-case hex bytes.
        let s = parse_send(&words("< send 601 8 40 41 60 0 0 0 0 0 >")).unwrap();
        assert_eq!(
            s,
            CanFrame {
                id: 0x601,
                extended: false,
                data: vec![0x40, 0x41, 0x60, 0, 0, 0, 0, 0]
            }
        );
        assert_eq!(send_body(&s), "send 601 8 40 41 60 00 00 00 00 00");
        let t = std::time::Duration::new(1_700_000_000, 1000);
        assert_eq!(
            frame_body(&f, t),
            "frame 581 1700000000.000001 4B41600037020000"
        );
        let e = parse_frame(&words("< frame 12345678 1.000000 >")).unwrap();
        assert!(e.extended && e.data.is_empty());
    }

    #[test]
    fn partial_and_garbage() {
        let mut b = BytesMut::from(&b"< frame 581 17"[..]);
        assert!(matches!(SocketcandCodec.decode(&mut b), Ok(None)));
        let mut g = BytesMut::from(&b"\xff\xfe\x00garbage<<>>"[..]);
        assert!(SocketcandCodec.decode(&mut g).is_err());
        let mut g = BytesMut::from(&b"< a < b >"[..]);
        assert!(SocketcandCodec.decode(&mut g).is_err());
        assert!(parse_send(&words("< send 601 9 1 2 3 4 5 6 7 8 9 >")).is_err());
        assert!(parse_send(&words("< send 601 2 1 >")).is_err());
        assert!(parse_frame(&words("< frame xyz 1.0 00 >")).is_err());
        assert!(parse_frame(&words("< frame 123 1.0 001122334455667788 >")).is_err());
    }
}
