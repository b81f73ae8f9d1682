//! U-WAVE API v1 line codec: CR-terminated ASCII lines `DT1`, `ST1`, `TI1`, `RI1`
//! (devices.md §2). The channel comes before the value, so parsing is positional.

use bytes::{Buf, BufMut, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

use crate::error::{CodecError, quote};

/// Longest line we accept before declaring the stream garbage.
const MAX_LINE: usize = 128;

/// Unit letter at the end of a `DT1` line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    /// `M`: millimetres.
    Millimetre,
    /// `I`: inches.
    Inch,
    /// `0`: no unit (counter, ...).
    None,
}

impl Unit {
    /// Factor that converts a value in this unit to millimetres (1 for no unit).
    pub fn to_mm(self) -> f64 {
        match self {
            Unit::Inch => 25.4,
            _ => 1.0,
        }
    }

    fn letter(self) -> char {
        match self {
            Unit::Millimetre => 'M',
            Unit::Inch => 'I',
            Unit::None => '0',
        }
    }
}

/// One parsed receiver line.
#[derive(Debug, Clone, PartialEq)]
pub enum UwaveLine {
    /// `DT1`: a measurement from one transmitter.
    Data {
        /// Group number (00-99).
        group: u8,
        /// Channel number (00-99).
        channel: u8,
        /// Measured value in `unit`.
        value: f64,
        /// Unit of `value`.
        unit: Unit,
        /// Decimal places as sent (resolution of the value).
        decimals: u8,
    },
    /// `ST1`: status or alarm; `None` fields were `FF`/`F…F` (not applicable).
    Status {
        /// Group, if applicable.
        group: Option<u8>,
        /// Channel, if applicable.
        channel: Option<u8>,
        /// 10-digit transmitter id, if applicable.
        transmitter: Option<String>,
        /// Status code (00 battery low, 01 not responding, ... 50, 51, 99).
        code: u8,
    },
    /// `TI1`: transmitter info reply.
    TransmitterInfo {
        /// State 0-5 (2 = connected).
        state: u8,
        /// Channel.
        channel: u8,
        /// Group.
        group: u8,
        /// Transmitter id.
        transmitter: String,
        /// Radio band 11-25.
        band: u8,
        /// 0 button mode, 1 event mode.
        mode: u8,
    },
    /// `RI1`: receiver info reply, kept raw so that a line of another layout does not break
    /// the stream; [`ReceiverInfo::parse`] reads it.
    ReceiverInfo {
        /// The text after `RI1`.
        raw: String,
    },
}

impl UwaveLine {
    /// Renders the line as the receiver sends it (without CR).
    pub fn render(&self) -> String {
        match self {
            UwaveLine::Data {
                group,
                channel,
                value,
                unit,
                decimals,
            } => {
                let sign = if *value < 0.0 { '-' } else { '+' };
                let d = *decimals as usize;
                let width = 11usize.max(d + 2);
                format!(
                    "DT1{group:02}{channel:02}{sign}{:0width$.d$}{}",
                    value.abs(),
                    unit.letter()
                )
            }
            UwaveLine::Status {
                group,
                channel,
                transmitter,
                code,
            } => format!(
                "ST1{}{}{}{code:02}",
                group.map_or("FF".to_string(), |g| format!("{g:02}")),
                channel.map_or("FF".to_string(), |c| format!("{c:02}")),
                transmitter.clone().unwrap_or_else(|| "F".repeat(10)),
            ),
            UwaveLine::TransmitterInfo {
                state,
                channel,
                group,
                transmitter,
                band,
                mode,
            } => format!("TI1{state}{channel:02}{group:02}{transmitter}{band:02}{mode}"),
            UwaveLine::ReceiverInfo { raw } => format!("RI1{raw}"),
        }
    }
}

fn two(s: &str, what: &str, line: &str) -> Result<u8, CodecError> {
    s.parse::<u8>()
        .map_err(|_| CodecError::malformed(format!("{what} {s:?} not two digits in {line:?}")))
}

fn opt_two(s: &str, what: &str, line: &str) -> Result<Option<u8>, CodecError> {
    if s == "FF" {
        Ok(None)
    } else {
        two(s, what, line).map(Some)
    }
}

