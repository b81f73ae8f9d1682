//! QTM parameters XML parsers (3D and General).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = std::str::from_utf8(data) {
        let _ = calibd_drivers::qtm::params::parse_3d(s);
        let _ = calibd_drivers::qtm::params::parse_general(s);
    }
});
