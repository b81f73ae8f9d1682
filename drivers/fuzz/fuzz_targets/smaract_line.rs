//! SmarAct line codec and MCS reply parser.
#![no_main]
use bytes::BytesMut;
use calibd_drivers::smaract::{mcs::parse_reply, LineCodec};
use libfuzzer_sys::fuzz_target;
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    let mut b = BytesMut::from(data);
    let mut c = LineCodec::default();
    while let Ok(Some(l)) = c.decode(&mut b) {
        let _ = parse_reply(&l);
    }
});
