//! The transcript format: recorded device traffic, one JSON object per line, used by every
//! device for recording (drivers tee to it) and replay (mocks serve from it).
//!
//! Format (see `drivers/TRANSCRIPTS.md`): lines starting with `#` are comments; the first
//! object may be a header `{"format":"calibd-transcript/1","device":"qtm",...}`; every other
//! line is a chunk `{"t_us":1200,"dir":"d2c","hex":"0900000006000000 01"}` with `dir` `c2d`
//! (client to device) or `d2c` (device to client), an optional `"udp":true` for datagrams and
//! an optional `"text"` (ignored, for reading). Chunks keep the TCP splitting as recorded.

use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Write};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use serde::{Deserialize, Serialize};

/// Format tag written in the header line.
pub const FORMAT: &str = "calibd-transcript/1";

/// Direction of a chunk of bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Direction {
    /// From the client (driver) to the device.
    #[serde(rename = "c2d")]
    ToDevice,
    /// From the device to the client.
    #[serde(rename = "d2c")]
    FromDevice,
}

/// One recorded chunk of bytes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Chunk {
    /// Microseconds since the start of the recording.
    pub t_us: u64,
    /// Who sent the bytes.
    pub dir: Direction,
    /// The bytes as hex (spaces allowed when reading).
    pub hex: String,
    /// True for a UDP datagram (one chunk = one datagram).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub udp: bool,
    /// Printable rendering of the bytes, for humans only (ignored when reading).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub text: Option<String>,
}

impl Chunk {
    /// Builds a chunk from bytes (fills `text` when the bytes are mostly printable).
    pub fn new(t_us: u64, dir: Direction, bytes: &[u8], udp: bool) -> Self {
        let printable = bytes
            .iter()
            .filter(|b| b.is_ascii_graphic() || **b == b' ')
            .count();
        let text = (!bytes.is_empty() && printable * 10 >= bytes.len() * 8)
            .then(|| bytes.escape_ascii().to_string());
        Chunk {
            t_us,
            dir,
            hex: to_hex(bytes),
            udp,
            text,
        }
    }

    /// Decodes the hex payload.
    pub fn bytes(&self) -> Result<Vec<u8>, TranscriptError> {
        from_hex(&self.hex).ok_or_else(|| TranscriptError::Hex {
            hex: self.hex.chars().take(40).collect(),
        })
    }
}

/// Header line of a transcript.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// Always [`FORMAT`].
    pub format: String,
    /// Device family (`qtm`, `abb`, `uwave`, `mcs`, `mcs2`, `can`, `microscope`, `joints`).
    pub device: String,
    /// Free text: where and how it was recorded.
    #[serde(default)]
    pub note: String,
}

/// A whole transcript in memory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transcript {
    /// Header, if the file had one.
    pub header: Option<Header>,
    /// Chunks in file order.
    pub chunks: Vec<Chunk>,
}

/// Error reading a transcript.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TranscriptError {
    /// The file could not be read.
    #[error("transcript: i/o: {0}")]
    Io(#[from] io::Error),
    /// A line is not valid JSON of the expected shape.
    #[error("transcript: line {line}: {detail}")]
    Line {
        /// 1-based line number.
        line: usize,
        /// Parser message.
        detail: String,
    },
    /// A `hex` field is not hex.
    #[error("transcript: invalid hex payload starting {hex:?}")]
    Hex {
        /// Start of the bad field.
        hex: String,
    },
}

impl Transcript {
    /// Parses transcript text.
    pub fn parse(text: &str) -> Result<Self, TranscriptError> {
        let mut header = None;
        let mut chunks = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let l = line.trim();
            if l.is_empty() || l.starts_with('#') {
                continue;
            }
            let v: serde_json::Value =
                serde_json::from_str(l).map_err(|e| TranscriptError::Line {
                    line: i + 1,
                    detail: e.to_string(),
                })?;
            let bad = |e: serde_json::Error| TranscriptError::Line {
                line: i + 1,
                detail: e.to_string(),
            };
            if v.get("format").is_some() {
                header = Some(serde_json::from_value(v).map_err(bad)?);
            } else {
                let c: Chunk = serde_json::from_value(v).map_err(bad)?;
                c.bytes().map_err(|_| TranscriptError::Line {
                    line: i + 1,
                    detail: "field hex is not an even number of hex digits".into(),
                })?;
                chunks.push(c);
            }
        }
        Ok(Transcript { header, chunks })
    }

    /// Reads and parses a transcript file.
    pub fn load(path: &Path) -> Result<Self, TranscriptError> {
        let mut text = String::new();
        for line in BufReader::new(File::open(path)?).lines() {
            text.push_str(&line?);
            text.push('\n');
        }
        Self::parse(&text)
    }

    /// All bytes in one direction (TCP only), concatenated.
    pub fn stream(&self, dir: Direction) -> Vec<u8> {
        self.chunks
            .iter()
            .filter(|c| c.dir == dir && !c.udp)
            .flat_map(|c| c.bytes().unwrap_or_default())
            .collect()
    }
}