/// Parses one line (without its CR).
pub fn parse_line(line: &str) -> Result<UwaveLine, CodecError> {
    let bad = |what: &str| CodecError::malformed(format!("{what} in U-WAVE line {line:?}"));
    if !line.is_ascii() {
        return Err(bad("non-ASCII byte"));
    }
    let (kind, rest) = line.split_at(line.len().min(3));
    match kind {
        "DT1" => {
            if rest.len() < 8 {
                return Err(bad("DT1 line too short"));
            }
            let group = two(&rest[0..2], "group", line)?;
            let channel = two(&rest[2..4], "channel", line)?;
            let body = &rest[4..];
            let (num, unit) = body.split_at(body.len() - 1);
            let unit = match unit {
                "M" => Unit::Millimetre,
                "I" => Unit::Inch,
                "0" => Unit::None,
                _ => return Err(bad("unknown unit letter")),
            };
            let digits = &num[1..];
            if !(num.starts_with('+') || num.starts_with('-'))
                || digits.is_empty()
                || !digits.bytes().all(|b| b.is_ascii_digit() || b == b'.')
                || digits.bytes().filter(|b| *b == b'.').count() > 1
            {
                return Err(bad("value is not a signed decimal"));
            }
            let decimals = digits.split_once('.').map_or(0, |(_, f)| f.len()) as u8;
            let value: f64 = num.parse().map_err(|_| bad("value is not a number"))?;
            Ok(UwaveLine::Data {
                group,
                channel,
                value,
                unit,
                decimals,
            })
        }
        "ST1" => {
            // Layout gg cc id(10) ss; real captures also show shorter ids, so the id is
            // whatever lies between the channel and the 2-digit code.
            if rest.len() < 6 {
                return Err(bad("ST1 line too short"));
            }
            let id = &rest[4..rest.len() - 2];
            let transmitter = if id.bytes().all(|b| b == b'F') {
                None
            } else if id.bytes().all(|b| b.is_ascii_hexdigit()) {
                Some(id.to_string())
            } else {
                return Err(bad("transmitter id not hex"));
            };
            Ok(UwaveLine::Status {
                group: opt_two(&rest[0..2], "group", line)?,
                channel: opt_two(&rest[2..4], "channel", line)?,
                transmitter,
                code: two(&rest[rest.len() - 2..], "status code", line)?,
            })
        }
        "TI1" => {
            if rest.len() != 18 {
                return Err(bad("TI1 line is not 21 characters"));
            }
            let state = two(&rest[0..1], "state", line)?;
            Ok(UwaveLine::TransmitterInfo {
                state,
                channel: two(&rest[1..3], "channel", line)?,
                group: two(&rest[3..5], "group", line)?,
                transmitter: rest[5..15].to_string(),
                band: two(&rest[15..17], "band", line)?,
                mode: two(&rest[17..18], "mode", line)?,
            })
        }
        "RI1" => Ok(UwaveLine::ReceiverInfo {
            raw: rest.to_string(),
        }),
        _ => Err(bad("unknown line type")),
    }
}

/// A parsed `RI1` receiver-info line: `RI1` gg rrrrrrrrrr bb l d + 16 3-digit noise values
/// (devices.md §2, U-WAVE API v1). The layout names `l` and `d` without saying what they
/// mean, so they are kept as sent.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ReceiverInfo {
    /// Receiver group (00-99).
    pub group: u8,
    /// 10-digit receiver id.
    pub receiver_id: String,
    /// Radio band (11-25).
    pub band: u8,
    /// The `l` character of the layout, as sent.
    pub l: char,
    /// The `d` character of the layout, as sent.
    pub d: char,
    /// The 16 noise values (3 digits each, raw receiver units), one per band slot.
    pub noise_raw: Vec<u16>,
}

impl ReceiverInfo {
    /// Length of the text after `RI1`: 2 + 10 + 2 + 1 + 1 + 16 * 3.
    pub const LEN: usize = 64;

