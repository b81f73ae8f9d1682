//! U-WAVE CR-line codec.
#![no_main]
use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    let mut b = BytesMut::from(data);
    let mut c = calibd_drivers::uwave::UwaveCodec;
    while let Ok(Some(_)) = c.decode(&mut b) {}
});
