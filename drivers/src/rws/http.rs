//! A small HTTP/1.1 codec (no TLS, no dependencies): enough for RWS 1.0 on a controller's
//! LAN port. Requests and responses with `Content-Length` bodies; chunked response bodies
//! are decoded too. Used by the RWS driver (client side) and the RWS mock (server side).

use bytes::{Buf, BufMut, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

use crate::error::{CodecError, quote};

/// Largest head (start line + headers) accepted.
const MAX_HEAD: usize = 64 * 1024;
/// Largest body accepted.
const MAX_BODY: usize = 16 * 1024 * 1024;

/// An HTTP request.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Request {
    /// Method, e.g. `GET`.
    pub method: String,
    /// Request target (path and query), e.g. `/rw/panel/ctrlstate?json=1`.
    pub target: String,
    /// Headers in order.
    pub headers: Vec<(String, String)>,
    /// Body bytes.
    pub body: Vec<u8>,
}

/// An HTTP response.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Response {
    /// Status code.
    pub status: u16,
    /// Reason phrase.
    pub reason: String,
    /// Headers in order.
    pub headers: Vec<(String, String)>,
    /// Body bytes (de-chunked).
    pub body: Vec<u8>,
}

/// Case-insensitive header lookup shared by requests and responses.
pub trait Headers {
    /// All headers.
    fn headers(&self) -> &[(String, String)];
    /// First value of header `name`.
    fn header(&self, name: &str) -> Option<&str> {
        self.headers()
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
    /// All values of header `name`.
    fn header_all<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a str> + 'a {
        self.headers()
            .iter()
            .filter(move |(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
}

impl Headers for Request {
    fn headers(&self) -> &[(String, String)] {
        &self.headers
    }
}

impl Headers for Response {
    fn headers(&self) -> &[(String, String)] {
        &self.headers
    }
}

struct Head {
    start: [String; 3],
    headers: Vec<(String, String)>,
    len: usize,
}

/// Parses the head if complete: `Ok(None)` when more bytes are needed.
fn parse_head(src: &[u8]) -> Result<Option<Head>, CodecError> {
    let Some(end) = src.windows(4).position(|w| w == b"\r\n\r\n") else {
        if src.len() > MAX_HEAD {
            return Err(CodecError::malformed("HTTP head longer than 64 KiB"));
        }
        // Fail early on bytes that cannot start an HTTP message.
        if let Some(b) = src
            .iter()
            .take(16)
            .find(|b| !(b.is_ascii_graphic() || **b == b' ' || **b == b'\r' || **b == b'\n'))
        {
            return Err(CodecError::malformed(format!(
                "byte {b:#04x} in HTTP head {}",
                quote(src)
            )));
        }
        return Ok(None);
    };
    let text = std::str::from_utf8(&src[..end]).map_err(|_| {
        CodecError::malformed(format!("non-UTF-8 HTTP head {}", quote(&src[..end])))
    })?;
    let mut lines = text.split("\r\n");
    let first = lines.next().unwrap_or_default();
    let mut parts = first.splitn(3, ' ');
    let start = [
        parts.next().unwrap_or_default().to_string(),
        parts.next().unwrap_or_default().to_string(),
        parts.next().unwrap_or_default().to_string(),
    ];
    if start[1].is_empty() {
        return Err(CodecError::malformed(format!(
            "bad HTTP start line {first:?}"
        )));
    }
    let mut headers = Vec::new();
    for l in lines {
        let (k, v) = l
            .split_once(':')
            .ok_or_else(|| CodecError::malformed(format!("bad HTTP header line {l:?}")))?;
        headers.push((k.trim().to_string(), v.trim().to_string()));
    }
    Ok(Some(Head {
        start,
        headers,
        len: end + 4,
    }))
}

fn content_length(headers: &[(String, String)]) -> Result<Option<usize>, CodecError> {
    match headers
        .iter()
        .find(|(k, _)| k.eq_ignore_ascii_case("content-length"))
    {
        None => Ok(None),
        Some((_, v)) => v
            .parse::<usize>()
            .ok()
            .filter(|n| *n <= MAX_BODY)
            .map(Some)
            .ok_or_else(|| CodecError::malformed(format!("bad Content-Length {v:?}"))),
    }
}

/// Decodes a chunked body starting at `src[0]`: `(body, bytes consumed)` when complete.
fn dechunk(src: &[u8]) -> Result<Option<(Vec<u8>, usize)>, CodecError> {
    let mut pos = 0;
    let mut body = Vec::new();
    loop {
        let Some(eol) = src[pos..].windows(2).position(|w| w == b"\r\n") else {
            return Ok(None);
        };
        let line = std::str::from_utf8(&src[pos..pos + eol]).unwrap_or("?");
        let size_hex = line.split(';').next().unwrap_or("").trim();
        let size = usize::from_str_radix(size_hex, 16)
            .map_err(|_| CodecError::malformed(format!("bad chunk size line {line:?}")))?;
        if size > MAX_BODY - body.len() {
            return Err(CodecError::malformed("chunked body too large"));
        }
        pos += eol + 2;
        if size == 0 {
            // Skip trailers up to the empty line.
            return match src[pos..].windows(2).position(|w| w == b"\r\n") {
                Some(0) => Ok(Some((body, pos + 2))),
                Some(_) => match src[pos..].windows(4).position(|w| w == b"\r\n\r\n") {
                    Some(e) => Ok(Some((body, pos + e + 4))),
                    None => Ok(None),
                },
                None => Ok(None),
            };
        }
        if src.len() < pos + size + 2 {
            return Ok(None);
        }
        body.extend_from_slice(&src[pos..pos + size]);
        pos += size + 2;
    }
}

/// Client side: encodes requests, decodes responses.
#[derive(Debug, Clone, Copy, Default)]
pub struct HttpClientCodec;

impl Decoder for HttpClientCodec {
    type Item = Response;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Response>, CodecError> {
        let Some(h) = parse_head(src)? else {
            return Ok(None);
        };
        if !h.start[0].starts_with("HTTP/1.") {
            return Err(CodecError::malformed(format!(
                "not an HTTP response: {}",
                quote(src)
            )));
        }
        let status: u16 = h.start[1]
            .parse()
            .map_err(|_| CodecError::malformed(format!("bad status code {:?}", h.start[1])))?;
        let chunked = h.headers.iter().any(|(k, v)| {
            k.eq_ignore_ascii_case("transfer-encoding")
                && v.to_ascii_lowercase().contains("chunked")
        });
        let (body, used) = if status == 204 || status == 304 || (100..200).contains(&status) {
            (Vec::new(), 0)
        } else if chunked {
            match dechunk(&src[h.len..])? {
                Some(x) => x,
                None => return Ok(None),
            }
        } else {
            let n = content_length(&h.headers)?.unwrap_or(0);
            if src.len() < h.len + n {
                return Ok(None);
            }
            (src[h.len..h.len + n].to_vec(), n)
        };
        src.advance(h.len + used);
        let [_, _, reason] = h.start;
        Ok(Some(Response {
            status,
            reason,
            headers: h.headers,
            body,
        }))
    }
}

impl Encoder<Request> for HttpClientCodec {
    type Error = CodecError;
    fn encode(&mut self, r: Request, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(format!("{} {} HTTP/1.1\r\n", r.method, r.target).as_bytes());
        for (k, v) in &r.headers {
            dst.put_slice(format!("{k}: {v}\r\n").as_bytes());
        }
        dst.put_slice(format!("Content-Length: {}\r\n\r\n", r.body.len()).as_bytes());
        dst.put_slice(&r.body);
        Ok(())
    }
}

/// Server side: decodes requests, encodes responses.
#[derive(Debug, Clone, Copy, Default)]
pub struct HttpServerCodec;

impl Decoder for HttpServerCodec {
    type Item = Request;
    type Error = CodecError;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Request>, CodecError> {
        let Some(h) = parse_head(src)? else {
            return Ok(None);
        };
        if !h.start[2].starts_with("HTTP/1.") {
            return Err(CodecError::malformed(format!(
                "not an HTTP request: {}",
                quote(src)
            )));
        }
        let n = content_length(&h.headers)?.unwrap_or(0);
        if src.len() < h.len + n {
            return Ok(None);
        }
        let body = src[h.len..h.len + n].to_vec();
        src.advance(h.len + n);
        let [method, target, _] = h.start;
        Ok(Some(Request {
            method,
            target,
            headers: h.headers,
            body,
        }))
    }
}

impl Encoder<Response> for HttpServerCodec {
    type Error = CodecError;
    fn encode(&mut self, r: Response, dst: &mut BytesMut) -> Result<(), CodecError> {
        dst.put_slice(format!("HTTP/1.1 {} {}\r\n", r.status, r.reason).as_bytes());
        for (k, v) in &r.headers {
            dst.put_slice(format!("{k}: {v}\r\n").as_bytes());
        }
        dst.put_slice(format!("Content-Length: {}\r\n\r\n", r.body.len()).as_bytes());
        dst.put_slice(&r.body);
        Ok(())
    }
}

/// Decodes `application/x-www-form-urlencoded` text into pairs.
pub fn parse_form(body: &str) -> Vec<(String, String)> {
    body.split('&')
        .filter(|p| !p.is_empty())
        .map(|p| {
            let (k, v) = p.split_once('=').unwrap_or((p, ""));
            (url_decode(k), url_decode(v))
        })
        .collect()
}

/// Percent-decodes (and `+` → space); invalid escapes are kept literally.
pub fn url_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'+' => out.push(b' '),
            b'%' if i + 2 < b.len() => {
                match u8::from_str_radix(std::str::from_utf8(&b[i + 1..i + 3]).unwrap_or("zz"), 16)
                {
                    Ok(v) => {
                        out.push(v);
                        i += 2;
                    }
                    Err(_) => out.push(b'%'),
                }
            }
            c => out.push(c),
        }
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Percent-encodes a form value.
pub fn url_encode(s: &str) -> String {
    let mut out = String::new();
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b"-_.~".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn response_with_length_chunked_and_partial() {
        let raw = b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: 2\r\n\r\n{}HTTP/1.1 204 No Content\r\n\r\n";
        let mut b = BytesMut::from(&raw[..20]);
        assert!(matches!(HttpClientCodec.decode(&mut b), Ok(None)));
        let mut b = BytesMut::from(&raw[..]);
        let r = HttpClientCodec.decode(&mut b).unwrap().unwrap();
        assert_eq!((r.status, r.body.as_slice()), (200, &b"{}"[..]));
        assert_eq!(r.header("content-type"), Some("application/json"));
        assert_eq!(HttpClientCodec.decode(&mut b).unwrap().unwrap().status, 204);
        let ch = b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n4\r\nWiki\r\n5\r\npedia\r\n0\r\n\r\n";
        let mut b = BytesMut::from(&ch[..ch.len() - 3]);
        assert!(matches!(HttpClientCodec.decode(&mut b), Ok(None)));
        let mut b = BytesMut::from(&ch[..]);
        assert_eq!(
            HttpClientCodec.decode(&mut b).unwrap().unwrap().body,
            b"Wikipedia"
        );
        let huge = b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\nffffffffffffffff\r\nx";
        assert!(
            HttpClientCodec
                .decode(&mut BytesMut::from(&huge[..]))
                .is_err()
        );
        assert!(b.is_empty());
    }

    #[test]
    fn request_round_trip_and_garbage() {
        let req = Request {
            method: "POST".into(),
            target: "/rw/rapid/symbol/data/RAPID/T_ROB1/calib_cmd?action=set&json=1".into(),
            headers: vec![("Host".into(), "robot".into())],
            body: b"value=7".to_vec(),
        };
        let mut b = BytesMut::new();
        HttpClientCodec.encode(req.clone(), &mut b).unwrap();
        let mut got = HttpServerCodec.decode(&mut b).unwrap().unwrap();
        got.headers.retain(|(k, _)| k != "Content-Length");
        assert_eq!(got, req);
        let mut g = BytesMut::from(&b"\xff\xfe\x00garbage<<>>"[..]);
        assert!(HttpClientCodec.decode(&mut g).is_err());
        let mut g = BytesMut::from(&b"SSH-2.0-OpenSSH\r\n\r\n"[..]);
        assert!(HttpClientCodec.decode(&mut g).is_err());
        let mut g = BytesMut::from(&b"HTTP/1.1 200 OK\r\nContent-Length: x\r\n\r\n"[..]);
        assert!(HttpClientCodec.decode(&mut g).is_err());
    }

    #[test]
    fn form_decoding() {
        let f = parse_form("value=%5B%5B10%2C0%5D%2C%5B9E9%5D%5D&x=a+b");
        assert_eq!(f[0], ("value".into(), "[[10,0],[9E9]]".into()));
        assert_eq!(f[1].1, "a b");
        assert_eq!(url_decode(&url_encode("[[1,2],\"x\"]")), "[[1,2],\"x\"]");
        assert_eq!(url_decode("100%"), "100%");
    }
}
