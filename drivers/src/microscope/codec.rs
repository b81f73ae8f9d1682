//! The `calibd-pose/1` wire format: typed requests and replies and a `tokio_util` codec
//! for each direction (the client encodes [`Request`] and decodes [`Reply`]; the mock does
//! the opposite through [`ServerCodec`]).

use bytes::{BufMut, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

use crate::error::{CodecError, quote};

/// Longest line of the protocol, LF included.
pub const MAX_LINE: usize = 128;

/// A request from the client.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// `ID?`: identification.
    Id,
    /// `POSE?`: the pose in a fresh image.
    Pose,
}

impl Request {
    /// The request's line, without the LF.
    pub fn text(self) -> &'static str {
        match self {
            Request::Id => "ID?",
            Request::Pose => "POSE?",
        }
    }

    /// Parse a request line (without its end of line).
    pub fn parse(line: &str) -> Option<Self> {
        match line.trim() {
            "ID?" => Some(Request::Id),
            "POSE?" => Some(Request::Pose),
            _ => None,
        }
    }
}

/// A reply from the microscope.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// `ID <text>`.
    Id(String),
    /// `POSE <seq> <x_m> <y_m> <theta_rad>`.
    Pose {
        /// Image counter.
        seq: u64,
        /// Position x (m).
        x_m: f64,
        /// Position y (m).
        y_m: f64,
        /// Angle (rad).
        theta_rad: f64,
    },
    /// `ERR <code> <text>`.
    Err {
        /// Error code (1 unknown request, 2 pattern not found, 3 busy, 4 internal).
        code: i64,
        /// The microscope's text.
        text: String,
    },
}

fn finite(field: &str, s: &str, line: &str) -> Result<f64, CodecError> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(CodecError::malformed(format!(
            "{field} = {s:?} is not a finite number in {line:?}"
        ))),
    }
}

impl Reply {
    /// Parse a reply line (without its end of line); errors name the field at fault.
    pub fn parse(line: &str) -> Result<Self, CodecError> {
        let (head, rest) = line.split_once(' ').unwrap_or((line, ""));
        match head {
            "ID" => Ok(Reply::Id(rest.to_string())),
            "POSE" => {
                let f: Vec<&str> = rest.split_ascii_whitespace().collect();
                if f.len() != 4 {
                    return Err(CodecError::malformed(format!(
                        "POSE needs 4 fields (seq x_m y_m theta_rad), got {} in {line:?}",
                        f.len()
                    )));
                }
                let seq = f[0].parse::<u64>().map_err(|_| {
                    CodecError::malformed(format!("seq = {:?} is not a u64 in {line:?}", f[0]))
                })?;
                Ok(Reply::Pose {
                    seq,
                    x_m: finite("x_m", f[1], line)?,
                    y_m: finite("y_m", f[2], line)?,
                    theta_rad: finite("theta_rad", f[3], line)?,
                })
            }
            "ERR" => {
                let (code, text) = rest.split_once(' ').unwrap_or((rest, ""));
                let code = code.parse::<i64>().map_err(|_| {
                    CodecError::malformed(format!(
                        "error code {code:?} is not an integer in {line:?}"
                    ))
                })?;
                Ok(Reply::Err {
                    code,
                    text: text.to_string(),
                })
            }
            _ => Err(CodecError::malformed(format!(
                "unknown reply {line:?} (expected ID, POSE or ERR)"
            ))),
        }
    }

    /// The reply's line, without the LF (floats in shortest round-trip form).
    pub fn text(&self) -> String {
        match self {
            Reply::Id(t) => format!("ID {t}"),
            Reply::Pose {
                seq,
                x_m,
                y_m,
                theta_rad,
            } => format!("POSE {seq} {x_m:e} {y_m:e} {theta_rad:e}"),
            Reply::Err { code, text } => format!("ERR {code} {text}"),
        }
    }
}

/// Split one LF-terminated printable line off `src`.
fn line(src: &mut BytesMut) -> Result<Option<String>, CodecError> {
    let Some(p) = src.iter().position(|b| *b == b'\n') else {
        if src.len() > MAX_LINE {
            return Err(CodecError::malformed(format!(
                "no LF within {MAX_LINE} bytes: {}",
                quote(src)
            )));
        }
        return Ok(None);
    };
    let raw = src.split_to(p + 1);
    let body = raw[..p].strip_suffix(b"\r").unwrap_or(&raw[..p]);
    if body.len() >= MAX_LINE || !body.iter().all(|b| (0x20..0x7f).contains(b)) {
        return Err(CodecError::malformed(format!(
            "not a printable line of at most {MAX_LINE} bytes: {}",
            quote(&raw)
        )));
    }
    Ok(Some(String::from_utf8_lossy(body).into_owned()))
}

