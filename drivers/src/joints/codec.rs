//! The `calibd-joints/1` wire format: typed requests and replies and a `tokio_util` codec
//! for each direction (the client encodes [`Request`] and decodes [`Reply`]; the mock does
//! the opposite through [`ServerCodec`], which turns any bad line into
//! [`Incoming::Bad`] instead of failing, so one bad request does not end a session).

use std::collections::BTreeMap;

use bytes::{BufMut, BytesMut};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use tokio_util::codec::{Decoder, Encoder};

use crate::error::{CodecError, quote};

/// Longest line of the protocol, LF included (64 KiB).
pub const MAX_LINE: usize = 64 * 1024;

/// A request from the client.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "lowercase")]
pub enum Request {
    /// `{"op":"hello"}`: identity, joints and limits.
    Hello,
    /// `{"op":"read"}`: current positions and whether a move runs.
    Read,
    /// `{"op":"move",...}`: go to a posture in `duration_s`; answered once reached.
    Move {
        /// Target of each named joint (rad); joints not named keep their positions.
        positions_rad: BTreeMap<String, f64>,
        /// Duration of the move (s, finite, >= 0).
        duration_s: f64,
    },
    /// `{"op":"stop"}`: halt any move in progress.
    Stop,
}

impl Request {
    /// The request's name (`hello`, `read`, `move`, `stop`), for logs and errors.
    pub fn op(&self) -> &'static str {
        match self {
            Request::Hello => "hello",
            Request::Read => "read",
            Request::Move { .. } => "move",
            Request::Stop => "stop",
        }
    }

    /// Parse a request line (without its end of line); the error is the `bad_request`
    /// message a server answers with.
    pub fn parse(line: &str) -> Result<Self, String> {
        let v: Value = serde_json::from_str(line).map_err(|e| format!("not a JSON object: {e}"))?;
        let Some(op) = v.get("op").and_then(Value::as_str).map(str::to_string) else {
            return Err("a request is an object with a string \"op\"".into());
        };
        if !matches!(op.as_str(), "hello" | "read" | "move" | "stop") {
            return Err(format!(
                "unknown op {:?} (expected hello, read, move or stop)",
                op.chars().take(32).collect::<String>()
            ));
        }
        let r: Request = serde_json::from_value(v).map_err(|e| format!("bad {op} request: {e}"))?;
        if let Request::Move { duration_s, .. } = &r
            && !(duration_s.is_finite() && *duration_s >= 0.0)
        {
            return Err(format!(
                "duration_s = {duration_s} is not a finite number >= 0"
            ));
        }
        Ok(r)
    }

    /// The request's line, without the LF.
    pub fn text(&self) -> String {
        // A request holds only strings and numbers: serialisation cannot fail, but a
        // non-finite number becomes `null` (the server refuses it).
        serde_json::to_string(self).unwrap_or_else(|_| format!("{{\"op\":\"{}\"}}", self.op()))
    }
}

/// Error codes of the protocol.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ErrorCode {
    /// `unknown_joint`: a move names a joint the robot does not have.
    UnknownJoint,
    /// `out_of_limits`: a move target lies outside the joint's limits.
    OutOfLimits,
    /// `busy`: another move is running.
    Busy,
    /// `fault`: the controller failed, or the move was stopped.
    Fault,
    /// `bad_request`: the request is not one of the protocol.
    BadRequest,
    /// A code this version does not know (kept as sent).
    Other(String),
}

impl ErrorCode {
    /// The code as on the wire.
    pub fn as_str(&self) -> &str {
        match self {
            ErrorCode::UnknownJoint => "unknown_joint",
            ErrorCode::OutOfLimits => "out_of_limits",
            ErrorCode::Busy => "busy",
            ErrorCode::Fault => "fault",
            ErrorCode::BadRequest => "bad_request",
            ErrorCode::Other(s) => s,
        }
    }

