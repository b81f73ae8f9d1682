//! QTM RT stream codec and datagram decoder: never panic, never loop.
#![no_main]
use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    let _ = calibd_drivers::qtm::packet::decode_whole(data);
    let mut b = BytesMut::from(data);
    let mut c = calibd_drivers::qtm::QtmCodec;
    while let Ok(Some(_)) = c.decode(&mut b) {}
});
