//! U-WAVE CR-line codec, and the RI1 receiver-info parser on every RI1 line.
#![no_main]
use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    let mut b = BytesMut::from(data);
    let mut c = calibd_drivers::uwave::UwaveCodec::default();
    while let Ok(Some(l)) = c.decode(&mut b) {
        if let calibd_drivers::uwave::UwaveLine::ReceiverInfo { raw } = l {
            let _ = calibd_drivers::uwave::ReceiverInfo::parse(&raw);
        }
    }
});