/// Appends chunks to a transcript file; cheap to clone and share between tasks.
#[derive(Debug, Clone)]
pub struct Recorder {
    inner: Arc<Mutex<RecorderInner>>,
}

#[derive(Debug)]
struct RecorderInner {
    out: Box<dyn WriteDebug>,
    start: Instant,
}

trait WriteDebug: Write + Send + std::fmt::Debug {}
impl<T: Write + Send + std::fmt::Debug> WriteDebug for T {}

impl Recorder {
    /// Creates `path` and writes the header line.
    pub fn create(path: &Path, device: &str, note: &str) -> io::Result<Self> {
        let f = BufWriter::new(File::create(path)?);
        Self::to_writer(f, device, note)
    }

    /// Records into any writer (tests use a `Vec<u8>` behind a shared buffer).
    pub fn to_writer(
        mut out: impl Write + Send + std::fmt::Debug + 'static,
        device: &str,
        note: &str,
    ) -> io::Result<Self> {
        let h = Header {
            format: FORMAT.into(),
            device: device.into(),
            note: note.into(),
        };
        writeln!(
            out,
            "{}",
            serde_json::to_string(&h).map_err(io::Error::other)?
        )?;
        out.flush()?;
        Ok(Recorder {
            inner: Arc::new(Mutex::new(RecorderInner {
                out: Box::new(out),
                start: Instant::now(),
            })),
        })
    }

    /// Appends one chunk, stamped with the time since the recorder was created.
    pub fn record(&self, dir: Direction, bytes: &[u8], udp: bool) {
        if bytes.is_empty() {
            return;
        }
        let Ok(mut g) = self.inner.lock() else { return };
        let t_us = g.start.elapsed().as_micros() as u64;
        let c = Chunk::new(t_us, dir, bytes, udp);
        if let Ok(line) = serde_json::to_string(&c) {
            // Recording is best effort: a full disk must not stop the instrument.
            let _ = writeln!(g.out, "{line}").and_then(|_| g.out.flush());
        }
    }
}

/// Lower-case hex without separators.
pub fn to_hex(b: &[u8]) -> String {
    const D: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(b.len() * 2);
    for x in b {
        s.push(D[(x >> 4) as usize] as char);
        s.push(D[(x & 15) as usize] as char);
    }
    s
}

/// Parses hex, ignoring ASCII whitespace; `None` if not an even count of hex digits.
pub fn from_hex(s: &str) -> Option<Vec<u8>> {
    let digits: Vec<u8> = s
        .bytes()
        .filter(|b| !b.is_ascii_whitespace())
        .map(|b| (b as char).to_digit(16).map(|d| d as u8))
        .collect::<Option<_>>()?;
    if !digits.len().is_multiple_of(2) {
        return None;
    }
    Some(digits.chunks(2).map(|p| p[0] << 4 | p[1]).collect())
}

#[cfg(test)]
mod tests {
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
    fn bad_lines_are_reported_with_line_number() {
        let e =
            Transcript::parse("# c\n{\"t_us\":0,\"dir\":\"c2d\",\"hex\":\"abc\"}\n").unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
        let e = Transcript::parse("{\"t_us\":0,\"dir\":\"up\",\"hex\":\"00\"}").unwrap_err();
        assert!(e.to_string().contains("line 1"), "{e}");
        assert_eq!(from_hex("0a 0B"), Some(vec![10, 11]));
        assert_eq!(from_hex("0g"), None);
    }
}
