//! The `calibd-frames/1` wire format: typed requests and replies, a client codec (encodes
//! [`Request`], decodes [`Reply`] with its pixel payload) and a server codec for the mock.

use bytes::{Buf, BufMut, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

use crate::error::{CodecError, quote};

/// Longest line of the protocol, LF included.
pub const MAX_LINE: usize = 128;
/// Largest width or height of a frame (px).
pub const MAX_SIDE: u32 = 16384;

/// A request from the client.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request {
    /// `ID?`.
    Id,
    /// `SET <exposure_us> <frame_rate_hz>`.
    Set {
        /// Exposure time (us).
        exposure_us: f64,
        /// Frame rate (Hz).
        frame_rate_hz: f64,
    },
    /// `FRAME?`: a fresh frame.
    Frame,
}

impl Request {
    /// The request's line, without the LF.
    pub fn text(&self) -> String {
        match self {
            Request::Id => "ID?".into(),
            Request::Set {
                exposure_us,
                frame_rate_hz,
            } => format!("SET {exposure_us} {frame_rate_hz}"),
            Request::Frame => "FRAME?".into(),
        }
    }

    /// Parse a request line; `None` when it is not one.
    pub fn parse(line: &str) -> Option<Self> {
        let f: Vec<&str> = line.split_ascii_whitespace().collect();
        match f.as_slice() {
            ["ID?"] => Some(Request::Id),
            ["FRAME?"] => Some(Request::Frame),
            ["SET", e, r] => {
                let (e, r) = (e.parse::<f64>().ok()?, r.parse::<f64>().ok()?);
                (e > 0.0 && r > 0.0 && e.is_finite() && r.is_finite()).then_some(Request::Set {
                    exposure_us: e,
                    frame_rate_hz: r,
                })
            }
            _ => None,
        }
    }
}

/// One camera frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Frame counter.
    pub seq: u64,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Bits per pixel (1..=16).
    pub bit_depth: u8,
    /// Exposure of this frame (us).
    pub exposure_us: f64,
    /// Row-major pixel values below 2^bit_depth.
    pub pixels: Vec<u16>,
}

impl Frame {
    /// Bytes per pixel on the wire.
    fn bytes_per_pixel(bit_depth: u8) -> usize {
        if bit_depth <= 8 { 1 } else { 2 }
    }

    /// The header line, without the LF.
    fn header(&self) -> String {
        format!(
            "FRAME {} {} {} {} {}",
            self.seq, self.width, self.height, self.bit_depth, self.exposure_us
        )
    }
}

/// A reply from the camera.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// `ID <text>`.
    Id(String),
    /// `OK`.
    Ok,
    /// `FRAME ...` and its pixels.
    Frame(Frame),
    /// `ERR <code> <text>`.
    Err {
        /// Error code (1 unknown request, 2 no frame, 3 busy, 4 internal, 5 settings refused).
        code: i64,
        /// The camera's text.
        text: String,
    },
}

impl Reply {
    /// The reply as bytes on the wire.
    pub fn wire(&self) -> Vec<u8> {
        let mut b = BytesMut::new();
        put_reply(self, &mut b);
        b.to_vec()
    }
}

fn put_reply(r: &Reply, dst: &mut BytesMut) {
    match r {
        Reply::Id(t) => dst.put_slice(format!("ID {t}\n").as_bytes()),
        Reply::Ok => dst.put_slice(b"OK\n"),
        Reply::Err { code, text } => dst.put_slice(format!("ERR {code} {text}\n").as_bytes()),
        Reply::Frame(f) => {
            dst.put_slice(f.header().as_bytes());
            dst.put_u8(b'\n');
            if Frame::bytes_per_pixel(f.bit_depth) == 1 {
                dst.extend(f.pixels.iter().map(|&p| p as u8));
            } else {
                dst.reserve(2 * f.pixels.len());
                for &p in &f.pixels {
                    dst.put_u16_le(p);
                }
            }
        }
    }
}