    /// The code from the wire.
    pub fn parse(s: &str) -> Self {
        match s {
            "unknown_joint" => ErrorCode::UnknownJoint,
            "out_of_limits" => ErrorCode::OutOfLimits,
            "busy" => ErrorCode::Busy,
            "fault" => ErrorCode::Fault,
            "bad_request" => ErrorCode::BadRequest,
            other => ErrorCode::Other(other.to_string()),
        }
    }

    /// The number a driver reports in `DriverError::Device` (1..5 in the order above, 0 for
    /// an unknown code).
    pub fn number(&self) -> i64 {
        match self {
            ErrorCode::UnknownJoint => 1,
            ErrorCode::OutOfLimits => 2,
            ErrorCode::Busy => 3,
            ErrorCode::Fault => 4,
            ErrorCode::BadRequest => 5,
            ErrorCode::Other(_) => 0,
        }
    }
}

/// What `hello` says about the robot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Identity {
    /// Protocol name and version (`calibd-joints/1`).
    pub protocol: String,
    /// Robot name.
    pub robot: String,
    /// Joint names in the robot's order.
    pub joints: Vec<String>,
    /// Limits `[lo, hi]` (rad) of each joint, same order.
    pub limits_rad: Vec<[f64; 2]>,
}

/// A reply from the joint interface.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// Reply to `hello`.
    Hello(Identity),
    /// Reply to `read`: positions (rad) and whether a move runs.
    State {
        /// Position of every joint (rad).
        positions_rad: BTreeMap<String, f64>,
        /// True while a move runs.
        moving: bool,
    },
    /// Reply to `move`: the posture was reached.
    Reached {
        /// Position of every joint once there (rad).
        positions_rad: BTreeMap<String, f64>,
    },
    /// Reply to `stop`: `{"ok":true}`.
    Done,
    /// The request failed.
    Error {
        /// What kind of failure.
        code: ErrorCode,
        /// The server's text.
        message: String,
    },
}

fn malformed(what: impl std::fmt::Display, line: &str) -> CodecError {
    CodecError::malformed(format!("{what} in {}", quote(line.as_bytes())))
}

fn positions(v: &Value, line: &str) -> Result<BTreeMap<String, f64>, CodecError> {
    let Some(m) = v.as_object() else {
        return Err(malformed("positions_rad is not an object", line));
    };
    m.iter()
        .map(|(k, v)| match v.as_f64() {
            Some(x) if x.is_finite() => Ok((k.clone(), x)),
            _ => Err(malformed(
                format!("position of {k:?} is not a number"),
                line,
            )),
        })
        .collect()
}

impl Reply {
    /// Parse a reply line (without its end of line); errors say what is wrong.
    pub fn parse(line: &str) -> Result<Self, CodecError> {
        let v: Value = serde_json::from_str(line).map_err(|e| malformed(e, line))?;
        let Some(o) = v.as_object() else {
            return Err(malformed("a reply is a JSON object", line));
        };
        match o.get("ok").and_then(Value::as_bool) {
            None => Err(malformed("a reply needs a boolean \"ok\"", line)),
            Some(false) => {
                let e = o.get("error").and_then(Value::as_object);
                let code = e.and_then(|e| e.get("code")).and_then(Value::as_str);
                let message = e.and_then(|e| e.get("message")).and_then(Value::as_str);
                match (code, message) {
                    (Some(c), m) => Ok(Reply::Error {
                        code: ErrorCode::parse(c),
                        message: m.unwrap_or_default().to_string(),
                    }),
                    (None, _) => Err(malformed("an error reply needs error.code", line)),
                }
            }
            Some(true) if o.contains_key("protocol") => {
                let id: Identity =
                    serde_json::from_value(v.clone()).map_err(|e| malformed(e, line))?;
                if id.joints.len() != id.limits_rad.len() {
                    return Err(malformed(
                        format!(
                            "{} joints but {} limits",
                            id.joints.len(),
                            id.limits_rad.len()
                        ),
                        line,
                    ));
                }
                if let Some(k) = id
                    .limits_rad
                    .iter()
                    .position(|[lo, hi]| !(lo.is_finite() && hi.is_finite() && lo <= hi))
                {
                    return Err(malformed(
                        format!(
                            "limits of {:?} are not [lo, hi] with lo <= hi",
                            id.joints[k]
                        ),
                        line,
                    ));
                }
                Ok(Reply::Hello(id))
            }
            Some(true) => match o.get("positions_rad") {
                None => Ok(Reply::Done),
                Some(p) => {
                    let positions_rad = positions(p, line)?;
                    match o.get("moving") {
                        None => Ok(Reply::Reached { positions_rad }),
                        Some(Value::Bool(moving)) => Ok(Reply::State {
                            positions_rad,
                            moving: *moving,
                        }),
                        Some(_) => Err(malformed("moving is not a boolean", line)),
                    }
                }
            },
        }
    }

