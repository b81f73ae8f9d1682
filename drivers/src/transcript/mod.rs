//! The transcript format: recorded device traffic, one JSON object per line, used by every
//! device for recording (drivers tee to it) and replay (mocks serve from it).
//!
//! Format (see `drivers/TRANSCRIPTS.md`): lines starting with `#` are comments; the first
//! object may be a header `{"format":"calibd-transcript/1","device":"qtm",...}`; every other
//! line is a chunk `{"t_us":1200,"dir":"d2c","hex":"0900000006000000 01"}` with `dir` `c2d`
//! (client to device) or `d2c` (device to client), an optional `"udp":true` for datagrams and
//! an optional `"text"` (ignored, for reading). Chunks keep the TCP splitting as recorded.
//! A lab recording also tags each chunk with its connection (`"conn":0`, `1`, ... in the order
//! the driver opened them) and masks HTTP `Authorization` values (`"redacted":[[from,to]]`,
//! the bytes replaced by `*`), so no credential is written and replay skips those bytes.

use std::fs::File;
use std::io::{self, BufWriter, Write};
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
    /// Connection the chunk belongs to (0 = the first the recorder saw); absent in
    /// transcripts of one connection.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub conn: Option<u32>,
    /// Byte ranges `[from, to)` of the payload masked when recording (credentials): their
    /// bytes are `*` and replay does not compare them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub redacted: Vec<[usize; 2]>,
    /// 1-based line of the file the chunk was read from (0 when not read from a file).
    #[serde(skip)]
    pub line: usize,
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
            conn: None,
            redacted: Vec::new(),
            line: 0,
        }
    }

    /// True when `got` is what this chunk recorded: ASCII case ignored, redacted bytes
    /// skipped. `None` when equal, else the first differing byte offset.
    pub fn first_difference(&self, recorded: &[u8], got: &[u8]) -> Option<usize> {
        let masked = |i: usize| self.redacted.iter().any(|[a, b]| (*a..*b).contains(&i));
        let n = recorded.len().max(got.len());
        (0..n).find(|&i| match (recorded.get(i), got.get(i)) {
            (Some(r), Some(g)) => !masked(i) && !r.eq_ignore_ascii_case(g),
            _ => true,
        })
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

/// One parsed line.
enum Line {
    Header(Header),
    Chunk(Box<Chunk>),
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
    /// Parses transcript text. A last line without its newline whose JSON ends early is
    /// dropped: it is what a recorder killed mid-write leaves.
    pub fn parse(text: &str) -> Result<Self, TranscriptError> {
        let mut header = None;
        let mut chunks = Vec::new();
        let lines: Vec<&str> = text.lines().collect();
        let cut = !text.is_empty() && !text.ends_with('\n');
        for (i, line) in lines.iter().enumerate() {
            let unfinished = || {
                serde_json::from_str::<serde_json::Value>(line.trim()).is_err_and(|e| e.is_eof())
            };
            if cut && i + 1 == lines.len() && unfinished() {
                break;
            }
            match Self::parse_line(line, i)? {
                Some(Line::Header(h)) => header = Some(h),
                Some(Line::Chunk(c)) => chunks.push(*c),
                None => {}
            }
        }
        Ok(Transcript { header, chunks })
    }

    /// One line of a transcript (`i` 0-based): nothing for blanks and comments.
    fn parse_line(line: &str, i: usize) -> Result<Option<Line>, TranscriptError> {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            return Ok(None);
        }
        let bad = |e: serde_json::Error| TranscriptError::Line {
            line: i + 1,
            detail: e.to_string(),
        };
        let v: serde_json::Value = serde_json::from_str(l).map_err(bad)?;
        if v.get("format").is_some() {
            return Ok(Some(Line::Header(serde_json::from_value(v).map_err(bad)?)));
        }
        let mut c: Chunk = serde_json::from_value(v).map_err(bad)?;
        c.bytes().map_err(|_| TranscriptError::Line {
            line: i + 1,
            detail: "field hex is not an even number of hex digits".into(),
        })?;
        c.line = i + 1;
        Ok(Some(Line::Chunk(Box::new(c))))
    }

    /// Reads and parses a transcript file.
    pub fn load(path: &Path) -> Result<Self, TranscriptError> {
        Self::parse(&std::fs::read_to_string(path)?)
    }

    /// True when the chunks carry connection numbers (a lab recording).
    pub fn has_connections(&self) -> bool {
        self.chunks.iter().any(|c| c.conn.is_some())
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
    /// The connection this handle records (see [`Recorder::connection`]).
    conn: Option<u32>,
}

#[derive(Debug)]
struct RecorderInner {
    out: Box<dyn WriteDebug>,
    start: Instant,
    /// Connections handed out so far.
    connections: u32,
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
                connections: 0,
            })),
            conn: None,
        })
    }

    /// A handle for the next connection to the device: its chunks carry that connection's
    /// number (0, 1, ...), so replay serves each reconnection what it got when recorded.
    pub fn connection(&self) -> Recorder {
        let conn = self.inner.lock().ok().map(|mut g| {
            g.connections += 1;
            g.connections - 1
        });
        Recorder {
            inner: self.inner.clone(),
            conn,
        }
    }

    /// Appends one chunk, stamped with the time since the recorder was created.
    pub fn record(&self, dir: Direction, bytes: &[u8], udp: bool) {
        if bytes.is_empty() {
            return;
        }
        let Ok(mut g) = self.inner.lock() else { return };
        let t_us = g.start.elapsed().as_micros() as u64;
        let mut c = if dir == Direction::ToDevice {
            let (masked, redacted) = redact(bytes);
            let mut c = Chunk::new(t_us, dir, &masked, udp);
            c.redacted = redacted;
            c
        } else {
            Chunk::new(t_us, dir, bytes, udp)
        };
        c.conn = self.conn;
        if let Ok(line) = serde_json::to_string(&c) {
            // Recording is best effort: a full disk must not stop the instrument.
            let _ = writeln!(g.out, "{line}").and_then(|_| g.out.flush());
        }
    }
}

/// The bytes with every HTTP `Authorization` header value replaced by `*` (same length,
/// so replay still counts bytes), and the masked ranges.
fn redact(bytes: &[u8]) -> (Vec<u8>, Vec<[usize; 2]>) {
    const NAME: &[u8] = b"authorization:";
    let mut out = bytes.to_vec();
    let mut ranges = Vec::new();
    let mut i = 0;
    while i + NAME.len() <= bytes.len() {
        let line_start = i == 0 || bytes[i - 1] == b'\n';
        if line_start && bytes[i..i + NAME.len()].eq_ignore_ascii_case(NAME) {
            let mut from = i + NAME.len();
            while bytes.get(from) == Some(&b' ') {
                from += 1;
            }
            let to = bytes[from..]
                .iter()
                .position(|b| *b == b'\r' || *b == b'\n')
                .map_or(bytes.len(), |p| from + p);
            out[from..to].fill(b'*');
            if to > from {
                ranges.push([from, to]);
            }
            i = to;
        } else {
            i += 1;
        }
    }
    (out, ranges)
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
mod tests;