    /// Parses the text after `RI1` (see [`UwaveLine::ReceiverInfo`]).
    pub fn parse(raw: &str) -> Result<Self, CodecError> {
        let bad = |what: &str| CodecError::malformed(format!("{what} in RI1 line {raw:?}"));
        if !raw.is_ascii() {
            return Err(bad("non-ASCII byte"));
        }
        if raw.len() != Self::LEN {
            return Err(bad(&format!(
                "{} characters after RI1, not {}",
                raw.len(),
                Self::LEN
            )));
        }
        let digits = |s: &str, what: &str| -> Result<u16, CodecError> {
            if s.bytes().all(|b| b.is_ascii_digit()) {
                s.parse().map_err(|_| bad(what))
            } else {
                Err(bad(&format!("{what} {s:?} not digits")))
            }
        };
        let receiver_id = &raw[2..12];
        if !receiver_id.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(bad("receiver id not hex"));
        }
        let ch = |i: usize| char::from(raw.as_bytes()[i]);
        let noise_raw = (0..16)
            .map(|i| digits(&raw[16 + 3 * i..19 + 3 * i], "noise value"))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(ReceiverInfo {
            group: two(&raw[0..2], "group", raw)?,
            receiver_id: receiver_id.to_string(),
            band: two(&raw[12..14], "band", raw)?,
            l: ch(14),
            d: ch(15),
            noise_raw,
        })
    }

    /// Renders the text after `RI1` (the inverse of [`ReceiverInfo::parse`] for valid values).
    pub fn render(&self) -> String {
        let noise: String = self.noise_raw.iter().map(|n| format!("{n:03}")).collect();
        format!(
            "{:02}{}{:02}{}{}{noise}",
            self.group, self.receiver_id, self.band, self.l, self.d
        )
    }
}

/// Codec for the receiver side of the port: decodes CR-terminated lines, encodes raw
/// request bytes (the caller includes the CR, since the request bytes are configuration).
///
/// A port opened while the receiver streams starts mid-line (`0000006.452M\r`): the first
/// line after an open is dropped when it does not parse, whatever it holds. From the second
/// line on, a line that does not parse is an error. Each connection starts from
/// `UwaveCodec::default()` (the link clones the codec it was given for every open).
#[derive(Debug, Clone, Copy, Default)]
pub struct UwaveCodec {
    /// A first complete line has been seen since the port was opened.
    synced: bool,
}

impl Decoder for UwaveCodec {
    type Item = UwaveLine;
    type Error = CodecError;

    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<UwaveLine>, CodecError> {
        loop {
            // A stray LF (CRLF from a terminal server) is skipped, not an error.
            while src.first() == Some(&b'\n') {
                src.advance(1);
            }
            let Some(pos) = src.iter().position(|b| *b == b'\r') else {
                if src.len() > MAX_LINE {
                    return Err(CodecError::malformed(format!(
                        "no CR within {MAX_LINE} bytes: {}",
                        quote(src)
                    )));
                }
                return Ok(None);
            };
            let line = src.split_to(pos + 1);
            let first = !std::mem::replace(&mut self.synced, true);
            let text = match std::str::from_utf8(&line[..pos]) {
                Ok(t) => t,
                Err(_) if first => continue,
                Err(_) => {
                    return Err(CodecError::malformed(format!(
                        "non-UTF-8 line {}",
                        quote(&line)
                    )));
                }
            };
            if text.is_empty() {
                continue;
            }
            match parse_line(text) {
                // The tail of a line sent before the port was opened.
                Err(_) if first => continue,
                parsed => return parsed.map(Some),
            }
        }
    }
}