    /// The reply as a JSON value.
    pub fn to_json(&self) -> Value {
        let map = |p: &BTreeMap<String, f64>| {
            Value::Object(p.iter().map(|(k, v)| (k.clone(), json!(v))).collect())
        };
        match self {
            Reply::Hello(id) => json!({
                "ok": true,
                "protocol": id.protocol,
                "robot": id.robot,
                "joints": id.joints,
                "limits_rad": id.limits_rad,
            }),
            Reply::State {
                positions_rad,
                moving,
            } => json!({"ok": true, "positions_rad": map(positions_rad), "moving": moving}),
            Reply::Reached { positions_rad } => {
                json!({"ok": true, "positions_rad": map(positions_rad)})
            }
            Reply::Done => json!({"ok": true}),
            Reply::Error { code, message } => json!({
                "ok": false,
                "error": {"code": code.as_str(), "message": message},
            }),
        }
    }

    /// The reply's line, without the LF.
    pub fn text(&self) -> String {
        self.to_json().to_string()
    }
}

/// Split one LF-terminated UTF-8 line off `src` (client side: anything else is an error).
fn line(src: &mut BytesMut) -> Result<Option<String>, CodecError> {
    let Some(p) = src.iter().position(|b| *b == b'\n') else {
        if src.len() >= MAX_LINE {
            return Err(CodecError::malformed(format!(
                "no LF within {MAX_LINE} bytes: {}",
                quote(src)
            )));
        }
        return Ok(None);
    };
    let raw = src.split_to(p + 1);
    if raw.len() > MAX_LINE {
        return Err(CodecError::malformed(format!(
            "line of {} bytes, longer than {MAX_LINE}: {}",
            raw.len(),
            quote(&raw)
        )));
    }
    let body = raw[..p].strip_suffix(b"\r").unwrap_or(&raw[..p]);
    match std::str::from_utf8(body) {
        Ok(s) => Ok(Some(s.to_string())),
        Err(_) => Err(CodecError::malformed(format!(
            "line is not UTF-8: {}",
            quote(&raw)
        ))),
    }
}

/// Client side: encodes requests, decodes typed replies.
#[derive(Debug, Clone, Copy, Default)]
pub struct JointsCodec;

impl Decoder for JointsCodec {
    type Item = Reply;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Reply>, CodecError> {
        match line(src)? {
            Some(l) => Reply::parse(&l).map(Some),
            None => Ok(None),
        }
    }
}

impl Encoder<Request> for JointsCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Request, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(item.text().as_bytes());
        dst.put_u8(b'\n');
        Ok(())
    }
}

/// One request line as the server sees it.
#[derive(Debug, Clone, PartialEq)]
pub enum Incoming {
    /// A request of the protocol.
    Request(Request),
    /// A line that is not one: the `bad_request` message to answer with.
    Bad(String),
}

/// Server side (the mock): decodes request lines (a bad line becomes [`Incoming::Bad`], an
/// over-long one is skipped up to its LF), encodes replies. Only I/O errors are errors.
#[derive(Debug, Clone, Copy, Default)]
pub struct ServerCodec {
    /// Skipping the rest of an over-long line.
    discarding: bool,
}