/// Client side: encodes requests, decodes typed replies.
#[derive(Debug, Clone, Copy, Default)]
pub struct MicroscopeCodec;

impl Decoder for MicroscopeCodec {
    type Item = Reply;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Reply>, CodecError> {
        match line(src)? {
            Some(l) => Reply::parse(&l).map(Some),
            None => Ok(None),
        }
    }
}

impl Encoder<Request> for MicroscopeCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Request, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(item.text().as_bytes());
        dst.put_u8(b'\n');
        Ok(())
    }
}

/// Server side (the mock): decodes request lines (unknown ones as text), encodes replies.
#[derive(Debug, Clone, Copy, Default)]
pub struct ServerCodec;

impl Decoder for ServerCodec {
    type Item = String;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<String>, CodecError> {
        line(src)
    }
}

impl Encoder<Reply> for ServerCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Reply, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(item.text().as_bytes());
        dst.put_u8(b'\n');
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(bytes: &[u8]) -> Vec<Result<Reply, String>> {
        let mut c = MicroscopeCodec;
        let mut b = BytesMut::from(bytes);
        let mut out = Vec::new();
        loop {
            match c.decode(&mut b) {
                Ok(Some(r)) => out.push(Ok(r)),
                Ok(None) => break,
                Err(e) => {
                    out.push(Err(e.to_string()));
                    break;
                }
            }
        }
        out
    }

    #[test]
    fn pose_id_and_error_lines_parse_to_typed_replies() {
        let r = decode_all(b"POSE 17 1.0125e-3 -2.5e-4 0.00123\r\nID calibd-pose/1 mock\nERR 2 pattern not found\n");
        assert_eq!(
            r,
            vec![
                Ok(Reply::Pose {
                    seq: 17,
                    x_m: 1.0125e-3,
                    y_m: -2.5e-4,
                    theta_rad: 0.00123
                }),
                Ok(Reply::Id("calibd-pose/1 mock".into())),
                Ok(Reply::Err {
                    code: 2,
                    text: "pattern not found".into()
                }),
            ]
        );
    }

    #[test]
    fn partial_lines_wait_for_the_rest() {
        let mut c = MicroscopeCodec;
        let mut b = BytesMut::from(&b"POSE 3 1e-3 2e-3"[..]);
        assert_eq!(c.decode(&mut b).expect("partial"), None);
        b.extend_from_slice(b" -1e-2\n");
        assert_eq!(
            c.decode(&mut b).expect("whole"),
            Some(Reply::Pose {
                seq: 3,
                x_m: 1e-3,
                y_m: 2e-3,
                theta_rad: -1e-2
            })
        );
        assert!(b.is_empty());
    }

    #[test]
    fn bad_lines_name_what_is_wrong() {
        let e = |b: &[u8]| match decode_all(b).pop() {
            Some(Err(e)) => e,
            other => panic!("expected an error, got {other:?}"),
        };
        assert!(e(b"POSE 1 2e-3 nan 0\n").contains("y_m"));
        assert!(e(b"POSE 1 2e-3 0\n").contains("4 fields"));
        assert!(e(b"POSE -1 0 0 0\n").contains("seq"));
        assert!(e(b"ERR x oops\n").contains("error code"));
        assert!(e(b"HELLO\n").contains("unknown reply"));
        assert!(e(b"\xff\xfe\x00garbage\r\n").contains("printable"));
        assert!(e(&[b'1'; 200]).contains("no LF"));
    }

    #[test]
    fn replies_round_trip_through_their_text() {
        let p = Reply::Pose {
            seq: 9,
            x_m: 1.234_567_890_123e-3,
            y_m: -9.87e-9,
            theta_rad: 3.0e-7,
        };
        let mut b = BytesMut::new();
        ServerCodec.encode(p.clone(), &mut b).expect("encode");
        assert_eq!(MicroscopeCodec.decode(&mut b).expect("decode"), Some(p));
        let mut b = BytesMut::new();
        MicroscopeCodec
            .encode(Request::Pose, &mut b)
            .expect("encode");
        assert_eq!(&b[..], b"POSE?\n");
        assert_eq!(
            ServerCodec.decode(&mut b).expect("decode").as_deref(),
            Some("POSE?")
        );
        assert_eq!(Request::parse("POSE?"), Some(Request::Pose));
        assert_eq!(Request::parse("POS?"), None);
    }
}
