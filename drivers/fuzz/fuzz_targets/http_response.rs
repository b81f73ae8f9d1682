//! HTTP/1.1 response and request codecs (RWS) and the Digest challenge parser.
#![no_main]
use bytes::BytesMut;
use calibd_drivers::rws::{digest, http};
use libfuzzer_sys::fuzz_target;
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    let mut b = BytesMut::from(data);
    while let Ok(Some(_)) = http::HttpClientCodec.decode(&mut b) {}
    let mut b = BytesMut::from(data);
    while let Ok(Some(_)) = http::HttpServerCodec.decode(&mut b) {}
    if let Ok(s) = std::str::from_utf8(data) {
        let _ = digest::Challenge::parse(s);
        let _ = digest::verify(s, "GET", "r", "u", "p");
        let _ = http::parse_form(s);
    }
});