impl Decoder for ServerCodec {
    type Item = Incoming;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Incoming>, CodecError> {
        loop {
            let lf = src.iter().position(|b| *b == b'\n');
            if self.discarding {
                match lf {
                    Some(p) => {
                        let _ = src.split_to(p + 1);
                        self.discarding = false;
                        continue;
                    }
                    None => {
                        src.clear();
                        return Ok(None);
                    }
                }
            }
            let Some(p) = lf else {
                if src.len() >= MAX_LINE {
                    src.clear();
                    self.discarding = true;
                    return Ok(Some(too_long()));
                }
                return Ok(None);
            };
            let raw = src.split_to(p + 1);
            if raw.len() > MAX_LINE {
                return Ok(Some(too_long()));
            }
            let body = raw[..p].strip_suffix(b"\r").unwrap_or(&raw[..p]);
            if body.iter().all(u8::is_ascii_whitespace) {
                continue; // blank lines are ignored
            }
            return Ok(Some(match std::str::from_utf8(body) {
                Ok(s) => match Request::parse(s) {
                    Ok(r) => Incoming::Request(r),
                    Err(m) => Incoming::Bad(m),
                },
                Err(_) => Incoming::Bad("line is not UTF-8".into()),
            }));
        }
    }
}

fn too_long() -> Incoming {
    Incoming::Bad(format!("line longer than {MAX_LINE} bytes"))
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

    fn decode_all<D: Decoder>(c: &mut D, b: &mut BytesMut) -> Vec<Result<D::Item, String>>
    where
        D::Error: std::fmt::Display,
    {
        let mut out = Vec::new();
        loop {
            match c.decode(b) {
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

    fn pos(p: &[(&str, f64)]) -> BTreeMap<String, f64> {
        p.iter().map(|(k, v)| (k.to_string(), *v)).collect()
    }

    #[test]
    fn coalesced_reply_lines_parse_to_typed_replies() {
        let mut b = BytesMut::from(
            concat!(
                "{\"ok\":true,\"protocol\":\"calibd-joints/1\",\"robot\":\"talos\",\"joints\":[\"a\",\"b\"],\"limits_rad\":[[-1.5,1.5],[0,2]]}\n",
                "{\"ok\":true,\"positions_rad\":{\"a\":0.25,\"b\":1e-3},\"moving\":true}\r\n",
                "{\"ok\":true,\"positions_rad\":{\"a\":-0.5,\"b\":1}}\n",
                "{\"ok\":true}\n",
                "{\"ok\":false,\"error\":{\"code\":\"out_of_limits\",\"message\":\"a = 2 rad\"}}\n",
                "{\"ok\":false,\"error\":{\"code\":\"melted\",\"message\":\"?\"}}\n",
            )
            .as_bytes(),
        );
        let r = decode_all(&mut JointsCodec, &mut b);
        assert_eq!(
            r,
            vec![
                Ok(Reply::Hello(Identity {
                    protocol: "calibd-joints/1".into(),
                    robot: "talos".into(),
                    joints: vec!["a".into(), "b".into()],
                    limits_rad: vec![[-1.5, 1.5], [0.0, 2.0]],
                })),
                Ok(Reply::State {
                    positions_rad: pos(&[("a", 0.25), ("b", 1e-3)]),
                    moving: true
                }),
                Ok(Reply::Reached {
                    positions_rad: pos(&[("a", -0.5), ("b", 1.0)])
                }),
                Ok(Reply::Done),
                Ok(Reply::Error {
                    code: ErrorCode::OutOfLimits,
                    message: "a = 2 rad".into()
                }),
                Ok(Reply::Error {
                    code: ErrorCode::Other("melted".into()),
                    message: "?".into()
                }),
            ]
        );
        assert!(b.is_empty());
    }

    #[test]
    fn a_reply_split_across_reads_waits_for_its_lf() {
        let whole =
            b"{\"ok\":true,\"positions_rad\":{\"arm_left_1_joint\":0.125},\"moving\":false}\n";
        for cut in [1, 10, 40, whole.len() - 1] {
            let mut c = JointsCodec;
            let mut b = BytesMut::from(&whole[..cut]);
            assert_eq!(c.decode(&mut b).expect("partial"), None, "cut {cut}");
            b.extend_from_slice(&whole[cut..]);
            assert_eq!(
                c.decode(&mut b).expect("whole"),
                Some(Reply::State {
                    positions_rad: pos(&[("arm_left_1_joint", 0.125)]),
                    moving: false
                })
            );
            assert!(b.is_empty());
        }
    }

    #[test]
    fn bad_reply_lines_are_errors_that_say_why() {
        let e = |bytes: &[u8]| match decode_all(&mut JointsCodec, &mut BytesMut::from(bytes)).pop()
        {
            Some(Err(e)) => e,
            other => panic!("expected an error for {bytes:?}, got {other:?}"),
        };
        assert!(e(b"{\"ok\":tru\n").contains("malformed"));
        assert!(e(b"[1,2]\n").contains("JSON object"));
        assert!(e(b"{\"positions_rad\":{}}\n").contains("\"ok\""));
        assert!(e(b"{\"ok\":false}\n").contains("error.code"));
        assert!(e(b"{\"ok\":true,\"positions_rad\":{\"a\":\"x\"}}\n").contains("\"a\""));
        assert!(e(b"{\"ok\":true,\"positions_rad\":[1]}\n").contains("not an object"));
        assert!(e(b"{\"ok\":true,\"positions_rad\":{},\"moving\":1}\n").contains("moving"));
        assert!(
            e(b"{\"ok\":true,\"protocol\":\"p\",\"robot\":\"r\",\"joints\":[\"a\"],\"limits_rad\":[]}\n")
                .contains("1 joints but 0 limits")
        );
        assert!(
            e(b"{\"ok\":true,\"protocol\":\"p\",\"robot\":\"r\",\"joints\":[\"a\"],\"limits_rad\":[[2,1]]}\n")
                .contains("lo <= hi")
        );
        assert!(e(b"{\"ok\":true,\"protocol\":7}\n").contains("malformed"));
        assert!(e(b"\xff\xfe\x00garbage\r\n").contains("UTF-8"));
        assert!(e(&vec![b' '; MAX_LINE]).contains("no LF"));
        let mut long = vec![b' '; MAX_LINE + 5];
        long.push(b'\n');
        assert!(e(&long).contains("longer than"));
    }

    #[test]
    fn server_reads_requests_and_answers_bad_lines_without_failing() {
        let mut c = ServerCodec::default();
        let mut b = BytesMut::from(
            concat!(
                "{\"op\":\"hello\"}\n",
                "\n",
                "{\"op\":\"move\",\"positions_rad\":{\"a\":0.5},\"duration_s\":1.5}\r\n",
                "{\"op\":\"dance\"}\n",
                "{\"op\":\"move\",\"positions_rad\":{\"a\":0.5}}\n",
                "{\"op\":\"move\",\"positions_rad\":{\"a\":0.5},\"duration_s\":-1}\n",
                "not json\n",
                "{\"op\":\"stop\"}\n",
                "{\"op\":\"re",
            )
            .as_bytes(),
        );
        let r: Vec<Incoming> = decode_all(&mut c, &mut b)
            .into_iter()
            .map(|r| r.expect("server decoding never fails"))
            .collect();
        let bad = |i: &Incoming, what: &str| match i {
            Incoming::Bad(m) => assert!(m.contains(what), "{m:?} lacks {what:?}"),
            other => panic!("expected a bad line, got {other:?}"),
        };
        assert_eq!(r.len(), 7, "{r:?}");
        assert_eq!(r[0], Incoming::Request(Request::Hello));
        assert_eq!(
            r[1],
            Incoming::Request(Request::Move {
                positions_rad: pos(&[("a", 0.5)]),
                duration_s: 1.5
            })
        );
        bad(&r[2], "unknown op \"dance\"");
        bad(&r[3], "duration_s");
        bad(&r[4], "duration_s");
        bad(&r[5], "not a JSON object");
        assert_eq!(r[6], Incoming::Request(Request::Stop));
        // The rest of a split request arrives later.
        b.extend_from_slice(b"ad\"}\n");
        assert_eq!(
            c.decode(&mut b).expect("decodes"),
            Some(Incoming::Request(Request::Read))
        );
    }

    #[test]
    fn server_skips_an_over_long_line_once_and_reads_on() {
        let mut c = ServerCodec::default();
        let mut b = BytesMut::from(&vec![b'x'; MAX_LINE + 10][..]);
        assert!(matches!(c.decode(&mut b), Ok(Some(Incoming::Bad(m))) if m.contains("longer")));
        assert!(b.is_empty());
        // More of the same line, then its end and a good request.
        b.extend_from_slice(&[b'y'; 1000]);
        assert_eq!(c.decode(&mut b).expect("discarding"), None);
        b.extend_from_slice(b"yyy\n{\"op\":\"read\"}\n");
        assert_eq!(
            c.decode(&mut b).expect("decodes"),
            Some(Incoming::Request(Request::Read))
        );
        // A whole over-long line in one read is one bad request too.
        let mut long = vec![b'z'; MAX_LINE + 1];
        long.extend_from_slice(b"\n{\"op\":\"stop\"}\n");
        let mut b = BytesMut::from(&long[..]);
        assert!(matches!(c.decode(&mut b), Ok(Some(Incoming::Bad(_)))));
        assert_eq!(
            c.decode(&mut b).expect("decodes"),
            Some(Incoming::Request(Request::Stop))
        );
        // Arbitrary bytes never panic.
        let mut b = BytesMut::from(&b"\xff\xfe\x00\n\x00\x01{\n}}\"\n{\"op\":null}\n"[..]);
        let r = decode_all(&mut c, &mut b);
        assert_eq!(r.len(), 4);
        assert!(r.iter().all(|i| matches!(i, Ok(Incoming::Bad(_)))), "{r:?}");
    }

    #[test]
    fn requests_and_replies_round_trip_through_their_lines() {
        let m = Request::Move {
            positions_rad: pos(&[("b", 1.0), ("a", -0.25)]),
            duration_s: 1.0,
        };
        let mut b = BytesMut::new();
        JointsCodec.encode(m.clone(), &mut b).expect("encode");
        assert_eq!(
            &b[..],
            b"{\"op\":\"move\",\"positions_rad\":{\"a\":-0.25,\"b\":1.0},\"duration_s\":1.0}\n"
        );
        assert_eq!(
            ServerCodec::default().decode(&mut b).expect("decode"),
            Some(Incoming::Request(m))
        );
        for (r, text) in [
            (Request::Hello, "{\"op\":\"hello\"}"),
            (Request::Read, "{\"op\":\"read\"}"),
            (Request::Stop, "{\"op\":\"stop\"}"),
        ] {
            assert_eq!(r.text(), text);
            assert_eq!(Request::parse(text), Ok(r));
        }
        for reply in [
            Reply::Hello(Identity {
                protocol: "calibd-joints/1".into(),
                robot: "r".into(),
                joints: vec!["j".into()],
                limits_rad: vec![[-0.1, 1.234_567_890_123]],
            }),
            Reply::State {
                positions_rad: pos(&[("j", 1e-9)]),
                moving: false,
            },
            Reply::Reached {
                positions_rad: pos(&[("j", -3.0)]),
            },
            Reply::Done,
            Reply::Error {
                code: ErrorCode::Busy,
                message: "moving".into(),
            },
        ] {
            let mut b = BytesMut::new();
            ServerCodec::default()
                .encode(reply.clone(), &mut b)
                .expect("encode");
            assert_eq!(JointsCodec.decode(&mut b).expect("decode"), Some(reply));
        }
        assert_eq!(Reply::Done.text(), "{\"ok\":true}");
    }
}