impl Encoder<Vec<u8>> for UwaveCodec {
    type Error = CodecError;
    fn encode(&mut self, item: Vec<u8>, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(&item);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(bytes: &[u8]) -> Vec<Result<UwaveLine, String>> {
        let mut c = UwaveCodec::default();
        let mut b = BytesMut::from(bytes);
        let mut out = Vec::new();
        loop {
            match c.decode(&mut b) {
                Ok(Some(l)) => out.push(Ok(l)),
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
    fn a_port_opened_mid_line_drops_the_fragment_then_parses() {
        // Opened while the receiver streamed: the tail of a DT1 line comes first.
        let r = decode_all(b"0000006.452M\rDT10001+0000006.453M\rDT10001+0000006.454M\r");
        assert_eq!(r.len(), 2, "{r:?}");
        assert!(matches!(r[0], Ok(UwaveLine::Data { value, .. }) if value == 6.453));
        // Non-UTF-8 noise of the open is a fragment too.
        let r = decode_all(b"\xff\xfe5M\rDT10001+0000006.453M\r");
        assert_eq!(r.len(), 1, "{r:?}");
        // A complete first line is kept; after it, a bad line is an error, not skipped.
        let r = decode_all(b"DT10001+0000006.453M\r0000006.452M\r");
        assert!(r[0].is_ok());
        assert!(
            r[1].as_ref()
                .is_err_and(|e| e.contains("unknown line type")),
            "{r:?}"
        );
    }

    #[test]
    fn real_captured_data_lines() {
        let r = decode_all(b"DT10000+00000011.88M\rDT10002-0000000.001M\r");
        assert_eq!(
            r[0],
            Ok(UwaveLine::Data {
                group: 0,
                channel: 0,
                value: 11.88,
                unit: Unit::Millimetre,
                decimals: 2
            })
        );
        assert_eq!(
            r[1],
            Ok(UwaveLine::Data {
                group: 0,
                channel: 2,
                value: -0.001,
                unit: Unit::Millimetre,
                decimals: 3
            })
        );
    }

    #[test]
    fn status_and_info_lines() {
        let r = decode_all(b"ST1000100009233899\rST1FFFFFFFFFFFFFF51\rTI1201000000012345151\r");
        assert_eq!(
            r[0],
            Ok(UwaveLine::Status {
                group: Some(0),
                channel: Some(1),
                transmitter: Some("000092338".into()),
                code: 99
            })
        );
        assert_eq!(
            r[1],
            Ok(UwaveLine::Status {
                group: None,
                channel: None,
                transmitter: None,
                code: 51
            })
        );
        match &r[2] {
            Ok(UwaveLine::TransmitterInfo {
                state: 2,
                channel: 1,
                group: 0,
                band: 15,
                mode: 1,
                ..
            }) => {}
            other => panic!("unexpected {other:?}"),
        }
    }

    #[test]
    fn receiver_info_line() {
        // RI1, group 00, receiver 0000123456, band 15, l 0, d 1, 16 noise values.
        let line = b"RI10000001234561501012008015003000000000000000000000000000000000099\r";
        let r = decode_all(line);
        let Ok(UwaveLine::ReceiverInfo { raw }) = &r[0] else {
            panic!("{r:?}")
        };
        let info = ReceiverInfo::parse(raw).unwrap();
        assert_eq!(info.group, 0);
        assert_eq!(info.receiver_id, "0000123456");
        assert_eq!(info.band, 15);
        assert_eq!((info.l, info.d), ('0', '1'));
        assert_eq!(info.noise_raw.len(), 16);
        assert_eq!(&info.noise_raw[..4], &[12, 8, 15, 3]);
        assert_eq!(info.noise_raw[15], 99);
        assert_eq!(info.render(), *raw);
        // One character short (an older mock's line), a letter in a noise value, non-hex id.
        assert!(ReceiverInfo::parse(&raw[1..]).is_err());
        let mut bad = raw.clone();
        bad.replace_range(20..21, "x");
        assert!(ReceiverInfo::parse(&bad).is_err());
        let mut bad = raw.clone();
        bad.replace_range(2..3, "Z");
        assert!(ReceiverInfo::parse(&bad).is_err());
    }

    #[test]
    fn render_round_trips() {
        for l in [
            "DT10000+00000011.88M",
            "DT10002-0000000.001M",
            "ST1000100009233899",
            "ST1FFFFFFFFFFFFFF51",
            "TI1201000000012345151",
        ] {
            assert_eq!(parse_line(l).unwrap().render(), l);
        }
    }

    #[test]
    fn partial_line_waits_and_garbage_fails() {
        let mut c = UwaveCodec::default();
        let mut b = BytesMut::from(&b"DT10000+0000"[..]);
        assert!(matches!(c.decode(&mut b), Ok(None)));
        b.extend_from_slice(b"0011.88M\r");
        assert!(matches!(c.decode(&mut b), Ok(Some(UwaveLine::Data { .. }))));
        // Garbage after a first good line (a first line that does not parse is dropped as
        // the fragment of an open: see a_port_opened_mid_line_drops_the_fragment_then_parses).
        let r = decode_all(b"DT10000+00000011.88M\rXX1 hello\r");
        assert!(
            r[1].as_ref()
                .is_err_and(|e| e.contains("unknown line type"))
        );
        let r = decode_all(b"DT10000+00000011.88M\rDT10000+00abc011.88M\r");
        assert!(r[1].is_err());
        let r = decode_all(b"DT10000+00000011.88M\rDT1000+1.0Q\r");
        assert!(r[1].is_err());
        let r = decode_all(&[b'D'; 200]);
        assert!(r[0].as_ref().is_err_and(|e| e.contains("no CR")));
        // The naive "first number" bug: the channel must never be read as the value.
        let Ok(UwaveLine::Data { value, .. }) = parse_line("DT10000+00000011.88M") else {
            panic!()
        };
        assert!((value - 11.88).abs() < 1e-12);
    }

    #[test]
    fn random_bytes_never_panic() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..2000 {
            let mut v = Vec::new();
            for _ in 0..(state % 40) {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                v.push(b"DTSI1+-.0123456789MF\r\n\xff"[(state % 23) as usize]);
            }
            let _ = decode_all(&v);
        }
    }
}