/// The header of a frame: (seq, width, height, bit depth, exposure).
fn frame_header(rest: &str, line: &str) -> Result<(u64, u32, u32, u8, f64), CodecError> {
    let f: Vec<&str> = rest.split_ascii_whitespace().collect();
    let bad = |what: &str| CodecError::malformed(format!("{what} in {line:?}"));
    let [seq, w, h, d, e] = f.as_slice() else {
        return Err(bad(&format!(
            "FRAME needs 5 fields (seq width height bit_depth exposure_us), got {}",
            f.len()
        )));
    };
    let seq = seq.parse::<u64>().map_err(|_| bad("seq is not a u64"))?;
    let side = |s: &str, name: &str| match s.parse::<u32>() {
        Ok(v) if (1..=MAX_SIDE).contains(&v) => Ok(v),
        _ => Err(bad(&format!("{name} = {s:?} is not in 1..={MAX_SIDE}"))),
    };
    let (w, h) = (side(w, "width")?, side(h, "height")?);
    let d = match d.parse::<u8>() {
        Ok(v) if (1..=16).contains(&v) => v,
        _ => return Err(bad(&format!("bit_depth = {d:?} is not in 1..=16"))),
    };
    let e = match e.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => v,
        _ => {
            return Err(bad(&format!(
                "exposure_us = {e:?} is not a finite number >= 0"
            )));
        }
    };
    Ok((seq, w, h, d, e))
}

/// The first line of `src` (without CR/LF) and its length with the LF, if complete.
fn peek_line(src: &BytesMut) -> Result<Option<(String, usize)>, CodecError> {
    let Some(p) = src.iter().take(MAX_LINE).position(|b| *b == b'\n') else {
        if src.len() >= MAX_LINE {
            return Err(CodecError::malformed(format!(
                "no LF within {MAX_LINE} bytes: {}",
                quote(src)
            )));
        }
        return Ok(None);
    };
    let body = src[..p].strip_suffix(b"\r").unwrap_or(&src[..p]);
    if !body.iter().all(|b| (0x20..0x7f).contains(b)) {
        return Err(CodecError::malformed(format!(
            "not a printable line: {}",
            quote(&src[..=p])
        )));
    }
    Ok(Some((String::from_utf8_lossy(body).into_owned(), p + 1)))
}

/// Client side: encodes requests, decodes typed replies (a frame once all its pixels came).
#[derive(Debug, Clone, Copy, Default)]
pub struct CameraCodec;

impl Decoder for CameraCodec {
    type Item = Reply;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Reply>, CodecError> {
        let Some((line, n)) = peek_line(src)? else {
            return Ok(None);
        };
        let (head, rest) = line.split_once(' ').unwrap_or((&line, ""));
        let reply = match head {
            "ID" => Reply::Id(rest.to_string()),
            "OK" if rest.is_empty() => Reply::Ok,
            "ERR" => {
                let (code, text) = rest.split_once(' ').unwrap_or((rest, ""));
                let code = code.parse::<i64>().map_err(|_| {
                    CodecError::malformed(format!(
                        "error code {code:?} is not an integer in {line:?}"
                    ))
                })?;
                Reply::Err {
                    code,
                    text: text.to_string(),
                }
            }
            "FRAME" => {
                let (seq, width, height, bit_depth, exposure_us) = frame_header(rest, &line)?;
                let count = width as usize * height as usize;
                let len = count * Frame::bytes_per_pixel(bit_depth);
                if src.len() < n + len {
                    src.reserve(n + len - src.len());
                    return Ok(None);
                }
                src.advance(n);
                let raw = src.split_to(len);
                let pixels: Vec<u16> = if bit_depth <= 8 {
                    raw.iter().map(|&b| u16::from(b)).collect()
                } else {
                    raw.chunks_exact(2)
                        .map(|c| u16::from_le_bytes([c[0], c[1]]))
                        .collect()
                };
                let max = (1u32 << bit_depth) - 1;
                if let Some(i) = pixels.iter().position(|&p| u32::from(p) > max) {
                    return Err(CodecError::malformed(format!(
                        "pixel {i} = {} exceeds {bit_depth}-bit full scale {max}",
                        pixels[i]
                    )));
                }
                return Ok(Some(Reply::Frame(Frame {
                    seq,
                    width,
                    height,
                    bit_depth,
                    exposure_us,
                    pixels,
                })));
            }
            _ => {
                return Err(CodecError::malformed(format!(
                    "unknown reply {line:?} (expected ID, OK, FRAME or ERR)"
                )));
            }
        };
        src.advance(n);
        Ok(Some(reply))
    }
}

