//! QTM 3D parameters XML parser.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = std::str::from_utf8(data) {
        let _ = calibd_drivers::qtm::params::parse_3d(s);
    }
});
