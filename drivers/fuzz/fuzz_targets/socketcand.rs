//! socketcand message codec and frame/send parsers.
#![no_main]
use bytes::BytesMut;
use calibd_drivers::can::socketcand::{parse_frame, parse_send, SocketcandCodec};
use libfuzzer_sys::fuzz_target;
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    let mut b = BytesMut::from(data);
    while let Ok(Some(w)) = SocketcandCodec.decode(&mut b) {
        let _ = parse_frame(&w);
        let _ = parse_send(&w);
    }
});