impl Encoder<Request> for CameraCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Request, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(item.text().as_bytes());
        dst.put_u8(b'\n');
        Ok(())
    }
}

/// Server side (the mock): decodes request lines, encodes replies.
#[derive(Debug, Clone, Copy, Default)]
pub struct ServerCodec;

impl Decoder for ServerCodec {
    type Item = String;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<String>, CodecError> {
        match peek_line(src) {
            Ok(Some((l, n))) => {
                src.advance(n);
                Ok(Some(l))
            }
            Ok(None) => Ok(None),
            Err(e) => {
                src.clear();
                Err(e)
            }
        }
    }
}

impl Encoder<Reply> for ServerCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Reply, dst: &mut BytesMut) -> Result<(), CodecError> {
        put_reply(&item, dst);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(bit_depth: u8) -> Frame {
        let max = (1u32 << bit_depth) - 1;
        Frame {
            seq: 7,
            width: 5,
            height: 3,
            bit_depth,
            exposure_us: 812.5,
            pixels: (0..15u32).map(|i| (i * 977 % (max + 1)) as u16).collect(),
        }
    }

    #[test]
    fn frames_of_8_and_16_bits_round_trip_even_when_split_across_reads() {
        for d in [8, 12, 16] {
            let f = frame(d);
            let wire = Reply::Frame(f.clone()).wire();
            let header = format!("FRAME 7 5 3 {d} 812.5\n");
            let bytes_per_pixel = if d <= 8 { 1 } else { 2 };
            assert_eq!(wire.len(), header.len() + 15 * bytes_per_pixel);
            assert_eq!(&wire[..header.len()], header.as_bytes());
            let mut c = CameraCodec;
            let mut b = BytesMut::new();
            // Byte by byte: nothing until the last pixel byte.
            for (i, byte) in wire.iter().enumerate() {
                b.put_u8(*byte);
                let r = c.decode(&mut b).expect("decode");
                if i + 1 < wire.len() {
                    assert_eq!(r, None, "early reply at byte {i}");
                } else {
                    assert_eq!(r, Some(Reply::Frame(f.clone())));
                }
            }
            assert!(b.is_empty());
        }
    }

    #[test]
    fn short_replies_and_requests_round_trip() {
        let mut b = BytesMut::new();
        for r in [
            Reply::Id("calibd-frames/1 mock".into()),
            Reply::Ok,
            Reply::Err {
                code: 2,
                text: "no frame".into(),
            },
        ] {
            ServerCodec.encode(r.clone(), &mut b).expect("encode");
            assert_eq!(CameraCodec.decode(&mut b).expect("decode"), Some(r));
        }
        for q in [
            Request::Id,
            Request::Frame,
            Request::Set {
                exposure_us: 800.0,
                frame_rate_hz: 25.5,
            },
        ] {
            CameraCodec.encode(q, &mut b).expect("encode");
            let line = ServerCodec.decode(&mut b).expect("decode").expect("line");
            assert_eq!(Request::parse(&line), Some(q));
        }
        assert_eq!(Request::parse("SET -1 10"), None);
        assert_eq!(Request::parse("FRAME"), None);
    }

    #[test]
    fn bad_headers_name_the_field() {
        let e = |s: &[u8]| {
            CameraCodec
                .decode(&mut BytesMut::from(s))
                .expect_err("malformed")
                .to_string()
        };
        assert!(e(b"FRAME 1 0 5 8 10\n").contains("width"));
        assert!(e(b"FRAME 1 5 99999 8 10\n").contains("height"));
        assert!(e(b"FRAME 1 5 5 17 10\n").contains("bit_depth"));
        assert!(e(b"FRAME 1 5 5 8 nan\n").contains("exposure_us"));
        assert!(e(b"FRAME 1 5 5 8\n").contains("5 fields"));
        assert!(e(b"HELLO\n").contains("unknown reply"));
        assert!(e(&[b'7'; 200]).contains("no LF"));
        // A 12-bit frame whose pixel is above 4095.
        let mut w = b"FRAME 1 1 1 12 5\n".to_vec();
        w.extend_from_slice(&5000u16.to_le_bytes());
        assert!(e(&w).contains("full scale"));
    }
}
