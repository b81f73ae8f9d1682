//! Transcript (JSON lines) parser used by replay mode.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = std::str::from_utf8(data) {
        let _ = calibd_drivers::Transcript::parse(s);
    }
});
